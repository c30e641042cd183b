"""Do look-alike cables get alike corrections? The late commitment's corrections in ``distill`` runs.

A run made with ``--teacher-commit K`` follows the teacher's plan for K decisions; at decision K a privileged
search (``ReplanSearch``) replaces the plan-following label where coasting on it fails. A student can learn
that correction only if cables that look alike get alike corrections. For every corrected episode this
replays the expert up to decision K (the teacher's plan from the recorded true observation at t = 0, the
run's smoothing and speed limit, the commanded state rebuilt from the recorded labels) to recover the
plan-following label, so that the correction is ``label[K] - plan-following label[K]``. It prints:

- the corrected episodes and the median size of their corrections (normalised action units);
- the mean cosine between the corrections of all pairs of corrected episodes (0: no common direction);
- the mean cosine between each corrected episode and the corrected episode whose cable is nearest to it
  (log Young's modulus, length and log mass factors, standardised): alike cables, alike corrections?
- for a run made with ``--search-candidates shared``: which of the shared offsets each correction is
  (``ReplanSearch.offsets``; ring 1 is the narrowest), how many distinct ones were chosen and how often.
  A student that must tell from P_DLO which correction a cable needs learns a class per offset from this
  many examples.
- for a run made with ``--search-candidates line:N``: each correction's signed length along the line (how
  often each was chosen), and whether the length follows the cable: its rank correlation with log Young's
  modulus, and how far it is from the length of the corrected cable nearest in (log E, length, log mass).

``--rounds N`` reads the first N rounds (each must be an expert round: the expert acted, so its commanded
state can be rebuilt from the labels); default 1.

    python benchmarks/correction_directions.py RUN [RUN ...] [--rounds N] [--out F.json]
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import numpy as np
from label_conflict import episode_cables  # the run's cables, drawn again from its seeds
from label_smoothness import replay_expert

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision import policies
from dyndlo_vision.learning.distill import Episodes, PlanFollowingExpert, ReplanSearch, make_distill_env


def corrections(run: Path, rounds: int = 1) -> dict:
    """The corrections of ``run``'s first ``rounds`` rounds at its commitment decision, with each episode's
    cable (and, with shared candidates, which offset each correction is)."""
    config = json.loads((run / "config.json").read_text())
    k_commit = config.get("teacher_commit_decision")
    if k_commit is None:
        raise SystemExit(f"{run} was not made with --teacher-commit")
    expert_rounds = config.get("expert_rounds", 1)
    if not 1 <= rounds <= expert_rounds:
        raise SystemExit(f"--rounds {rounds}: {run} has {expert_rounds} expert round(s); "
                         f"expected 1..{expert_rounds}")
    data = Episodes.concatenate([Episodes.load(run / f"round{r}.npz") for r in range(rounds)])
    candidates = config.get("search_candidates", "episode")
    line = ReplanSearch.line_offset(candidates) is not None
    cables = episode_cables(data, config)
    env = make_distill_env(config.get("task_options", {}), None, None, config["task"])
    u = env.unwrapped
    teacher = policies.load(config["teacher"])
    expert = PlanFollowingExpert(u.spec_actions, speed_limit_m_s=config.get("expert_speed_limit_m_s"),
                                 smoothing=config.get("expert_smoothing", 0.0))
    home = u.scene.gripper_home
    # distill's searches use the default rings and population
    search = ReplanSearch(candidates=candidates if candidates != "episode" else "shared")
    offsets = search.offsets(u.action_space.shape[0]) if candidates != "episode" else None
    found, factors, chosen, match_error, corrected_seeds = [], [], [], [], []
    for seed in data.episode_seeds:
        rows = np.flatnonzero(data.seeds == seed)
        if len(rows) <= k_commit:
            continue  # ended before the commitment
        labels = data.actions[rows]
        plan, _ = teacher.predict(data.true_observations[rows[0]], deterministic=True)
        replayed, _ = replay_expert(expert, u.spec_actions, home, labels, plan, k_commit + 1)
        delta = labels[k_commit] - replayed[k_commit]
        if np.abs(delta).max() > 1e-3:
            found.append(delta)
            corrected_seeds.append(int(seed))
            factors.append(cables[rows[0]] if cables is not None else np.full(4, np.nan))
            if offsets is not None:  # the label is clip(plan-following label + offset)
                origin = np.clip(np.asarray(replayed[k_commit], dtype=np.float64), -1.0, 1.0)
                error = np.abs(np.clip(origin + offsets, -1.0, 1.0) - labels[k_commit]).max(axis=1)
                chosen.append(int(np.argmin(error)))
                match_error.append(float(error.min()))
    env.close()
    found_arr, factors_arr = np.array(found), np.array(factors)
    result: dict = {"run": str(run), "rounds": rounds, "commit_decision": k_commit,
                    "episodes": len(data.successes), "corrected": len(found),
                    "corrected_seeds": corrected_seeds}
    if chosen:
        population = search.population
        index, count = np.unique(chosen, return_counts=True)
        order = np.argsort(-count, kind="stable")
        # a line's offsets are multiples of one direction: each one's signed length along the first's
        signed = np.round(offsets @ (offsets[0] / np.linalg.norm(offsets[0])), 6).tolist() if line else []

        def name(i: int) -> str:
            return f"{signed[i]:+.2f}" if line else f"ring {i // population + 1} #{i % population}"

        result.update({
            "offset_match_error_max": max(match_error),  # ~0: every correction is one of the offsets
            "distinct_offsets": len(index),
            "offsets_chosen": {name(i): int(c) for i, c in zip(index[order], count[order], strict=True)},
        })
        if line:
            result["line_length_of_corrected"] = [signed[i] for i in chosen]
    if len(found) >= 2:
        unit = found_arr / np.linalg.norm(found_arr, axis=1, keepdims=True)
        cos = unit @ unit.T
        pairs = cos[np.triu_indices(len(found), 1)]
        x = np.c_[np.log(factors_arr[:, 2]), factors_arr[:, 0], np.log(factors_arr[:, 1])]
        x = (x - x.mean(0)) / (x.std(0) + 1e-12)
        dist = np.linalg.norm(x[:, None] - x[None], axis=2) + np.diag(np.full(len(x), np.inf))
        nearest = dist.argmin(1)
        if line:
            length = np.array(result["line_length_of_corrected"])
            rank = np.argsort(np.argsort(length)).astype(float)
            rank_e = np.argsort(np.argsort(factors_arr[:, 2])).astype(float)
            result.update({
                "length_vs_log_young_spearman": float(np.corrcoef(rank, rank_e)[0, 1]),
                "length_nearest_cable_abs_diff_median": float(np.median(np.abs(length - length[nearest]))),
                "length_abs_diff_all_pairs_median": float(np.median(
                    np.abs(length[:, None] - length[None])[np.triu_indices(len(length), 1)])),
            })
        result.update({
            "correction_norm_median": float(np.median(np.linalg.norm(found_arr, axis=1))),
            "cosine_all_pairs_mean": float(pairs.mean()),
            "cosine_nearest_cable_mean": float(np.mean(cos[np.arange(len(x)), nearest])),
            "young_factor_of_corrected": [float(f) for f in factors_arr[:, 2]],
        })
    return result


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--rounds", type=int, default=1, help="the first N rounds, all expert rounds (default 1)")
    p.add_argument("--out")
    args = p.parse_args()
    results = [corrections(run, args.rounds) for run in args.runs]
    for r in results:
        long_lists = ("young_factor_of_corrected", "corrected_seeds", "line_length_of_corrected")
        print(json.dumps({k: v for k, v in r.items() if k not in long_lists}))
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"command": vars(args) | {"runs": [str(r) for r in args.runs]},
                       "machine": platform.machine(), "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
