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
    q[1, j] = q[3, j] = bound + sign * 0.1  # 0.1 rad beyond, twice (slow: no speed limit broken)
    q[3, j] = bound + sign * 0.05
    report = check_joint_limits(arm, t, q)
    assert [(v.joint, v.quantity) for v in report.violations] == [(arm.joint_names[j], "position")]
    v = report.violations[0]
    assert (v.t_s, v.first_t_s, v.samples) == (0.5, 0.5, 2)  # the worst and the first are the same sample
    assert v.value == pytest.approx(bound + sign * 0.1, abs=1e-12)
    assert v.limit == pytest.approx(bound, abs=1e-12)
    # Exactly at the bound is within it.
    q[1, j] = q[3, j] = bound
    assert check_joint_limits(arm, t, q).ok


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
