"""Speed of the paper's own cable model, MuJoCo 3.x: run in a separate venv with ``mujoco==3.*``, prints JSON.

The DynDLO paper (section III-A) builds the cable with MuJoCo 3's ``<composite type="cable">`` and the
``mujoco.elasticity.cable`` plugin: 20 capsule bodies on ball joints for a 50 cm cable, a TCP on three slide
joints with position actuators, 1 ms steps. MuJoCo 4 removed both (see its changelog), so this script needs
MuJoCo 3 and stays out of the package (it imports nothing from ``dyndlo_vision``):

    python3 -m venv /tmp/mj3 && /tmp/mj3/bin/pip install "mujoco==3.*"
    taskset -c 1 /tmp/mj3/bin/python benchmarks/paper_model_speed.py --refs refs.npz [--repeats 5]

``--refs`` is an ``.npz`` with ``pos`` (S, K, 3) TCP displacements from home, one row per 1 ms step, for S
episodes, and optionally ``lengths`` (S,): episode s uses its first ``lengths[s]`` rows
(``benchmarks/chain_speed.py`` writes it from random tip-control plans, so the three models follow the same
motions); without it one planar whip is used. Per repeat it reports the wall and CPU (thread) time
of stepping every episode with ``mj_step`` from Python and with MuJoCo's C rollout (``mujoco.rollout``), and
it counts MuJoCo's warnings (a diverging simulation is reset by MuJoCo and only shows there).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

HOME = (0.45, 0.0, 0.60)


def paper_mjcf(home: tuple[float, float, float] = HOME, length: float = 0.5, bodies: int = 20,
               radius: float = 0.002, mass: float = 0.010, young: float = 2e6, poisson: float = 0.3,
               damping: float = 5e-4, timestep: float = 0.001, integrator: str = "implicitfast",
               selfcollide: bool = True) -> str:
    """The paper's 50 cm cable: composite cable + elasticity plugin under a TCP on slide joints."""
    shear = young / (2 * (1 + poisson))
    seg = length / bodies
    # Density that gives each capsule (cylinder + two half spheres) its share of the mass.
    density = mass / bodies / (math.pi * radius**2 * seg + 4.0 / 3.0 * math.pi * radius**3)
    collide = "" if selfcollide else 'contype="2" conaffinity="1"'
    return f"""<mujoco model="dyndlo_paper_cable">
  <extension>
    <plugin plugin="mujoco.elasticity.cable"/>
  </extension>
  <option timestep="{timestep}" integrator="{integrator}"/>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1"/>
    <body name="tcp" pos="{home[0]} {home[1]} {home[2]}" gravcomp="1">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="z" type="slide" axis="0 0 1"/>
      <geom type="sphere" size="0.02" mass="1" contype="0" conaffinity="0"/>
      <body name="mount" euler="0 90 0">
        <composite prefix="c" type="cable" curve="s" count="{bodies + 1} 1 1" size="{length}" initial="none">
          <plugin plugin="mujoco.elasticity.cable">
            <config key="twist" value="{shear:.9g}"/>
            <config key="bend" value="{young:.9g}"/>
            <config key="vmax" value="0"/>
          </plugin>
          <joint kind="main" damping="{damping:.9g}"/>
          <geom type="capsule" size="{radius}" density="{density:.9g}" condim="3" friction="0.6" {collide}/>
        </composite>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="x" kp="2000" kv="100"/>
    <position joint="y" kp="2000" kv="100"/>
    <position joint="z" kp="2000" kv="100"/>
  </actuator>
</mujoco>
"""


def whip(duration: float = 2.0, timestep: float = 0.001) -> np.ndarray:
    """One planar whip of the TCP (peak about 1.4 m/s), (1, K, 3)."""
    t = np.arange(int(round(duration / timestep))) * timestep
    amp = 0.15
    pos = np.stack([amp * np.sin(9 * t), 0 * t, amp / 3 * np.sin(7 * t)], axis=1)
    return pos[None]


def warnings(d: mujoco.MjData) -> int:
    return int(sum(d.warning[i].number for i in range(len(d.warning))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--refs", help=".npz with pos (S, K, 3) TCP displacements per 1 ms step")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--damping", type=float, default=5e-4, help="joint damping of the cable (N m s/rad)")
    parser.add_argument("--integrator", default="implicitfast")
    parser.add_argument("--no-selfcollide", action="store_true", help="filter contacts between capsules")
    parser.add_argument("--settle", type=float, default=0.5, help="simulated s to settle before each run")
    parser.add_argument("--length", type=float, default=0.5, help="cable length (m)")
    parser.add_argument("--bodies", type=int, default=20, help="number of capsule bodies")
    parser.add_argument("--home", type=float, nargs=3, default=HOME, help="TCP start position (m)")
    args = parser.parse_args()

    mujoco.set_mju_user_warning(lambda text: None)  # counted from mjData.warning instead of printed
    if args.refs:
        data = np.load(args.refs)
        refs = list(data["pos"])
        if "lengths" in data:  # padded episodes of different lengths
            refs = [r[:n] for r, n in zip(refs, data["lengths"], strict=True)]
    else:
        refs = list(whip())
    xml = paper_mjcf(home=tuple(args.home), length=args.length, bodies=args.bodies, damping=args.damping,
                     integrator=args.integrator, selfcollide=not args.no_selfcollide)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    for _ in range(int(round(args.settle / m.opt.timestep))):
        mujoco.mj_step(m, d)
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    settled = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, settled, spec)
    cable_bodies = [b for b in range(m.nbody) if m.body(b).name.startswith("c")]
    steps = int(sum(r.shape[0] for r in refs))

    try:
        from mujoco import rollout
        roller = rollout.Rollout(nthread=0)
    except (ImportError, AttributeError):
        roller = None

    python_wall, python_cpu, rollout_wall, rollout_cpu, warn_python, warn_rollout = [], [], [], [], [], []
    bad_episodes: list[int] = []
    for repeat in range(args.repeats):
        warn = 0
        start, cpu = time.perf_counter(), time.thread_time()
        for e, ref in enumerate(refs):
            mujoco.mj_setState(m, d, settled, spec)
            for i in range(len(d.warning)):
                d.warning[i].number = 0
            for k in range(ref.shape[0]):
                d.ctrl[:3] = ref[k]
                mujoco.mj_step(m, d)
            warn += warnings(d)
            if repeat == 0 and warnings(d):
                bad_episodes.append(e)
        python_wall.append(time.perf_counter() - start)
        python_cpu.append(time.thread_time() - cpu)
        warn_python.append(warn)
        if roller is None:
            continue
        full = mujoco.mjtState.mjSTATE_FULLPHYSICS
        warn = 0
        start, cpu = time.perf_counter(), time.thread_time()
        for ref in refs:
            mujoco.mj_setState(m, d, settled, spec)
            state0 = np.empty(mujoco.mj_stateSize(m, full))
            mujoco.mj_getState(m, d, state0, full)
            states, _ = roller.rollout(m, d, state0[None], np.ascontiguousarray(ref[None]),
                                       control_spec=mujoco.mjtState.mjSTATE_CTRL)
            expected = state0[0] + m.opt.timestep * np.arange(1, ref.shape[0] + 1)
            warn += int(np.any(np.abs(states[0, :, 0] - expected) > 0.5 * m.opt.timestep))
        rollout_wall.append(time.perf_counter() - start)
        rollout_cpu.append(time.thread_time() - cpu)
        warn_rollout.append(warn)
    sim_s = steps * m.opt.timestep
    out = {
        "mujoco": mujoco.__version__,
        "machine": f"{platform.machine()}, {os.cpu_count()} cpus",
        "model": {"nq": m.nq, "nv": m.nv, "nbody": m.nbody, "cable_bodies": len(cable_bodies),
                  "integrator": args.integrator, "timestep": m.opt.timestep, "damping": args.damping,
                  "selfcollide": not args.no_selfcollide},
        "episodes": len(refs), "steps": steps, "sim_s": sim_s,
        "python_wall_s": python_wall, "python_cpu_s": python_cpu,
        "python_cpu_us_per_step": [c / steps * 1e6 for c in python_cpu], "warnings_python": warn_python,
        "episodes_with_warnings": bad_episodes,
        "rollout_wall_s": rollout_wall, "rollout_cpu_s": rollout_cpu,
        "rollout_cpu_us_per_step": [c / steps * 1e6 for c in rollout_cpu],
        "rollout_resets": warn_rollout,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
