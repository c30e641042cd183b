"""Can a student tell which cables need the late commitment's correction, from what it observes?

A ``dyndlo-vision distill`` run made with ``--teacher-commit K`` follows the teacher's plan for K decisions;
at decision K a privileged search corrects the plan where coasting on it fails for the true cable. A student
can only imitate that if what it observes up to decision K tells the corrected cables from the others. For
each decision k this measures how well it does: the cross-validated AUC (0.5: no better than chance, 1:
perfect ranking) of ridge regression and of k nearest neighbours (``cable_visibility.cv_predictions``,
10-fold over episodes, features standardised on each fold) predicting "corrected" from:

- ``P_DLO``: P_DLO of decisions 0..k as the student saw it (through the run's noise model, or through
  ``--obs-noise F.json``: drawn again from the true state, as a student for that tracker would see it);
- ``P_DLO + plan``: the same and the plan (the episode's first label: the teacher's plan, made from the
  observation at t = 0; the student's own first action tells it);
- ``P_DLO + TCP (noisy)``: the same and the TCP position and velocity of decisions 0..k with Gaussian noise
  of ``--tcp-noise POS,VEL`` added to the simulator's TCP state (m, m/s; default 0.2 mm and 5 mm/s, the
  packaged noise model's TCP noise since session 28);
- ``TCP exact``: the TCP state of decisions 0..k as the simulator gives it. A warning row: the gripper
  settles under the cable's load by micrometres, so the exact TCP position at t = 0 already fingerprints the
  cable (standardised features amplify it). Nothing a real arm reports resolves that;
- ``cable (privileged)``: the cable's parameters (length, log mass, log Young's modulus, log damping), drawn
  again from the episodes' seeds: what perfect inference of the cable would give.

The corrected episodes are found by replaying the expert (``correction_directions.corrections``), so only
expert rounds are read (``--rounds N``: the first N, default all of the run's expert rounds).

    python benchmarks/commit_detection.py RUN [--rounds N] [--decisions 0,2,4,6,8] [--tcp-noise 2e-4,5e-3]
        [--obs-noise F.json] [--out F.json]
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import numpy as np
from cable_visibility import cv_predictions, renoised
from correction_directions import corrections
from label_conflict import episode_cables, load_rounds

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision.learning.correction_gate import rank_auc as auc

TCP, P_DLO = slice(0, 6), slice(6, 9)  # table II for one gripper: TCP position, velocity; P_DLO; goal


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--rounds", type=int, default=None, help="first N rounds (default: all expert rounds)")
    ap.add_argument("--decisions", default="0,2,4,6,8")
    ap.add_argument("--tcp-noise", default="2e-4,5e-3", help="POS,VEL standard deviations (m, m/s)")
    ap.add_argument("--obs-noise", default=None, help="noise model (JSON or 'packaged') to see P_DLO through "
                    "instead of the run's")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    config = json.loads((args.run / "config.json").read_text())
    rounds = args.rounds or config.get("expert_rounds", 1)
    pos_sd, vel_sd = (float(v) for v in args.tcp_noise.split(","))
    found = corrections(args.run, rounds)
    data = renoised(load_rounds(args.run, list(range(rounds))), args.obs_noise)
    seeds = data.episode_seeds.tolist()
    rows = {s: np.flatnonzero(data.seeds == s) for s in seeds}
    corrected = np.isin(seeds, found["corrected_seeds"])
    cables = episode_cables(data, config)
    if cables is None:
        raise SystemExit(f"{args.run} ran on the nominal cable: there is no cable to tell apart")
    factors = cables[[rows[s][0] for s in seeds]]
    noisy = data.true_observations.copy()  # the simulator's TCP state: the only noise on it is added here
    rng = np.random.default_rng(0)
    noisy[:, 0:3] += rng.normal(0.0, pos_sd, noisy[:, 0:3].shape)
    noisy[:, 3:6] += rng.normal(0.0, vel_sd, noisy[:, 3:6].shape)
    plans = np.array([data.actions[rows[s][0]] for s in seeds])
    k_commit = found["commit_decision"]
    report = {"run": str(args.run), "rounds": rounds, "episodes": len(seeds),
              "corrected": int(corrected.sum()),
              "commit_decision": k_commit, "tcp_noise": [pos_sd, vel_sd], "machine": platform.machine(),
              "obs_noise": args.obs_noise or config.get("noise_model"),
              "rows": []}
    print(f"{args.run}: {len(seeds)} expert episodes, {corrected.sum()} corrected at decision {k_commit}")

    def measure(name: str, x: np.ndarray, k: int | None) -> None:
        row = {"features": name, "decision": k}
        for method in ("ridge", "knn"):
            row[method] = round(auc(cv_predictions(x, corrected.astype(float), method), corrected), 3)
        report["rows"].append(row)
        at = "" if k is None else f"k={k}"
        print(f"  {at:5s} {name:22s} AUC ridge {row['ridge']:.3f}  knn {row['knn']:.3f}")

    def history(obs: np.ndarray, columns: slice, k: int) -> np.ndarray:
        return np.array([obs[rows[s][: k + 1], columns].ravel() for s in seeds])

    for k in (int(v) for v in args.decisions.split(",")):
        if k >= min(len(r) for r in rows.values()):
            break
        p_dlo = history(data.observations, P_DLO, k)
        measure("P_DLO", p_dlo, k)
        measure("P_DLO + plan", np.c_[p_dlo, plans], k)
        measure("P_DLO + TCP (noisy)", np.c_[p_dlo, history(noisy, TCP, k)], k)
        measure("TCP exact", history(data.true_observations, TCP, k), k)
    privileged = np.c_[factors[:, 0], np.log(factors[:, 1]), np.log(factors[:, 2]), np.log(factors[:, 3])]
    measure("cable (privileged)", privileged, None)
    if args.out:
        args.out.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
