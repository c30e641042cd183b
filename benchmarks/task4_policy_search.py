"""Task IV: can a single-step plan beat the geometric lift at equal time? Cross-entropy search over plans.

Task IV starts from the same state every episode and its goal is fixed, so a plan (one action) is a complete
policy and the environment's reward can be optimised directly. This searches the action with the cross-entropy
method, starting at the geometric lift of the paper's trajectory time, then compares the best plan with the
geometric lift of the same planned time, as ``task4_vs_geometric.py`` does for a trained SB3 policy. It asks
whether the task admits better plans than the baseline; it is not the SAC training the paper reports.

    python benchmarks/task4_policy_search.py [--target up|down] [--layout diagonal|vertical] [--iterations 12]
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import dyndlo_vision  # noqa: F401
from dyndlo_vision.tasks.baselines import GeometricLift

PAPER_TIME_S = {"up": 1.35, "down": 1.468}


def episode(env: gym.Env, action: np.ndarray) -> tuple[float, dict, float]:
    """Reward, info and planned trajectory time of the plan ``action``."""
    env.reset(seed=0)
    base = env.unwrapped
    _, times = base.spec_actions.decode(
        np.asarray(action, float), base.scene.gripper_home[0], 0.0, base.task.final_point(base.goal)
    )
    _, reward, _, _, info = env.step(np.asarray(action, np.float32))
    return float(reward), info, float(times[-1])


def summary(reward: float, info: dict, planned_s: float) -> dict:
    return {
        "reward": round(reward, 3),
        "planned_time_s": round(planned_s, 4),
        "arrival_time_s": round(float(info["trajectory_time_s"]), 4),
        "residual_oscillation_m": round(float(info["residual_oscillation_m"]), 4),
        "success": bool(info["is_success"]),
        "avoid": [k for k, v in info["avoid"].items() if v],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--target", default="up", choices=["up", "down"])
    parser.add_argument("--layout", default="diagonal", choices=["diagonal", "vertical"])
    parser.add_argument("--iterations", type=int, default=12)
    parser.add_argument("--population", type=int, default=12)
    parser.add_argument("--elite", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    env = gym.make("DynDLO/TimeOscillation-v0", target=args.target, layout=args.layout)
    obs, _ = env.reset(seed=0)
    start = np.asarray(GeometricLift(env, PAPER_TIME_S[args.target])(obs), dtype=float)
    rng = np.random.default_rng(args.seed)
    mean, std = start.copy(), np.full(start.size, 0.3)
    best_reward, best = episode(env, start)[0], start
    t0 = time.perf_counter()
    for it in range(args.iterations):
        population = np.clip(mean + std * rng.standard_normal((args.population, start.size)), -1.0, 1.0)
        rewards = np.array([episode(env, a)[0] for a in population])
        elite = population[np.argsort(rewards)[-args.elite :]]
        mean, std = elite.mean(axis=0), np.maximum(elite.std(axis=0), 0.02)
        if rewards.max() > best_reward:
            best_reward, best = float(rewards.max()), population[int(np.argmax(rewards))]
        print(
            f"iteration {it}: best {rewards.max():.2f}, median {np.median(rewards):.2f}, "
            f"best so far {best_reward:.2f} ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    found = summary(*episode(env, best))
    geometric = summary(*episode(env, GeometricLift(env, found["planned_time_s"])(obs)))
    episodes = 1 + args.iterations * args.population
    print(
        json.dumps(
            {
                "target": args.target,
                "layout": args.layout,
                "episodes": episodes,
                "search": found,
                "geometric_same_time": geometric,
                "action": np.round(best, 4).tolist(),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
