"""Re-planning from the commanded state: the one place where actions become TCP trajectories.

The environment and the control loop both use :class:`Replanner`, so a policy sees the same planning in
training and on a robot. Each action plans a B-spline from the position *and velocity* the current plan
commands at the re-plan time (the TCP's home, at rest, before the first plan), so commanded motion stays C1
across re-plans. With two grippers the second one mirrors the first's lateral (y) motion about its own home.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision.trajectory.actions import ActionSpec
from dyndlo_vision.trajectory.bspline import BSplineTrajectory

#: The second gripper's motion is the first's with y mirrored.
MIRROR = np.array([1.0, -1.0, 1.0])


class Replanner:
    """Turns actions into trajectories of every gripper.

    Args:
        spec: How actions decode into via points and times.
        gripper_home: (n_g, 3) start positions of the grippers; gripper 0 follows the plan.
        final_point: Fixed last point appended to every plan (task IV), or None.
    """

    def __init__(
        self, spec: ActionSpec, gripper_home: ArrayLike, final_point: ArrayLike | None = None
    ) -> None:
        home = np.asarray(gripper_home, dtype=float)
        if home.ndim != 2 or home.shape[1] != 3:
            raise ValueError(f"gripper_home must have shape (n_g, 3), got {home.shape}")
        self.spec = spec
        self.home = home
        self.final_point = None if final_point is None else np.asarray(final_point, dtype=float)
        self.trajectory: BSplineTrajectory | None = None

    def reset(self, final_point: ArrayLike | None = None) -> None:
        """Forget the current plan (the grippers are back home, at rest)."""
        self.trajectory = None
        self.final_point = None if final_point is None else np.asarray(final_point, dtype=float)

    def commanded_state(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Commanded position and velocity of gripper 0 at time ``t``."""
        if self.trajectory is None:
            return self.home[0].copy(), np.zeros(3)
        return self.trajectory.position(t), self.trajectory.velocity(t)

    def replan(self, action: ArrayLike, t: float) -> BSplineTrajectory:
        """Plan from the commanded state at ``t`` with a normalised action.

        Raises:
            ValueError: For an action of the wrong shape or with NaN/inf (from :meth:`ActionSpec.decode`).
        """
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (self.spec.size,):
            raise ValueError(f"action must have shape ({self.spec.size},), got shape {a.shape}")
        p0, v0 = self.commanded_state(t)
        points, times = self.spec.decode(a, p0, t, self.final_point)
        self.trajectory = BSplineTrajectory(points, times, start_velocity=v0)
        return self.trajectory

    def references(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Commanded positions and velocities of every gripper at times ``t`` (K,), each (K, n_g, 3)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self.trajectory is None:
            p = np.broadcast_to(self.home, (t.size, *self.home.shape)).copy()
            return p, np.zeros_like(p)
        pos, vel = self.trajectory.position(t), self.trajectory.velocity(t)
        home0 = self.home[0]
        p = [pos]
        v = [vel]
        for i in range(1, len(self.home)):
            p.append(self.home[i] + (pos - home0) * MIRROR)
            v.append(vel * MIRROR)
        return np.stack(p, axis=1), np.stack(v, axis=1)


def replan_many(replanners: list[Replanner], actions: ArrayLike, times: ArrayLike) -> None:
    """:meth:`Replanner.replan` of M planners at once (one action and one time each, (M, size), (M,)): the
    decoding and the spline fits of all plans in one computation, each plan equal to the last bit to what
    its own ``replan`` makes. Planners with a final point (task IV) re-plan one by one.

    Raises:
        ValueError: An action of the wrong shape or with NaN/inf, naming the row.
    """
    a = np.asarray(actions, dtype=np.float64)
    t = np.asarray(times, dtype=float)
    if not replanners:
        return
    spec = replanners[0].spec
    if any(r.final_point is not None or r.spec != spec for r in replanners):
        for r, action, time in zip(replanners, a, t, strict=True):
            r.replan(action, float(time))
        return
    starts = [r.commanded_state(float(time)) for r, time in zip(replanners, t, strict=True)]
    points, via_times = spec.decode_many(a, np.array([s[0] for s in starts]), t)
    plans = BSplineTrajectory.many(points, via_times, np.array([s[1] for s in starts]))
    for r, plan in zip(replanners, plans, strict=True):
        r.trajectory = plan
