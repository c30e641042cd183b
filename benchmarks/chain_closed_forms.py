"""The chain cable against closed forms: prints the figures tests/sim/test_chain.py checks (issue 15).

    PYTHONPATH=. python benchmarks/chain_closed_forms.py

Hanging chain (TCP fixed, started at 3 degrees in its first mode): omega_1 against the discrete N-link
pendulum and the continuous chain's 1.2025 sqrt(g / L') (L' = L - l, the first link is clamped) and
1.2025 sqrt(g / L). Static cantilever (10 cm, horizontal): tip sag against the discrete closed form and
Euler-Bernoulli w L^4 / (8 EI).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "sim"))
import test_chain as t  # noqa: E402

from dyndlo_vision.sim import Scene, SceneConfig  # noqa: E402
from dyndlo_vision.sim import chain as chain_model  # noqa: E402
from dyndlo_vision.sim.scene import CABLE_NAME  # noqa: E402

G = 9.81


def hanging(young: float) -> None:
    cable = t._chain(young_pa=young, damping_s=0.0)
    home = np.array([0.5, 0.0, 0.8])
    seg = cable.segment_length_m
    probe = Scene(SceneConfig(cable=cable, grippers_m=(tuple(home),), settle_s=0.0))
    body = probe.model.body(chain_model.body_name(CABLE_NAME, 1))
    wd, shape = t._pendulum_first_mode(float(body.mass[0]), float(body.inertia[0]), seg, float(body.ipos[2]),
                                       cable.bending_stiffness_nm2 / seg, cable.num_segments - 1)
    theta = math.radians(3.0) * shape / np.abs(shape).max()
    path = [home, home + [0, 0, -seg]]
    for th in theta:
        path.append(path[-1] + seg * np.array([math.sin(th), 0.0, -math.cos(th)]))
    path[-1] = path[-1] + (path[-1] - path[-2])
    scene = Scene(SceneConfig(cable=cable, grippers_m=(tuple(home),), initial_path_m=tuple(map(tuple, path)),
                              settle_s=0.0))
    scene.reset()
    x = []
    for _ in range(2000):
        scene.step(2)
        x.append(scene.cable_nodes()[-1, 0])
    w = t._zero_crossing_omega(np.array(x), 0.002)
    cont = 1.2025 * math.sqrt(G / (cable.length_m - seg))
    full = 1.2025 * math.sqrt(G / cable.length_m)
    print(f"hanging E={young:g}: omega {w:.4f} rad/s; "
          f"discrete N-link {wd:.4f} ({(w / wd - 1) * 100:+.3f} %); "
          f"1.2025 sqrt(g/(L-l)) {cont:.4f} ({(w / cont - 1) * 100:+.2f} %); "
          f"1.2025 sqrt(g/L) {full:.4f} ({(w / full - 1) * 100:+.2f} %)")


def cantilever(n: int) -> None:
    cable = t._chain(length_m=0.1, num_segments=n, mass_kg=0.002, radius_m=0.001, young_pa=8e8,
                     damping_s=0.05)
    scene = Scene(SceneConfig(cable=cable, grippers_m=((0.5, 0.0, 0.5),), cable_axis=(1.0, 0.0, 0.0),
                              settle_s=3.0))
    scene.reset()
    d = 0.5 - scene.cable_nodes()[-1, 2]
    disc = t._cantilever_tip_deflection(cable)
    eb = (cable.mass_kg * G / cable.length_m) * cable.length_m**4 / (8 * cable.bending_stiffness_nm2)
    print(f"cantilever N={n}: sag {d * 1e3:.4f} mm; discrete closed form {disc * 1e3:.4f} mm "
          f"({(d / disc - 1) * 100:+.3f} %); "
          f"Euler-Bernoulli wL^4/8EI {eb * 1e3:.4f} mm ({(d / eb - 1) * 100:+.2f} %)")


if __name__ == "__main__":
    for young in (1e3, 2e6):
        hanging(young)
    for n in (10, 20, 40):
        cantilever(n)
