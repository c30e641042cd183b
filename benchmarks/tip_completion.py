"""How far the tracked polyline's end is from the true tip, by how much of the cable the polyline covers.

Runs tracked loop episodes of tip control (``run_loop_episode``, the demo's loop) and, for every frame the
tracker measures, compares with the simulator's truth:
- the polyline's own last node (what the loop took as the tip before the known cable was used);
- :func:`~dyndlo_vision.tracking.tracker.tip_from_polyline`, which continues a short polyline straight by the
  missing length (what the loop uses now; None under ``MIN_SEEN_LENGTH_FRACTION`` of the cable).
Frames are binned by the share of the cable's length the polyline covers, from the gripper. These figures set
``MIN_SEEN_LENGTH_FRACTION`` (docs/RESULTS.md, "The switch").

    python benchmarks/tip_completion.py [--policy tip-control-multi-step] [--episodes 30] [--seed 500000]
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np

import dyndlo_vision  # noqa: F401
from dyndlo_vision import policies
from dyndlo_vision.control.episode import run_loop_episode
from dyndlo_vision.tracking.tracker import CableTracker, tip_from_polyline

BINS = ((0.0, 0.3), (0.3, 0.5), (0.5, 0.8), (0.8, 0.97), (0.97, 0.99), (0.99, 1.01), (1.01, 9.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--policy", default="tip-control-multi-step")
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--seed", type=int, default=500000)
    args = parser.parse_args()

    meta = policies.metadata(args.policy)
    env = gym.make("DynDLO/TipControl-v0", multi_step=meta["multi_step"], **meta["env_options"])
    base = env.unwrapped
    model = policies.load(args.policy, env=env)
    length_m = base.scene.config.cable.length_m
    rows: list[tuple[float, float, float]] = []
    process = CableTracker.process

    def recording_process(self: CableTracker, rgb, t_capture, depth=None, anchor_uv=None):  # type: ignore[no-untyped-def]
        meas = process(self, rgb, t_capture, depth=depth, anchor_uv=anchor_uv)
        held = base.scene.tcp_positions()[0]  # no camera latency here: the frame is the present
        end = meas.point(-1)
        if end is not None:
            truth = base.cable_nodes()[-1]
            continued = tip_from_polyline(meas, held, length_m, min_fraction=0.0)
            rows.append((meas.length_from(held) / length_m, float(np.linalg.norm(end - truth)),
                         float(np.linalg.norm(continued - truth))))
        return meas

    CableTracker.process = recording_process  # type: ignore[method-assign]
    try:
        for k in range(args.episodes):
            run_loop_episode(env, lambda obs: model.predict(obs, deterministic=True)[0], args.seed + k,
                             observation="tracked")
    finally:
        CableTracker.process = process  # type: ignore[method-assign]
    data = np.array(rows)
    table = []
    for lo, hi in BINS:
        sel = (data[:, 0] >= lo) & (data[:, 0] < hi)
        if not sel.any():
            continue
        end, cont = 1000 * data[sel, 1], 1000 * data[sel, 2]
        table.append({"share_of_cable": [lo, hi], "frames": int(sel.sum()),
                      "end_mm_median": round(float(np.median(end)), 1),
                      "end_mm_max": round(float(end.max()), 1),
                      "continued_mm_median": round(float(np.median(cont)), 1),
                      "continued_mm_max": round(float(cont.max()), 1)})
    print(json.dumps({"policy": args.policy, "episodes": args.episodes, "seed": args.seed,
                      "frames": len(rows), "bins": table}, indent=2))


if __name__ == "__main__":
    main()
