"""Where a chain-cable step spends its time, and what each candidate setting changes (issue 15, step 3).

Profiles the 50 cm chain in the tip-control scene on the same random tip-control single-step motions as
``benchmarks/chain_speed.py``: MuJoCo's own stage timers (``mjData.timer``, through ``mjcb_time``), then the
CPU time of a Python ``mj_step`` loop for variants, interleaved per round (A, B, C, ..., A, B, C, ...), with
the median over rounds of each variant's time relative to the package's chain:

* ``implicitfast`` instead of ``discrete``; ``Euler``;
* no twist-correction actuators (``poisson=0``, so GJ = EI: the cost of the 19 bias actuators);
* no quadratic damping; contacts off (``disableflags``: the cost of collision detection);
* fewer solver iterations; the CG solver.

    taskset -c 1 python benchmarks/chain_profile.py [--rounds 7] [--episodes 20]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from dataclasses import replace
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402

from dyndlo_vision.sim import CableParams, PhysicsOptions, Scene  # noqa: E402
from dyndlo_vision.tasks import TipControl  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from chain_speed import step_from_python, tip_control_plans  # noqa: E402


def _dense(m: mujoco.MjModel) -> None:
    m.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE


def _sparse(m: mujoco.MjModel) -> None:
    m.opt.jacobian = mujoco.mjtJacobian.mjJAC_SPARSE


def _pgs(m: mujoco.MjModel) -> None:
    m.opt.solver = mujoco.mjtSolver.mjSOL_PGS


def _no_contacts(m: mujoco.MjModel) -> None:
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT


def variants() -> dict[str, tuple[CableParams, PhysicsOptions, Any]]:
    chain, physics = CableParams(model="chain"), PhysicsOptions()
    return {
        "chain (package: discrete, Newton 50)": (chain, physics, None),
        "implicitfast": (chain, replace(physics, integrator="implicitfast"), None),
        "Euler": (chain, replace(physics, integrator="Euler"), None),
        "no twist actuators (poisson 0)": (replace(chain, poisson=0.0), physics, None),
        "no quadratic damping": (replace(chain, damping_quadratic_s2=0.0), physics, None),
        "contacts off": (chain, physics, _no_contacts),
        "dense Jacobian": (chain, physics, _dense),
        "sparse Jacobian": (chain, physics, _sparse),
        "PGS solver": (chain, physics, _pgs),
        "Newton 10 iterations": (chain, replace(physics, iterations=10), None),
        "CG solver": (chain, replace(physics, solver="CG"), None),
        "implicitfast, no twist actuators": (replace(chain, poisson=0.0),
                                             replace(physics, integrator="implicitfast"), None),
    }


def build(cable: CableParams, physics: PhysicsOptions, change: Any, pos: list, vel: list) -> tuple:
    task = TipControl(cable=cable, physics=physics)
    scene = Scene(task.scene_config())
    if change is not None:
        change(scene.model)
    home = scene.gripper_home[0]
    controls = [scene.tcp_controls((home + p)[:, None], v[:, None]) for p, v in zip(pos, vel, strict=True)]
    return scene, controls


def loop(scene: Scene, controls: list) -> tuple[float, int]:
    """CPU microseconds per ``mj_step`` over the motions, and MuJoCo's warnings."""
    cpu_s, _, warnings = step_from_python(scene, controls)
    return cpu_s / sum(len(c) for c in controls) * 1e6, warnings


def stage_profile(scene: Scene, controls: list) -> dict[str, float]:
    """Share of each MuJoCo timer stage in a step (callback overhead included in every stage alike)."""
    m, d = scene.model, scene.data
    mujoco.set_mjcb_time(time.perf_counter)
    try:
        for i in range(len(d.timer)):
            d.timer[i].duration = 0
            d.timer[i].number = 0
        for ctrl in controls:
            scene.reset()
            for k in range(len(ctrl)):
                d.ctrl[:] = ctrl[k]
                mujoco.mj_step(m, d)
    finally:
        mujoco.set_mjcb_time(None)
    names = [n for n in dir(mujoco.mjtTimer) if n.startswith("mjTIMER_") and n != "mjNTIMER"]
    index = {n: int(getattr(mujoco.mjtTimer, n)) for n in names}
    total = d.timer[mujoco.mjtTimer.mjTIMER_STEP].duration
    ordered = sorted(index.items(), key=lambda x: x[1])
    return {n.removeprefix("mjTIMER_"): d.timer[i].duration / total for n, i in ordered
            if i < len(d.timer) and total > 0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    mujoco.set_mju_user_warning(lambda text: None)
    print(f"# {os.cpu_count()} cpus, affinity {sorted(os.sched_getaffinity(0))}, load {os.getloadavg()}; "
          f"mujoco {mujoco.__version__}; {' '.join(sys.argv[1:])}", flush=True)
    pos, vel = tip_control_plans(args.episodes, TipControl().settle_s, 0.001)
    built = {name: build(*v, pos, vel) for name, v in variants().items()}
    base = next(iter(built))
    shares = stage_profile(*built[base])
    print("\nMuJoCo stage timers, share of mj_step (package chain):\n")
    for name, share in shares.items():
        if share > 0.005 and name != "STEP":
            print(f"- {name}: {share * 100:.1f} %")
    times: dict[str, list[float]] = {name: [] for name in built}
    warns: dict[str, int] = dict.fromkeys(built, 0)
    for r in range(args.rounds):
        for name, (scene, controls) in built.items():
            us, w = loop(scene, controls)
            times[name].append(us)
            warns[name] += w
        print(f"# round {r + 1}: " + ", ".join(f"{t[-1]:.1f}" for t in times.values()), flush=True)
    print(f"\nmj_step CPU us per step (median of {args.rounds} rounds) and speed relative to the package's "
          "chain (median of per-round ratios, > 1: faster):\n")
    print("| variant | us/step | speed vs package chain | MuJoCo warnings |")
    print("|---|---|---|---|")
    for name, t in times.items():
        rel = statistics.median(b / x for b, x in zip(times[base], t, strict=True))
        print(f"| {name} | {statistics.median(t):.1f} | {rel:.2f} | {warns[name]} |")


if __name__ == "__main__":
    main()
