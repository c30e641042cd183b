"""What judging plans on a real arm costs per episode, and how many plans pass.

For each seed, the same action is stepped in a tip-control environment without an arm and in one with the
arm (``make_env(robot=...)``): the step's wall time with and without the check, and the verdict. Random
actions (uniform, the task's chance level) and a policy's actions are measured apart. A refused plan is not
simulated, so the "with arm" time of a refused plan is the check alone: the check's own cost is measured on
the plans the arm accepts (which are simulated in both), and, for every plan, by timing the check alone.

    python benchmarks/joint_feasibility.py --robot gofa --episodes 100 [--policy tip-control-single-step]
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

import dyndlo_vision  # noqa: F401  (MUJOCO_GL before mujoco)
from dyndlo_vision import policies
from dyndlo_vision.robots.feasibility import ROBOT_ARMS
from dyndlo_vision.tasks.registry import make_env


def main() -> None:
    raw = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=raw)
    parser.add_argument("--robot", choices=sorted(ROBOT_ARMS), default="gofa")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=100_000)
    parser.add_argument("--policy", default="tip-control-single-step", help="shipped name or .zip")
    parser.add_argument("--out", default=None, help="JSON file for the figures")
    parser.add_argument("--quick", action="store_true", help="3 episodes (a check that it runs)")
    args = parser.parse_args()
    if args.quick:
        args.episodes = 3

    plain = make_env("tip-control")
    judged = make_env("tip-control", robot=args.robot)
    model = policies.load(args.policy)
    rng = np.random.default_rng(args.seed)
    rows: dict[str, list[dict]] = {"random": [], args.policy: []}
    for kind in rows:
        for k in range(args.episodes):
            seed = args.seed + k
            obs, _ = plain.reset(seed=seed)
            judged.reset(seed=seed)
            if kind == "random":
                action = rng.uniform(-1, 1, plain.action_space.shape).astype(np.float32)
            else:
                action = model.predict(obs, deterministic=True)[0]
            t0 = time.perf_counter()
            _, _, _, _, info_plain = plain.step(action)
            t1 = time.perf_counter()
            _, _, _, _, info = judged.step(action)
            t2 = time.perf_counter()
            # The check alone, on the same plan (the judged env's, on the arm's cycle), timed apart.
            base = judged.unwrapped
            check = base.arm_check
            period = check.period_s
            times = period * np.arange(int(np.ceil(base.trajectory.t_end / period)) + 1)
            positions = base.replanner.references(times)[0][:, 0]
            check.start(0.0, positions[0])
            t3 = time.perf_counter()
            check.check(times, positions)
            t4 = time.perf_counter()
            tcp_ok = not any(v for key, v in info_plain["avoid"].items())
            rows[kind].append({
                "seed": seed, "plain_ms": 1e3 * (t1 - t0), "judged_ms": 1e3 * (t2 - t1),
                "check_ms": 1e3 * (t4 - t3), "feasible": bool(info["joint_feasible"]), "tcp_ok": tcp_ok,
                "hit": bool(info_plain["is_success"]),
                "kind": info.get("joint_limit_kind"), **info["joint_usage"],
            })
    report = {"robot": args.robot, "episodes": args.episodes, "seed": args.seed,
              "machine": f"{platform.machine()}, {platform.system()} {platform.release()}"}
    for kind, rs in rows.items():
        feasible = [r for r in rs if r["feasible"]]
        tcp_ok = [r for r in rs if r["tcp_ok"]]
        kinds: dict[str, int] = {}
        for r in rs:
            if r["kind"]:
                kinds[r["kind"]] = kinds.get(r["kind"], 0) + 1
        report[kind] = {
            "feasible": len(feasible),
            "tcp_checks_pass": len(tcp_ok),
            "feasible_of_tcp_checks_pass": sum(r["feasible"] for r in tcp_ok),
            "hits_without_arm": sum(r["hit"] for r in rs),
            "hits_with_feasible_plan": sum(r["hit"] and r["feasible"] for r in rs),
            "refusals": dict(sorted(kinds.items(), key=lambda kv: -kv[1])),
            "check_ms_median": float(np.median([r["check_ms"] for r in rs])),
            "episode_ms_median_without_arm": float(np.median([r["plain_ms"] for r in rs])),
            "episode_ms_median_with_arm_accepted": (float(np.median([r["judged_ms"] for r in feasible]))
                                                    if feasible else None),
            "episode_ms_median_without_arm_accepted": (float(np.median([r["plain_ms"] for r in feasible]))
                                                       if feasible else None),
            "velocity_fraction_median": _median(rs, "velocity_fraction"),
            "acceleration_fraction_median": _median(rs, "acceleration_fraction"),
        }
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)


def _median(rows: list[dict], key: str) -> float | None:
    values = [r[key] for r in rows if key in r]  # an IK refusal has no usage
    return float(np.median(values)) if values else None


if __name__ == "__main__":
    main()
