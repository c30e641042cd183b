"""How well a student can fit the plan-following expert's labels, with and without the expert's smoothing.

Takes the round-0 episodes of a ``dyndlo-vision distill`` run (the expert acted), relabels their states
offline with :class:`~dyndlo_vision.learning.distill.PlanFollowingExpert` at each ``--weights`` value
(the teacher's plan is the episode's first label; each later decision is fitted from the *commanded* TCP
state at ``k * 40 ms``, rebuilt with a :class:`~dyndlo_vision.trajectory.replanner.Replanner` from the
recorded labels, which is what the expert fitted from when it acted), and for the recorded labels and each
relabelling reports:

- roughness: the mean squared change between consecutive labels of an episode (normalised action units);
- the expert's fit residual (median and 90th percentile over decisions, mm);
- a fresh student (the run's network) fitted on them: training and validation MSE (a fifth of the episodes
  held out, the same for every row);
- how far the relabels are from the recorded labels (largest absolute difference): at the run's own
  smoothing this replays the expert, so it must be ~0 (a check of the replay; session 25 found the earlier
  relabelling from the *true* TCP state up to 0.065 off).

Episodes that a late-committing teacher (``--teacher-commit``) corrected are left out: after the correction
they follow another plan than the first label's.

    python benchmarks/label_smoothness.py RUN [--episodes 20] [--weights 0,0.003,0.01,0.03,0.1] [--out F.json]

The relabelled states are those the recorded expert reached, so only the labels change, not the roll-out.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision.learning.distill import (
    Episodes,
    PlanFollowingExpert,
    fit_student,
    make_distill_env,
    new_student,
)
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
from dyndlo_vision.trajectory.replanner import Replanner


def replay_expert(
    expert: PlanFollowingExpert, spec: Any, home: np.ndarray, executed: np.ndarray, plan: np.ndarray,
    decisions: int | None = None,
) -> tuple[list[np.ndarray], list[float]]:
    """The expert's labels along one recorded episode, and its fit residuals (m) from decision 1 on.

    It starts from ``plan`` (the single-step plan, normalised); each later decision ``k`` is fitted from the
    commanded state, rebuilt by re-planning from ``home`` (every gripper's start; gripper 0 follows the
    plan) with the recorded ``executed`` actions of decisions ``0..k-1``. So only the labels change, not the
    roll-out. ``decisions``: how many labels (default: one per executed action).
    """
    planner = Replanner(spec, home)
    labels, residuals = [expert.start(plan, home[0])], []
    for k in range(1, len(executed) if decisions is None else decisions):
        planner.replan(executed[k - 1], (k - 1) * CONTROL_PERIOD_S)
        t = k * CONTROL_PERIOD_S
        labels.append(expert.act(t, *planner.commanded_state(t)))
        residuals.append(expert.last_rms_m)
    return labels, residuals


def relabel(
    data: Episodes, spec: Any, home: np.ndarray, weight: float, speed_limit_m_s: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Labels of the expert with ``smoothing=weight`` for ``data``'s states (the teacher's plan is each
    episode's first label; :func:`replay_expert`), and its fit residuals (m)."""
    labels, residuals = [], []
    for seed in data.episode_seeds.tolist():
        executed = data.actions[data.seeds == seed]
        expert = PlanFollowingExpert(spec, speed_limit_m_s=speed_limit_m_s, smoothing=weight)
        episode_labels, episode_residuals = replay_expert(expert, spec, home, executed, executed[0])
        labels += episode_labels
        residuals += episode_residuals
    return np.array(labels, dtype=np.float32), np.array(residuals)


def roughness(data: Episodes) -> float:
    """Mean squared change between consecutive labels of the same episode."""
    same = data.seeds[1:] == data.seeds[:-1]
    return float(np.mean(np.sum(np.diff(data.actions, axis=0)[same] ** 2, axis=1)))


def student_fit(data: Episodes, env: Any, net_arch: list[int]) -> dict[str, float]:
    """Train and validation MSE of a fresh student (seed 1) fitted on ``data``."""
    import torch

    torch.manual_seed(1)
    model = new_student(env, net_arch, 1)
    return fit_student(model, data, seed=1, validation_fraction=0.2)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run", type=Path, help="a distill run folder with round0.npz and config.json")
    parser.add_argument("--episodes", type=int, default=20, help="first N episodes of round 0 (default 20)")
    parser.add_argument(
        "--weights", default="0,0.003,0.01,0.03,0.1", help="smoothing weights to relabel with"
    )
    parser.add_argument("--out", type=Path, default=None, help="also write the rows as JSON")
    args = parser.parse_args()

    config = json.loads((args.run / "config.json").read_text())
    data = Episodes.load(args.run / "round0.npz")
    # Episodes the late-committing teacher corrected (--teacher-commit) follow another plan after the
    # correction, which a plan-following relabelling would pull back: they are left out.
    first, first_replans = data.episode_seeds[: args.episodes], data.replans[: args.episodes]
    corrected, seeds = first[first_replans > 0], first[first_replans == 0].tolist()
    keep = np.isin(data.seeds, seeds)
    chosen = np.isin(data.episode_seeds, seeds)
    data = Episodes(
        data.observations[keep],
        data.true_observations[keep],
        data.actions[keep],
        data.seeds[keep],
        data.successes[chosen],
        data.avoided[chosen],
        data.fit_rms_m[chosen],
        data.replans[chosen],
    )
    n = len(seeds)
    env = make_distill_env(
        config["task_options"], None, config.get("cable_ranges"), config.get("task", "tip-control")
    )
    env.reset(seed=int(seeds[0]))
    spec, home = env.unwrapped.spec_actions, env.unwrapped.scene.gripper_home.copy()

    rows = [
        {
            "labels": "recorded",
            "weight": config.get("expert_smoothing", 0.0),
            "roughness": roughness(data),
            **student_fit(data, env, config["net_arch"]),
        }
    ]
    for weight in (float(w) for w in args.weights.split(",")):
        start = time.monotonic()
        labels, residuals = relabel(data, spec, home, weight, config.get("expert_speed_limit_m_s"))
        relabelled = replace(data, actions=labels)
        rows.append(
            {
                "labels": "relabelled",
                "weight": weight,
                "roughness": roughness(relabelled),
                "fit_rms_mm_median": 1000 * float(np.median(residuals)),
                "fit_rms_mm_p90": 1000 * float(np.quantile(residuals, 0.9)),
                "max_change_from_recorded": float(np.abs(labels - data.actions).max()),
                "relabel_s": round(time.monotonic() - start, 1),
                **student_fit(relabelled, env, config["net_arch"]),
            }
        )
    env.close()
    print(
        f"{args.run}: {n} episodes (of the first {args.episodes}, {len(corrected)} corrected left out), "
        f"{len(data.actions)} labels ({platform.machine()}, {platform.node()})"
    )
    print("| labels | smoothing | roughness | fit residual median / p90 (mm) | student train / val. MSE "
          "| largest change from recorded |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        fit = f"{r['fit_rms_mm_median']:.2f} / {r['fit_rms_mm_p90']:.2f}" if "fit_rms_mm_median" in r else "-"
        print(
            f"| {r['labels']} | {r['weight']} | {r['roughness']:.4f} | {fit} | "
            f"{r['train_mse']:.4f} / {r['validation_mse']:.4f} | "
            f"{r.get('max_change_from_recorded', 0.0):.5f} |"
        )
    if args.out:
        summary = {"run": str(args.run), "episodes": n, "left_out_corrected": corrected.tolist()}
        summary["rows"] = rows
        args.out.write_text(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
