"""Per-frame speed of the cable tracking pipeline on one CPU core (640x480 synthetic frames).

Stages: segmentation (BackgroundSegmenter), centreline (thinning + graph + ordering +
resampling; thinning also shown alone), lifting to 3D on a plane, and the N-node Kalman
filter (update + latency-compensated read). "total" is the whole per-frame pipeline timed
end to end, not the sum of the stage medians. Two per-node alternatives the filter's design
rejected are timed after it on a still cable: N one-point filters (``PointFilter``), and N
filterpy ``KalmanFilter`` objects doing only the Kalman predict/update (no gating, no replay).

Run from the repository root:

    python benchmarks/tracking_speed.py [--frames 300] [--nodes 20]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# One core: set before numpy/OpenCV start their thread pools.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

# Benchmark the checkout this file lives in, even if another copy is installed.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from filterpy.kalman import KalmanFilter  # noqa: E402

from dyndlo_vision.tracking import (  # noqa: E402
    BackgroundSegmenter,
    FilterParams,
    MultiPointFilter,
    PinholeCamera,
    Plane,
    PointFilter,
    extract_centerline,
    lift_with_plane,
    thin_coords,
)
from dyndlo_vision.tracking.filter import cv_process_noise, cv_transition  # noqa: E402
from dyndlo_vision.tracking.synthetic import loop_curve, render_cable, s_curve  # noqa: E402


def make_frames(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Moving cables (S-curves and self-crossing loops), each with its start pixel."""
    frames = []
    for k in range(n):
        t = k / 25.0
        if (k // 50) % 2 == 0:
            curve = s_curve(
                u0=90 + 30 * np.sin(2 * t),
                u1=550 + 40 * np.sin(1.3 * t),
                v0=240 + 50 * np.sin(3 * t),
                amp=100 * np.cos(2.5 * t),
                periods=0.9 + 0.3 * np.sin(1.7 * t),
            )
        else:
            curve = loop_curve(
                u0=70 + 20 * np.sin(t), v0=260 + 30 * np.sin(2 * t), radius=80 + 15 * np.sin(3 * t)
            )
        rgb, _ = render_cable(curve, thickness=6, noise_sigma=4.0, seed=k)
        frames.append((rgb, curve[0]))
    return frames


def look_down_camera() -> PinholeCamera:
    R = np.diag([1.0, -1.0, -1.0])  # looking straight down at z = 0 from z = 1
    K = np.array([[520.0, 0, 319.5], [0, 520.0, 239.5], [0, 0, 1]])
    return PinholeCamera(640, 480, K, np.zeros(0), R, -R @ np.array([0.0, 0.0, 1.0]), fps=25.0)


def filterpy_filter(z0: np.ndarray, params: FilterParams) -> KalmanFilter:
    """A filterpy KalmanFilter of the same constant-velocity model, initialised at ``z0`` at rest."""
    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.H = np.hstack((np.eye(3), np.zeros((3, 3))))
    kf.R = np.eye(3) * params.sigma_meas**2
    kf.x = np.concatenate((z0, np.zeros(3))).reshape(6, 1)
    kf.P = np.diag([params.sigma_meas**2] * 3 + [params.init_speed_sigma**2] * 3)
    return kf


def stats(ms: list[float]) -> tuple[float, float, float]:
    a = np.asarray(ms)
    return float(np.median(a)), float(np.percentile(a, 95)), float(a.mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--nodes", type=int, default=20)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    frames = make_frames(args.frames)
    cam = look_down_camera()
    plane = Plane(np.array([0.0, 0.0, 1.0]), 0.0)
    seg = BackgroundSegmenter()
    params = FilterParams()
    flt = MultiPointFilter(args.nodes, params)
    timings: dict[str, list[float]] = {
        k: []
        for k in (
            "segmentation",
            "centreline",
            "  of which thinning",
            "lift (plane)",
            f"filter (N={args.nodes})",
            "total",
        )
    }
    prev = None
    clock = time.perf_counter
    for _ in range(2):  # warm-up pass
        for rgb, anchor in frames[:10]:
            extract_centerline(seg(rgb), args.nodes, anchor_uv=anchor)
    for k, (rgb, anchor) in enumerate(frames):
        t_cap = k / 25.0
        t0 = clock()
        mask = seg(rgb)
        t1 = clock()
        cl = extract_centerline(mask, args.nodes, anchor_uv=anchor, prev_nodes_uv=prev)
        t2 = clock()
        xyz = lift_with_plane(cl.nodes_uv, cam, plane, cl.visible)
        t3 = clock()
        flt.update(xyz, t_cap, visible=cl.visible)
        flt.estimate(t_cap + 0.04)
        t4 = clock()
        prev = cl.nodes_uv
        timings["segmentation"].append((t1 - t0) * 1e3)
        timings["centreline"].append((t2 - t1) * 1e3)
        timings["lift (plane)"].append((t3 - t2) * 1e3)
        timings[f"filter (N={args.nodes})"].append((t4 - t3) * 1e3)
        timings["total"].append((t4 - t0) * 1e3)
        m8 = mask.astype(np.uint8)
        x, y, w, h = cv2.boundingRect(m8)
        t5 = clock()
        thin_coords(m8[y : y + h, x : x + w])
        timings["  of which thinning"].append((clock() - t5) * 1e3)

    # The alternatives the filter's design rejected: N one-point filters, and N filterpy KalmanFilters.
    z = np.zeros((args.nodes, 3))
    singles = [PointFilter(params) for _ in range(args.nodes)]
    per_point: list[float] = []
    for k in range(200):
        t0 = clock()
        for i, f in enumerate(singles):
            f.update(z[i] + 0.001 * k, k / 25.0)
            f.estimate(k / 25.0 + 0.04)
        per_point.append((clock() - t0) * 1e3)
    kfs = [filterpy_filter(z[i], params) for i in range(args.nodes)]
    F, Q = cv_transition(0.04), cv_process_noise(0.04, params.sigma_accel)
    per_kf: list[float] = []
    for k in range(1, 201):
        t0 = clock()
        for i, kf in enumerate(kfs):
            kf.predict(F=F, Q=Q)
            kf.update((z[i] + 0.001 * k).reshape(3, 1))
            _ = F @ kf.x, F @ kf.P @ F.T + Q  # the latency-compensated read
        per_kf.append((clock() - t0) * 1e3)

    print(f"command: {' '.join([os.path.basename(sys.executable), *sys.argv])}")
    print(
        f"frames: {args.frames} synthetic 640x480 RGB, cable 6 px thick; nodes: {args.nodes}; "
        f"cv2 threads: {cv2.getNumThreads()}; OpenCV {cv2.__version__}, numpy {np.__version__}"
    )
    print(f"{'stage':<24}{'median ms':>10}{'p95 ms':>10}{'mean ms':>10}")
    for name, ms in timings.items():
        med, p95, mean = stats(ms)
        print(f"{name:<24}{med:>10.3f}{p95:>10.3f}{mean:>10.3f}")
    for name, ms in (("(N PointFilters, unused)", per_point), ("(filterpy x N, unused)", per_kf)):
        med, p95, mean = stats(ms)
        print(f"{name:<24}{med:>10.3f}{p95:>10.3f}{mean:>10.3f}")


if __name__ == "__main__":
    main()
