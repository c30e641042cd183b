"""Simulation speed of a task on one core: sim-s per wall-s, env steps/s, episodes/s, cost per segment.

    python benchmarks/sim_speed.py [--episodes 20] [--compare-paths] [--task tip-control|time-oscillation]

``--compare-paths`` also times 20 segments with the environment's Python step loop instead of MuJoCo's C
rollout (the two give the same episodes to solver tolerance; tests/tasks/test_envs.py checks it).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import dyndlo_vision  # noqa: E402,F401
from dyndlo_vision.sim import CableParams  # noqa: E402

ENV_IDS = {"tip-control": "DynDLO/TipControl-v0", "time-oscillation": "DynDLO/TimeOscillation-v0"}


def measure(segments: int, multi_step: bool, episodes: int, c_rollout: bool = True,
            task: str = "tip-control") -> dict[str, float]:
    cable = CableParams(num_segments=segments)
    env = gym.make(ENV_IDS[task], multi_step=multi_step, cable=cable).unwrapped
    env.batch_monitor = c_rollout  # the two simulation paths
    rng = np.random.default_rng(0)
    sim_s = wall = 0.0
    steps = 0
    for ep in range(episodes):
        env.reset(seed=ep)
        done = False
        start = time.perf_counter()
        while not done:
            _, _, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
            steps += 1
            done = term or trunc
        wall += time.perf_counter() - start
        sim_s += info["sim_time_s"]
    return {"sim_rate": sim_s / wall, "steps_per_s": steps / wall, "episodes_per_s": episodes / wall,
            "us_per_physics_step": wall / (sim_s / env.scene.timestep) * 1e6}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--compare-paths", action="store_true", help="also time the Python step loop")
    parser.add_argument("--task", choices=sorted(ENV_IDS), default="tip-control")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, one process; {args.task}, random actions; "
          "default physics")
    print("| segments | mode | sim-s / wall-s | env steps/s | episodes/s | us per physics step |")
    print("|---|---|---|---|---|---|")
    for segments in (20, 40, 60):
        for multi_step in (False, True):
            r = measure(segments, multi_step, args.episodes, task=args.task)
            mode = "multi-step" if multi_step else "single-step"
            print(f"| {segments} | {mode} | {r['sim_rate']:.1f} | {r['steps_per_s']:.1f} | "
                  f"{r['episodes_per_s']:.2f} | {r['us_per_physics_step']:.0f} |", flush=True)
    if args.compare_paths:
        print("\n| 20 segments | C rollout sim-s/wall-s | Python stepping sim-s/wall-s | ratio |")
        print("|---|---|---|---|")
        for multi_step in (False, True):
            fast = measure(20, multi_step, args.episodes, True, args.task)["sim_rate"]
            slow = measure(20, multi_step, args.episodes, False, args.task)["sim_rate"]
            mode = "multi-step" if multi_step else "single-step"
            print(f"| {mode} | {fast:.1f} | {slow:.1f} | {fast / slow:.2f} |", flush=True)


if __name__ == "__main__":
    main()
