"""Explicit Euler with armature on the rod's twist hinges: accuracy, speed and robustness against the default.

MuJoCo 4's rod gives every edge a twist hinge on a body of 1e-9 kg m^2. Explicit integrators diverge on
these stiff, light hinges under the violent motions an RL agent explores, which is why the default is the
``discrete`` integrator. Armature on the hinges (``PhysicsOptions.twist_armature_kg_m2``) slows the twist
mode down. This script measures, per configuration:

* accuracy: the free tip along a planar and a 3D whip (peak TCP speed v_max = 1.8 m/s, 50 cm / 20 segments)
  against ``discrete`` at 0.125 ms *without* armature (the model itself), at 0.25 / 0.5 / 1.0 s;
* speed: CPU microseconds per physics step on the whip (one process, CPU time, so a loaded machine
  distorts it less than wall time) and the simulated seconds per CPU second that gives;
* robustness: episodes that diverged among random-action episodes of tip control (single- and multi-step),
  task IV and hooking, and the peak TCP speed of the diverged ones.

    python benchmarks/twist_armature.py [--episodes 20]
    taskset -c 0 python benchmarks/twist_armature.py --timing-only   # clean speed A/B on an idle core
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from integrator_choice import follow_reference, whip_reference  # noqa: E402

import dyndlo_vision  # noqa: E402,F401
from dyndlo_vision.sim import CableParams, PhysicsOptions, Scene, SceneConfig  # noqa: E402

CONFIGS = {
    "discrete 1 ms (default)": PhysicsOptions(),
    "discrete 1 ms, armature 1e-8": PhysicsOptions(twist_armature_kg_m2=1e-8),
    "discrete 1 ms, armature 1e-6": PhysicsOptions(twist_armature_kg_m2=1e-6),
    "Euler 1 ms": PhysicsOptions(integrator="Euler"),
    "Euler 1 ms, armature 1e-8": PhysicsOptions(integrator="Euler", twist_armature_kg_m2=1e-8),
    "Euler 1 ms, armature 1e-7": PhysicsOptions(integrator="Euler", twist_armature_kg_m2=1e-7),
    "Euler 1 ms, armature 1e-6": PhysicsOptions(integrator="Euler", twist_armature_kg_m2=1e-6),
    "Euler 2 ms, armature 1e-6": PhysicsOptions(
        integrator="Euler", timestep_s=0.002, twist_armature_kg_m2=1e-6
    ),
}
ROBUSTNESS = (
    ("tip control", "DynDLO/TipControl-v0", False),
    ("tip control multi-step", "DynDLO/TipControl-v0", True),
    ("task IV", "DynDLO/TimeOscillation-v0", False),
    ("hooking", "DynDLO/Hooking-v0", False),
)


def whip(physics: PhysicsOptions, planar: bool, duration_s: float = 1.0) -> tuple[np.ndarray, float]:
    """Tip positions at 100 Hz along the whip, and CPU seconds per physics step."""
    scene = Scene(SceneConfig(cable=CableParams(num_segments=20), physics=physics, settle_s=0.5))
    scene.reset()
    dt = scene.timestep
    n = int(round(duration_s / dt))
    t = np.arange(n) * dt
    pos, vel = whip_reference(t, 1.8)
    if not planar:  # add a lateral figure-eight component
        w = 2 * np.pi * 1.25
        pos[:, 1] = 0.06 * np.sin(2 * w * t) * np.clip(t / 0.4, 0, 1)
        vel[:, 1] = np.gradient(pos[:, 1], t)
    pos = pos + scene.gripper_home[0]
    tips, _, cpu = follow_reference(scene, pos, vel)
    return tips, cpu / n


def robustness(
    physics: PhysicsOptions, env_id: str, multi_step: bool, episodes: int
) -> tuple[int | str, list, float]:
    """Diverged episodes, peak TCP speeds of the diverged ones, simulated seconds per CPU second."""
    try:
        env = gym.make(env_id, multi_step=multi_step, physics=physics).unwrapped
    except ValueError:  # the scene blew up while settling, before any episode
        return "settling", [], float("nan")
    rng = np.random.default_rng(0)
    diverged, speeds, sim_s = 0, [], 0.0
    start = time.process_time()
    for seed in range(episodes):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, done, _, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        sim_s += info["sim_time_s"]
        if info.get("diverged"):
            diverged += 1
            speeds.append(round(env.monitor.max_tcp_speed_m_s, 1))
    return diverged, speeds, sim_s / (time.process_time() - start)


TIMING = ("discrete 1 ms (default)", "Euler 1 ms, armature 1e-8", "Euler 2 ms, armature 1e-6")


def timing(repeats: int = 3) -> None:
    """CPU time per physics step, alternating the configurations; median over planar and 3D whips."""
    costs: dict[str, list[float]] = {name: [] for name in TIMING}
    for _ in range(repeats):
        for name in TIMING:
            for planar in (True, False):
                costs[name].append(whip(CONFIGS[name], planar)[1])
    for name, values in costs.items():
        per_step = float(np.median(values))
        print(f"{name}: median {per_step * 1e6:.1f} CPU-us per step over {len(values)} whips, "
              f"{CONFIGS[name].timestep_s / per_step:.1f} simulated s per CPU s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=20, help="random-action episodes per task")
    parser.add_argument("--timing-only", action="store_true", help="only the alternating speed A/B")
    args = parser.parse_args()
    if args.timing_only:
        timing()
        return
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, python {platform.python_version()}; "
          f"command: python benchmarks/twist_armature.py --episodes {args.episodes}")
    reference = {planar: whip(PhysicsOptions(timestep_s=0.000125), planar)[0] for planar in (True, False)}
    print("| configuration | planar tip err @0.25/0.5/1.0 s (mm) | 3D tip err (mm) | CPU us/step | "
          "sim-s per CPU-s | diverged of " + str(args.episodes) + ": " + ", ".join(r[0] for r in ROBUSTNESS)
          + " | peak TCP speed of diverged (m/s) |")
    print("|---|---|---|---|---|---|---|")
    for name, physics in CONFIGS.items():
        errors, cost = [], []
        for planar in (True, False):
            tips, per_step = whip(physics, planar)
            err = np.linalg.norm(tips - reference[planar], axis=1) * 1e3
            errors.append(f"{err[24]:.2f} / {err[49]:.2f} / {err[99]:.1f}")
            cost.append(per_step)
        per_step = float(np.median(cost))
        counts, speeds = [], []
        for _, env_id, multi in ROBUSTNESS:
            d, s, _ = robustness(physics, env_id, multi, args.episodes)
            counts.append(str(d))
            speeds += s
        print(f"| {name} | {errors[0]} | {errors[1]} | {per_step * 1e6:.0f} | "
              f"{physics.timestep_s / per_step:.1f} | {' / '.join(counts)} | {speeds or '-'} |", flush=True)


if __name__ == "__main__":
    main()
