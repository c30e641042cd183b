"""Task II: search the scripted vault's shape for a cable model (cross-entropy over the single action).

Vaulting starts from one state whatever the cable, so one action is a whole single-step policy. This searches
that action with the cross-entropy method, scoring each candidate by its mean reward over the nominal cable
and ``--cables`` random ones (:func:`draw_cable`, fixed seeds, so every candidate sees the same cables). It
starts from :class:`FlickVault` and prints the best action decoded as the via-point offsets and intervals
that :class:`FlickVault` holds per cable model. With ``--random N`` it first tries N uniformly random actions
on the nominal cable and starts from the best of them and :class:`FlickVault` (a vault found for another
model can sit in a region where no perturbation vaults). Its episodes are the search's own; evaluate the
result on other seeds (``dyndlo-vision evaluate flick-vault --task vaulting --randomize-cable --seed ...``).

    python benchmarks/vault_search.py --env-option cable=chain [--random 200] [--iterations 10] [--cables 3]
        [--objective shaped]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dyndlo_vision.tasks import make_env
from dyndlo_vision.tasks.baselines import FlickVault
from dyndlo_vision.tasks.vaulting import vault_progress
from dyndlo_vision.tasks.wrappers import DEFAULT_CABLE_RANGES, draw_cable


def parse_options(pairs: list[str]) -> dict[str, str]:
    options = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"--env-option {pair!r}: expected KEY=VALUE")
        options[key] = value
    return options


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env-option", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--population", type=int, default=12)
    parser.add_argument("--elite", type=int, default=3)
    parser.add_argument("--cables", type=int, default=3, help="random cables besides the nominal one")
    parser.add_argument("--random", type=int, default=0, help="uniform random actions tried first")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cable-seed", type=int, default=700000)
    parser.add_argument("--start", metavar="A1,...,An",
                        help="normalised action to start from (default: FlickVault's)")
    parser.add_argument("--std", type=float, default=0.3, help="initial std of the search distribution")
    parser.add_argument("--objective", choices=("reward", "shaped"), default="reward",
                        help="shaped: reward plus vault_progress() of failed episodes (a slope to climb)")
    args = parser.parse_args()

    env = make_env("vaulting", **parse_options(args.env_option))
    base = env.unwrapped
    nominal = base.scene.config.cable
    cables = [nominal] + [
        draw_cable(nominal, DEFAULT_CABLE_RANGES, np.random.default_rng(args.cable_seed + k))
        for k in range(args.cables)
    ]
    obs, _ = env.reset(seed=0)

    def score(action: np.ndarray) -> tuple[float, int]:
        rewards, successes = [], 0
        for cable in cables:
            env.reset(seed=0, options={"cable": cable})
            _, reward, _, _, info = env.step(action.astype(np.float32))
            if args.objective == "shaped" and not info["is_success"]:
                reward += vault_progress(base.scene.cable_nodes(), base.task.p_dlo_node(base.scene))
            rewards.append(reward)
            successes += bool(info["is_success"])
        return float(np.mean(rewards)), successes

    start = np.asarray(FlickVault(env)(obs), dtype=float)
    if args.start is not None:
        start = np.array([float(v) for v in args.start.split(",")])
        if start.shape != env.action_space.shape or np.any(np.abs(start) > 1):
            raise SystemExit(
                f"--start: expected {env.action_space.shape[0]} numbers in [-1, 1], got {args.start}"
            )
    rng = np.random.default_rng(args.seed)
    if args.random:
        # The nominal cable alone: the cheap filter. Ties (most random actions score the same) go to the
        # first.
        best_random, best_random_reward, hits = start, -np.inf, 0
        env.reset(seed=0, options={"cable": nominal})
        for _ in range(args.random):
            action = rng.uniform(-1.0, 1.0, start.size)
            env.reset(seed=0)
            _, reward, _, _, info = env.step(action.astype(np.float32))
            hits += bool(info["is_success"])
            if args.objective == "shaped" and not info["is_success"]:
                reward += vault_progress(base.scene.cable_nodes(), base.task.p_dlo_node(base.scene))
            if reward > best_random_reward:
                best_random, best_random_reward = action, float(reward)
        print(f"random phase: {hits}/{args.random} vault the nominal cable; "
              f"best reward {best_random_reward:.2f}", flush=True)
        if score(best_random)[0] > score(start)[0]:
            start = best_random
    mean, std = start.copy(), np.full(start.size, args.std)
    best, (best_score, best_successes) = start, score(start)
    origin = "--start" if args.start else "FlickVault"
    print(f"start ({origin}): mean reward {best_score:.2f}, {best_successes}/{len(cables)} vaults",
          flush=True)
    t0 = time.perf_counter()
    for it in range(args.iterations):
        population = np.clip(mean + std * rng.standard_normal((args.population, start.size)), -1.0, 1.0)
        scored = [score(a) for a in population]
        rewards = np.array([s for s, _ in scored])
        elite = population[np.argsort(rewards)[-args.elite:]]
        mean, std = elite.mean(axis=0), np.maximum(elite.std(axis=0), 0.02)
        k = int(np.argmax(rewards))
        if rewards[k] > best_score:
            best, best_score, best_successes = population[k], float(rewards[k]), scored[k][1]
        print(f"iteration {it}: best {rewards.max():.2f} ({scored[k][1]}/{len(cables)} vaults), "
              f"median {np.median(rewards):.2f}, best so far {best_score:.2f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)

    env.reset(seed=0, options={"cable": nominal})
    points, times = base.spec_actions.decode(best, base.scene.gripper_home[0], 0.0)
    offsets = points[1:] - points[0]
    print(json.dumps({
        "env_options": parse_options(args.env_option),
        "episodes": len(cables) * (1 + args.iterations * args.population),
        "cables": len(cables),
        "mean_reward": round(best_score, 3),
        "vaults": best_successes,
        "action": np.round(best, 4).tolist(),
        "offsets_m": np.round(offsets, 3).tolist(),
        "intervals_s": np.round(np.diff(times), 3).tolist(),
    }, indent=2))


if __name__ == "__main__":
    main()
