"""Does the paper's own cable model vault in our vaulting scene? MuJoCo 3's composite cable, replayed.

Issue 15 found (session 9, second layout: support 0.2 m beyond the box) that the rod's flick vaulted the
MuJoCo 4 rod but not the chain, and asked which of the two behaves like the paper's model; this script showed
that the paper's model agrees with the chain. Session 12 moved to the third layout (support 0.45 m beyond the
box), where one carry vaults both; the script now replays that layout. It rebuilds the vaulting scene around
MuJoCo 3's ``<composite type="cable">`` with the ``mujoco.elasticity.cable`` plugin: 60 capsules for 90 cm,
10 g, r = 2 mm, E = 2 MPa, on the same initial path, far end connected to the support, the same box. It drives
the TCP (on three slide joints with position actuators, as the paper's model) along exactly the references our
environment computes for an action. Two steps, two venvs:

    # 1. in the package's venv (MuJoCo 4): the TCP references and the initial path
    python benchmarks/paper_model_vault.py --export vault_refs.npz [--action carry | A1,...,A9]
    # 2. in a MuJoCo 3 venv (python3 -m venv /tmp/mj3 && /tmp/mj3/bin/pip install "mujoco==3.*")
    /tmp/mj3/bin/python benchmarks/paper_model_vault.py --refs vault_refs.npz [--damping 5e-4 1e-4 2e-5]

Step 2 imports nothing from ``dyndlo_vision``. It settles the cable for 1.5 s (as the scene does), follows the
references for 2 s, lets the cable land for 0.5 s more, and prints per joint damping: the middle node's final
position and its largest x on the way, where (y, z) the cable crosses the box's mid-plane, whether
that is a vault by the task's rule (middle beyond the far face and below the top, every crossing no lower than
1 cm under the top and within the box's width), MuJoCo's warnings and the largest edge stretch.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

# The scene (dyndlo_vision.tasks.vaulting), repeated here so that step 2 needs only MuJoCo 3.
OBSTACLE_CENTRE_M = (0.55, 0.0, 0.07)
OBSTACLE_SIZE_M = (0.04, 0.08, 0.14)
SUPPORT_M = (1.00, 0.0, 0.01)
LENGTH_M, SEGMENTS, RADIUS_M, MASS_KG, YOUNG_PA, POISSON = 0.9, 60, 0.002, 0.010, 2.0e6, 0.3


def export(out: str, action_text: str) -> None:
    """Step 1: the TCP references (1 ms steps) of one action from the reset state, and the initial path."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from dyndlo_vision.sim.chain import walk_polyline
    from dyndlo_vision.tasks import make_env
    from dyndlo_vision.tasks.baselines import FlickVault
    from dyndlo_vision.tasks.vaulting import initial_path

    env = make_env("vaulting")
    base = env.unwrapped
    obs, _ = env.reset(seed=0)
    if action_text == "carry":  # the scripted vault
        action = np.asarray(FlickVault(env)(obs), dtype=np.float32)
    else:
        action = np.array([float(v) for v in action_text.split(",")], dtype=np.float32)
    dt = base.scene.timestep
    base.replanner.replan(action.astype(np.float64), base.scene.time)  # what env.step plans from this action
    n = int(round(2.0 / dt))
    ref_p, _ = base.replanner.references(base.scene.time + dt * np.arange(1, n + 1))
    path = np.array(initial_path(LENGTH_M))
    # Vertices one segment's chord apart (as the package lays its chain), so that no capsule is shortened
    # where the path turns (equal arc-length samples cut the corner at the foot of the drop by 25 %).
    vertices = np.vstack([path[0], walk_polyline(path, path[0], 0, LENGTH_M / SEGMENTS, SEGMENTS)])
    np.savez(out, pos=ref_p.reshape(n, -1)[:, :3], home=np.asarray(base.scene.gripper_home[0]),
             vertices=vertices, action=action)
    print(f"wrote {out}: {n} TCP references, action {np.round(action, 4).tolist()}")


def scene_mjcf(home: np.ndarray, vertices: np.ndarray, damping: float, integrator: str) -> str:
    """The vaulting scene around the paper's composite cable (MuJoCo 3 only)."""
    shear = YOUNG_PA / (2 * (1 + POISSON))
    seg = LENGTH_M / SEGMENTS
    density = MASS_KG / SEGMENTS / (math.pi * RADIUS_M**2 * seg + 4.0 / 3.0 * math.pi * RADIUS_M**3)
    vertex = " ".join(f"{c:.7f}" for c in (vertices - home).ravel())
    half = " ".join(f"{s / 2:g}" for s in OBSTACLE_SIZE_M)
    centre = " ".join(f"{c:g}" for c in OBSTACLE_CENTRE_M)
    support = " ".join(f"{c:g}" for c in SUPPORT_M)
    slides = "".join(f'<joint name="{a}" type="slide" axis="{v}"/>' for a, v in
                     (("x", "1 0 0"), ("y", "0 1 0"), ("z", "0 0 1")))
    servos = "".join(f'<position joint="{a}" kp="2000" kv="100"/>' for a in "xyz")
    return f"""<mujoco model="paper_cable_vaulting">
  <extension><plugin plugin="mujoco.elasticity.cable"/></extension>
  <option timestep="0.001" integrator="{integrator}"/>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1"/>
    <geom name="obstacle" type="box" pos="{centre}" size="{half}"/>
    <body name="support" pos="{support}"/>
    <body name="tcp" pos="{home[0]:.7f} {home[1]:.7f} {home[2]:.7f}" gravcomp="1">
      {slides}
      <geom type="sphere" size="0.02" mass="1" contype="0" conaffinity="0"/>
      <body name="mount">
        <composite prefix="c" type="cable" vertex="{vertex}" initial="none">
          <plugin plugin="mujoco.elasticity.cable">
            <config key="twist" value="{shear:.9g}"/>
            <config key="bend" value="{YOUNG_PA:.9g}"/>
            <config key="vmax" value="0"/>
          </plugin>
          <joint kind="main" damping="{damping:.9g}"/>
          <geom type="capsule" size="{RADIUS_M}" density="{density:.9g}" condim="3" friction="0.6"
                contype="2" conaffinity="1"/>
        </composite>
      </body>
    </body>
  </worldbody>
  <equality><connect body1="cB_last" body2="support" anchor="{seg:.7f} 0 0"/></equality>
  <actuator>{servos}</actuator>
</mujoco>"""


def crossings(nodes: np.ndarray) -> list[tuple[float, float]]:
    """(y, z) where the node polyline crosses the box's mid-plane x = its centre."""
    x_mid = OBSTACLE_CENTRE_M[0]
    side = np.sign(nodes[:, 0] - x_mid)
    points = []
    for i in np.flatnonzero(side[:-1] * side[1:] <= 0):
        a, b = nodes[i], nodes[i + 1]
        w = 0.0 if b[0] == a[0] else (x_mid - a[0]) / (b[0] - a[0])
        points.append((float(a[1] + w * (b[1] - a[1])), float(a[2] + w * (b[2] - a[2]))))
    return points


def replay(refs_path: str, damping: float, integrator: str) -> dict:
    """Step 2 (MuJoCo 3): settle, follow the references, land; the outcome by the task's rule."""
    import mujoco

    data = np.load(refs_path)
    refs, home, vertices = data["pos"], data["home"], data["vertices"]
    m = mujoco.MjModel.from_xml_string(scene_mjcf(home, vertices, damping, integrator))
    d = mujoco.MjData(m)
    seg = LENGTH_M / SEGMENTS
    bodies = ([m.body("cB_first").id] + [m.body(f"cB_{i}").id for i in range(1, SEGMENTS - 1)]
              + [m.body("cB_last").id])

    def nodes() -> np.ndarray:
        end = d.xpos[bodies[-1]] + d.xmat[bodies[-1]].reshape(3, 3)[:, 0] * seg
        return np.vstack([d.xpos[bodies], end])

    mujoco.mj_forward(m, d)
    start_error = float(np.abs(nodes() - vertices).max())
    for _ in range(1500):
        mujoco.mj_step(m, d)
    middle_x = []
    for k in range(refs.shape[0]):
        d.ctrl[:3] = refs[k] - home
        mujoco.mj_step(m, d)
        middle_x.append(float(d.xpos[bodies[SEGMENTS // 2]][0]))
    for _ in range(500):
        mujoco.mj_step(m, d)
    final = nodes()
    middle = final[SEGMENTS // 2]
    points = crossings(final)
    top = OBSTACLE_CENTRE_M[2] + OBSTACLE_SIZE_M[2] / 2
    landed = middle[0] > OBSTACLE_CENTRE_M[0] + OBSTACLE_SIZE_M[0] / 2 and middle[2] < top
    over = bool(points) and all(z >= top - 0.01 and abs(y) <= OBSTACLE_SIZE_M[1] / 2 for y, z in points)
    return {
        "mujoco": mujoco.__version__,
        "damping": damping,
        "integrator": integrator,
        "start_error_m": start_error,
        "middle_final_m": np.round(middle, 4).tolist(),
        "middle_max_x_m": round(max(middle_x), 4),
        "crossings_yz_m": np.round(points, 4).tolist(),
        "vault": bool(landed and over),
        "warnings": int(sum(d.warning[i].number for i in range(len(d.warning)))),
        "max_edge_stretch": float(np.abs(np.linalg.norm(np.diff(final, axis=0), axis=1) / seg - 1).max()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--export", metavar="OUT.npz", help="step 1 (MuJoCo 4 venv): write the references")
    parser.add_argument("--action", default="carry",
                        help="step 1: 'carry' (the scripted vault, FlickVault.SHAPE) or a normalised action "
                        "A1,...,A9")
    parser.add_argument("--refs", metavar="IN.npz", help="step 2 (MuJoCo 3 venv): replay these references")
    parser.add_argument("--damping", type=float, nargs="+", default=[5e-4, 1e-4, 2e-5],
                        help="joint damping of the cable, N m s/rad (the paper model's benchmark uses 5e-4)")
    parser.add_argument("--integrator", default="implicitfast")
    args = parser.parse_args()
    if args.export:
        export(args.export, args.action)
        return
    if not args.refs:
        parser.error("give --export OUT.npz (step 1) or --refs IN.npz (step 2)")
    for damping in args.damping:
        print(json.dumps(replay(args.refs, damping, args.integrator)), flush=True)


if __name__ == "__main__":
    main()
