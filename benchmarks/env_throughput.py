"""Environment throughput for training by vectorised environment, n_envs and mode; against the paper's model.

Part 1, side by side: tip control (single-step and multi-step), random actions, no learning. Each round runs
every configuration for ``--seconds`` of wall time, in turn (DummyVecEnv with 1 environment, SubprocVecEnv
with 2 workers, the batched environment with 2, 4, 8 and 16 simulations), and counts env steps (decisions).
Reported per configuration: the median over rounds of env steps/s, and the median of its per-round ratio to
SubprocVecEnv with 2 workers and to one environment; and the CPU time one env step costs (this process with
all its threads, and the worker processes), which a loaded machine changes much less than the wall time: on
2 idle cores a configuration that keeps both busy makes about 2 000 / (CPU ms per step) steps per second.

Part 2, one core: whole single-step episodes (reset, plan, simulate, observe, reward) with the same random
actions, per CPU second of this thread: the single environment, the batched environment (8 simulations,
1 thread), and, with ``--paper-python``, the paper's own MuJoCo 3 model (``paper_model_speed.py``, its C
rollout over the same TCP motions: physics only, its best case). Ratios per round, then their median.

    python benchmarks/env_throughput.py [--quick] [--rounds 5] [--seconds 20]
        [--paper-python /tmp/mj3/bin/python]

The paper's model needs MuJoCo 3 in a venv of its own:
``python3 -m venv /tmp/mj3 && /tmp/mj3/bin/pip install "mujoco==3.*"``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from dyndlo_vision.learning.config import RunConfig  # noqa: E402
from dyndlo_vision.learning.envs import make_vec_env  # noqa: E402
from dyndlo_vision.tasks import TipControl, make_env  # noqa: E402
from dyndlo_vision.tasks.batched import BatchedEpisodes  # noqa: E402
from dyndlo_vision.trajectory import BSplineTrajectory  # noqa: E402

HERE = Path(__file__).resolve().parent
#: (vectorised environment, n_envs) measured side by side; the first SubprocVecEnv row is the reference.
CONFIGS = (("dummy", 1), ("subproc", 2), ("batch", 2), ("batch", 4), ("batch", 8), ("batch", 16))
REFERENCE = ("subproc", 2)


def cpu_seconds(pids: list[int]) -> float:
    """CPU time (user + system) of this process, all its threads, and of the processes ``pids`` (Linux)."""
    total = sum(os.times()[:2])
    tick = os.sysconf("SC_CLK_TCK")
    for pid in pids:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    return total


def env_steps_per_s(multi_step: bool, kind: str, n_envs: int, seconds: float, seed: int
                    ) -> tuple[float, float]:
    """Env steps per second of wall time and CPU milliseconds per env step (this process, its threads and
    its worker processes), random actions, after one warm-up step."""
    config = RunConfig(task="tip-control", multi_step=multi_step, algo="sac", timesteps=1, n_envs=n_envs,
                       vec_env=kind)
    vec = make_vec_env(config, n_envs, seed, None, kind)
    rng = np.random.default_rng(seed)
    shape = (n_envs, *vec.action_space.shape)
    workers = [p.pid for p in getattr(vec, "processes", [])]
    try:
        vec.reset()
        vec.step(rng.uniform(-1, 1, shape).astype(np.float32))
        steps = 0
        cpu = cpu_seconds(workers)
        start = time.perf_counter()
        while time.perf_counter() - start < seconds:
            vec.step(rng.uniform(-1, 1, shape).astype(np.float32))
            steps += n_envs
        wall = time.perf_counter() - start
        return steps / wall, 1e3 * (cpu_seconds(workers) - cpu) / steps
    finally:
        vec.close()


def side_by_side(rounds: int, seconds: float, configs: tuple[tuple[str, int], ...]) -> list[dict[str, Any]]:
    rows = []
    for multi_step in (False, True):
        rates: dict[tuple[str, int], list[float]] = {c: [] for c in configs}
        costs: dict[tuple[str, int], list[float]] = {c: [] for c in configs}
        for r in range(rounds):
            for kind, n in configs:
                rate, cost = env_steps_per_s(multi_step, kind, n, seconds, seed=1000 * r)
                rates[(kind, n)].append(rate)
                costs[(kind, n)].append(cost)
        for kind, n in configs:
            vs_ref = [a / b for a, b in zip(rates[(kind, n)], rates[REFERENCE], strict=True)]
            vs_one = [a / b for a, b in zip(rates[(kind, n)], rates[("dummy", 1)], strict=True)]
            cost_ref = [b / a for a, b in zip(costs[(kind, n)], costs[REFERENCE], strict=True)]
            rows.append({"mode": "multi-step" if multi_step else "single-step", "vec_env": kind, "n_envs": n,
                         "env_steps_per_s": statistics.median(rates[(kind, n)]),
                         "vs_subproc_2": statistics.median(vs_ref), "vs_one_env": statistics.median(vs_one),
                         "cpu_ms_per_step": statistics.median(costs[(kind, n)]),
                         "cpu_efficiency_vs_subproc_2": statistics.median(cost_ref),
                         "rounds": [round(x, 2) for x in rates[(kind, n)]]})
    return rows


def one_core_episodes(episodes: int, seed: int) -> tuple[dict[str, float], list[np.ndarray]]:
    """Single-step episodes per CPU second of this thread: the single and the batched environment, the same
    random actions; and the TCP motions they follow (displacement from home at every 1 ms step)."""
    task = TipControl()
    spec = task.action_spec()
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (episodes, spec.size)).astype(np.float32)
    env = make_env("tip-control").unwrapped
    cpu = time.thread_time()
    for k in range(episodes):
        env.reset(seed=seed + k)
        env.step(actions[k])
    single = episodes / (time.thread_time() - cpu)
    n = 8
    batch = BatchedEpisodes(task, n, nthread=1)  # the physics on this thread: its CPU time is the cost
    cpu = time.thread_time()
    for start in range(0, episodes - episodes % n, n):
        ids = list(range(n))
        batch.reset(ids, [seed + start + i for i in ids], [None] * n)
        batch.step(actions[start:start + n])
    batched = (episodes - episodes % n) / (time.thread_time() - cpu)
    home = np.asarray(task.scene_config().grippers_m[0], dtype=float)
    motions = []
    for action in actions:
        points, times = spec.decode(action, home, 0.0, None)
        plan = BSplineTrajectory(points, times)
        t = env.scene.timestep * np.arange(int(np.ceil((plan.t_end + task.settle_s) / env.scene.timestep)))
        motions.append(plan.position(t) - home)
    return {"single_env_episodes_per_cpu_s": single, "batched_episodes_per_cpu_s": batched}, motions


def paper_episodes(python: str, motions: list[np.ndarray]) -> float:
    """The paper model's episodes per CPU second (C rollout of the same TCP motions, physics only)."""
    with tempfile.TemporaryDirectory() as tmp:
        refs = Path(tmp) / "refs.npz"
        length = max(len(m) for m in motions)
        pos = np.zeros((len(motions), length, 3))
        for k, m in enumerate(motions):
            pos[k, : len(m)] = m
        np.savez(refs, pos=pos, lengths=np.array([len(m) for m in motions]))
        cmd = [python, str(HERE / "paper_model_speed.py"), "--refs", str(refs), "--repeats", "1"]
        out = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    return out["episodes"] / out["rollout_cpu_s"][0]


def against_paper(rounds: int, episodes: int, python: str | None) -> dict[str, Any]:
    rows = []
    for r in range(rounds):
        row, motions = one_core_episodes(episodes, seed=100 * r)
        if python:
            row["paper_episodes_per_cpu_s"] = paper_episodes(python, motions)
            row["single_vs_paper"] = row["single_env_episodes_per_cpu_s"] / row["paper_episodes_per_cpu_s"]
            row["batched_vs_paper"] = row["batched_episodes_per_cpu_s"] / row["paper_episodes_per_cpu_s"]
        row["batched_vs_single"] = row["batched_episodes_per_cpu_s"] / row["single_env_episodes_per_cpu_s"]
        rows.append(row)
    return {key: statistics.median(r[key] for r in rows) for key in rows[0]} | {"rounds": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=20.0, help="wall time per configuration and round")
    parser.add_argument("--episodes", type=int, default=24, help="single-step episodes per round, one core")
    parser.add_argument("--paper-python", default=None,
                        help="python of a venv with mujoco==3.* (the paper's model); omitted: not compared")
    parser.add_argument("--quick", action="store_true", help="one short round of a few configurations")
    args = parser.parse_args()
    configs = CONFIGS
    if args.quick:
        args.rounds, args.seconds, args.episodes = 1, 1.0, 8
        configs = (("dummy", 1), ("subproc", 2), ("batch", 2))
    if args.paper_python and not Path(args.paper_python).exists():
        sys.exit(f"--paper-python {args.paper_python}: no such file")
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, python {platform.python_version()}; tip control, "
          f"random actions, no learning; {args.rounds} rounds of {args.seconds:g} s per configuration")
    print("| mode | vec env | n_envs | env steps/s (median) | vs SubprocVecEnv 2 | vs one env | CPU ms per "
          "env step | CPU per step, SubprocVecEnv 2 / this |")
    print("|---|---|---|---|---|---|---|---|")
    for row in side_by_side(args.rounds, args.seconds, configs):
        print(f"| {row['mode']} | {row['vec_env']} | {row['n_envs']} | {row['env_steps_per_s']:.1f} | "
              f"{row['vs_subproc_2']:.2f} | {row['vs_one_env']:.2f} | {row['cpu_ms_per_step']:.1f} | "
              f"{row['cpu_efficiency_vs_subproc_2']:.2f} |", flush=True)
    paper = against_paper(args.rounds, args.episodes, args.paper_python)
    print("\n# one core, single-step episodes per CPU second (medians over rounds)")
    print(json.dumps({k: round(v, 3) for k, v in paper.items() if k != "rounds"}))


if __name__ == "__main__":
    main()
