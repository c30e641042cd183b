"""Evaluate a policy over many episodes: success rate with a 95% interval, reward and its terms.

A policy here is anything with ``predict(obs, deterministic=True) -> (action, state)``
(stable-baselines3 models) or a plain callable ``obs -> action`` (e.g. the geometric baseline of task IV).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

REWARD_TERMS = ("r_avoid", "r_distance", "r_success", "r_dyn")


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95% for the default z)."""
    if n <= 0:
        raise ValueError(f"n={n}; expected at least one episode")
    if not 0 <= successes <= n:
        raise ValueError(f"successes={successes} outside [0, {n}]")
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


@dataclass
class EpisodeRecord:
    """One evaluated episode."""

    seed: int
    reward: float
    success: bool
    length: int
    terms: dict[str, float] = field(default_factory=dict)
    avoid: dict[str, bool] = field(default_factory=dict)
    extras: dict[str, float] = field(default_factory=dict)
    cable: dict[str, float] = field(default_factory=dict)
    #: With a robot (``DynDLOEnv.set_robot``): whether the arm could follow every plan, how close the plan
    #: came to its limits, and why it could not (the first refusal).
    joint_feasible: bool | None = None
    joint_usage: dict[str, float] = field(default_factory=dict)
    joint_limit_reason: str | None = None
    joint_limit_kind: str | None = None


def as_action_fn(policy: Any) -> Callable[[np.ndarray], np.ndarray]:
    """``obs -> action`` for an SB3 model (deterministic) or a callable.

    For a model, the function has ``reset()``, which :func:`evaluate_episode` calls at every reset (a
    :class:`~dyndlo_vision.policies.HistoryPolicy` forgets its episode).
    """
    if hasattr(policy, "predict"):
        return _Predict(policy)
    if callable(policy):
        return policy  # type: ignore[no-any-return]
    raise ValueError(f"policy {policy!r} has no predict() and is not callable")


class _Predict:
    """``obs -> action`` of a model's deterministic ``predict``; ``reset`` resets a model with a history."""

    def __init__(self, model: Any) -> None:
        self.model = model

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.model.predict(obs, deterministic=True)[0]  # type: ignore[no-any-return]

    def reset(self, *_: Any) -> None:
        if hasattr(self.model, "reset"):
            self.model.reset()


def evaluate_episode(
    env: Any, act: Callable[[np.ndarray], np.ndarray], seed: int, on_step: Callable[[Any], None] | None = None
) -> EpisodeRecord:
    """Run one episode from ``reset(seed=seed)``; reward terms are summed over the episode's steps."""
    obs, reset_info = env.reset(seed=seed)
    if hasattr(act, "reset"):
        act.reset(env)
    terms = dict.fromkeys(REWARD_TERMS, 0.0)
    total, length, done, info = 0.0, 0, False, {}
    while not done:
        obs, reward, terminated, truncated, info = env.step(act(obs))
        done = terminated or truncated
        total += float(reward)
        length += 1
        for key in REWARD_TERMS:
            terms[key] += float(info.get(key, 0.0))
        if on_step is not None:
            on_step(env)
    extras = {
        k: float(info[k])
        for k in ("trajectory_time_s", "residual_oscillation_m", "min_distance_m", "sim_time_s")
        if info.get(k) is not None  # task IV's trajectory time is None when the tip never arrived
    }
    return EpisodeRecord(
        seed=seed,
        reward=total,
        success=bool(info.get("is_success", False)),
        length=length,
        terms=terms,
        avoid=dict(info.get("avoid", {})),
        extras=extras,
        cable=_cable_summary(reset_info.get("cable")),
        joint_feasible=info.get("joint_feasible"),
        joint_usage=dict(info.get("joint_usage", {})),
        joint_limit_reason=info.get("joint_limit_reason"),
        joint_limit_kind=info.get("joint_limit_kind"),
    )


def _cable_summary(cable: Any) -> dict[str, float]:
    """The randomised parameters of the episode's cable (``info["cable"]`` of ``CableRandomization``)."""
    if cable is None:
        return {}
    from dyndlo_vision.tasks.wrappers import DEFAULT_CABLE_RANGES

    return {name: float(getattr(cable, name)) for name in DEFAULT_CABLE_RANGES}


def summarize(records: list[EpisodeRecord]) -> dict[str, Any]:
    """Success rate with its 95% Wilson interval, reward mean/std, term means, avoid rates, extras' means."""
    n = len(records)
    k = sum(r.success for r in records)
    lo, hi = wilson_interval(k, n)
    rewards = np.array([r.reward for r in records])
    report: dict[str, Any] = {
        "episodes": n,
        "successes": k,
        "success_rate": k / n,
        "success_ci95": [lo, hi],
        "reward_mean": float(rewards.mean()),
        "reward_std": float(rewards.std()),
        "reward_terms_mean": {t: float(np.mean([r.terms[t] for r in records])) for t in REWARD_TERMS},
        "avoid_rate": {
            a: float(np.mean([r.avoid.get(a, False) for r in records]))
            for a in sorted({a for r in records for a in r.avoid})
        },
        "length_mean": float(np.mean([r.length for r in records])),
    }
    judged = [r for r in records if r.joint_feasible is not None]
    if judged:
        report["joints"] = joint_summary(judged)
    for key in sorted({key for r in records for key in r.extras}):
        values = np.array([r.extras[key] for r in records if key in r.extras])
        report[f"{key}_mean"] = float(values.mean())
        report[f"{key}_median"] = float(np.median(values))
    return report


def joint_summary(records: list[EpisodeRecord]) -> dict[str, Any]:
    """Joint feasibility over episodes judged on an arm: rates with Wilson intervals, limit usage, reasons.

    ``success_and_feasible`` counts the episodes that succeed with plans the arm can follow: what a real arm
    would achieve if the simulated cable were the real one. Usage: medians over episodes of the largest
    joint speed and acceleration as fractions of their limits, and the smallest position margin seen.
    """
    n = len(records)
    feasible = sum(bool(r.joint_feasible) for r in records)
    both = sum(bool(r.joint_feasible) and r.success for r in records)
    reasons: dict[str, int] = {}
    for r in records:
        if r.joint_limit_kind:
            reasons[r.joint_limit_kind] = reasons.get(r.joint_limit_kind, 0) + 1
    usage = [r.joint_usage for r in records if r.joint_usage]
    out: dict[str, Any] = {
        "episodes": n,
        "feasible": feasible,
        "feasible_rate": feasible / n,
        "feasible_ci95": list(wilson_interval(feasible, n)),
        "success_and_feasible": both,
        "success_and_feasible_rate": both / n,
        "success_and_feasible_ci95": list(wilson_interval(both, n)),
        "refusals": dict(sorted(reasons.items(), key=lambda kv: -kv[1])),
    }
    if usage:
        out["velocity_fraction_median"] = float(np.median([u["velocity_fraction"] for u in usage]))
        out["acceleration_fraction_median"] = float(np.median([u["acceleration_fraction"] for u in usage]))
        out["position_margin_deg_min"] = float(np.min([u["position_margin_deg"] for u in usage]))
    return out


def evaluate(
    policy: Any,
    env: Any,
    episodes: int,
    seed: int,
    on_step: Callable[[Any], None] | None = None,
    on_episode: Callable[[EpisodeRecord], None] | None = None,
) -> tuple[dict[str, Any], list[EpisodeRecord]]:
    """Evaluate ``policy`` for ``episodes`` episodes seeded ``seed, seed + 1, ...``.

    Args:
        policy: An SB3 model or a callable ``obs -> action`` (see :func:`as_action_fn`).
        env: The environment the episodes run in.
        episodes: Number of episodes (>= 1).
        seed: Seed of the first episode.
        on_step: Called with ``env`` after every step (e.g. to record frames).
        on_episode: Called with each finished episode's record, in order (e.g. to show progress; this
            function prints nothing itself).

    Returns:
        The report of :func:`summarize` with the first seed, and the episodes' records.
    """
    if episodes < 1:
        raise ValueError(f"episodes={episodes}; expected >= 1")
    act = as_action_fn(policy)
    records = []
    for i in range(episodes):
        records.append(evaluate_episode(env, act, seed + i, on_step))
        if on_episode is not None:
            on_episode(records[-1])
    report = summarize(records)
    report["seed"] = seed
    return report, records


def records_as_dicts(records: list[EpisodeRecord]) -> list[dict[str, Any]]:
    """JSON-ready episode records."""
    return [asdict(r) for r in records]
