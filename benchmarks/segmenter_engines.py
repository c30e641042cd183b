"""The shipped segmenter networks' forward pass in ONNX Runtime (what runs) against OpenCV's ``cv2.dnn``.

For each shipped network, the input it gets for a 640x480 frame (its resize and layout), timed interleaved in
one process: ``cv2.dnn`` with 1 and 2 threads, ONNX Runtime with 1 and 2 threads (the shipped engine runs
``learned.ENGINE_THREADS``). Prints the medians, the ratios to ``cv2.dnn`` on one thread, the largest
difference of the logits between the two engines and the share of pixels whose sign (cable or not) differs.

With ``--segment``, the whole ``LearnedSegmenter.segment`` call instead (resize, block layout, forward pass,
threshold, mask back at the frame's size) for each shipped network on one and two threads, interleaved: the
time per 640x480 photo that ``dyndlo-vision segment`` spends in the network, and the figures the networks'
JSON and docs/segmentation.md quote.

    python benchmarks/segmenter_engines.py [--calls 60] [--out engines.json]
    python benchmarks/segmenter_engines.py --segment [--calls 40] [--out segment.json]
    python benchmarks/segmenter_engines.py --quick [--segment]   # one network, a few calls (a smoke test)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from typing import Any

import cv2
import numpy as np

from dyndlo_vision.tracking.learned import LearnedSegmenter, onnx_session
from dyndlo_vision.tracking.networks import SHIPPED_NAMES, onnx_bytes

HEIGHT, WIDTH = 480, 640


def compare(name: str, calls: int, rgb: np.ndarray) -> dict[str, Any]:
    """Interleaved timings (ms, medians after two warm-up calls) and the engines' agreement for ``name``."""
    onnx = onnx_bytes(name)
    x = LearnedSegmenter(onnx).network_input(rgb)
    dnn = cv2.dnn.readNetFromONNX(np.frombuffer(onnx, np.uint8))
    sessions = {threads: onnx_session(onnx, threads) for threads in (1, 2)}
    feed = sessions[1].get_inputs()[0].name

    def run_dnn(threads: int) -> np.ndarray:
        cv2.setNumThreads(threads)
        dnn.setInput(x)
        return np.asarray(dnn.forward(), np.float32)

    def run_ort(threads: int) -> np.ndarray:
        return np.asarray(sessions[threads].run(None, {feed: x})[0], np.float32)

    engines = {
        "cv2.dnn, 1 thread": lambda: run_dnn(1),
        "cv2.dnn, 2 threads": lambda: run_dnn(2),
        "onnxruntime, 1 thread": lambda: run_ort(1),
        "onnxruntime, 2 threads": lambda: run_ort(2),
    }
    times: dict[str, list[float]] = {k: [] for k in engines}
    outputs: dict[str, np.ndarray] = {}
    for _ in range(calls + 2):
        for key, run in engines.items():
            t0 = time.perf_counter()
            outputs[key] = run()
            times[key].append(1e3 * (time.perf_counter() - t0))
    cv2.setNumThreads(os.cpu_count() or 1)
    median = {k: float(np.median(v[2:])) for k, v in times.items()}
    a, b = outputs["cv2.dnn, 1 thread"], outputs["onnxruntime, 2 threads"]
    return {
        "input": list(x.shape),
        "ms": median,
        "vs_cv2_one_thread": {k: median["cv2.dnn, 1 thread"] / v for k, v in median.items()},
        "max_logit_difference": float(np.abs(a - b).max()),
        "sign_differs_share": float(np.mean((a > 0) != (b > 0))),
    }


def time_segment(names: list[str], calls: int, rgb: np.ndarray) -> dict[str, dict[str, float]]:
    """Median ms of ``LearnedSegmenter.segment(rgb)`` per network and thread count, after two warm-up
    calls, every segmenter called once per round so that all share the machine's state."""
    segmenters = {(name, threads): LearnedSegmenter(onnx_bytes(name), threads=threads)
                  for name in names for threads in (1, 2)}
    times: dict[tuple[str, int], list[float]] = {key: [] for key in segmenters}
    for _ in range(calls + 2):
        for key, segmenter in segmenters.items():
            t0 = time.perf_counter()
            segmenter.segment(rgb)
            times[key].append(1e3 * (time.perf_counter() - t0))
    label = {1: "1 thread", 2: "2 threads"}
    return {name: {label[threads]: float(np.median(times[(name, threads)][2:])) for threads in (1, 2)}
            for name in names}


def sample_frame() -> np.ndarray:
    """A 640x480 frame of smooth colour blobs with a few dark curves (neither engine's time depends on it)."""
    rng = np.random.default_rng(0)
    blobs = rng.integers(0, 255, (12, 16, 3), dtype=np.uint8)
    rgb = cv2.resize(blobs, (WIDTH, HEIGHT), interpolation=cv2.INTER_CUBIC)
    for k in range(4):
        pts = np.column_stack([np.linspace(40, 600, 30), 240 + 150 * np.sin(np.linspace(0, 3, 30) + k)])
        cv2.polylines(rgb, [pts.astype(np.int32)], False, (30, 30, 30), 5)
    return rgb


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--calls", type=int, default=60, help="timed calls per engine and network")
    parser.add_argument("--out", default=None, help="write the results as JSON here")
    parser.add_argument("--segment", action="store_true",
                        help="time the whole LearnedSegmenter.segment call per network on 1 and 2 threads")
    parser.add_argument("--quick", action="store_true", help="one network, 3 calls (a smoke test)")
    args = parser.parse_args()
    if args.calls < 1:
        raise SystemExit(f"--calls must be >= 1, got {args.calls}")
    names = ["cable-segmenter-loop"] if args.quick else list(SHIPPED_NAMES)
    calls = 3 if args.quick else args.calls
    rgb = sample_frame()
    report: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cpus",
        "onnxruntime": __import__("onnxruntime").__version__,
        "opencv": cv2.__version__,
        "frame": f"{WIDTH}x{HEIGHT}",
        "calls": calls,
    }
    if args.segment:
        segment_ms = time_segment(names, calls, rgb)
        report["segment_ms"] = segment_ms
        print(f"# {report['machine']}; onnxruntime {report['onnxruntime']}; LearnedSegmenter.segment on a "
              f"{WIDTH}x{HEIGHT} frame, medians of {calls} interleaved calls")
        print("| network | 1 thread | 2 threads |")
        print("|---|---|---|")
        for name, ms in segment_ms.items():
            print(f"| `{name}` | {ms['1 thread']:.2f} ms | {ms['2 threads']:.2f} ms |")
    else:
        results = {name: compare(name, calls, rgb) for name in names}
        report["networks"] = results
        print(f"# {report['machine']}; onnxruntime {report['onnxruntime']}, OpenCV {report['opencv']}; "
              f"medians of {calls} interleaved calls on a {WIDTH}x{HEIGHT} frame's input")
        keys = list(next(iter(results.values()))["ms"])
        print("| network | input | " + " | ".join(keys) + " | max logit difference | sign differs |")
        print("|---|---|" + "---|" * (len(keys) + 2))
        for name, r in results.items():
            cells = " | ".join(f"{r['ms'][k]:.2f} ms ({r['vs_cv2_one_thread'][k]:.2f}x)" for k in keys)
            shape = "x".join(map(str, r["input"][1:]))
            print(f"| `{name}` | {shape} | {cells} | {r['max_logit_difference']:.1e} | "
                  f"{100 * r['sign_differs_share']:.4f} % |")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
