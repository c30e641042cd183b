"""The joint-limit check (``robots.kinematics.check_joint_limits``) on every joint of both arms.

One joint at a time breaks one limit (position on either side, velocity, acceleration) by a hand-computed
amount while the others rest: the report names that joint and quantity, with the value, the limit, the first
time and the count. Exactly at a limit is within it; a part per million over is not.
"""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.robots.kinematics import JointLimitError, abb_gofa_crb15000, check_joint_limits, ur5e

ARMS = [abb_gofa_crb15000, ur5e]

JOINTS = [(make, j) for make in ARMS for j in range(6)]


def _joint_ids(case: tuple) -> str:
    make, j = case
    return f"{make.__name__}-joint{j + 1}"


@pytest.mark.parametrize("case", JOINTS, ids=_joint_ids)
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_each_joints_position_limit_is_checked(case: tuple, sign: float) -> None:
    make, j = case
    arm = make()
    bound = arm.upper_rad[j] if sign > 0 else arm.lower_rad[j]
    t = np.arange(4) * 0.5
    q = np.zeros((4, 6))
    q[:, j] = bound - sign * 0.1  # inside
    q[1, j] = bound + sign * 0.05  # beyond at 0.5 s, and farther at 1.5 s (slow: no speed limit broken)
    q[3, j] = bound + sign * 0.1
    report = check_joint_limits(arm, t, q)
    assert [(v.joint, v.quantity) for v in report.violations] == [(arm.joint_names[j], "position")]
    v = report.violations[0]
    assert (v.t_s, v.first_t_s, v.samples) == (1.5, 0.5, 2)  # the worst sample, the first one, how many
    assert v.value == pytest.approx(bound + sign * 0.1, abs=1e-12)
    assert v.limit == pytest.approx(bound, abs=1e-12)
    # Exactly at the bound is within it, and so is the relative tolerance beyond it (rounding), not more.
    slack = 1e-9 * abs(bound)
    for beyond, ok in ((0.0, True), (0.5 * slack, True), (slack, True), (2.0 * slack, False)):
        q[1, j] = q[3, j] = bound + sign * beyond
        assert check_joint_limits(arm, t, q).ok == ok, beyond


@pytest.mark.parametrize("make", ARMS)
def test_the_worst_position_breach_is_the_farthest_beyond_either_bound(make) -> None:
    """A joint that goes past both of its bounds: the report's value is the sample farthest beyond a bound."""
    arm = make()
    j = 2
    lo, hi = arm.lower_rad[j], arm.upper_rad[j]
    t = np.arange(5) * 10.0  # slow enough for every speed limit
    q = np.zeros((5, 6))
    q[:, j] = [0.0, lo - 0.1, 0.0, hi + 0.05, 0.0]
    (v,) = check_joint_limits(arm, t, q).violations
    assert (v.quantity, v.t_s, v.value, v.first_t_s, v.samples) == ("position", 10.0, lo - 0.1, 10.0, 2)
    assert v.limit == lo
    q[:, j] = [0.0, lo - 0.05, 0.0, hi + 0.1, 0.0]
    (v,) = check_joint_limits(arm, t, q).violations
    assert (v.t_s, v.value, v.limit) == (30.0, hi + 0.1, hi)


@pytest.mark.parametrize("case", JOINTS, ids=_joint_ids)
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_each_joints_velocity_limit_is_checked(case: tuple, sign: float) -> None:
    make, j = case
    arm = make()
    vmax = arm.max_velocity_rad_s[j]
    t = np.arange(6) * 0.004
    for factor, broken in ((1.0, False), (1.0 + 1e-6, True), (1.2, True)):
        q = np.zeros((6, 6))
        q[:, j] = sign * factor * vmax * t  # constant speed: no acceleration, positions near 0
        report = check_joint_limits(arm, t, q)
        if not broken:
            assert report.ok, str(report)
            continue
        assert [(v.joint, v.quantity) for v in report.violations] == [(arm.joint_names[j], "velocity")]
        v = report.violations[0]
        assert v.value == pytest.approx(sign * factor * vmax, rel=1e-9)
        assert v.limit == pytest.approx(vmax, rel=1e-12)
        assert (v.first_t_s, v.samples) == (pytest.approx(0.004), 5)
    # Two samples are one velocity: checked too.
    q = np.zeros((2, 6))
    q[1, j] = sign * 1.2 * vmax * 0.004
    (v,) = check_joint_limits(arm, t[:2], q).violations
    assert (v.joint, v.quantity, v.t_s) == (arm.joint_names[j], "velocity", 0.004)


@pytest.mark.parametrize("case", JOINTS, ids=_joint_ids)
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_each_joints_acceleration_limit_is_checked(case: tuple, sign: float) -> None:
    make, j = case
    arm = make()
    amax = arm.max_acceleration_rad_s2[j]
    t = np.arange(11) * 0.004  # 40 ms at up to 1.2 amax: below every speed limit
    for factor, broken in ((1.0, False), (1.0 + 1e-6, True), (1.2, True)):
        q = np.zeros((11, 6))
        q[:, j] = sign * 0.5 * factor * amax * t**2
        report = check_joint_limits(arm, t, q)
        if not broken:
            assert report.ok, str(report)
            continue
        assert [(v.joint, v.quantity) for v in report.violations] == [(arm.joint_names[j], "acceleration")]
        v = report.violations[0]
        assert v.value == pytest.approx(sign * factor * amax, rel=1e-6)
        assert v.limit == pytest.approx(amax, rel=1e-12)
        assert (v.first_t_s, v.samples) == (pytest.approx(0.004), 9)
    # Three samples are one acceleration: checked too.
    q = np.zeros((3, 6))
    q[:, j] = sign * 0.5 * 1.2 * amax * t[:3] ** 2
    (v,) = check_joint_limits(arm, t[:3], q).violations
    assert (v.joint, v.quantity, v.t_s) == (arm.joint_names[j], "acceleration", 0.004)


@pytest.mark.parametrize("make", ARMS)
def test_accelerations_on_uneven_time_steps_use_both_intervals(make) -> None:
    """Samples of a constant acceleration a at uneven times: the check's finite difference is exactly a (the
    difference of two interval velocities over half the sum of the two intervals), at and past the limit."""
    arm = make()
    amax = arm.max_acceleration_rad_s2[4]
    t = np.array([0.0, 0.002, 0.006, 0.007, 0.011, 0.014])
    for factor in (1.0, 1.1):
        q = np.zeros((t.size, 6))
        q[:, 4] = 0.5 * factor * amax * t**2
        report = check_joint_limits(arm, t, q)
        assert report.ok == (factor == 1.0), str(report)
    (v,) = report.violations
    assert v.value == pytest.approx(1.1 * amax, rel=1e-9)
    assert v.samples == t.size - 2


def test_bad_input_is_refused_with_what_was_expected() -> None:
    arm = ur5e()
    t = np.array([0.0, 0.1, 0.2])
    with pytest.raises(ValueError, match=r"^need t \(N,\) and q \(N, 6\), got shapes \(3,\) and \(3, 5\)$"):
        check_joint_limits(arm, t, np.zeros((3, 5)))
    with pytest.raises(ValueError, match=r"got shapes \(1, 3\) and \(3, 6\)$"):
        check_joint_limits(arm, t[None], np.zeros((3, 6)))
    q = np.zeros((3, 6))
    q[1, 3] = np.nan
    with pytest.raises(ValueError, match=r"^t and q must be finite$"):
        check_joint_limits(arm, t, q)
    with pytest.raises(ValueError, match=r"^t and q must be finite$"):
        check_joint_limits(arm, [0.0, np.inf, 0.2], np.zeros((3, 6)))
    for times in ([0.0, 0.1, 0.1], [0.0, 0.2, 0.1]):
        with pytest.raises(ValueError, match=r"^t must be strictly increasing$"):
            check_joint_limits(arm, times, np.zeros((3, 6)))


def test_every_broken_joint_is_reported_in_joint_order() -> None:
    arm = ur5e()
    t = np.arange(6) * 0.004
    speeds = 1.5 * np.array(arm.max_velocity_rad_s) * np.array([1, -1, 1, -1, 1, -1])
    report = check_joint_limits(arm, t, np.outer(t, speeds))
    assert [(v.joint, v.quantity) for v in report.violations] == [(n, "velocity") for n in arm.joint_names]
    assert [v.value for v in report.violations] == pytest.approx(list(speeds))
    with pytest.raises(JointLimitError) as info:
        report.raise_if_violated()
    assert "wrist_3 velocity -4.712 rad/s" in str(info.value)
    assert info.value.report is report and not info.value.at_join
