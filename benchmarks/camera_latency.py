"""Closed-loop tip control on tracked state behind a camera latency: success and P_DLO estimate error.

A real camera hands a frame over tens of milliseconds after exposing it. This runs the demo's loop (render,
track, filter, policy, re-plan at 25 Hz) with the pipeline seeing every frame ``latency`` late
(``LoopPerception(latency_s=...)``: the filter updates at the frame's capture time and predicts to the
controller's), for several latencies, with the loop's shipped filter for that latency
(``tracking.params.LOOP_FILTER`` without latency, ``LATENT_LOOP_FILTER`` with one) or with the acceleration
noises ``--sigmas``. The error is |estimate - truth| at the controller's time, per cycle; its RMSE per
episode is summarised over the episodes.

    python benchmarks/camera_latency.py [--episodes 20] [--latencies-ms 0 40 80] [--sigmas 200 2000]
        [--segmenter background|learned] [--policy NAME|PATH] [--out results.json]
    python benchmarks/camera_latency.py --quick     # one episode at 0 and 40 ms (a smoke test)
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from dataclasses import replace

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import dyndlo_vision  # noqa: E402,F401  (before mujoco)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=300_000)
    parser.add_argument("--latencies-ms", type=float, nargs="+", default=[0.0, 40.0, 80.0])
    parser.add_argument("--sigmas", type=float, nargs="*", default=[],
                        help="filter acceleration noises (m/s^2) to run besides the shipped filter")
    parser.add_argument("--segmenter", choices=("background", "learned"), default=None,
                        help="the loop's segmenter (default: the scene's own)")
    parser.add_argument("--policy", default=None, help="policy (default: the demo's)")
    parser.add_argument("--out", default=None)
    parser.add_argument("--quick", action="store_true", help="one episode at 0 and 40 ms (a smoke test)")
    args = parser.parse_args()
    if args.quick:
        args.episodes, args.latencies_ms, args.sigmas = 1, [0.0, 40.0], []
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    import torch

    from dyndlo_vision import policies
    from dyndlo_vision.control.episode import run_loop_episode
    from dyndlo_vision.control.sim_perception import LoopPerception, loop_segmenter
    from dyndlo_vision.policies.actor import deterministic_policy
    from dyndlo_vision.tasks import make_env
    from dyndlo_vision.tracking.params import LATENT_LOOP_FILTER, LOOP_FILTER

    torch.set_num_threads(1)
    logging.disable(logging.WARNING)
    name = args.policy or policies.default_for("tip-control")
    _, meta = policies.resolve(name)
    env = make_env("tip-control", multi_step=bool(meta.get("multi_step", False)))
    model = policies.load(name, env=env)
    act = deterministic_policy(model)

    segmenter = None if args.segmenter is None else loop_segmenter(args.segmenter)
    rows = []
    print(f"# {platform.machine()}, {os.cpu_count()} cpus; policy {name}; {args.episodes} episodes per row, "
          f"seeds {args.seed}+; segmenter {args.segmenter or 'the scene default'}")
    print("| latency ms | filter sigma_accel m/s^2 | hits | estimate RMSE per episode, median / p95 (mm) |")
    print("|---|---|---|---|")
    for latency_ms in args.latencies_ms:
        shipped = LOOP_FILTER if latency_ms == 0 else LATENT_LOOP_FILTER
        for sigma in [None, *args.sigmas]:
            params = None if sigma is None else replace(shipped, sigma_accel=sigma)
            perception = LoopPerception(segmenter=segmenter, latency_s=1e-3 * latency_ms, filter=params)
            t0 = time.perf_counter()
            hits, rmse = 0, []
            for i in range(args.episodes):
                if hasattr(model, "reset"):
                    model.reset()
                r = run_loop_episode(env, act, args.seed + i, "tracked", "tracking", perception=perception)
                hits += bool(r["success"])
                rmse.append(np.nan if r["estimate_rmse_m"] is None else r["estimate_rmse_m"])
            sigma_used = shipped.sigma_accel if sigma is None else sigma
            row = {
                "latency_ms": latency_ms,
                "filter": "shipped" if sigma is None else "sigma",
                "sigma_accel": sigma_used,
                "episodes": args.episodes,
                "hits": hits,
                "estimate_rmse_mm_median": 1e3 * float(np.nanmedian(rmse)),
                "estimate_rmse_mm_p95": 1e3 * float(np.nanpercentile(rmse, 95)),
                "wall_s": round(time.perf_counter() - t0, 1),
            }
            rows.append(row)
            label = f"{sigma_used:g}" + (" (shipped)" if sigma is None else "")
            print(f"| {latency_ms:.0f} | {label} | {hits} / {args.episodes} | "
                  f"{row['estimate_rmse_mm_median']:.1f} / {row['estimate_rmse_mm_p95']:.1f} |", flush=True)
    env.close()
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"command": " ".join(sys.argv), "machine": platform.platform(), "policy": str(name),
                       "seed": args.seed, "rows": rows}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
