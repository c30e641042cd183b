"""Latency of the perception-in-the-loop controller in simulation, per stage, on one core.

Runs closed-loop tip-control episodes on tracked state (render the "tracking" camera at 640x480, segment,
order, lift, filter, query the policy, re-plan) and prints the median and p95 of each stage, and p50, p95 and
p99 of the controller's whole cycle (everything but the simulated robot's physics, which a real robot runs by
itself) with and without the simulated camera's render, plus the share of cycles that missed the 40 ms
deadline and the estimate's error against the truth. The ``track`` stage is the sum of ``segment``,
``centreline``, ``identity`` and ``lift``.

    python benchmarks/loop_latency.py [--episodes 10] [--policy NAME|PATH] [--out results.json]
    python benchmarks/loop_latency.py --busy        # beside one busy process on the loop's core
    python benchmarks/loop_latency.py --quick       # one episode (a smoke test)
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import os
import platform
import sys
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from dyndlo_vision.policies.actor import deterministic_policy  # noqa: E402
from dyndlo_vision.tasks import make_env  # noqa: E402


def pinned_demo_policy(policy: str | None) -> tuple[str, Any, Any]:
    """One core, one torch thread, no warnings; the tip-control env and the policy (default: the demo's).

    Returns the policy's name, the environment in the policy's mode and the policy as ``obs -> action``.
    """
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    import torch

    torch.set_num_threads(1)
    logging.disable(logging.WARNING)
    from dyndlo_vision import policies

    name = policy or policies.default_for("tip-control")
    _, meta = policies.resolve(name)
    env = make_env("tip-control", multi_step=bool(meta.get("multi_step", False)))
    model = policies.load(name, env=env)
    return str(name), env, deterministic_policy(model)


def _spin(core: int) -> None:
    """A busy process: pinned to ``core``, it computes until it is terminated."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})
    x = 0
    while True:
        x = (x * 31 + 7) % 1_000_003


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=200_000)
    parser.add_argument("--policy", default=None, help="policy (default: the demo's)")
    parser.add_argument("--out", default=None)
    parser.add_argument("--busy", action="store_true",
                        help="run beside one busy process pinned to the loop's core (load, not idle)")
    parser.add_argument("--quick", action="store_true", help="one episode (a smoke test)")
    args = parser.parse_args()
    if args.quick:
        args.episodes = 1
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    from dyndlo_vision.control.episode import run_loop_episode

    name, env, act = pinned_demo_policy(args.policy)
    busy = None
    if args.busy:
        core = min(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 0
        busy = multiprocessing.get_context("spawn").Process(target=_spin, args=(core,), daemon=True)
        busy.start()
    stages: dict[str, list[float]] = {}
    cycle: list[float] = []
    misses = cycles = 0
    rmse = []
    for i in range(args.episodes):
        r = run_loop_episode(env, act, args.seed + i, "tracked", "tracking")
        rmse.append(r["estimate_rmse_m"])
        misses += r["deadline_misses"]
        cycles += r["cycles"]
        cycle.extend(r["_cycle_ms"])
        for k, v in r["_stage_ms"].items():
            stages.setdefault(k, []).extend(v)
    if busy is not None:
        busy.terminate()
    without_render = np.asarray(cycle) - np.asarray(stages["camera"])
    result = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cpus, pinned to one core"
        + (", beside one busy process on that core" if args.busy else ""),
        "policy": str(name),
        "episodes": args.episodes,
        "cycles": cycles,
        "controller_ms_p50": float(np.percentile(cycle, 50)),
        "controller_ms_p95": float(np.percentile(cycle, 95)),
        "controller_ms_p99": float(np.percentile(cycle, 99)),
        "without_render_ms_p50": float(np.percentile(without_render, 50)),
        "without_render_ms_p95": float(np.percentile(without_render, 95)),
        "without_render_ms_p99": float(np.percentile(without_render, 99)),
        "deadline_miss_share": misses / max(cycles, 1),
        "stage_ms_p50": {k: float(np.percentile(v, 50)) for k, v in stages.items()},
        "stage_ms_p95": {k: float(np.percentile(v, 95)) for k, v in stages.items()},
        "estimate_rmse_m_median": float(np.median([x for x in rmse if x is not None])),
    }
    print(f"# {result['machine']}; {cycles} cycles over {args.episodes} episodes; policy {name}")
    print("| stage | p50 ms | p95 ms | p99 ms |")
    print("|---|---|---|---|")
    for k in sorted(stages):
        print(f"| {k} | {result['stage_ms_p50'][k]:.2f} | {result['stage_ms_p95'][k]:.2f} | |")
    for label, key in (("controller cycle without the render", "without_render"),
                       ("controller cycle", "controller")):
        print(f"| {label} | {result[key + '_ms_p50']:.2f} | {result[key + '_ms_p95']:.2f} | "
              f"{result[key + '_ms_p99']:.2f} |")
    print(
        f"deadline misses: {100 * result['deadline_miss_share']:.1f} % of cycles; "
        f"estimate RMSE median {1e3 * result['estimate_rmse_m_median']:.1f} mm"
    )
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
