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


def test_braking_tail_hand_computed() -> None:
    """All joints brake uniformly over the slowest joint's stop time, rounded up to whole periods:
    q(s) = q_end + (s - s^2 / (2 T)) qd, at s = period, 2 period, ..., T."""
    qd = np.array([1.0, -0.5, 0.0, 0.2, 0.0, 0.0])
    amax = np.array([10.0, 2.0, 1.0, 10.0, 1.0, 1.0])  # stop times 0.1, 0.25, 0, 0.02: joint 2 decides
    q_end = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    t, q = braking_tail(7.0, q_end, qd, amax, 0.05)
    np.testing.assert_allclose(t, 7.0 + 0.05 * np.arange(1, 6))
    s = 0.05 * np.arange(1, 6)
    np.testing.assert_allclose(q, q_end + np.outer(s - s * s / (2 * 0.25), qd), atol=1e-12)
    np.testing.assert_allclose(q[-1], q_end + 0.125 * qd)  # v T / 2
    # A stop time between periods is rounded up: 0.26 s at 0.05 s is 6 periods (0.30 s).
    t, q = braking_tail(0.0, q_end, qd * 1.04, amax, 0.05)
    assert t.size == 6 and t[-1] == pytest.approx(0.30)
    np.testing.assert_allclose(q[-1], q_end + 0.15 * qd * 1.04)
    # At rest: nothing to add.
    t, q = braking_tail(1.0, q_end, np.zeros(6), amax, 0.05)
    assert t.shape == (0,) and q.shape == (0, 6)


def test_join_plan_drops_samples_already_sent_and_brakes_the_rest() -> None:
    from dyndlo_vision.robots.feasibility import join_plan

    arm = robot_arm("gofa").model()
    t = 0.004 * np.arange(5)  # 0 and 0.004 are at or before the last target sent: dropped
    q = np.zeros((5, 6))
    q[:, 0] = 0.1 * t  # 0.1 rad/s on axis 1
    hist_t, hist_q = t[:2], q[:2].copy()
    hist_q[:, 0] -= 1e-9  # the targets sent (a hair off the plan, to tell them apart), moving at 0.1 rad/s
    plan = join_plan(arm, t, q, hist_t, hist_q, 0.004)
    np.testing.assert_array_equal(plan.q[:2], hist_q)
    assert plan.history == 2
    np.testing.assert_allclose(plan.t[:5], [0.0, 0.004, 0.008, 0.012, 0.016])
    np.testing.assert_allclose(plan.q[2:5, 0], [0.0008, 0.0012, 0.0016])
    # Then the braking tail at 0.9 of axis 1's 10 rad/s^2 limit: 0.1 / 9 s, rounded up to 3 periods (T).
    s_tail, big_t = 0.004 * np.arange(1, 4), 0.012
    np.testing.assert_allclose(plan.t[5:], 0.016 + s_tail)
    np.testing.assert_allclose(plan.q[5:, 0], 0.0016 + 0.1 * (s_tail - s_tail**2 / (2 * big_t)))
    np.testing.assert_array_equal(plan.q[5:, 1:], 0.0)
    assert plan.report.ok
    with pytest.raises(ValueError, match=r"the plan ends at t=0\.0040 s, before the target already sent for "
                                         r"t=0\.0040 s"):
        join_plan(arm, t[:2], q[:2], hist_t, hist_q, 0.004)


def test_limit_usage_hand_computed() -> None:
    arm = robot_arm("ur5e").model()  # every joint 180 deg/s; elbow +-180 deg; accelerations 15 / 25 rad/s^2
    t = np.array([0.0, 0.1, 0.2])
    q = np.zeros((3, 6))
    q[:, 2] = [np.pi - 0.1, np.pi - 0.1, np.pi - 0.1]  # the elbow 0.1 rad from its upper limit
    q[:, 3] = [0.0, 0.1 * np.pi, 0.3 * np.pi]  # wrist 1: pi/s then 2 pi/s, accelerating 10 pi rad/s^2
    usage = limit_usage(arm, t, q)
    assert usage["position_margin_deg"] == pytest.approx(np.degrees(0.1))
    assert usage["velocity_fraction"] == pytest.approx(2.0)
    assert usage["acceleration_fraction"] == pytest.approx(10 * np.pi / 25.0)
    q[:, 2] = -np.pi + 0.2  # now 0.2 rad from the lower limit
    assert limit_usage(arm, t, q)["position_margin_deg"] == pytest.approx(np.degrees(0.2))
    two = limit_usage(arm, t[:2], q[:2])
    assert two["velocity_fraction"] == pytest.approx(1.0) and two["acceleration_fraction"] == 0.0
    one = limit_usage(arm, t[:1], q[:1])
    assert one["velocity_fraction"] == 0.0 and one["acceleration_fraction"] == 0.0


def test_plan_feasibility_needs_a_start_and_joins_plans_at_the_arms_cycle():
    check = PlanFeasibility("gofa")
    with pytest.raises(RuntimeError, match=r"^PlanFeasibility\.start\(\) first$"):
        check.check(np.array([0.0, 0.004]), np.array([HOME, HOME]))
    assert check.period_s == 0.004 and check.arm is ROBOT_ARMS["gofa"]
    check.start(2.0, HOME)
    t, p = straight_line(2.0, HOME, HOME + [0.02, 0.0, 0.0], 1.0, 0.004)
    verdict = check.check(t, p)
    assert verdict.ok and verdict.kind is None
    assert 0.0 < verdict.usage["velocity_fraction"] < 0.2


def test_robot_arms_are_placed_with_the_shoulder_at_the_tasks_height():
    from dyndlo_vision.robots.kinematics import pose_matrix

    for name, shoulder_z in (("gofa", 0.265), ("ur5e", 0.1625)):
        arm = robot_arm(name)
        base = arm.kinematics().base_in_world
        assert base[2, 3] + shoulder_z == pytest.approx(0.265)
        moved = arm.kinematics(base_in_world=pose_matrix((1.0, 0.0, 0.0)))
        q = moved.ik(HOME + [1.0, 0.0, 0.0]).q
        np.testing.assert_allclose(moved.fk(q)[0], HOME + [1.0, 0.0, 0.0], atol=1e-8)


def test_a_stop_within_one_period_takes_one_sample_and_joint_plan_brakes_as_asked():
    t, q = braking_tail(0.0, np.zeros(6), np.array([0.01, 0, 0, 0, 0, 0]), np.full(6, 10.0), 0.01)
    np.testing.assert_allclose(t, [0.01])
    np.testing.assert_allclose(q[0, 0], 0.01 * (0.01 - 0.01**2 / 0.02))
    arm = robot_arm("ur5e")
    kin = arm.kinematics()
    q0 = kin.joint_trajectory(np.array([0.0]), HOME[None]).q[0]
    t, p = straight_line(0.0, HOME, HOME + [0.0, 0.0, 0.1], 0.5, arm.period_s, ease=False)
    t, p = t[: t.size // 2], p[: t.size // 2]  # ends moving
    firm = joint_plan(kin, t, p, [0.0], [q0], arm.period_s)
    gentle = joint_plan(kin, t, p, [0.0], [q0], arm.period_s, braking_fraction=0.3)
    assert firm.history == 1 and gentle.t.size > firm.t.size  # a third of the deceleration: a longer tail


def test_join_plan_names_both_times_when_the_plan_is_already_past():
    from dyndlo_vision.robots.feasibility import join_plan

    arm = robot_arm("gofa").model()
    with pytest.raises(ValueError, match=r"^the plan ends at t=0\.0080 s, before the target already sent for "
                                         r"t=0\.0120 s$"):
        join_plan(arm, [0.0, 0.004, 0.008], np.zeros((3, 6)), [0.012], np.zeros((1, 6)), 0.004)


def test_an_unreachable_plan_has_no_usage_and_the_kind_ik():
    check = PlanFeasibility("gofa")
    check.start(0.0, np.array([[0.45, 0.0, 0.6]]))  # a (1, 3) position is one point
    t, p = straight_line(0.0, HOME, [2.0, 0.0, 0.6], 3.0, 0.004)
    verdict = check.check(t, p)
    assert (verdict.ok, verdict.kind, verdict.usage) == (False, "IK", {})


def test_the_worst_breach_is_the_one_farthest_over_its_own_limit(monkeypatch):
    from dyndlo_vision.robots import feasibility
    from dyndlo_vision.robots.kinematics import LimitReport, LimitViolation

    # Axis 1 at 1.8 times its limit, axis 2 at 1.67 times its (larger in value, smaller as a fraction).
    a = LimitViolation("axis_1", "velocity", 0.1, 0.9, 0.5, 0.1, 1)
    b = LimitViolation("axis_2", "acceleration", 0.2, 1.5, 0.9, 0.2, 1)

    def refused(kinematics, t, positions, history_t, history_q, period_s):
        return feasibility.JointPlan(np.asarray(t), np.zeros((len(t), 6)), 2, LimitReport((b, a)))

    monkeypatch.setattr(feasibility, "joint_plan", refused)
    check = PlanFeasibility("gofa")
    check.start(0.0, HOME)
    verdict = check.check(np.array([0.0, 0.004]), np.array([HOME, HOME]))
    assert verdict.reason == str(a) and verdict.kind == "velocity axis_1"


def test_a_tool_offset_reaches_the_arms_kinematics():
    from dyndlo_vision.robots.kinematics import pose_matrix

    arm = robot_arm("gofa")
    plain, tool = arm.kinematics(), arm.kinematics(tcp_in_flange=pose_matrix((0.0, 0.0, 0.1)))
    q = plain.ik(HOME).q
    np.testing.assert_allclose(tool.fk(q)[0], plain.fk(q)[0] + [0.0, 0.0, -0.1], atol=1e-12)  # tool down


def test_braking_tail_in_whole_seconds_gives_float_times():
    """From 2 rad/s at 1 rad/s^2 a joint stops after 2 s and v^2 / (2 a) = 2 rad; integers in, floats out."""
    qd = np.array([2, 0, 0, 0, 0, 0])
    t, q = braking_tail(7, np.zeros(6, dtype=int), qd, np.ones(6, dtype=int), 1)
    assert t.dtype == np.float64 and q.dtype == np.float64
    np.testing.assert_array_equal(t, [8.0, 9.0])
    np.testing.assert_allclose(q[:, 0], [1.5, 2.0])  # 2 (s - s^2 / 4) at s = 1, 2


def test_joint_plan_seeds_the_ik_from_the_last_target_sent():
    """The UR5e's wrist 3 turns +-360 deg: with it one turn round, the same TCP pose is reached by a
    different joint vector. The plan must stay on the arm's turn (seeded from it), not jump a full turn."""
    arm = robot_arm("ur5e")
    kin = arm.kinematics()
    q0 = kin.joint_trajectory(np.array([0.0]), HOME[None]).q[0]
    q_turned = q0 - np.array([0, 0, 0, 0, 0, 2 * np.pi])
    assert q_turned[5] > -2 * np.pi
    np.testing.assert_allclose(kin.fk(q_turned)[0], HOME, atol=1e-9)
    t, p = straight_line(0.0, HOME, HOME + [0.02, 0.0, 0.0], 0.5, arm.period_s)
    plan = joint_plan(kin, t, p, [-arm.period_s, 0.0], [q_turned, q_turned], arm.period_s)
    assert plan.report.ok, plan.report
    assert np.all(plan.q[:, 5] < -np.pi)  # still a turn round
    assert np.max(np.abs(plan.q[2] - q_turned)) < 1e-3  # the first new target is next to the last sent


def test_a_plan_starting_where_the_arm_rests_is_judged_as_it_is_alone():
    """A smooth move from rest, taking over where the arm rests: its first sample is the target already
    sent, so joining it adds nothing (the same limit usage as the plan alone) and it is accepted. A plan of
    a single step after the take-over is judged too."""
    arm = robot_arm("gofa")
    check = PlanFeasibility(arm)
    check.start(1.0, HOME)
    t, p = straight_line(1.0, HOME, HOME + [0.0, 0.0, 0.03], 0.25, arm.period_s)
    kin = arm.kinematics()
    q_rest = kin.joint_trajectory(np.array([1.0]), HOME[None]).q[0]
    alone = limit_usage(arm.model(), t, kin.joint_trajectory(t, p, q_rest).q)
    assert 0.3 < alone["acceleration_fraction"] < 0.5  # twice as much would still be allowed: the test
    verdict = check.check(t, p)
    assert verdict.ok, verdict.reason
    for key in ("velocity_fraction", "acceleration_fraction", "position_margin_deg"):
        assert verdict.usage[key] == pytest.approx(alone[key], rel=1e-3), key
    check.start(3.0, HOME)
    one_step = check.check(np.array([3.0, 3.0 + arm.period_s]), np.array([HOME, HOME]))
    assert one_step.ok and one_step.usage["velocity_fraction"] == pytest.approx(0.0, abs=1e-6)
