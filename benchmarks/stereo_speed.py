"""Costs of two-view tracking: one render of a loop camera per task, and the matching of two centrelines.

    python benchmarks/stereo_speed.py                      # MuJoCo's default tessellation (28 x 16)
    python benchmarks/stereo_speed.py --tessellation 12,6  # cheaper capsules and spheres (docs/RESULTS.md)

Medians over ``--repeats`` calls, one process; run it on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import dyndlo_vision  # noqa: E402,F401  (before mujoco)


def _median_ms(fn: object, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _matching_ms(base: object, repeats: int) -> tuple[float, int]:
    """Median time to match the vault cameras' centrelines of an arch from the TCP over to the support, its
    middle 0.12 m off the motion plane, as dense as the tracker's (about a pixel apart); and their length."""
    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.tracking import match_centerlines

    first = MujocoCamera(base.model, base.data, "tracking")  # type: ignore[attr-defined]
    second = MujocoCamera(base.model, base.data, "tracking2")  # type: ignore[attr-defined]
    s = np.linspace(0.0, 1.0, 400)
    arch = np.column_stack([0.4 + 0.6 * s, -0.12 * np.sin(np.pi * s),
                            0.5 - 0.49 * s + 0.25 * np.sin(np.pi * s)])
    ca, cb = first.calibration, second.calibration
    ua, ub = ca.project(arch[8:]), cb.project(arch[8:])
    first.close()
    second.close()
    return _median_ms(lambda: match_centerlines(ca, ua, cb, ub, arch[0]), repeats), len(ua)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--tessellation", default=None, metavar="SLICES,STACKS",
                   help="MuJoCo's visual quality numslices,numstacks for the renders (default: the scene's)")
    p.add_argument("--repeats", type=int, default=60)
    args = p.parse_args(argv)

    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.control.sim_env import as_sim_env
    from dyndlo_vision.tasks.registry import make_env

    result: dict[str, object] = {"machine": platform.machine(), "tessellation": args.tessellation}
    for task in ("tip-control", "vaulting"):
        env = make_env(task, multi_step=True)
        env.reset(seed=0)
        base = as_sim_env(env)
        if args.tessellation:
            slices, stacks = (int(v) for v in args.tessellation.split(","))
            base.model.vis.quality.numslices, base.model.vis.quality.numstacks = slices, stacks
        camera = MujocoCamera(base.model, base.data, "tracking")
        result[f"{task}_render_ms"] = _median_ms(camera.read, args.repeats)
        camera.close()
        if task == "vaulting":
            result["matching_ms"], result["matching_path_points"] = _matching_ms(base, args.repeats)
        env.close()
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
