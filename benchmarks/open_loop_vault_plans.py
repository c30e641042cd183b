"""How far open loop goes on vaulting: single-step plans searched per cable, or one plan for all cables.

Issue 16 asks a multi-step vaulting policy to beat the shipped single-step plan by 15 points (84 -> 99 of the
100 fresh cables 200000-200099), and the privileged teachers built for it reach 94-96 clean vaults. This asks
what open loop itself can do, by the cross-entropy method over the 9-dimensional single-step action (the
task starts from one state whatever the cable, so one action is a whole single-step policy), starting from
the shipped ``vaulting`` plan. A vault counts when it is clean: ``is_success`` and no avoid condition.
Cables are drawn from the episode seed with issue 16's ``beyond`` ranges, as ``demo --randomize-cable
--cable-ranges beyond`` draws them.

* ``per-cable --seeds S1,S2,...``: for each cable alone, up to ``--generations`` of ``--population`` plans,
  stopping at the first clean vault. With the cable known, is there an open-loop plan that vaults it?
* ``one-plan --train-seeds A:B``: one plan scored on all training cables together (the sum of the episode
  rewards plus 5 per clean vault, every candidate on the same cables); prints and stores the best.
* ``evaluate --plans F.json --seeds A:B``: clean vaults of each plan in ``F.json`` (a list of actions, or a
  ``one-plan`` output) and of the shipped plan on other cables.

    python benchmarks/open_loop_vault_plans.py per-cable --seeds 200009,200031 --out per_cable.jsonl
    python benchmarks/open_loop_vault_plans.py one-plan --train-seeds 3000000:3000024 --generations 4 \\
        --out one_plan.json
    python benchmarks/open_loop_vault_plans.py evaluate --plans one_plan.json --seeds 200000:200100

One single-step vault episode takes about 5 s on one core here; ``--workers`` run them in parallel.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision import policies
from dyndlo_vision.tasks.registry import make_env
from dyndlo_vision.tasks.wrappers import cable_ranges_for

_ENV = None


def _env():
    global _ENV
    if _ENV is None:
        import torch

        torch.set_num_threads(1)
        _ENV = make_env("vaulting", multi_step=False, randomize_cable_every=1,
                        cable_ranges=cable_ranges_for("vaulting", "beyond"), distance_reward="shaped")
    return _ENV


def episode(job: tuple[int, list[float]]) -> tuple[float, bool, bool]:
    """(reward, clean vault, vault) of the single-step plan ``action`` on the cable of ``seed``."""
    seed, action = job
    env = _env()
    env.reset(seed=seed)
    _, reward, _, _, info = env.step(np.clip(np.asarray(action), -1.0, 1.0).astype(np.float32))
    vault = bool(info["is_success"])
    return float(reward), vault and not any(bool(v) for v in info["avoid"].values()), vault


def shipped_plan() -> np.ndarray:
    """The shipped single-step ``vaulting`` policy's action (the same for every cable: one start state)."""
    env = make_env("vaulting", multi_step=False)
    obs, _ = env.reset(seed=0)
    env.close()
    return np.clip(policies.load("vaulting").predict(obs, deterministic=True)[0], -1.0, 1.0).astype(float)


def seed_range(text: str) -> list[int]:
    """``A:B`` (B excluded) or ``S1,S2,...``."""
    try:
        if ":" in text:
            a, b = (int(x) for x in text.split(":"))
            if b <= a:
                raise ValueError
            return list(range(a, b))
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise SystemExit(f"seeds: expected A:B with A < B or S1,S2,..., got {text!r}") from None


def per_cable(pool: ProcessPoolExecutor, args: argparse.Namespace, start: np.ndarray) -> None:
    done = set()
    if args.out and Path(args.out).exists():
        done = {json.loads(line)["seed"] for line in Path(args.out).read_text().splitlines() if line}
    for seed in seed_range(args.seeds):
        if seed in done:
            continue
        t0 = time.time()
        rng = np.random.default_rng(seed)
        reward, clean, vault = episode((seed, start.tolist()))
        outcomes = [(reward, clean, vault)]
        found = start if clean else None
        mean, sigma = start.copy(), np.full(start.size, args.sigma)
        for _ in range(args.generations):
            if found is not None:
                break
            population = np.clip(mean + sigma * rng.standard_normal((args.population, start.size)), -1.0, 1.0)
            results = list(pool.map(episode, [(seed, a.tolist()) for a in population]))
            outcomes += results
            clean_ones = [a for a, r in zip(population, results, strict=True) if r[1]]
            if clean_ones:
                found = clean_ones[0]
                break
            score = np.array([r[0] for r in results])
            elite = population[np.argsort(-score)[: args.elite]]
            mean, sigma = elite.mean(axis=0), np.maximum(elite.std(axis=0), 0.05)
        row = {"seed": seed, "found": found is not None, "plan": None if found is None else found.tolist(),
               "distance_from_start": None if found is None else float(np.linalg.norm(found - start)),
               "episodes": len(outcomes), "clean": sum(r[1] for r in outcomes),
               "vault_with_avoid": sum(r[2] and not r[1] for r in outcomes),
               "wall_s": round(time.time() - t0)}
        print(json.dumps(row), flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(json.dumps(row) + "\n")


def one_plan(pool: ProcessPoolExecutor, args: argparse.Namespace, start: np.ndarray) -> None:
    seeds = seed_range(args.train_seeds)
    rng = np.random.default_rng(args.seed)

    def score(action: np.ndarray) -> tuple[float, int]:
        results = list(pool.map(episode, [(s, action.tolist()) for s in seeds]))
        return sum(r[0] for r in results), sum(r[1] for r in results)

    def objective(row: dict) -> float:  # the summed reward plus 5 per clean vault
        return row["reward"] + 5.0 * row["clean"]

    reward, clean = score(start)
    history = [{"generation": -1, "plan": start.tolist(), "reward": reward, "clean": clean}]
    print(json.dumps(history[-1]), flush=True)
    best = history[-1]
    mean, sigma = start.copy(), np.full(start.size, args.sigma)
    for generation in range(args.generations):
        population = np.clip(mean + sigma * rng.standard_normal((args.population, start.size)), -1.0, 1.0)
        scores = []
        for action in population:
            reward, clean = score(action)
            history.append({"generation": generation, "plan": action.tolist(), "reward": reward,
                            "clean": clean})
            print(json.dumps(history[-1]), flush=True)
            scores.append(objective(history[-1]))
            if scores[-1] > objective(best):
                best = history[-1]
        elite = population[np.argsort(scores)[::-1][: args.elite]]
        mean, sigma = elite.mean(axis=0), np.maximum(elite.std(axis=0), 0.03)
    result = {"command": " ".join(sys.argv), "machine": platform.machine(), "train_cables": len(seeds),
              "best": best, "history": history}
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1))
    print(json.dumps({"best": best}))


def evaluate(pool: ProcessPoolExecutor, args: argparse.Namespace, start: np.ndarray) -> None:
    data = json.loads(Path(args.plans).read_text())
    plans = {"shipped": start}
    if isinstance(data, dict):  # a one-plan output
        plans["one-plan best"] = np.asarray(data["best"]["plan"], dtype=float)
    else:
        plans.update({f"plan {k}": np.asarray(a, dtype=float) for k, a in enumerate(data)})
    seeds = seed_range(args.seeds)
    out = {"command": " ".join(sys.argv), "machine": platform.machine(), "cables": len(seeds), "plans": {}}
    for name, action in plans.items():
        if action.shape != start.shape or np.any(np.abs(action) > 1):
            raise SystemExit(f"{name}: expected {start.size} numbers in [-1, 1], got {action.tolist()}")
        results = list(pool.map(episode, [(s, action.tolist()) for s in seeds]))
        out["plans"][name] = {"plan": action.tolist(), "clean": sum(r[1] for r in results),
                              "vaults": sum(r[2] for r in results),
                              "clean_seeds": [s for s, r in zip(seeds, results, strict=True) if r[1]]}
        print(name, "clean", out["plans"][name]["clean"], "vaults", out["plans"][name]["vaults"], flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mode", choices=("per-cable", "one-plan", "evaluate"))
    p.add_argument("--seeds", help="per-cable / evaluate: A:B or S1,S2,...")
    p.add_argument("--train-seeds", default="3000000:3000024", help="one-plan: A:B or S1,S2,...")
    p.add_argument("--plans", help="evaluate: a JSON list of actions, or a one-plan output")
    p.add_argument("--generations", type=int, default=6)
    p.add_argument("--population", type=int, default=None, help="default: 16 per cable, 10 for one plan")
    p.add_argument("--elite", type=int, default=None, help="default: 4 per cable, 3 for one plan")
    p.add_argument("--sigma", type=float, default=None, help="initial std (default: 0.35 per cable, 0.15)")
    p.add_argument("--seed", type=int, default=0, help="one-plan: the search's random seed")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out")
    args = p.parse_args()
    wide = args.mode == "per-cable"
    args.population = args.population or (16 if wide else 10)
    args.elite = args.elite or (4 if wide else 3)
    args.sigma = args.sigma or (0.35 if wide else 0.15)
    if args.mode in ("per-cable", "evaluate") and not args.seeds:
        raise SystemExit(f"{args.mode} needs --seeds")
    if args.mode == "evaluate" and not args.plans:
        raise SystemExit("evaluate needs --plans")
    if not (args.generations >= 1 and 1 <= args.elite <= args.population and args.sigma > 0):
        raise SystemExit("need --generations >= 1, 1 <= --elite <= --population and --sigma > 0")
    start = shipped_plan()
    with ProcessPoolExecutor(args.workers) as pool:
        {"per-cable": per_cable, "one-plan": one_plan, "evaluate": evaluate}[args.mode](pool, args, start)


if __name__ == "__main__":
    main()
