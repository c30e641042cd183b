"""Does ``IKOptions.coarse_step_s`` change the joints ``joint_trajectory`` gives, and how fast is each?

Random tip-control single-step plans (actions uniform in [-1, 1], drawn from ``--seed``), sampled at each
arm's streaming period, are solved from the joints at the task's home with every coarse step given. Reports,
per arm and step: the median solve time, how many plans have no IK solution (out of reach), and the largest
joint difference from the first step's solution over the plans every step solves.

    python benchmarks/ik_coarse_step.py [--plans 60] [--steps 0.02,0.04,0.08] [--seed 0] [--out F.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import replace

import numpy as np

from dyndlo_vision.robots.feasibility import ROBOT_ARMS
from dyndlo_vision.robots.kinematics import IKError
from dyndlo_vision.tasks.tip_control import TCP_HOME_M, TipControl
from dyndlo_vision.trajectory import Replanner


def study(arm_name: str, plans: int, steps: list[float], seed: int) -> dict[str, object]:
    arm = ROBOT_ARMS[arm_name]
    kins = {}
    for step in steps:
        kin = arm.kinematics()
        kin.options = replace(kin.options, coarse_step_s=step)
        kins[step] = kin
    q0 = kins[steps[0]].ik(np.array(TCP_HOME_M)).q
    spec = TipControl(planar=True).action_spec()
    rng = np.random.default_rng(seed)
    times: dict[float, list[float]] = {s: [] for s in steps}
    unsolved = dict.fromkeys(steps, 0)
    worst = dict.fromkeys(steps, 0.0)
    compared = 0
    for _ in range(plans):
        traj = Replanner(spec, np.array([TCP_HOME_M])).replan(rng.uniform(-1.0, 1.0, spec.size), 0.0)
        ts = np.arange(0.0, traj.t_end, arm.period_s)
        p = traj.position(ts)
        q = {}
        for step, kin in kins.items():
            t0 = time.perf_counter()
            try:
                q[step] = kin.joint_trajectory(ts, p, q0).q
            except IKError:
                unsolved[step] += 1
            times[step].append(time.perf_counter() - t0)
        if len(q) == len(steps):
            compared += 1
            for step in steps:
                worst[step] = max(worst[step], float(np.abs(q[step] - q[steps[0]]).max()))
    return {"arm": arm_name, "plans": plans, "compared": compared,
            "median_ms": {str(s): 1e3 * float(np.median(v)) for s, v in times.items()},
            "unsolved": {str(s): n for s, n in unsolved.items()},
            "max_joint_difference_rad": {str(s): d for s, d in worst.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plans", type=int, default=60)
    parser.add_argument("--steps", default="0.02,0.04,0.08",
                        help="coarse steps (s); the first is the reference")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", help="JSON file for the results")
    args = parser.parse_args()
    steps = [float(s) for s in args.steps.split(",")]
    rows = [study(name, args.plans, steps, args.seed) for name in ("ur5e", "gofa")]
    for row in rows:
        print(json.dumps(row))
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"machine": platform.platform(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
