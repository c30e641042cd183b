"""When does P_DLO show the cable? Cross-validated R^2 of the cable's length and log Young's modulus predicted
from the P_DLO trajectory up to decision k, over the episodes of a ``dyndlo-vision distill`` run.

A multi-step student reads the table-II observation (plus a P_DLO history), never the cable's parameters: it
can only act on the cable once P_DLO has shown it. This measures when that is, from a run's own episodes:
for each decision k, the P_DLO of decisions 0..k (the simulator's true state, and as the student saw it
through the run's noise model) is regressed onto each episode's cable (drawn again from its seed, as the run
drew it), by ridge regression (linear) and by k nearest neighbours (not linear), 10-fold cross-validated
over episodes. R^2 near 0: the trajectory tells nothing about that parameter yet; near 1: it shows it.

    python benchmarks/cable_visibility.py RUN [--decisions 0,1,2,3,4,6,8,12] [--obs-noise F.json]
        [--out F.json]

``--obs-noise F.json`` ("as seen" through another noise model): the episodes' true observations are drawn
again through it (``learning.distill.with_noise``), as a student trained for that tracker would see them.
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path
from typing import Any

import numpy as np

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision.learning.distill import episode_cables, load_rounds  # the run's cables, from its seeds

P_DLO = slice(6, 9)  # table II for one gripper: TCP position (3), velocity (3), P_DLO (3), goal (3)


def renoised(data: Any, obs_noise: str | None) -> Any:
    """``data`` with its observations drawn again through the noise model ``obs_noise`` (a JSON file or
    ``"packaged"``); None: unchanged (as the run's student saw them)."""
    if obs_noise is None:
        return data
    from dyndlo_vision.learning.distill import with_noise
    from dyndlo_vision.tasks.noise import noise_model_file

    return with_noise(data, noise_model_file(obs_noise))


def cv_predictions(x: np.ndarray, y: np.ndarray, method: str, folds: int = 10, ridge: float = 1e-2,
                   neighbours: int = 5) -> np.ndarray:
    """Out-of-fold predictions of ``y`` from ``x`` (rows: episodes), features standardised on each fold."""
    n = len(y)
    order = np.random.default_rng(0).permutation(n)
    pred = np.zeros(n)
    for f in range(folds):
        test = order[f::folds]
        train = np.setdiff1d(order, test)
        mu, sd = x[train].mean(0), x[train].std(0) + 1e-9
        a, b = (x[train] - mu) / sd, (x[test] - mu) / sd
        if method == "ridge":
            gram = a.T @ a + ridge * len(train) * np.eye(a.shape[1])
            w = np.linalg.solve(gram, a.T @ (y[train] - y[train].mean()))
            pred[test] = b @ w + y[train].mean()
        else:
            dist = np.linalg.norm(b[:, None, :] - a[None, :, :], axis=2)
            nearest = np.argsort(dist, axis=1)[:, :neighbours]
            pred[test] = y[train][nearest].mean(axis=1)
    return pred


def r2(pred: np.ndarray, y: np.ndarray) -> float:
    return float(1.0 - np.mean((pred - y) ** 2) / np.var(y))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--decisions", default="0,1,2,3,4,6,8,12")
    ap.add_argument("--obs-noise", default=None, help="noise model (JSON or 'packaged') to see P_DLO through "
                    "instead of the run's")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    config = json.loads((args.run / "config.json").read_text())
    if not config.get("cable_ranges"):
        raise SystemExit(f"{args.run} ran on the nominal cable: there is no cable to tell apart")
    data = renoised(load_rounds(args.run, None), args.obs_noise)
    task = config.get("task", "tip-control")
    seeds = data.episode_seeds.tolist()
    rows = {s: np.flatnonzero(data.seeds == s) for s in seeds}
    # Factors of the nominal cable (length, mass, E, damping); R^2 does not change with the nominal's scale.
    factors = episode_cables(data, config)[[r[0] for r in rows.values()]]
    targets = {"length": factors[:, 0], "log E": np.log(factors[:, 2])}
    shortest = min(len(r) for r in rows.values())
    report = {"run": str(args.run), "task": task, "episodes": len(seeds), "machine": platform.machine(),
              "obs_noise": args.obs_noise or config.get("noise_model"), "rows": []}
    print(f"{args.run}: {len(seeds)} episodes of {task}, cable ranges {config['cable_ranges']}")
    for k in (int(v) for v in args.decisions.split(",")):
        if k >= shortest:
            break
        for seen, obs in (("true", data.true_observations), ("as seen", data.observations)):
            x = np.array([obs[rows[s][: k + 1], P_DLO].ravel() for s in seeds])
            row = {"decision": k, "p_dlo": seen}
            for name, y in targets.items():
                for method in ("ridge", "knn"):
                    row[f"{name} {method}"] = round(r2(cv_predictions(x, y, method), y), 3)
            report["rows"].append(row)
            scores = "  ".join(f"{key} {value:5.2f}" for key, value in list(row.items())[2:])
            print(f"  k={k:2d} {seen:8s} {scores}")
    if args.out:
        args.out.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
