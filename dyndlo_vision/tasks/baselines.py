"""Scripted policies to compare learned ones with.

:class:`FlickVault` is a scripted vault for task II (not in the paper), one shape per cable model: on the
rod a quick dip towards the box, a flick up and forward that throws a wave along the cable over the box, and a
step back; on the chain a lift, a carry over the box and a drop beyond it. Each shape was found by searching
the single action (random actions, then Gaussian perturbations of the best); it is the demonstrator of
``dyndlo-vision train --task vaulting --demonstrations N``.

:class:`RandomActions` draws every action uniformly from the action space: the chance level of a task, what
a learner's exploration starts from.

:class:`GeometricLift` is the paper's baseline for task IV (section V-B): a linear path that brings the TCP
20 cm below the goal (or to z = 0.55 m if that would be too close to the floor), then a fast upward move to
the goal, with a total trajectory time chosen to equal the learned policy's. The paper does not say how the
time is split between the two phases; the issue that asked for it reads "a fast upward move with the same
duration". Half of the total for the upward move would not fit the action's interval range (dt <= 0.6 s)
at the paper's 1.35 s, and would not be fast, so by default every interval of the plan (three along the
line, one upward) takes the same time: the upward move covers 20 cm in a quarter of the total. The split
is a parameter.

The demonstrators (:func:`geometric_demonstration`, :func:`vault_demonstration`) perturb the baselines'
actions to seed an off-policy learner's replay buffer (``dyndlo-vision train --demonstrations N``): Gaussian
noise of a per-episode scale drawn from :data:`NOISE_SCALES` on the normalised action, so the buffer covers
the baseline family and its neighbourhood, not one point.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

BELOW_GOAL_M = 0.20
LOWEST_Z_M = 0.55
#: Trajectory times of the geometric-lift demonstrations (s); the paper's results lie at 1.35-1.47 s.
GEOMETRIC_TIME_RANGE_S = (1.0, 2.0)
#: Standard deviations of the noise added to a demonstration's normalised action, one drawn per episode.
NOISE_SCALES = (0.0, 0.05, 0.15)


class GeometricLift:
    """Task IV baseline as a single-step policy ``obs -> action`` for ``DynDLO/TimeOscillation-v0``.

    Args:
        env: The (single-step) TimeOscillation environment, used for its action encoding.
        total_time_s: Trajectory time from the start to the goal.
        upward_fraction: Share of ``total_time_s`` spent on the final upward move (default: every interval of
            the plan equally long).
    """

    def __init__(self, env: Any, total_time_s: float, upward_fraction: float | None = None) -> None:
        base = env.unwrapped
        if base.multi_step:
            raise ValueError("GeometricLift plans once: use a single-step environment (multi_step=False)")
        if not base.spec_actions.append_final_point:
            raise ValueError("GeometricLift needs an action spec that appends the goal (task IV)")
        if upward_fraction is None:
            upward_fraction = 1.0 / base.spec_actions.num_intervals
        if not 0.0 < upward_fraction < 1.0:
            raise ValueError(f"upward_fraction={upward_fraction}; expected a value in (0, 1)")
        self.spec = base.spec_actions
        self.n_g = base.scene.num_grippers
        lo, hi = self.spec.dt_s
        n_lin = self.spec.num_points
        t_lin, t_up = total_time_s * (1 - upward_fraction), total_time_s * upward_fraction
        if not (n_lin * lo <= t_lin <= n_lin * hi and lo <= t_up <= hi):
            raise ValueError(
                f"total_time_s={total_time_s} with upward_fraction={upward_fraction} needs intervals outside "
                f"the action range dt in [{lo}, {hi}] s"
            )
        self.total_time_s = total_time_s
        self.upward_fraction = upward_fraction

    def lowest_point(self, start: NDArray[np.float64], goal: NDArray[np.float64]) -> NDArray[np.float64]:
        """Where the linear phase ends: below the goal, not lower than ``LOWEST_Z_M``."""
        low = goal.copy()
        low[2] = max(goal[2] - BELOW_GOAL_M, LOWEST_Z_M)
        return low

    def plan(
        self, start: NDArray[np.float64], goal: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Points (P0, via points on the line, goal) and their times."""
        n = self.spec.num_points
        low = self.lowest_point(start, goal)
        s = np.linspace(0.0, 1.0, n + 1)
        points = np.vstack([start + s[:, None] * (low - start), goal])
        t_lin = self.total_time_s * (1 - self.upward_fraction)
        times = np.concatenate([np.linspace(0.0, t_lin, n + 1), [self.total_time_s]])
        return points, times

    def __call__(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        start = np.asarray(obs[:3], dtype=float)
        goal = np.asarray(obs[-3:], dtype=float)
        points, times = self.plan(start, goal)
        return self.spec.encode(points, times).astype(np.float32)


class FlickVault:
    """Task II scripted vault as a single-step policy ``obs -> action`` for ``DynDLO/Vaulting-v0``.

    Via points are offsets from the TCP's position in the observation, each interval a fixed duration
    (:attr:`SHAPE`): the TCP lifts the cable up and forward over the box (above M = 0.3 m: it pays table V's
    lambda_4), and comes back to lay it over the box, its middle beyond (reward 8 on the nominal cable of
    either model). It came out of a cross-entropy search, kept because it vaulted the most random chain
    cables the search never saw without breaking an avoid condition.
    """

    #: (offsets from the start (m), intervals (s)).
    SHAPE: tuple[tuple[tuple[float, float, float], ...], tuple[float, ...]] = (
        ((0.071, 0.0, 0.363), (0.314, 0.0, 0.495), (0.081, 0.0, 0.316)), (0.336, 0.354, 0.32)
    )

    def __init__(self, env: Any) -> None:
        base = env.unwrapped
        if base.multi_step:
            raise ValueError("FlickVault plans once: use a single-step environment (multi_step=False)")
        from dyndlo_vision.tasks.vaulting import Vaulting

        if not isinstance(base.task, Vaulting):
            raise ValueError(f"FlickVault vaults in DynDLO/Vaulting-v0, not in {type(base.task).__name__}")
        self.spec = base.spec_actions

    def __call__(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        offsets, intervals = self.SHAPE
        start = np.asarray(obs[:3], dtype=float)
        points = np.vstack([start, start + np.asarray(offsets)])
        times = np.concatenate([[0.0], np.cumsum(intervals)])
        return self.spec.encode(points, times).astype(np.float32)


class RandomActions:
    """Uniformly random normalised actions, ``obs -> action``, for any DynDLO environment and mode.

    Args:
        env: The environment (for its action space).
        seed: Seed of the action stream: the same seed gives the same actions in the same order.
    """

    def __init__(self, env: Any, seed: int | None = None) -> None:
        space = env.action_space
        self.shape = space.shape
        self.low, self.high = space.low, space.high
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: NDArray[Any]) -> NDArray[np.float32]:
        """One random action (the observation is ignored)."""
        return self.rng.uniform(self.low, self.high, size=self.shape).astype(np.float32)


def _perturbed(action: NDArray[np.float32], rng: np.random.Generator) -> NDArray[np.float32]:
    scale = NOISE_SCALES[rng.integers(len(NOISE_SCALES))]
    return np.clip(action + scale * rng.standard_normal(action.shape), -1.0, 1.0).astype(np.float32)


def geometric_demonstration(
    env: Any, obs: NDArray[np.float32], rng: np.random.Generator
) -> NDArray[np.float32]:
    """One perturbed geometric-lift action (time drawn from :data:`GEOMETRIC_TIME_RANGE_S`) for task IV."""
    total_time_s = rng.uniform(*GEOMETRIC_TIME_RANGE_S)
    return _perturbed(GeometricLift(env, total_time_s)(obs), rng)


def vault_demonstration(
    env: Any, obs: NDArray[np.float32], rng: np.random.Generator
) -> NDArray[np.float32]:
    """One perturbed scripted-vault action for a single-step task II environment."""
    return _perturbed(FlickVault(env)(obs), rng)
