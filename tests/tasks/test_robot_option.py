"""``make_env(robot=...)``: a plan a real arm cannot follow is refused, as its driver refuses it: the episode
ends there with the avoid condition ``joints``."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from dyndlo_vision.tasks.base import JOINT_EXCESS_CAP
from dyndlo_vision.tasks.registry import make_env
from dyndlo_vision.tasks.rewards import TABLE_V


def slow_action(env) -> np.ndarray:
    """A plan the GoFa can follow: 3 x (5 cm forward), 0.5 s each."""
    spec = env.unwrapped.spec_actions
    p0 = np.asarray(env.unwrapped.scene.tcp_positions()[0])
    points = p0 + np.array([[0, 0, 0], [0.05, 0, 0], [0.10, 0, 0], [0.15, 0, 0]])
    return spec.encode(points, np.array([0.0, 0.5, 1.0, 1.5])).astype(np.float32)


def fast_action(env) -> np.ndarray:
    """A flick the GoFa cannot follow, within the paper's TCP limits: 10 cm forward, up, back, 0.15 s each."""
    spec = env.unwrapped.spec_actions
    p0 = np.asarray(env.unwrapped.scene.tcp_positions()[0])
    points = p0 + np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0, 0.1], [0.0, 0, 0.1]])
    return spec.encode(points, np.array([0.0, 0.15, 0.3, 0.45])).astype(np.float32)


@pytest.fixture(scope="module")
def env():
    e = make_env("tip-control", robot="gofa")
    yield e
    e.close()


def test_a_plan_the_arm_can_follow_is_not_an_avoid_condition(env):
    env.reset(seed=1)
    _, reward, _, _, info = env.step(slow_action(env))
    assert info["joint_feasible"] is True and info["avoid"]["joints"] is False
    assert "joint_limit_reason" not in info
    assert 0 < info["joint_usage"]["acceleration_fraction"] < 1
    assert info["r_avoid"] == 0.0


def test_a_plan_the_arm_cannot_follow_is_refused_and_costs_the_avoid_penalty(env):
    env.reset(seed=1)
    _, reward, terminated, _, info = env.step(fast_action(env))
    assert info["joint_feasible"] is False and info["avoid"]["joints"] is True
    assert "breaks the limit" in info["joint_limit_reason"] or info["joint_limit_reason"].startswith("IK:")
    coeffs = TABLE_V["tip_control"]
    usage = info["joint_usage"]
    excess = max(usage["velocity_fraction"], usage["acceleration_fraction"]) - 1.0
    assert excess > 0
    assert info["r_avoid"] == pytest.approx(coeffs.avoid * (1.0 + min(excess, JOINT_EXCESS_CAP)))
    assert reward == pytest.approx(info["r_avoid"] + coeffs.distance)
    # Nothing of it ran: the TCP is still at home, no time passed, no success.
    assert terminated and info["sim_time_s"] == 0.0 and info["is_success"] is False
    assert env.unwrapped.monitor.max_tcp_speed_m_s < 1e-6
    # The TCP-only conditions of the paper do not see it: the same plan without an arm is not an avoid.
    plain = make_env("tip-control")
    plain.reset(seed=1)
    _, _, _, _, info_plain = plain.step(fast_action(plain))
    assert "joints" not in info_plain["avoid"] and not any(info_plain["avoid"].values())
    plain.close()


def test_the_refusal_penalty_grows_with_the_excess_and_is_capped(env):
    """Faster versions of the same flick break the limits further and cost more, up to 4 lambda_1; a plan
    just over the limits costs about lambda_1, never less."""
    spec = env.unwrapped.spec_actions
    penalties = []
    for duration in (0.6, 0.45, 0.3, 0.1):
        env.reset(seed=1)
        p0 = np.asarray(env.unwrapped.scene.tcp_positions()[0])
        points = p0 + np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0, 0.1], [0.0, 0, 0.1]])
        times = np.array([0.0, 1.0, 2.0, 3.0]) * duration / 3
        info = env.step(spec.encode(points, np.maximum(times, [0, 0.1, 0.2, 0.3])).astype(np.float32))[4]
        penalties.append(info["r_avoid"])
    avoid = TABLE_V["tip_control"].avoid
    assert all(a >= b for a, b in zip(penalties, penalties[1:], strict=False)), penalties
    assert penalties[-1] == pytest.approx(avoid * (1 + JOINT_EXCESS_CAP))
    assert all(avoid * (1 + JOINT_EXCESS_CAP) <= p < 0 for p in penalties)


def test_the_next_episode_starts_feasible_again(env):
    env.reset(seed=1)
    env.step(fast_action(env))
    env.reset(seed=2)
    _, _, _, _, info = env.step(slow_action(env))
    assert info["joint_feasible"] is True and info["avoid"]["joints"] is False


def test_multi_step_judges_every_replan():
    env = make_env("tip-control", robot="gofa", multi_step=True)
    env.reset(seed=3)
    slow = slow_action(env)
    infos = []
    for _ in range(3):
        infos.append(env.step(slow)[4])
    assert all(i["joint_feasible"] for i in infos)
    t_before = env.unwrapped.scene.time
    _, _, terminated, _, info = env.step(fast_action(env))
    assert info["joint_feasible"] is False and info["avoid"]["joints"] is True
    assert terminated and info["sim_time_s"] == t_before  # the arm stops; the episode ends there
    env.close()


def test_the_robot_survives_pickling(env):
    """SubprocVecEnv workers get the environment by pickle: the arm must come along."""
    copy = pickle.loads(pickle.dumps(env.unwrapped))
    assert copy.arm_check is not None and copy.arm_check.arm.name == "gofa"
    copy.close()


def test_a_two_gripper_task_refuses_an_arm():
    with pytest.raises(ValueError, match="one TCP.*2 grippers"):
        make_env("hooking", robot="gofa")


def test_an_unknown_robot_is_refused():
    with pytest.raises(ValueError, match="unknown robot 'ur10'"):
        make_env("tip-control", robot="ur10")


def test_a_plan_is_judged_on_the_arms_cycle_from_now_to_its_end(env):
    env.reset(seed=1)
    check = env.unwrapped.arm_check
    seen = []
    original = check.check

    def spy(t, positions):
        seen.append(np.array(t))
        return original(t, positions)

    check.check = spy
    try:
        env.step(slow_action(env))
    finally:
        check.check = original
    (t,) = seen
    t_end = env.unwrapped.trajectory.t_end
    assert t[0] == 0.0 and np.allclose(np.diff(t), check.period_s)
    assert t[-1] >= t_end - 1e-9 and t[-2] < t_end - 1e-9  # the last sample at or just past the plan's end


def test_a_refused_plan_reports_the_verdict_and_what_the_task_evaluates(env):
    env.reset(seed=1)
    task = env.unwrapped.task
    calls = []
    original = task.evaluate

    def succeeding(scene, goal, monitor, final):
        calls.append((scene, np.array(goal), final))
        terms, _, extra = original(scene, goal, monitor, final)
        return terms, True, extra

    task.evaluate = succeeding
    try:
        _, _, terminated, truncated, info = env.step(fast_action(env))
    finally:
        task.evaluate = original
    assert terminated and not truncated
    assert info["is_success"] is True  # the task's own verdict on the state reached, reported as it is
    ((scene, goal, final),) = calls
    assert scene is env.unwrapped.scene and np.array_equal(goal, env.unwrapped.goal) and final
    kind = info["joint_limit_kind"]
    assert kind == "IK" or kind.split()[0] in ("position", "velocity", "acceleration")


def test_just_over_the_limits_costs_lambda_1_and_no_verdict_costs_the_cap() -> None:
    """The refusal's avoid term: lambda_1 (1 + excess), excess = max(speed, acceleration fraction) - 1 in
    [0, JOINT_EXCESS_CAP]; a plan without IK solution (no usage) costs the cap."""
    from dyndlo_vision.robots.feasibility import Feasibility

    env = make_env("tip-control", robot="gofa")
    base = env.unwrapped
    avoid = TABLE_V["tip_control"].avoid
    for usage, expected in (
        ({"velocity_fraction": 1.2, "acceleration_fraction": 0.5}, avoid * 1.2),
        ({"velocity_fraction": 0.5, "acceleration_fraction": 1.3}, avoid * 1.3),
        ({"velocity_fraction": 0.5, "acceleration_fraction": 9.0}, avoid * (1 + JOINT_EXCESS_CAP)),
        ({}, avoid * (1 + JOINT_EXCESS_CAP)),
    ):
        base.reset(seed=1)
        base.arm_check.check = lambda t, p, u=usage: Feasibility("limit broken", u, "velocity axis_1")
        info = base.step(slow_action(env))[4]
        assert info["r_avoid"] == pytest.approx(expected), usage
        assert info["joint_limit_kind"] == "velocity axis_1" and info["joint_usage"] == usage
    env.close()


def test_the_outcome_before_any_plan_is_reported_without_a_verdict(env):
    env.reset(seed=1)
    _, success, info = env.unwrapped.outcome()
    assert not success and "joint_feasible" not in info
    env.step(slow_action(env))
    assert env.unwrapped.outcome()[2]["joint_feasible"] is True


def test_a_replan_is_judged_from_its_own_start():
    env = make_env("tip-control", robot="gofa", multi_step=True)
    env.reset(seed=3)
    check = env.unwrapped.arm_check
    seen = []
    original = check.check

    def spy(t, positions):
        seen.append(np.array(t))
        return original(t, positions)

    check.check = spy
    slow = slow_action(env)
    env.step(slow)
    env.step(slow)
    t = seen[1]
    t_end = env.unwrapped.trajectory.t_end
    assert t[0] == pytest.approx(0.04) and t[-1] >= t_end - 1e-9 and t[-2] < t_end - 1e-9
    env.close()
