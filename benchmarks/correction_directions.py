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

    python benchmarks/correction_directions.py RUN [RUN ...] [--out F.json]
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
from dyndlo_vision.learning.distill import Episodes, PlanFollowingExpert, make_distill_env


def corrections(run: Path) -> dict:
    """The corrections of ``run``'s round 0 at its commitment decision, with each episode's cable."""
    config = json.loads((run / "config.json").read_text())
    k_commit = config.get("teacher_commit_decision")
    if k_commit is None:
        raise SystemExit(f"{run} was not made with --teacher-commit")
    data = Episodes.load(run / "round0.npz")
    cables = episode_cables(data, config)
    env = make_distill_env(config.get("task_options", {}), None, None, config["task"])
    u = env.unwrapped
    teacher = policies.load(config["teacher"])
    expert = PlanFollowingExpert(u.spec_actions, speed_limit_m_s=config.get("expert_speed_limit_m_s"),
                                 smoothing=config.get("expert_smoothing", 0.0))
    home = u.scene.gripper_home
    found, factors = [], []
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
            factors.append(cables[rows[0]] if cables is not None else np.full(4, np.nan))
    env.close()
    found_arr, factors_arr = np.array(found), np.array(factors)
    result: dict = {"run": str(run), "commit_decision": k_commit, "episodes": len(data.successes),
                    "corrected": len(found)}
    if len(found) >= 2:
        unit = found_arr / np.linalg.norm(found_arr, axis=1, keepdims=True)
        cos = unit @ unit.T
        pairs = cos[np.triu_indices(len(found), 1)]
        x = np.c_[np.log(factors_arr[:, 2]), factors_arr[:, 0], np.log(factors_arr[:, 1])]
        x = (x - x.mean(0)) / (x.std(0) + 1e-12)
        dist = np.linalg.norm(x[:, None] - x[None], axis=2) + np.diag(np.full(len(x), np.inf))
        nearest = dist.argmin(1)
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
    p.add_argument("--out")
    args = p.parse_args()
    results = [corrections(run) for run in args.runs]
    for r in results:
        print(json.dumps({k: v for k, v in r.items() if k != "young_factor_of_corrected"}))
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"command": vars(args) | {"runs": [str(r) for r in args.runs]},
                       "machine": platform.machine(), "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
