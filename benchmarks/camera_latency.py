"""Closed-loop tip control on tracked state behind a camera latency: success and P_DLO estimate error.

A real camera hands a frame over tens of milliseconds after exposing it. This runs the demo's loop (render,
track, filter, policy, re-plan at 25 Hz) with the tracker seeing every frame ``latency`` late
(``DelayedCamera``), for several latencies and tip-filter settings (``sigma_accel``), with the filter's
prediction to the controller's time ("predict") and without it ("hold": the estimate at the newest frame's
capture time, i.e. uncompensated). The error is |estimate - truth| at the controller's time, per cycle.

    python benchmarks/camera_latency.py [--episodes 20] [--latencies-ms 0 40 80]
        [--sigmas 20 200 2000] [--noise piecewise continuous] [--policy NAME|PATH] [--out results.json]

``--noise continuous`` runs each sigma as a continuous white acceleration of the same velocity variance per
40 ms frame (``FilterParams.accel_psd`` = sigma^2 x 0.04), the loop filter's model since session 23.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from loop_latency import pinned_demo_policy  # noqa: E402

import dyndlo_vision  # noqa: E402,F401


class HoldAtCapture:
    """A point filter read at its newest measurement's time, whatever time it is asked for (no prediction)."""

    def __init__(self, point_filter: Any) -> None:
        self.filter = point_filter
        self.t_measured: float | None = None

    def reset(self) -> None:
        self.filter.reset()
        self.t_measured = None

    def update(self, point: Any, t: float) -> bool:
        accepted = bool(self.filter.update(point, t))
        if accepted:
            self.t_measured = t
        return accepted

    def estimate(self, t: float) -> Any:
        return self.filter.estimate(t if self.t_measured is None else self.t_measured)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=300_000)
    parser.add_argument("--latencies-ms", type=float, nargs="+", default=[0.0, 40.0, 80.0])
    parser.add_argument("--sigmas", type=float, nargs="+", default=[20.0, 200.0, 2000.0])
    parser.add_argument("--noise", nargs="+", choices=("piecewise", "continuous"), default=["piecewise"],
                        help="the process noise model(s) to run each sigma with")
    parser.add_argument("--policy", default=None, help="policy (default: the demo's)")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    from dataclasses import replace

    from dyndlo_vision.control.episode import run_loop_episode
    from dyndlo_vision.tracking import FilterParams, PointFilter

    name, env, act = pinned_demo_policy(args.policy)
    rows = []
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, pinned to one core; policy {name}; "
          f"{args.episodes} episodes per row, seeds {args.seed}+")
    print("| latency ms | sigma_accel m/s^2 | noise | read | hits | estimate RMSE per episode, median / p95 "
          "(mm) |")
    print("|---|---|---|---|---|---|")
    cases = [(latency_ms, sigma, noise) for latency_ms in args.latencies_ms for sigma in args.sigmas
             for noise in args.noise]
    for latency_ms, sigma, noise in cases:
        for read in ("predict", "hold"):
            if read == "hold" and latency_ms == 0:
                continue  # without latency both read the filter at the frame's time
            t0 = time.perf_counter()
            hits, rmse = 0, []
            for i in range(args.episodes):
                params = replace(FilterParams(), sigma_accel=sigma,
                                 accel_psd=sigma**2 * 0.04 if noise == "continuous" else None,
                                 max_coast_s=FilterParams().max_coast_s + 1e-3 * latency_ms)
                base_filter = PointFilter(params)
                point_filter = base_filter if read == "predict" else HoldAtCapture(base_filter)
                r = run_loop_episode(env, act, args.seed + i, "tracked", "tracking",
                                     latency_s=1e-3 * latency_ms, point_filter=point_filter)
                hits += bool(r["success"])
                if r["estimate_rmse_m"] is not None:
                    rmse.append(r["estimate_rmse_m"])
            row = {
                "latency_ms": latency_ms,
                "sigma_accel": sigma,
                "noise": noise,
                "read": read,
                "episodes": args.episodes,
                "hits": hits,
                "estimate_rmse_mm_median": 1e3 * float(np.median(rmse)),
                "estimate_rmse_mm_p95": 1e3 * float(np.percentile(rmse, 95)),
                "wall_s": time.perf_counter() - t0,
            }
            rows.append(row)
            rmse_mm = f"{row['estimate_rmse_mm_median']:.1f} / {row['estimate_rmse_mm_p95']:.1f}"
            print(f"| {latency_ms:.0f} | {sigma:g} | {noise} | {read} | {hits} / {args.episodes} | "
                  f"{rmse_mm} |", flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"policy": str(name), "seed": args.seed, "rows": rows}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
