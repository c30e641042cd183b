"""Learning curves (the paper's Fig. 3): success rate and mean episode reward against timesteps.

Runs are read from their ``eval/evaluations.npz`` (written by the EvalCallback during training). Runs whose
configurations differ only in the seed form one group: each run is drawn thin, the group's mean thick, and the
spread (min to max over runs) shaded, on a common grid of timesteps.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Curve:
    """One run's evaluations."""

    label: str
    group: str
    timesteps: NDArray[np.int64]
    success: NDArray[np.float64]
    reward: NDArray[np.float64]


def group_name(config: dict) -> str:
    """A run configuration without its seed, as a legend label: task, mode, algorithm, what else was set."""
    mode = "multi-step" if config.get("multi_step") else "single-step"
    parts = [str(config.get("task")), mode, str(config.get("algo", "")).upper()]
    parts += [f"{k}={v}" for k, v in sorted((config.get("env_options") or {}).items())]
    if config.get("demonstrations"):
        parts.append(f"+{config['demonstrations']} demos")
    if config.get("obs_noise"):
        parts.append("noisy obs")
    if config.get("randomize_cable"):
        ranges = config.get("cable_ranges", "training")
        parts.append("random cable" if ranges == "training" else f"random cable ({ranges})")
    return " ".join(parts)


def load_curve(run: Path) -> Curve:
    """Read a run folder's evaluations, with a clear error if it has none."""
    run = Path(run)
    evals = run / "eval" / "evaluations.npz"
    if not evals.is_file():
        raise FileNotFoundError(f"{evals} not found: is {run} a run folder of `dyndlo-vision train`?")
    try:
        data = np.load(evals)
        steps, results = data["timesteps"], data["results"]
        success = data["successes"].mean(axis=1) if "successes" in data and data["successes"].size else None
    except (KeyError, ValueError, OSError) as err:
        raise ValueError(f"{evals} is not a readable evaluations file: {err}") from err
    if len(steps) == 0:
        raise ValueError(f"{evals} holds no evaluations yet")
    group = run.name
    config_file = run / "config.json"
    if config_file.is_file():
        config = json.loads(config_file.read_text())
        group = group_name(config)
    return Curve(
        label=run.name,
        group=group,
        timesteps=np.asarray(steps),
        success=np.asarray(success if success is not None else np.full(len(steps), np.nan)),
        reward=np.asarray(results).mean(axis=1),
    )


def group_stats(
    curves: list[Curve], field: str, points: int = 100
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Mean, min and max of ``field`` over curves, interpolated on a common grid up to the shortest run."""
    end = min(int(c.timesteps[-1]) for c in curves)
    start = max(int(c.timesteps[0]) for c in curves)
    grid = np.linspace(start, end, points) if end > start else np.array([end], dtype=float)
    values = np.stack([np.interp(grid, c.timesteps, getattr(c, field)) for c in curves])
    return grid, values.mean(axis=0), values.min(axis=0), values.max(axis=0)


def plot_runs(runs: list[Path], out: Path, title: str | None = None) -> dict[str, list[str]]:
    """Draw success rate and mean reward against timesteps for ``runs`` into the PNG ``out``.

    Returns:
        The groups and the runs in each.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dyndlo_vision._atomic import write_atomic

    curves = [load_curve(r) for r in runs]
    groups: dict[str, list[Curve]] = {}
    for c in curves:
        groups.setdefault(c.group, []).append(c)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (group, members) in enumerate(sorted(groups.items())):
        color = colors[i % len(colors)]
        for ax, field, name in (
            (axes[0], "success", "success rate"),
            (axes[1], "reward", "mean episode reward"),
        ):
            for c in members:
                ax.plot(c.timesteps, getattr(c, field), color=color, alpha=0.3, lw=0.8)
            grid, mean, lo, hi = group_stats(members, field)
            ax.plot(grid, mean, color=color, lw=2, label=f"{group} (n={len(members)})")
            if len(members) > 1:
                ax.fill_between(grid, lo, hi, color=color, alpha=0.15)
            ax.set_xlabel("timesteps")
            ax.set_ylabel(name)
            ax.grid(alpha=0.3)
    axes[0].set_ylim(-0.02, 1.02)
    axes[0].legend(fontsize=8, loc="lower right")
    fig.suptitle(title or "DynDLO learning curves (evaluation episodes, deterministic policy)")
    fig.tight_layout()
    write_atomic(Path(out), lambda p: fig.savefig(p, dpi=110, format="png"))
    plt.close(fig)
    return {g: [c.label for c in m] for g, m in groups.items()}
