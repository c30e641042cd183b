"""Two-view tracking of the vault: the middle's estimate error per second-camera placement and setting.

Runs ``vaulting-multi-step`` through the loop on tracked state (two cameras) on randomised cables from issue
16's vaulting ranges, and prints the per-episode success and RMSE of P_DLO (the cable's middle) against the
simulator, with their median. The second camera and the matching parameters can be changed to compare
placements (docs/RESULTS.md, session 18)::

    python benchmarks/stereo_views.py                                  # the shipped placement and defaults
    python benchmarks/stereo_views.py --camera 0.70,-0.45,1.7 --smooth 5
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import dyndlo_vision  # noqa: E402,F401  (before mujoco)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--camera", default=None, metavar="X,Y,Z",
                   help="second camera position (it looks at (0.70, 0, 0.35)); default: the shipped one")
    p.add_argument("--smooth", type=int, default=None, help="StereoParams.smooth (default: its default)")
    p.add_argument("--min-crossing-deg", type=float, default=None, help="StereoParams.min_crossing_deg")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--seed", type=int, default=100000)
    p.add_argument("--views", type=int, choices=[1, 2], default=2)
    args = p.parse_args(argv)

    import dyndlo_vision.tasks.vaulting as vaulting
    import dyndlo_vision.tracking.stereo as stereo
    from dyndlo_vision import policies
    from dyndlo_vision.control.episode import run_loop_episode
    from dyndlo_vision.sim.scene import CameraPose
    from dyndlo_vision.tasks.registry import make_env
    from dyndlo_vision.tasks.wrappers import cable_ranges_for

    if args.camera is not None:
        pos = tuple(float(v) for v in args.camera.split(","))
        vaulting.SECOND_TRACKING_CAMERA = CameraPose.looking_at(pos, (0.70, 0.0, 0.35))
    overrides = {k: v for k, v in (("smooth", args.smooth), ("min_crossing_deg", args.min_crossing_deg))
                 if v is not None}
    params = stereo.StereoParams(**overrides)
    measure = stereo.stereo_measurement

    def with_params(*a: Any, **k: Any) -> Any:
        return measure(*a[:6], params)

    stereo.stereo_measurement = with_params  # what StereoTrackedState calls
    env = make_env("vaulting", multi_step=True, randomize_cable_every=1,
                   cable_ranges=cable_ranges_for("vaulting", "beyond"))
    policy = policies.load("vaulting-multi-step", env)
    rows = []
    def act(obs: Any) -> Any:
        return policy.predict(obs, deterministic=True)[0]

    for seed in range(args.seed, args.seed + args.episodes):
        policy.reset()
        record = run_loop_episode(env, act, seed, "tracked", views=args.views)
        rows.append({"seed": seed, "success": record["success"], "rmse": record["estimate_rmse_m"]})
        print(f"seed {seed}: success={record['success']} rmse={1e3 * record['estimate_rmse_m']:.1f} mm",
              flush=True)
    env.close()
    print(json.dumps({
        "machine": platform.machine(), "camera": list(vaulting.SECOND_TRACKING_CAMERA.pos_m),
        "views": args.views, "params": params.__dict__, "successes": sum(r["success"] for r in rows),
        "episodes": len(rows), "estimate_rmse_m_median": float(np.median([r["rmse"] for r in rows])),
    }))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
