"""Task IV: a learned single-step policy against the paper's geometric lift at the same trajectory time.

Task IV starts from the same state every episode and its goal is fixed, so a deterministic policy plays the
same episode every time: one episode each is the comparison. The geometric baseline
(``dyndlo_vision.tasks.baselines.GeometricLift``) gets the planned trajectory time of the learned plan.

    python benchmarks/task4_vs_geometric.py POLICY [--target up|down] [--layout diagonal|vertical] [--quick]

``--quick`` runs the same comparison: one episode each is all there is.
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np

import dyndlo_vision  # noqa: F401
from dyndlo_vision import policies
from dyndlo_vision.tasks.baselines import GeometricLift


def run(env: gym.Env, act: object) -> dict[str, float]:
    obs, _ = env.reset(seed=0)
    action = np.asarray(act(obs), dtype=np.float32)  # type: ignore[operator]
    base = env.unwrapped
    _, times = base.spec_actions.decode(
        action.astype(float), base.scene.gripper_home[0], 0.0, base.task.final_point(base.goal)
    )
    _, reward, _, _, info = env.step(action)
    return {
        "planned_time_s": float(times[-1]),
        "arrival_time_s": info["trajectory_time_s"],
        "residual_oscillation_m": info["residual_oscillation_m"],
        "success": bool(info["is_success"]),
        "reward": float(reward),
        "avoid": [k for k, v in info["avoid"].items() if v],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("policy")
    parser.add_argument("--target", default="up", choices=["up", "down"])
    parser.add_argument("--layout", default="diagonal", choices=["diagonal", "vertical"])
    parser.add_argument("--quick", action="store_true", help="the same (one episode each is the comparison)")
    args = parser.parse_args()
    env = gym.make("DynDLO/TimeOscillation-v0", target=args.target, layout=args.layout)
    model = policies.load(args.policy, env=env)
    learned = run(env, lambda obs: model.predict(obs, deterministic=True)[0])
    geometric = run(env, GeometricLift(env, learned["planned_time_s"]))
    print(
        json.dumps(
            {"target": args.target, "layout": args.layout, "learned": learned, "geometric": geometric},
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
