"""Where a decision's time goes: a profile of tip-control episodes, single-step and multi-step.

Runs whole episodes with random actions under ``cProfile`` and splits each decision's wall time into
physics (MuJoCo's C rollout or ``mujoco.batch``), planning (decoding the action, fitting the splines),
references (evaluating the plans at every physics step), the monitor (the avoid conditions and the goal
distance of every recorded sample, the cable's node positions), and the rest (observation, reward, reset,
bookkeeping). The batched environment (``--n-envs``, default 8) is profiled beside the single environment,
unless the package has none (``--single-only``: the same figures for an older version of the package, put
first on ``PYTHONPATH``).

    python benchmarks/env_profile.py [--quick] [--episodes 40] [--n-envs 8] [--single-only]

The profiler's own cost inflates Python-heavy parts; the shares, not the absolute times, are the figure.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import platform
import pstats
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import dyndlo_vision  # noqa: E402
from dyndlo_vision.tasks import TipControl, make_env  # noqa: E402

#: Parts of a decision: (package-relative file name, function name) whose cumulative time counts for it. The
#: names of both the single and the batched environment, and of older versions (before the batched fits).
PARTS: dict[str, list[tuple[str, str]]] = {
    "physics": [("", "<built-in method mujoco._rollout.rollout>"),
                ("", "<built-in method mujoco._batch.rollout>")],
    "plan": [("trajectory/replanner.py", "replan"), ("trajectory/replanner.py", "replan_many")],
    "references": [("trajectory/replanner.py", "references"), ("tasks/batched.py", "_references")],
    "monitor": [("tasks/base.py", "_sample_monitor_batch"), ("tasks/batched.py", "_record_many")],
}


def shares(stats: pstats.Stats, wall: float) -> dict[str, float]:
    """Seconds of each part (cumulative time of its functions) and of the rest."""
    found = {name: 0.0 for name in PARTS}
    for (path, _, func), (_, _, _, cumtime, _) in stats.stats.items():  # type: ignore[attr-defined]
        for name, keys in PARTS.items():
            for file, function in keys:
                if (file == "" and func == function) or (file and path.endswith(file) and func == function):
                    found[name] += cumtime
    total = stats.total_tt  # type: ignore[attr-defined]
    found["rest"] = max(0.0, total - sum(found.values()))
    found["total_profiled_s"] = total
    found["wall_s"] = wall
    return found


def profile_single(multi_step: bool, episodes: int) -> dict[str, Any]:
    env = make_env("tip-control", multi_step=multi_step).unwrapped
    rng = np.random.default_rng(0)
    shape = env.action_space.shape

    def run(count: int, offset: int) -> int:
        decisions = 0
        for k in range(count):
            env.reset(seed=offset + k)
            done = False
            while not done:
                _, _, done, _, _ = env.step(rng.uniform(-1, 1, shape).astype(np.float32))
                decisions += 1
        return decisions

    run(2, 10_000)
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    decisions = run(episodes, 0)
    profiler.disable()
    wall = time.perf_counter() - start
    out = shares(pstats.Stats(profiler), wall)
    return {"env": "single", "decisions": decisions, "ms_per_decision": 1e3 * wall / decisions,
            **{k: round(v, 3) for k, v in out.items()}}


def profile_batched(multi_step: bool, episodes: int, n_envs: int) -> dict[str, Any]:
    from dyndlo_vision.learning.vec_env import BatchedVecEnv
    from dyndlo_vision.tasks.batched import BatchedEpisodes

    vec = BatchedVecEnv(BatchedEpisodes(TipControl(multi_step=multi_step), n_envs))
    rng = np.random.default_rng(0)
    shape = (n_envs, *vec.action_space.shape)
    vec.seed(0)
    vec.reset()
    for _ in range(3):
        vec.step(rng.uniform(-1, 1, shape).astype(np.float32))
    profiler = cProfile.Profile()
    decisions = ended = 0
    start = time.perf_counter()
    profiler.enable()
    while ended < episodes:
        _, _, dones, _ = vec.step(rng.uniform(-1, 1, shape).astype(np.float32))
        decisions += n_envs
        ended += int(dones.sum())
    profiler.disable()
    wall = time.perf_counter() - start
    out = shares(pstats.Stats(profiler), wall)
    return {"env": f"batched, {n_envs} simulations, {vec.episodes.physics.nthread} threads",  # type: ignore[attr-defined]
            "decisions": decisions, "ms_per_decision": 1e3 * wall / decisions,
            **{k: round(v, 3) for k, v in out.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=40, help="episodes per mode and environment")
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--single-only", action="store_true", help="profile the single environment only")
    parser.add_argument("--quick", action="store_true", help="a few episodes (checks the script runs)")
    args = parser.parse_args()
    episodes = 3 if args.quick else args.episodes
    package = os.path.dirname(dyndlo_vision.__file__)
    print(f"# {platform.machine()}, {os.cpu_count()} cpus; package at {package}")
    print("| mode | environment | ms per decision | physics | plan | references | monitor | rest |")
    print("|---|---|---|---|---|---|---|---|")
    for multi_step in (False, True):
        rows = [profile_single(multi_step, episodes)]
        if not args.single_only:
            rows.append(profile_batched(multi_step, episodes, args.n_envs))
        for row in rows:
            total = row["total_profiled_s"]
            parts = " | ".join(f"{100 * row[k] / total:.0f} %" for k in ("physics", "plan", "references",
                                                                        "monitor", "rest"))
            mode = "multi-step" if multi_step else "single-step"
            print(f"| {mode} | {row['env']} | {row['ms_per_decision']:.2f} | {parts} |", flush=True)
            print(json.dumps(row))


if __name__ == "__main__":
    main()
