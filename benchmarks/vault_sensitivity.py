"""How sensitive is a vault's outcome to a small change of its plan? Per random cable, the shipped single-step
``vaulting`` policy's plan and ``--perturbations`` random perturbations of it (Gaussian, ``--sigmas`` in the
normalised [-1, 1] action units, clipped) are each run as a single-step episode on that cable.

Why (issue 16): the privileged teachers reach 97-99 % by correcting the plan per cable, and the corrections
that :class:`~dyndlo_vision.learning.distill.ReplanSearch` finds are small (0.05-0.1 rings) and point in no
common direction. If a 0.05 perturbation flips the outcome of many cables, success on them is a matter of
which side of a fine boundary the plan lands, and a student that infers the cable from a noisy P_DLO cannot
place its plan that precisely. This measures that: the share of perturbed plans whose outcome differs from
the unperturbed plan's, by Young's-modulus tercile.

Cables are drawn from the episode seed (``tasks.wrappers.cable_for_seed``, the ``beyond`` ranges, as
``demo --randomize-cable`` draws them). The default seeds (5 200 000+) are no evaluation's or training's.

    python benchmarks/vault_sensitivity.py [--cables 40] [--perturbations 6] [--sigmas 0.02,0.05]
        [--seed 5200000] [--workers 2] [--out F.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision import policies
from dyndlo_vision.tasks.registry import make_env
from dyndlo_vision.tasks.wrappers import cable_ranges_for

TERCILE_EDGES_PA = (1.32e6, 3.83e6)  # the Young's-modulus terciles of issue 16's table (evaluation seeds)


def run_cable(job: tuple[int, int, tuple[float, ...]]) -> dict:
    """The plan and its perturbations on the cable of ``seed``: outcomes, and the cable."""
    import torch

    torch.set_num_threads(1)
    seed, perturbations, sigmas = job
    env = make_env("vaulting", multi_step=False, randomize_cable_every=1,
                   cable_ranges=cable_ranges_for("vaulting", "beyond"))
    policy = policies.load("vaulting")
    obs, _ = env.reset(seed=seed)
    cable = env.unwrapped.task.cable
    plan, _ = policy.predict(obs, deterministic=True)
    rng = np.random.default_rng([seed, 0x5E5])

    def outcome(action: np.ndarray) -> bool:
        env.reset(seed=seed)  # the same cable and start (a settled scene is cached)
        _, _, _, _, info = env.step(np.asarray(action, dtype=np.float32))
        return bool(info["is_success"])

    row = {"seed": seed, "young_pa": cable.young_pa, "length_m": cable.length_m, "mass_kg": cable.mass_kg,
           "plan_success": outcome(plan), "perturbed": {}}
    for sigma in sigmas:
        actions = np.clip(plan + sigma * rng.standard_normal((perturbations, plan.size)), -1.0, 1.0)
        row["perturbed"][str(sigma)] = [outcome(a) for a in actions]
    env.close()
    return row


def summarise(rows: list[dict], sigmas: tuple[float, ...]) -> dict:
    """Per Young's-modulus tercile and in all: the plan's successes, the share of perturbed plans whose
    outcome differs from the plan's, their success rate, and the cables with both outcomes among them."""
    tercile = np.digitize([r["young_pa"] for r in rows], TERCILE_EDGES_PA)
    summary = {}
    for name, t in (("soft", 0), ("middle", 1), ("stiff", 2), ("all", None)):
        sel = [r for r, k in zip(rows, tercile, strict=True) if t is None or k == t]
        entry: dict = {"cables": len(sel), "plan_success": sum(r["plan_success"] for r in sel)}
        for s in sigmas:
            pairs = [(r, r["perturbed"][str(s)]) for r in sel]
            flips = [x != r["plan_success"] for r, xs in pairs for x in xs]
            wins = [x for _, xs in pairs for x in xs]
            mixed = sum(0 < sum(xs) + r["plan_success"] < len(xs) + 1 for r, xs in pairs)
            failing_won = sum(not r["plan_success"] and any(xs) for r, xs in pairs)
            entry[f"sigma {s}"] = {"flipped": float(np.mean(flips)) if flips else None,
                                   "perturbed_success": float(np.mean(wins)) if wins else None,
                                   "cables_with_both_outcomes": mixed, "failing_plans_won_back": failing_won}
        summary[name] = entry
        print(name, json.dumps(entry))
    return summary


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cables", type=int, default=40)
    p.add_argument("--perturbations", type=int, default=6)
    p.add_argument("--sigmas", default="0.02,0.05")
    p.add_argument("--seed", type=int, default=5_200_000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out")
    p.add_argument("--summarise", metavar="F.json", help="summarise an earlier --out file again, run nothing")
    args = p.parse_args()
    sigmas = tuple(float(s) for s in args.sigmas.split(","))
    if args.cables < 1 or args.perturbations < 1 or any(not 0 < s < 2 for s in sigmas):
        raise SystemExit(f"need --cables >= 1, --perturbations >= 1 and sigmas in (0, 2); got {args.cables}, "
                         f"{args.perturbations}, {sigmas}")
    start = time.time()
    if args.summarise:
        with open(args.summarise) as f:
            rows = json.load(f)["cables"]
        sigmas = tuple(float(s) for s in rows[0]["perturbed"])
    else:
        jobs = [(args.seed + i, args.perturbations, sigmas) for i in range(args.cables)]
        with ProcessPoolExecutor(args.workers) as pool:
            rows = list(pool.map(run_cable, jobs))
    summary = summarise(rows, sigmas)
    result = {"command": vars(args), "machine": f"{platform.machine()}, {platform.node()}",
              "wall_s": round(time.time() - start, 1), "summary": summary, "cables": rows}
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
    print(f"{time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
