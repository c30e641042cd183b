"""Simulation speed of tip control on one core: sim-s per wall-s, env steps/s, episodes/s, cost per segment.

    python benchmarks/sim_speed.py [--episodes 20]
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


def measure(segments: int, multi_step: bool, episodes: int) -> dict[str, float]:
    env = gym.make("DynDLO/TipControl-v0", multi_step=multi_step, cable=CableParams(num_segments=segments)).unwrapped
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
    args = parser.parse_args()
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, one process; random actions; default physics")
    print("| segments | mode | sim-s / wall-s | env steps/s | episodes/s | us per physics step |")
    print("|---|---|---|---|---|---|")
    for segments in (20, 40, 60):
        for multi_step in (False, True):
            r = measure(segments, multi_step, args.episodes)
            mode = "multi-step" if multi_step else "single-step"
            print(f"| {segments} | {mode} | {r['sim_rate']:.1f} | {r['steps_per_s']:.1f} | {r['episodes_per_s']:.2f} |"
                  f" {r['us_per_physics_step']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
