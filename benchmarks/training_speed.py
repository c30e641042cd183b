"""Environment throughput for training: DummyVecEnv vs SubprocVecEnv, single-step and multi-step tip control.

Steps the vectorised environments with random actions (no learning) for a fixed wall time and prints env
steps (decisions) per second; the ratio between rows is what ``--vec-env`` and ``--n-envs`` buy on this
machine.

    python benchmarks/training_speed.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from dyndlo_vision.learning.config import RunConfig  # noqa: E402
from dyndlo_vision.learning.envs import make_vec_env  # noqa: E402


def measure(multi_step: bool, n_envs: int, kind: str, seconds: float) -> float:
    config = RunConfig(
        task="tip-control", multi_step=multi_step, algo="sac", timesteps=1, n_envs=n_envs, vec_env=kind
    )
    vec = make_vec_env(config, n_envs, 0, None, kind)
    rng = np.random.default_rng(0)
    vec.reset()
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        vec.step(rng.uniform(-1, 1, (n_envs, *vec.action_space.shape)).astype(np.float32))
        steps += n_envs
    rate = steps / (time.perf_counter() - start)
    vec.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    print(f"# {platform.machine()}, {os.cpu_count()} cpus; random actions, no learning")
    print("| mode | vec env | n_envs | env steps/s |")
    print("|---|---|---|---|")
    for multi_step in (False, True):
        for kind, n in (("dummy", 1), ("dummy", 2), ("subproc", 2)):
            rate = measure(multi_step, n, kind, args.seconds)
            mode = "multi-step" if multi_step else "single-step"
            print(f"| {mode} | {kind} | {n} | {rate:.1f} |", flush=True)


if __name__ == "__main__":
    main()
