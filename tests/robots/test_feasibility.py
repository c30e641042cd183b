"""Joint feasibility of TCP plans (robots.feasibility): the drivers' test, usable without a robot."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.robots.feasibility import (
    ROBOT_ARMS,
    PlanFeasibility,
    braking_tail,
    joint_plan,
    limit_usage,
    robot_arm,
)
from dyndlo_vision.robots.kinematics import check_joint_limits

HOME = np.array([0.45, 0.0, 0.6])  # tip control's TCP home


def straight_line(t0: float, p0, p1, duration: float, period: float, ease: bool = True):
    """Samples of a move from p0 to p1 (smoothstep in time when ``ease``, else constant speed)."""
    t = t0 + period * np.arange(int(round(duration / period)) + 1)
    s = (t - t0) / duration
    w = s * s * (3 - 2 * s) if ease else s
    return t, np.asarray(p0) + w[:, None] * (np.asarray(p1) - np.asarray(p0))


@pytest.mark.parametrize("name", sorted(ROBOT_ARMS))
def test_a_slow_move_is_feasible_and_the_same_move_fast_is_not(name):
    arm = robot_arm(name)
    check = PlanFeasibility(arm)
    check.start(0.0, HOME)
    t, p = straight_line(0.0, HOME, HOME + [0.1, 0.0, 0.05], 2.0, arm.period_s)
    slow = check.check(t, p)
    assert slow.ok, slow.reason
    assert slow.usage["velocity_fraction"] < 0.5 and slow.usage["acceleration_fraction"] < 0.5
    check.start(0.0, HOME)
    t, p = straight_line(0.0, HOME, HOME + [0.1, 0.0, 0.05], 0.05, arm.period_s)
    fast = check.check(t, p)
    assert not fast.ok
    assert "breaks the limit" in fast.reason and fast.usage["acceleration_fraction"] > 1.0


def test_a_plan_that_starts_moving_from_rest_is_judged_joined_to_rest():
    """A constant-speed line is fine on its own, but starting it from rest is a jump in velocity: refused,
    as the driver refuses it (the plan is joined to the targets already sent)."""
    arm = robot_arm("gofa")
    check = PlanFeasibility(arm)
    check.start(0.0, HOME)
    t, p = straight_line(0.0, HOME, HOME + [0.0, 0.0, 0.1], 0.5, arm.period_s, ease=False)
    alone = check_joint_limits(arm.model(), t, arm.kinematics().joint_trajectory(t, p).q)
    verdict = check.check(t, p)
    assert not any(v.quantity == "acceleration" for v in alone.violations)
    assert not verdict.ok and "acceleration" in verdict.reason


def test_an_unreachable_plan_is_refused_with_the_ik_reason():
    check = PlanFeasibility("gofa")
    check.start(0.0, HOME)
    t, p = straight_line(0.0, HOME, [2.0, 0.0, 0.6], 3.0, 0.004)
    verdict = check.check(t, p)
    assert not verdict.ok and verdict.reason.startswith("IK:") and "no IK solution" in verdict.reason


def test_a_refused_replan_leaves_the_accepted_plan_as_history():
    """Multi-step: after a refusal the arm keeps following the accepted plan, so the next plan is joined to
    that one, not to the refused one."""
    arm = robot_arm("gofa")
    check = PlanFeasibility(arm)
    check.start(0.0, HOME)
    target = HOME + [0.1, 0.0, 0.0]
    t, p = straight_line(0.0, HOME, target, 2.0, arm.period_s)
    assert check.check(t, p).ok
    t_fast, p_fast = straight_line(1.0, p[250], HOME + [0.3, 0.0, 0.2], 0.05, arm.period_s)
    assert not check.check(t_fast, p_fast).ok
    # The accepted plan continued from t = 1.02 s: feasible, joined to the accepted plan (joined to the
    # refused one it would jump).
    assert check.check(t[255:], p[255:]).ok


def test_joint_plan_ends_with_a_braking_tail_within_the_limits():
    arm = robot_arm("ur5e")
    kin = arm.kinematics()
    q0 = kin.joint_trajectory(np.array([0.0]), HOME[None]).q[0]
    t, p = straight_line(0.0, HOME, HOME + [0.0, 0.0, 0.1], 0.5, arm.period_s, ease=False)
    t, p = t[: t.size // 2], p[: t.size // 2]  # cut mid-move: the plan ends at speed
    plan = joint_plan(kin, t, p, [-arm.period_s, 0.0], [q0, q0], arm.period_s)
    assert plan.history == 2 and plan.t.size > plan.history + t.size - 1
    tail = plan.t > t[-1] + 1e-9
    last_speed = np.abs(plan.q[-1] - plan.q[-2]) / arm.period_s
    assert np.all(last_speed <= np.array(arm.model().max_acceleration_rad_s2) * arm.period_s)  # at rest
    assert np.max(np.abs(plan.q[t.size] - plan.q[t.size - 1])) > 10 * np.max(last_speed) * arm.period_s
    acc = np.diff(np.diff(plan.q[tail], axis=0), axis=0) / arm.period_s**2
    assert np.all(np.abs(acc) <= 0.9 * np.array(arm.model().max_acceleration_rad_s2) + 1e-6)


def test_braking_tail_stops_at_the_closed_form_distance():
    """Uniform deceleration a from speed v stops after v^2 / (2 a) (the slowest joint sets the time)."""
    qd = np.array([1.0, 0.5, 0, 0, 0, 0])
    amax = np.full(6, 10.0)
    t, q = braking_tail(0.0, np.zeros(6), qd, amax, 0.001)
    assert t[-1] == pytest.approx(0.1, abs=1e-3)
    assert q[-1, 0] == pytest.approx(1.0**2 / (2 * 10.0), rel=1e-2)
    assert q[-1, 1] == pytest.approx(0.5 * 0.1 / 2, rel=1e-2)


def test_limit_usage_reports_margins_against_the_limits():
    arm = robot_arm("gofa").model()
    t = np.arange(5) * 0.01
    q = np.zeros((5, 6))
    q[:, 0] = 0.5 * arm.max_velocity_rad_s[0] * t  # half the speed limit, no acceleration
    usage = limit_usage(arm, t, q)
    assert usage["velocity_fraction"] == pytest.approx(0.5)
    assert usage["acceleration_fraction"] == pytest.approx(0.0, abs=1e-9)
    assert usage["position_margin_deg"] == pytest.approx(np.degrees(min(np.min(np.abs(arm.lower_rad)),
                                                                      np.min(arm.upper_rad))) - 0.0, abs=2.0)


def test_unknown_robot_names_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown robot 'kuka'.*gofa.*ur5e"):
        robot_arm("kuka")
