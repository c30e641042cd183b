"""Speed of the chain cable against the rod and against the paper's own MuJoCo 3 model, in the same run.

All three follow the same TCP motions: ``--episodes`` random tip-control single-step plans (the TCP's
displacement from home at every 1 ms step, through the plan and the task's 0.5 s settle). Per round, in turn:

* chain and rod (this package, MuJoCo 4), tip-control scene: ``mj_step`` in a Python loop (CPU us per step)
  and MuJoCo's C rollout (simulated s per CPU s), then whole environment episodes (tip control,
  single-step, random actions, same seeds: episodes per CPU s, simulated s per CPU s);
* the paper's model (MuJoCo 3.x composite cable + elasticity plugin, ``benchmarks/paper_model_speed.py``)
  in its own venv, as a subprocess: the same ``mj_step`` loop and C rollout over the same motions.

Times are CPU (thread) time on one pinned core as well as wall time: on a shared, loaded machine the CPU time
is the steadier figure. Ratios are taken within each round, then their median over rounds is reported.

    python3 -m venv /tmp/mj3 && /tmp/mj3/bin/pip install "mujoco==3.*"
    taskset -c 1 python benchmarks/chain_speed.py --paper-python /tmp/mj3/bin/python [--rounds 5]
        [--episodes 20] [--long]

``--long`` also compares the 90 cm / 60-body cable (TCP at 1.2 m, hanging clear of the floor).
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
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from dyndlo_vision.sim import CableParams, PhysicsOptions, Scene, SceneConfig, paper_cable  # noqa: E402
from dyndlo_vision.tasks import TipControl, make_env  # noqa: E402
from dyndlo_vision.trajectory import BSplineTrajectory  # noqa: E402

HERE = Path(__file__).resolve().parent


def tip_control_actions(episodes: int, size: int) -> list[np.ndarray]:
    """The random tip-control single-step action of episode ``seed`` (the same for every model)."""
    return [np.random.default_rng(seed).uniform(-1, 1, size) for seed in range(episodes)]


def tip_control_plans(episodes: int, settle_s: float, dt: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """TCP displacement and velocity (K, 3) at every step of random tip-control single-step plans, each as
    long as its episode (the plan and the task's settle)."""
    task = TipControl()
    spec = task.action_spec()
    home = np.asarray(task.scene_config().grippers_m[0], dtype=float)
    pos, vel = [], []
    for action in tip_control_actions(episodes, spec.size):
        points, times = spec.decode(action, home, 0.0, None)
        plan = BSplineTrajectory(points, times)
        t = dt * np.arange(int(round((plan.t_end + settle_s) / dt)))
        pos.append(plan.position(t) - home)
        vel.append(plan.velocity(t))
    return pos, vel


def step_from_python(scene: Scene, controls: list[np.ndarray]) -> tuple[float, float, int]:
    """Each control sequence from a reset, one ``mj_step`` per row from Python: CPU s, wall s, MuJoCo
    warnings."""
    m, d = scene.model, scene.data
    warnings = 0
    wall, cpu = time.perf_counter(), time.thread_time()
    for ctrl in controls:
        scene.reset()
        for k in range(len(ctrl)):
            d.ctrl[:] = ctrl[k]
            mujoco.mj_step(m, d)
        warnings += int(sum(d.warning[i].number for i in range(len(d.warning))))
    return time.thread_time() - cpu, time.perf_counter() - wall, warnings


def time_scene(config: SceneConfig, pos: list[np.ndarray], vel: list[np.ndarray]) -> dict[str, float]:
    """CPU/wall time of the same motions with ``mj_step`` from Python and with the C rollout."""
    scene = Scene(config)
    home = scene.gripper_home[0]
    controls = [scene.tcp_controls((home + p)[:, None], v[:, None]) for p, v in zip(pos, vel, strict=True)]
    steps = sum(len(c) for c in controls)
    step_cpu, step_wall, warnings = step_from_python(scene, controls)
    wall, cpu = time.perf_counter(), time.thread_time()
    resets = 0
    for ctrl in controls:
        scene.reset()
        _, _, finite = scene.rollout(ctrl)
        resets += finite < len(ctrl)
    roll_cpu, roll_wall = time.thread_time() - cpu, time.perf_counter() - wall
    sim_s = steps * scene.timestep
    return {"step_cpu_us": step_cpu / steps * 1e6, "step_wall_us": step_wall / steps * 1e6,
            "rollout_sim_per_cpu_s": sim_s / roll_cpu, "rollout_sim_per_wall_s": sim_s / roll_wall,
            "warnings": warnings, "rollout_resets": resets, "nv": scene.model.nv}


def time_episodes(config: SceneConfig, episodes: int) -> dict[str, float]:
    """Tip-control single-step episodes with random actions: the same actions as the motions of
    :func:`tip_control_plans` (reset, plan, simulate, observe, reward)."""
    env = make_env("tip-control", cable=config.cable, physics=config.physics).unwrapped
    actions = tip_control_actions(episodes, env.action_space.shape[0])
    sim_s = 0.0
    diverged = 0
    wall, cpu = time.perf_counter(), time.thread_time()
    for seed in range(episodes):
        env.reset(seed=seed)
        _, _, _, _, info = env.step(actions[seed].astype(np.float32))
        sim_s += info["sim_time_s"]
        diverged += bool(info.get("diverged"))
    cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
    return {"episodes_per_cpu_s": episodes / cpu, "episodes_per_wall_s": episodes / wall,
            "env_sim_per_cpu_s": sim_s / cpu, "env_sim_per_wall_s": sim_s / wall, "diverged": diverged}


def time_paper(python: str, refs: Path, extra: list[str]) -> dict[str, Any]:
    cmd = [python, str(HERE / "paper_model_speed.py"), "--refs", str(refs), "--repeats", "1", *extra]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    r = json.loads(out)
    return {"step_cpu_us": r["python_cpu_us_per_step"][0],
            "step_wall_us": r["python_wall_s"][0] / r["steps"] * 1e6,
            "rollout_sim_per_cpu_s": r["sim_s"] / r["rollout_cpu_s"][0],
            "rollout_sim_per_wall_s": r["sim_s"] / r["rollout_wall_s"][0],
            "warnings": r["warnings_python"][0], "rollout_resets": r["rollout_resets"][0],
            "nv": r["model"]["nv"], "mujoco": r["mujoco"],
            # physics only (no planning, observation or reward): the paper model's best case
            "paper_episodes_per_cpu_s": r["episodes"] / r["rollout_cpu_s"][0],
            "paper_episodes_per_cpu_s_python": r["episodes"] / r["python_cpu_s"][0]}


def median(rows: list[dict[str, Any]], key: str) -> float:
    return float(statistics.median(r[key] for r in rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--paper-python", default="/tmp/mj3/bin/python",
                        help="python of a venv with mujoco==3.* ('' to skip the paper model)")
    parser.add_argument("--paper-damping", type=float, default=5e-4,
                        help="joint damping of the paper model, N m s/rad (5e-4: the probe's value; lower "
                             "values diverge under random whips at 1 ms)")
    parser.add_argument("--long", action="store_true", help="also the 90 cm / 60-body cable")
    parser.add_argument("--chain-integrators", nargs="*", default=[],
                        help="also the 50 cm chain under these integrators (e.g. implicitfast Euler)")
    parser.add_argument("--paper-variants", action="store_true",
                        help="also the paper model without self-contacts and with the discrete integrator")
    parser.add_argument("--json")
    args = parser.parse_args()
    mujoco.set_mju_user_warning(lambda text: None)
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, affinity {sorted(os.sched_getaffinity(0))}, "
          f"load {os.getloadavg()}; mujoco {mujoco.__version__}; {' '.join(sys.argv[1:])}", flush=True)

    chain, rod = CableParams(model="chain"), CableParams()
    paper_damping = args.paper_damping
    tip = TipControl()
    base = tip.scene_config()
    pos, vel = tip_control_plans(args.episodes, tip.settle_s, 0.001)
    variants: list[tuple[str, SceneConfig | None, list[str], list[np.ndarray], list[np.ndarray]]] = [
        ("chain 50 cm", replace(base, cable=chain), [], pos, vel),
        ("rod 50 cm", replace(base, cable=rod), [], pos, vel),
    ]
    for integrator in args.chain_integrators:
        physics = PhysicsOptions(integrator=integrator)
        config = replace(base, cable=chain, physics=physics)
        variants.append((f"chain 50 cm {integrator}", config, [], pos, vel))
    paper_variants = [("paper 50 cm", ["--damping", str(paper_damping)], pos)]
    if args.paper_variants:
        damping = ["--damping", str(paper_damping)]
        paper_variants += [("paper 50 cm, no self-contacts", [*damping, "--no-selfcollide"], pos),
                           ("paper 50 cm, discrete", [*damping, "--integrator", "discrete"], pos)]
    if args.long:
        long_chain, long_rod = paper_cable(0.9, model="chain"), paper_cable(0.9)
        high = replace(base, grippers_m=((0.45, 0.0, 1.2),))
        variants += [("chain 90 cm", replace(high, cable=long_chain), [], pos, vel),
                     ("rod 90 cm", replace(high, cable=long_rod), [], pos, vel)]
        paper_variants.append(("paper 90 cm", ["--damping", str(paper_damping), "--length", "0.9",
                                               "--bodies", "60", "--home", "0.45", "0", "1.2"], pos))
    results: dict[str, list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        refs = Path(tmp) / "refs.npz"
        lengths = np.array([len(p) for p in pos])
        padded = np.zeros((len(pos), lengths.max(), 3))
        for i, p in enumerate(pos):
            padded[i, :len(p)] = p
        np.savez(refs, pos=padded, lengths=lengths)
        for r in range(args.rounds):
            for name, config, _, p, v in variants:
                assert config is not None
                row = time_scene(config, p, v)
                if "50 cm" in name:
                    row.update(time_episodes(config, args.episodes))
                results.setdefault(name, []).append(row)
            if args.paper_python:
                for name, extra, _ in paper_variants:
                    results.setdefault(name, []).append(time_paper(args.paper_python, refs, extra))
            done = ", ".join(f"{k} {v[-1]['step_cpu_us']:.1f} us" for k, v in results.items())
            print(f"# round {r + 1}: {done}", flush=True)

    print(f"\nMedians over {args.rounds} rounds of {args.episodes} tip-control plans "
          f"({sum(len(p) for p in pos) / 1000:.0f} simulated s per measurement):\n")
    print("| model | nv | mj_step CPU us/step | (wall) | C rollout sim-s per CPU-s | (per wall-s) | "
          "env episodes per CPU-s | env sim-s per CPU-s | warnings / resets / diverged |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, rows in results.items():
        if "episodes_per_cpu_s" in rows[0]:
            env = f"{median(rows, 'episodes_per_cpu_s'):.2f} | {median(rows, 'env_sim_per_cpu_s'):.1f}"
        elif "paper_episodes_per_cpu_s" in rows[0]:
            env = f"({median(rows, 'paper_episodes_per_cpu_s'):.2f}, physics only) | -"
        else:
            env = "- | -"
        print(f"| {name} | {rows[0]['nv']} | {median(rows, 'step_cpu_us'):.1f} | "
              f"{median(rows, 'step_wall_us'):.1f} | {median(rows, 'rollout_sim_per_cpu_s'):.1f} | "
              f"{median(rows, 'rollout_sim_per_wall_s'):.1f} | {env} | "
              f"{sum(x['warnings'] for x in rows)} / {sum(x['rollout_resets'] for x in rows)} / "
              f"{sum(x.get('diverged', 0) for x in rows)} |")

    def ratio(a: str, b: str, key: str) -> str:
        if a not in results or b not in results:
            return "-"
        pairs = zip(results[a], results[b], strict=True)
        return f"{statistics.median(x[key] / y[key] for x, y in pairs):.2f}"

    print("\nSpeed ratios (median of per-round ratios; > 1: the first is faster):\n")
    print("| pair | mj_step (CPU) | C rollout (CPU) | env episodes (CPU) |")
    print("|---|---|---|---|")
    pairs = [("chain 50 cm", "rod 50 cm"), ("chain 50 cm", "paper 50 cm"), ("rod 50 cm", "paper 50 cm")]
    if args.long:
        pairs += [("chain 90 cm", "rod 90 cm"), ("chain 90 cm", "paper 90 cm")]
    pairs += [(f"chain 50 cm {i}", "chain 50 cm") for i in args.chain_integrators]
    if args.paper_variants:
        pairs += [("chain 50 cm", "paper 50 cm, no self-contacts"), ("chain 50 cm", "paper 50 cm, discrete")]

    def env_ratio(a: str, b: str) -> str:
        if a not in results or b not in results:
            return "-"
        if "episodes_per_cpu_s" in results[b][0]:
            return ratio(a, b, "episodes_per_cpu_s")
        if "paper_episodes_per_cpu_s" in results[b][0] and "episodes_per_cpu_s" in results[a][0]:
            pairs_ = zip(results[a], results[b], strict=True)
            value = statistics.median(x["episodes_per_cpu_s"] / y["paper_episodes_per_cpu_s"]
                                      for x, y in pairs_)
            return f"{value:.2f} (vs physics only)"
        return "-"

    for a, b in pairs:
        env = env_ratio(a, b)
        print(f"| {a} / {b} | {ratio(b, a, 'step_cpu_us')} | {ratio(a, b, 'rollout_sim_per_cpu_s')} | "
              f"{env} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"argv": sys.argv[1:], "results": results}, fh, indent=1)


if __name__ == "__main__":
    main()
