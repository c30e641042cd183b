"""Fit the observation-noise model to the control loop's own tracked estimates, for any task and cameras.

``benchmarks/tracking_accuracy.py`` fits the packaged model on rendered tip-control episodes through one
camera. A student trained on that model sees P_DLO as tip control's one-camera tracker gives it, whatever
task it is for. This script takes the records from the loop itself: ``N`` episodes of ``dyndlo-vision demo
--observation tracked`` (the task's own cameras: two for vaulting, the cable triangulated), driven by a
shipped or given policy on randomised cables. Per control cycle it keeps the true P_DLO, the estimate the
policy read (a dropout where the cycle had no accepted measurement) and the true velocity (central difference
of the truth over the neighbouring cycles; the speed the model scales with is the backward difference over
the last period, as :class:`~dyndlo_vision.tasks.noise.NoiseProcess` computes it), and fits
:meth:`~dyndlo_vision.tasks.noise.ObservationNoiseModel.fit` to them.

    python benchmarks/loop_noise_model.py --task vaulting --policy vaulting-multi-step --episodes 40 \
        --seed 300000 --cable-ranges beyond --out noise_vault.json [--records rec.npz]

    python benchmarks/loop_noise_model.py --quick --out /tmp/noise.json   # one episode (a smoke test)

Seeds default to 300000+, away from the evaluation seeds (100000+, 200000+).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision.tasks.noise import ObservationNoiseModel


def episode_records(trace: dict[str, Any], period_s: float) -> dict[str, np.ndarray]:
    """Per-cycle truth, estimate (NaN where nothing was measured), velocity and speed of one episode's
    trace."""
    n = len(trace["t"])
    truth = np.asarray(trace["truth"][:n], dtype=float)  # the cycles' truths come first, then the snapshots
    estimate = np.asarray(trace["estimate"], dtype=float).copy()
    estimate[~np.asarray(trace["measured"], dtype=bool)] = np.nan
    velocity = np.gradient(truth, period_s, axis=0) if n > 1 else np.zeros_like(truth)
    speed = np.zeros(n)
    speed[1:] = np.linalg.norm(np.diff(truth, axis=0), axis=1) / period_s
    return {"truth": truth, "estimate": estimate, "velocity": velocity, "speed": speed}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="vaulting")
    ap.add_argument("--policy", default=None,
                    help="shipped name or zip (default: the task's multi-step policy)")
    ap.add_argument("--episodes", type=int, default=40)
    ap.add_argument("--seed", type=int, default=300000)
    ap.add_argument("--cable-ranges", default="beyond", help="training or beyond (cables drawn per episode)")
    ap.add_argument("--segmenter", choices=("learned", "background"), default=None,
                    help="the loop's segmenter (default: the scene's own, "
                    "control.sim_perception.default_segmenter)")
    ap.add_argument("--out", type=Path, required=True, help="the fitted model (JSON)")
    ap.add_argument("--records", type=Path, default=None, help="also write the per-cycle records (.npz)")
    ap.add_argument("--quick", action="store_true", help="one episode (a smoke test)")
    args = ap.parse_args(argv)
    if args.quick:
        args.episodes = 1
    if args.episodes < 1:
        raise SystemExit(f"--episodes must be >= 1, got {args.episodes}")

    from dyndlo_vision import policies
    from dyndlo_vision.control.episode import run_loop_episode
    from dyndlo_vision.control.sim_perception import (
        LoopPerception,
        default_segmenter,
        loop_segmenter,
        scene_views,
    )
    from dyndlo_vision.policies.actor import deterministic_policy
    from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
    from dyndlo_vision.tasks.registry import make_env
    from dyndlo_vision.tasks.wrappers import cable_ranges_for

    name = args.policy or f"{args.task}-multi-step"
    _, meta = policies.resolve(name)
    env = make_env(args.task, multi_step=bool(meta.get("multi_step", False)), randomize_cable_every=1,
                   cable_ranges=cable_ranges_for(args.task, args.cable_ranges))
    model = policies.load(name, env=env)
    views = scene_views(env)
    segmenter = args.segmenter or default_segmenter(env)
    perception = LoopPerception(segmenter=loop_segmenter(segmenter), views=views)
    parts: list[dict[str, np.ndarray]] = []
    rmse = []
    t0 = time.perf_counter()
    for i in range(args.episodes):
        if hasattr(model, "reset"):
            model.reset()  # a policy with a P_DLO history starts every episode afresh (as the demo does)
        record = run_loop_episode(env, deterministic_policy(model), args.seed + i,
                                  "tracked", "tracking", perception=perception)
        rec = episode_records(record["trace"], CONTROL_PERIOD_S)
        rec["episode"] = np.full(len(rec["speed"]), i)
        parts.append(rec)
        rmse.append(record["estimate_rmse_m"])
        print(f"episode {i} (seed {args.seed + i}): {len(rec['speed'])} cycles, estimate RMSE "
              f"{1e3 * record['estimate_rmse_m']:.2f} mm", file=sys.stderr)
    records = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    cameras = f"{views} camera{'s' if views > 1 else ''}, {segmenter} segmenter"
    source = (f"benchmarks/loop_noise_model.py --task {args.task} --policy {name} --episodes {args.episodes} "
              f"--seed {args.seed} --cable-ranges {args.cable_ranges} --segmenter {segmenter}: the loop's "
              f"tracked P_DLO ({cameras}) as the policy read it, per control cycle")
    fitted = ObservationNoiseModel.fit(records["truth"], records["estimate"], records["velocity"],
                                       episode=records["episode"], speed=records["speed"], source=source)
    fitted.save(args.out)
    if args.records is not None:
        np.savez_compressed(args.records, **records)
    err = records["estimate"] - records["truth"]
    seen = np.all(np.isfinite(err), axis=1)
    summary = {
        "machine": f"{platform.machine()}, {platform.system()}",
        "wall_s": round(time.perf_counter() - t0, 1),
        "cycles": int(len(err)),
        "dropouts": int(np.count_nonzero(~seen)),
        "error_rms_mm_per_axis": (1e3 * np.sqrt(np.mean(err[seen] ** 2, axis=0))).round(3).tolist(),
        "episode_rmse_mm_median": round(1e3 * float(np.median(rmse)), 3),
        "model": fitted.to_dict(),
    }
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
