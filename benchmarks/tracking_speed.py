"""Per-frame time of each stage of the perception pipeline, as the control loop runs it, per segmenter.

Tip control's loop camera (640x480, a 1.6 px cable) on episodes of the demo's policy: each frame is rendered
once and given to two :class:`~dyndlo_vision.tracking.pipeline.CablePipeline` built as the loop builds
them (``control.sim_perception.loop_pipeline_config`` and ``view_segmenter``), one with the learned segmenter
(``cable-segmenter-loop`` at 1.5x, following the cable) and one with the classical one (against the scene
rendered without the cable), in alternating order so that both see the same load. Stages, medians per
frame:

* ``render``: the camera's render (the loop's ``camera`` stage);
* ``segment``: the view's segmenter stack (the network or background model, the cable's reach, the gripper
  mask), timed around the stack's call;
* ``centreline..point``: the rest of the pipeline's ``track`` stage (``FrameResult.stage_ms["track"]`` minus
  ``segment``): centreline, the held end's identity, lifting onto the plane, the tracked point;
* ``filter``: ``FrameResult.stage_ms["filter"]``, the Kalman update;
* ``total``: ``track`` + ``filter``.

One core (``OMP_NUM_THREADS=1``, one torch thread); on a shared machine quote the ratio of the two
segmenters, measured side by side.

    python benchmarks/tracking_speed.py [--episodes 5] [--seed 100000] [--out speed.json]
    python benchmarks/tracking_speed.py --quick     # one episode (a smoke test)
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import dyndlo_vision  # noqa: E402,F401  (before mujoco)
from dyndlo_vision.tracking.segmenters import ViewSegmenter  # noqa: E402

SEGMENTERS = ("learned", "background")
STAGES = ("render", "segment", "centreline..point", "filter", "total")


class TimedSegmenter(ViewSegmenter):
    """A view's segmenter stack that records the wall time of each call (ms)."""

    def __init__(self, stack: ViewSegmenter) -> None:
        super().__init__(stack.base, stack.reach, stack.gripper, stack.shape)
        self.ms: list[float] = []

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        mask = super().__call__(rgb)
        self.ms.append(1e3 * (time.perf_counter() - t0))
        return mask


def loop_pipeline(env: Any, kind: str, camera: Any) -> tuple[Any, TimedSegmenter]:
    """The loop's pipeline for ``kind`` on ``camera`` (call at the start of an episode), with its segmenter
    stack timed."""
    from dyndlo_vision.control.sim_env import as_sim_env
    from dyndlo_vision.control.sim_perception import (
        loop_pipeline_config,
        loop_segmenter,
        render_without_cable,
        view_segmenter,
    )
    from dyndlo_vision.tracking.params import LOOP_FILTER
    from dyndlo_vision.tracking.pipeline import CablePipeline

    base = as_sim_env(env)
    node = base.task.p_dlo_node(base.scene)
    point = node / (base.scene.config.cable.num_nodes - 1)
    config = loop_pipeline_config(base.scene, point, loop_segmenter(kind), LOOP_FILTER)
    calibration = camera.calibration
    background = None if kind == "learned" else render_without_cable(camera)
    seg = TimedSegmenter(view_segmenter(config, camera, calibration, background))
    return CablePipeline(config, [calibration], [seg]), seg


def median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=5)
    ap.add_argument("--seed", type=int, default=100_000)
    ap.add_argument("--out", default=None, help="JSON file of the results")
    ap.add_argument("--quick", action="store_true", help="one episode (a smoke test)")
    args = ap.parse_args()
    if args.quick:
        args.episodes = 1
    if args.episodes < 1:
        ap.error(f"--episodes must be >= 1, got {args.episodes}")
    import cv2
    import torch

    from dyndlo_vision import policies
    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.control.sim_env import as_sim_env
    from dyndlo_vision.tasks import make_env

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    logging.disable(logging.WARNING)
    name = policies.default_for("tip-control")
    _, meta = policies.resolve(name)
    env = make_env("tip-control", multi_step=bool(meta.get("multi_step", False)))
    model = policies.load(name, env=env)
    times: dict[str, dict[str, list[float]]] = {k: {s: [] for s in STAGES} for k in SEGMENTERS}
    measured = dict.fromkeys(SEGMENTERS, 0)
    frames = 0
    for e in range(args.episodes):
        obs, _ = env.reset(seed=args.seed + e)
        if hasattr(model, "reset"):
            model.reset()
        base = as_sim_env(env)
        camera = MujocoCamera(base.model, base.data, "tracking", 640, 480)
        pipes = {k: loop_pipeline(env, k, camera) for k in SEGMENTERS}
        done = False
        while not done:
            t0 = time.perf_counter()
            frame = camera.read()
            render_ms = 1e3 * (time.perf_counter() - t0)
            held = np.asarray(base.scene.tcp_positions())[0].copy()
            order = SEGMENTERS if frames % 2 == 0 else SEGMENTERS[::-1]
            for kind in order:
                pipeline, seg = pipes[kind]
                result = pipeline.step([frame.rgb], frame.t_capture, held_world=held)
                stage = times[kind]
                stage["render"].append(render_ms)
                stage["segment"].append(seg.ms[-1])
                stage["centreline..point"].append(result.stage_ms["track"] - seg.ms[-1])
                stage["filter"].append(result.stage_ms["filter"])
                stage["total"].append(result.stage_ms["track"] + result.stage_ms["filter"])
                measured[kind] += bool(result.status.seen)
            frames += 1
            obs, _, term, trunc, _ = env.step(model.predict(obs, deterministic=True)[0])
            done = bool(term or trunc)
        camera.close()
    env.close()
    medians = {k: {s: round(median(v), 3) for s, v in times[k].items()} for k in SEGMENTERS}
    ratio = medians["learned"]["total"] / medians["background"]["total"]
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, one thread; {frames} frames of {args.episodes} "
          f"episode(s), seeds {args.seed}+, policy {name}; OpenCV {cv2.__version__}")
    print("| stage | " + " | ".join(f"{k} median ms" for k in SEGMENTERS) + " |")
    print("|---|" + "---|" * len(SEGMENTERS))
    for s in STAGES:
        print(f"| {s} | " + " | ".join(f"{medians[k][s]:.2f}" for k in SEGMENTERS) + " |")
    print(f"learned / classical total: {ratio:.2f}; point measured in "
          + ", ".join(f"{measured[k]} ({k})" for k in SEGMENTERS) + f" of {frames} frames")
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"command": " ".join(sys.argv), "machine": platform.platform(), "frames": frames,
                       "median_ms": medians, "learned_over_classical": ratio, "measured": measured}, f,
                      indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
