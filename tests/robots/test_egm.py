"""Tests for the ABB EGM driver against the fake EGM controller on loopback (protobuf messages over UDP)."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np
import pytest

pytest.importorskip("abb_robot_client")

from dyndlo_vision.robots import EgmRobot, FakeEgmController  # noqa: E402
from dyndlo_vision.robots.kinematics import (  # noqa: E402
    ArmKinematics,
    JointLimitError,
    abb_gofa_crb15000,
    check_joint_limits,
)
from dyndlo_vision.robots.protocol import (
    Robot,
    Setpoints,  # noqa: E402
)
from dyndlo_vision.tasks.tip_control import TCP_HOME_M  # noqa: E402
from dyndlo_vision.trajectory import BSplineTrajectory  # noqa: E402

from .robot_plans import (  # noqa: E402
    GENTLE_ACTION,
    TIMEOUT_S,
    VIOLENT_ACTION,
    send_from_now,
    tip_control_setpoints,
)


@pytest.fixture
def setup() -> Iterator[tuple[EgmRobot, FakeEgmController, ArmKinematics, np.ndarray]]:
    kin = ArmKinematics(abb_gofa_crb15000())
    q_home = kin.ik(TCP_HOME_M).q
    robot = EgmRobot(kin, port=0, answer_timeout_s=5.0, connect_timeout_s=TIMEOUT_S)
    fake = FakeEgmController(kin.arm, q_home, ("127.0.0.1", robot.bind()), reply_timeout_s=2.0)
    fake.start()
    robot.connect()
    yield robot, fake, kin, q_home
    robot.close()
    fake.close()
    assert fake.error is None


def _received_trajectory(fake: FakeEgmController) -> tuple[np.ndarray, np.ndarray]:
    received = fake.received
    return np.array([r.t for r in received]), np.array([r.q for r in received])


def test_driver_is_a_robot(setup) -> None:
    robot, _, _, _ = setup
    assert isinstance(robot, Robot)
    np.testing.assert_allclose(robot.state().position[0], TCP_HOME_M, atol=1e-9)


def test_moves_the_fake_robot_along_a_tip_control_plan(setup) -> None:
    robot, fake, kin, _ = setup
    setpoints, end = send_from_now(robot, fake, GENTLE_ACTION)
    assert fake.wait_until(setpoints.t[-1] + 0.3, TIMEOUT_S)
    q_end = kin.ik(end, fake.q).q
    np.testing.assert_allclose(fake.q, q_end, atol=1e-4)
    np.testing.assert_allclose(kin.fk(fake.q)[0], end, atol=1e-4)
    np.testing.assert_allclose(robot.state().position[0], end, atol=1e-4)
    # Every target the controller received is within the joint limits, and the TCP kept its orientation.
    t, q = _received_trajectory(fake)
    assert check_joint_limits(kin.arm, t, q).ok
    np.testing.assert_allclose(kin.fk(q)[1], np.broadcast_to(kin.tool_rotation, (t.size, 3, 3)), atol=1e-6)
    # The targets follow the plan: TCP of the target sent for time t is the plan at t (one cycle ahead).
    mid = (t > setpoints.t[0] + 0.1) & (t < setpoints.t[-1] - 0.1)
    plan = np.array(
        [np.interp(t[mid] + robot.lookahead_s, setpoints.t, setpoints.position[:, 0, i]) for i in range(3)]
    )
    assert np.max(np.abs(kin.fk(q[mid])[0] - plan.T)) < 1e-4


def test_refuses_a_plan_that_breaks_a_joint_limit(setup, caplog: pytest.LogCaptureFixture) -> None:
    robot, fake, _, q_home = setup
    with (
        caplog.at_level(logging.ERROR),
        pytest.raises(JointLimitError, match=r"joint axis_\d \w+ [+-][\d.]+") as err,
    ):
        send_from_now(robot, fake, VIOLENT_ACTION)
    assert any(v.quantity == "acceleration" for v in err.value.report.violations)
    assert "EGM: refusing setpoints, nothing of them sent" in caplog.text
    assert robot.wait_cycles(50, TIMEOUT_S)
    # Nothing of the plan reached the controller: every target is the position held since connect (EGM must be
    # answered every cycle; the degrees on the wire round the radians at 1e-16).
    _, q = _received_trajectory(fake)
    assert len(q) >= 50 and np.max(np.abs(q - q_home)) < 1e-12
    np.testing.assert_allclose(fake.q, q_home, atol=1e-12)
    assert robot.fault is None  # refusing is not a fault: the driver keeps going


def test_stop_brakes_within_the_joint_limits(setup) -> None:
    robot, fake, kin, _ = setup
    setpoints, _ = send_from_now(robot, fake, GENTLE_ACTION)
    assert fake.wait_until(setpoints.t[0] + 0.6, TIMEOUT_S)
    robot.stop()
    assert robot.wait_cycles(100, TIMEOUT_S)
    t, q = _received_trajectory(fake)
    assert check_joint_limits(kin.arm, t, q).ok
    np.testing.assert_allclose(q[-1], q[-2], atol=1e-12)  # at rest, holding
    assert np.linalg.norm(kin.fk(q[-1])[0] - setpoints.position[-1, 0]) > 0.01  # stopped short of the end


def test_watchdog_stops_when_the_robot_stops_answering(caplog: pytest.LogCaptureFixture) -> None:
    kin = ArmKinematics(abb_gofa_crb15000())
    q_home = kin.ik(TCP_HOME_M).q
    robot = EgmRobot(kin, port=0, answer_timeout_s=0.3, connect_timeout_s=TIMEOUT_S)
    with FakeEgmController(kin.arm, q_home, ("127.0.0.1", robot.bind()), reply_timeout_s=2.0) as fake:
        robot.connect()
        with caplog.at_level(logging.ERROR):
            fake.hang()
            assert not robot.wait_cycles(10_000, TIMEOUT_S)  # returns False once the driver faulted
        assert (
            "EGM: watchdog: the robot stopped answering (no state for 0.300 s); streaming stopped"
            in caplog.text
        )
        with pytest.raises(RuntimeError, match="stopped after a fault"):
            robot.send(tip_control_setpoints(GENTLE_ACTION, robot.state().t + 0.1)[0])
        robot.close()


def test_an_exception_in_the_streaming_thread_stops_the_driver(
    setup, caplog: pytest.LogCaptureFixture
) -> None:
    robot, fake, _, _ = setup
    with caplog.at_level(logging.ERROR):
        fake.send_garbage()
        assert not robot.wait_cycles(10_000, TIMEOUT_S)
    assert robot.fault is not None and robot.fault.startswith("exception in the streaming thread")
    assert "EGM: exception in the streaming thread" in caplog.text


def test_a_stopped_rapid_program_stops_the_driver(setup, caplog: pytest.LogCaptureFixture) -> None:
    robot, fake, _, _ = setup
    with caplog.at_level(logging.ERROR):
        fake.rapid_running = False
        assert not robot.wait_cycles(10_000, TIMEOUT_S)
    assert robot.fault == "the controller reports the RAPID program stopped"


def test_setpoints_for_two_grippers_are_rejected(setup) -> None:
    robot, _, _, _ = setup
    t = robot.state().t + np.array([0.1, 0.2])
    with pytest.raises(ValueError, match="n_g = 1"):
        robot.send(Setpoints(t=t, position=np.zeros((2, 2, 3)), velocity=np.zeros((2, 2, 3))))


def test_replanning_mid_motion_from_the_commanded_state(setup) -> None:
    """The closed loop's use: replace a running plan by one that starts from the commanded state."""
    robot, fake, kin, _ = setup
    first, _ = send_from_now(robot, fake, GENTLE_ACTION)
    assert fake.wait_until(first.t[0] + 0.5, TIMEOUT_S)
    fake.hang()
    try:
        now = robot.commanded_state()
        p0, v0 = now.position[0], now.velocity[0]
        goal = p0 + np.array([0.05, 0.0, 0.08])
        plan = BSplineTrajectory(
            [p0, 0.5 * (p0 + goal), goal], [now.t, now.t + 0.4, now.t + 0.8], start_velocity=v0
        )
        t = np.arange(now.t, now.t + 0.8 + 1e-9, 0.01)
        robot.send(Setpoints(t=t, position=plan.position(t)[:, None], velocity=plan.velocity(t)[:, None]))
    finally:
        fake.resume()
    assert fake.wait_until(t[-1] + 0.3, TIMEOUT_S)
    np.testing.assert_allclose(kin.fk(fake.q)[0], goal, atol=1e-4)
    received = fake.received
    assert check_joint_limits(
        kin.arm, np.array([r.t for r in received]), np.array([r.q for r in received])
    ).ok


def test_a_plan_that_does_not_start_where_the_robot_is_commanded_is_refused(setup) -> None:
    robot, fake, _, _ = setup
    fake.hang()
    try:
        now = robot.commanded_state()
        t = now.t + np.arange(1, 51) * 0.01
        p = np.tile(now.position[0] + [0.1, 0.0, 0.0], (t.size, 1))  # 10 cm away, at rest
        with pytest.raises(JointLimitError, match="where the setpoints join the targets already sent"):
            robot.send(Setpoints(t=t, position=p[:, None], velocity=np.zeros((t.size, 1, 3))))
    finally:
        fake.resume()
