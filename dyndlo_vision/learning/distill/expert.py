"""The expert that labels a multi-step student's decisions: it keeps following one single-step plan.

A single-step policy knows *which* whip hits the target; a multi-step policy must keep following that whip
while it re-plans every 40 ms from the current position and velocity. :class:`PlanFollowingExpert` finds, at
each decision, by bounded least squares, the action whose re-planned B-spline (from the commanded position
*and velocity* now) stays closest to the rest of the single-step trajectory. It knows the time and the plan,
which the multi-step observation (table II) does not contain, so it is a teacher, not a policy.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from dyndlo_vision.trajectory import ActionSpec, BSplineTrajectory

__all__ = ["PlanFollowingExpert"]


class PlanFollowingExpert:
    """Multi-step actions that keep following one single-step plan.

    Args:
        spec: The task's action spec (multi-step and single-step share it).
        samples: Times at which the re-plan is compared with the reference, spread over the rest of the
            reference (at least ``spec``'s shortest plan) plus ``tail_s``.
        early_s: The re-plan is executed only until the next decision; errors in the first ``early_s`` (at
            ``early_samples`` more times) count ``early_weight`` times more while the reference still moves.
            Once it has ended, every sample counts the same: holding its end point with the first 40 ms
            weighted up is unstable (each re-plan starts from the last one's velocity, and on the vault the
            commanded speed grew by about 20 % per decision, 0.3 to 4.6 m/s).
        max_nfev: Evaluation budget of each least-squares fit (warm-started from the previous action).
        smoothing: Weight (metres of residual per normalised action unit) of a term that keeps each action
            near the previous one. Many actions re-plan the rest of a plan almost equally well, and without
            it the fit picks among them by where its search happens to stop: on the vault consecutive
            labels jumped by 0.6 (mean squared change) for a residual under 1 mm, and the student could not
            fit them. 0 (default, what the shipped policies were made with) turns it off.
    """

    def __init__(
        self,
        spec: ActionSpec,
        samples: int = 30,
        tail_s: float = 0.1,
        early_s: float = 0.04,
        early_samples: int = 10,
        early_weight: float = 10.0,
        max_nfev: int = 60,
        smoothing: float = 0.0,
    ) -> None:
        if spec.append_final_point:
            raise ValueError("PlanFollowingExpert needs an ActionSpec without a fixed final point")
        self.spec = spec
        self.samples = int(samples)
        self.tail_s = float(tail_s)
        self.early_s = float(early_s)
        self.early_samples = int(early_samples)
        self.early_weight = float(early_weight)
        self.max_nfev = int(max_nfev)
        if not (isinstance(smoothing, int | float) and 0.0 <= smoothing < float("inf")):
            raise ValueError(f"smoothing must be a finite weight >= 0, got {smoothing!r}")
        self.smoothing = float(smoothing)
        self.reference: BSplineTrajectory | None = None
        self._last: NDArray[np.float64] | None = None
        self.last_rms_m = 0.0

    def start(self, plan_action: NDArray[np.floating[Any]], home: NDArray[np.float64]) -> NDArray[np.float64]:
        """Take the single-step plan (its normalised action from ``home`` at rest, t = 0); return it.

        At t = 0 from rest the multi-step re-plan of this action *is* the single-step trajectory.
        """
        a = np.clip(np.asarray(plan_action, dtype=np.float64), -1.0, 1.0)
        points, times = self.spec.decode(a, home, 0.0)
        self.reference = BSplineTrajectory(points, times)
        self._last = a
        self.last_rms_m = 0.0
        return a.copy()

    def adopt(self, action: NDArray[np.floating[Any]], t: float, position: NDArray[np.float64],
              velocity: NDArray[np.float64]) -> None:
        """Follow from now on the plan that ``action`` makes at ``t`` from the commanded ``position`` and
        ``velocity`` (a re-plan found by :class:`~dyndlo_vision.learning.distill.teachers.ReplanSearch`)
        instead of the plan taken at :meth:`start`."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        points, times = self.spec.decode(a, np.asarray(position, dtype=np.float64), t)
        v0 = np.asarray(velocity, dtype=np.float64)
        self.reference = BSplineTrajectory(points, times, start_velocity=v0)
        self._last = a
        self.last_rms_m = 0.0

    def act(
        self, t: float, position: NDArray[np.float64], velocity: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """The action whose re-plan from the commanded ``position``/``velocity`` at ``t`` follows the plan."""
        if self.reference is None or self._last is None:
            raise RuntimeError("call start() with the single-step plan first")
        ref = self.reference
        horizon = max(ref.t_end - t, self.spec.num_intervals * self.spec.dt_s[0]) + self.tail_s
        early = np.linspace(0.002, self.early_s, self.early_samples)
        ts = t + np.concatenate([early, np.linspace(self.early_s, horizon, self.samples + 1)[1:]])
        early_weight = self.early_weight if t < ref.t_end else 1.0
        weight = np.where(ts - t <= self.early_s + 1e-9, early_weight, 1.0)[:, None]
        target = ref.position(ts)
        p0 = np.asarray(position, dtype=np.float64)
        v0 = np.asarray(velocity, dtype=np.float64)
        previous = self._last.copy()

        def residuals(a: NDArray[np.float64]) -> NDArray[np.float64]:
            points, times = self.spec.decode(a, p0, t)
            plan = BSplineTrajectory(points, times, start_velocity=v0)
            error = ((plan.position(ts) - target) * weight).ravel()
            if self.smoothing > 0.0:
                return np.concatenate([error, self.smoothing * (a - previous)])
            return error

        guess = np.clip(self._last, -0.999, 0.999)
        sol = least_squares(residuals, guess, bounds=(-1.0, 1.0), diff_step=1e-3, max_nfev=self.max_nfev)
        self._last = sol.x
        self.last_rms_m = float(np.sqrt(np.mean(sol.fun[: 3 * len(ts)] ** 2)))
        return np.asarray(sol.x, dtype=np.float64)
