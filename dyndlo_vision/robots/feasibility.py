"""Can a real arm follow a TCP plan? The joint-limit test the drivers apply, as a pure function for training.

The EGM and RTDE drivers refuse a plan whose joint trajectory breaks a limit (:mod:`~._streaming`). The same
test decides here whether a plan the policy makes in simulation would be refused on the robot:

1. the TCP path sampled at the robot's cycle (4 ms for the GoFa's EGM, 2 ms for the UR5e's RTDE),
2. IK for every sample, the tool held pointing down, seeded from the joints the arm is at,
3. joined to the last two joint targets (at rest before the first plan) and followed by the braking tail the
   driver appends,
4. positions, velocities and accelerations against the arm's limits (:func:`~.kinematics.check_joint_limits`).

:func:`joint_plan` is steps 2-4 and is what the drivers call; :class:`PlanFeasibility` keeps the joint history
across the re-plans of an episode. :data:`ROBOT_ARMS` places each arm in the task's world as our tasks assume:
the shoulder (axis 2) at (0, 0, 0.265), where the outreach limit is measured from.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision.robots.kinematics import (
    ArmKinematics,
    ArmModel,
    IKError,
    LimitReport,
    abb_gofa_crb15000,
    check_joint_limits,
    pose_matrix,
    ur5e,
)

__all__ = [
    "ROBOT_ARMS",
    "Feasibility",
    "JointPlan",
    "PlanFeasibility",
    "RobotArm",
    "braking_tail",
    "join_plan",
    "joint_plan",
    "limit_usage",
    "robot_arm",
]

FloatArray = NDArray[np.float64]

#: Fraction of the joint acceleration limits the drivers brake with (their default).
BRAKING_FRACTION = 0.9


@dataclass(frozen=True)
class RobotArm:
    """An arm as the tasks and the drivers use it.

    Attributes:
        name: Short name (``gofa``, ``ur5e``): the ``--robot`` value.
        model: Builds the arm model (DH, limits).
        period_s: The streaming interface's cycle (EGM 4 ms, RTDE 2 ms).
        base_in_world: Default base position in the task's world (m): the arm's shoulder at the tasks'
            (0, 0, 0.265).
        protocol: The driver that streams to it (``egm`` or ``rtde``).
    """

    name: str
    model: Callable[[], ArmModel]
    period_s: float
    base_in_world: tuple[float, float, float]
    protocol: str

    def kinematics(self, base_in_world: ArrayLike | None = None, tcp_in_flange: ArrayLike | None = None
                   ) -> ArmKinematics:
        """The arm placed in the world (default: :attr:`base_in_world`, no rotation), tool pointing down."""
        base = pose_matrix(self.base_in_world) if base_in_world is None else base_in_world
        return ArmKinematics(self.model(), base_in_world=base, tcp_in_flange=tcp_in_flange)


#: The arms the drivers stream to, by ``--robot`` name. GoFa: axis 2 is 0.265 m above its base, so the base
#: is at the origin; UR5e: 0.1625 m, so the base is raised 0.1025 m (a pedestal).
ROBOT_ARMS: dict[str, RobotArm] = {
    "gofa": RobotArm("gofa", abb_gofa_crb15000, 0.004, (0.0, 0.0, 0.0), "egm"),
    "ur5e": RobotArm("ur5e", ur5e, 0.002, (0.0, 0.0, 0.1025), "rtde"),
}


def robot_arm(name: str) -> RobotArm:
    """The :data:`ROBOT_ARMS` entry of ``name``.

    Raises:
        ValueError: An unknown name, listing the known ones.
    """
    if name not in ROBOT_ARMS:
        raise ValueError(f"unknown robot {name!r}; expected one of {sorted(ROBOT_ARMS)}")
    return ROBOT_ARMS[name]


def braking_tail(
    t_end: float, q_end: FloatArray, qd_end: FloatArray, max_acceleration: FloatArray, period_s: float
) -> tuple[FloatArray, FloatArray]:
    """Samples after ``t_end`` that bring the joints from velocity ``qd_end`` to rest.

    All joints decelerate uniformly over the same time (the joint-space direction of motion is kept), the
    slowest joint at ``max_acceleration``; the stop time is rounded up to whole periods, so every
    finite-difference acceleration is at most the limit.

    Returns:
        Times (n,) and joint positions (n, 6); empty when ``qd_end`` is zero.
    """
    t_stop = float(np.max(np.abs(qd_end) / max_acceleration))
    if t_stop <= 0.0:
        return np.empty(0), np.empty((0, 6))
    n = max(1, math.ceil(t_stop / period_s - 1e-9))
    t_stop = n * period_s
    s = period_s * np.arange(1, n + 1)
    q = q_end + np.outer(s - s * s / (2.0 * t_stop), qd_end)
    return np.asarray(t_end + s, dtype=np.float64), np.asarray(q, dtype=np.float64)


@dataclass(frozen=True)
class JointPlan:
    """A TCP plan in joints as a driver would stream it.

    Attributes:
        t: Times (N,): the history samples first, then the plan's samples after them, then the braking tail.
        q: Joint positions (N, 6).
        history: How many leading samples are the history (targets already sent).
        report: The limit check of all of it.
    """

    t: FloatArray
    q: FloatArray
    history: int
    report: LimitReport


def joint_plan(
    kinematics: ArmKinematics,
    t: ArrayLike,
    positions: ArrayLike,
    history_t: ArrayLike,
    history_q: ArrayLike,
    period_s: float,
    braking_fraction: float = BRAKING_FRACTION,
) -> JointPlan:
    """IK along a TCP plan, joined to the joint targets already sent, with a braking tail, limit-checked.

    Args:
        kinematics: The placed arm.
        t: Plan times (M,) on the robot's cycle, strictly increasing.
        positions: TCP positions (M, 3).
        history_t: Times of the last targets sent (1 or 2), increasing; plan samples not after the last are
            dropped.
        history_q: Those targets (1 or 2, 6); the last seeds the IK.
        period_s: The robot's cycle (the braking tail's spacing).
        braking_fraction: Fraction of the acceleration limits the tail brakes with.

    Raises:
        IKError: A sample has no IK solution (a ``ValueError``).
        ValueError: The plan ends before the last target sent.
    """
    hist_q = np.atleast_2d(np.asarray(history_q, dtype=float))
    traj = kinematics.joint_trajectory(t, positions, hist_q[-1])
    return join_plan(kinematics.arm, traj.t, traj.q, history_t, hist_q, period_s, braking_fraction)


def join_plan(
    arm: ArmModel,
    t: ArrayLike,
    q: ArrayLike,
    history_t: ArrayLike,
    history_q: ArrayLike,
    period_s: float,
    braking_fraction: float = BRAKING_FRACTION,
) -> JointPlan:
    """Steps 3-4 of :func:`joint_plan` for a plan already in joints (``t`` (M,), ``q`` (M, 6)).

    Raises:
        ValueError: The plan ends before the last target sent.
    """
    hist_t = np.atleast_1d(np.asarray(history_t, dtype=float))
    hist_q = np.atleast_2d(np.asarray(history_q, dtype=float))
    ts, qs = np.asarray(t, dtype=float), np.asarray(q, dtype=float)
    keep = ts > hist_t[-1] + 1e-9
    if not np.any(keep):
        raise ValueError(
            f"the plan ends at t={ts[-1]:.4f} s, before the target already sent for t={hist_t[-1]:.4f} s"
        )
    t_all = np.concatenate([hist_t, ts[keep]])
    q_all = np.concatenate([hist_q, qs[keep]])
    qd_end = (q_all[-1] - q_all[-2]) / (t_all[-1] - t_all[-2])
    braking = braking_fraction * np.array(arm.max_acceleration_rad_s2)
    tail_t, tail_q = braking_tail(t_all[-1], q_all[-1], qd_end, braking, period_s)
    t_all, q_all = np.concatenate([t_all, tail_t]), np.concatenate([q_all, tail_q])
    return JointPlan(t_all, q_all, hist_t.size, check_joint_limits(arm, t_all, q_all))


def limit_usage(arm: ArmModel, t: ArrayLike, q: ArrayLike) -> dict[str, float]:
    """How close a joint trajectory comes to the limits, over all joints.

    Returns:
        ``position_margin_deg``: the smallest distance to a position limit (negative: beyond it);
        ``velocity_fraction`` and ``acceleration_fraction``: the largest |value| / limit (above 1: broken).
    """
    ts, qs = np.asarray(t, dtype=float), np.asarray(q, dtype=float)
    lo, hi = np.array(arm.lower_rad), np.array(arm.upper_rad)
    out = {"position_margin_deg": float(np.degrees(np.min(np.minimum(qs - lo, hi - qs))))}
    vel = np.diff(qs, axis=0) / np.diff(ts)[:, None] if ts.size >= 2 else np.zeros((0, 6))
    out["velocity_fraction"] = float(np.max(np.abs(vel) / np.array(arm.max_velocity_rad_s), initial=0.0))
    if ts.size >= 3:
        acc = np.diff(vel, axis=0) / (0.5 * (ts[2:] - ts[:-2]))[:, None]
        out["acceleration_fraction"] = float(np.max(np.abs(acc) / np.array(arm.max_acceleration_rad_s2)))
    else:
        out["acceleration_fraction"] = 0.0
    return out


@dataclass(frozen=True)
class Feasibility:
    """The verdict on one plan: ``reason`` is None when the arm can follow it; ``kind`` names what broke in
    a few words (``"IK"``, or quantity and joint of the worst breach, e.g. ``"acceleration axis_2"``)."""

    reason: str | None
    usage: dict[str, float]
    kind: str | None = None

    @property
    def ok(self) -> bool:
        """True when the arm can follow the plan."""
        return self.reason is None


class PlanFeasibility:
    """Whether the arm could follow each plan of an episode, as the driver would judge it.

    Call :meth:`start` with the TCP's position at the episode's start (the arm at rest there), then
    :meth:`check` with each plan from the time it takes over. An accepted plan becomes the history the next
    plan joins; a refused one leaves the previous (the driver keeps following it).

    Args:
        arm: A :data:`ROBOT_ARMS` name or entry.
        kinematics: The placed arm (default: the entry's placement).
    """

    def __init__(self, arm: str | RobotArm, kinematics: ArmKinematics | None = None) -> None:
        self.arm = robot_arm(arm) if isinstance(arm, str) else arm
        self.kinematics = kinematics or self.arm.kinematics()
        self.period_s = self.arm.period_s
        self._plan: tuple[FloatArray, FloatArray] | None = None

    def start(self, t: float, position: ArrayLike) -> None:
        """The arm at rest with its TCP at ``position`` at time ``t`` (IK from the arm's usual seed).

        Raises:
            IKError: The position is out of the arm's reach with the tool down.
        """
        p = np.asarray(position, dtype=float).reshape(3)
        q = self.kinematics.joint_trajectory(np.array([t]), p[None]).q[0]
        self._plan = (np.array([t - self.period_s, t]), np.array([q, q]))

    def _history(self, t: float) -> tuple[FloatArray, FloatArray]:
        if self._plan is None:
            raise RuntimeError("PlanFeasibility.start() first")
        pt, pq = self._plan
        times = np.array([t - self.period_s, t])
        q = np.stack([np.interp(times, pt, pq[:, j]) for j in range(6)], axis=1)
        return times, q

    def check(self, t: ArrayLike, positions: ArrayLike) -> Feasibility:
        """Judge the plan whose TCP positions (N, 3) at times ``t`` (N,) take over at ``t[0]``.

        ``t`` should be on the arm's cycle (:attr:`period_s`) from the take-over time on.
        """
        ts = np.asarray(t, dtype=float)
        hist_t, hist_q = self._history(float(ts[0]))
        try:
            plan = joint_plan(self.kinematics, ts, positions, hist_t, hist_q, self.period_s)
        except IKError as exc:
            return Feasibility(f"IK: {exc}", {}, "IK")
        usage = limit_usage(self.kinematics.arm, plan.t, plan.q)
        if not plan.report.ok:
            worst = max(plan.report.violations, key=lambda v: abs(v.value) / max(abs(v.limit), 1e-12))
            return Feasibility(str(worst), usage, f"{worst.quantity} {worst.joint}")
        self._plan = (plan.t, plan.q)
        return Feasibility(None, usage)
