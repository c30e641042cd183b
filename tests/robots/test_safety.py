"""Tests for dyndlo_vision.robots.safety: workspace and speed clamps, the watchdog."""

from __future__ import annotations

import logging
import threading

import numpy as np
import pytest

from dyndlo_vision.robots.protocol import Robot, Setpoints, TcpState
from dyndlo_vision.robots.safety import ClampedRobot, ClampReport, Watchdog, WorkspaceBox, clamp_setpoints

BOX = WorkspaceBox((0.2, -0.4, 0.1), (0.9, 0.4, 0.9))


def _setpoints(t: np.ndarray, p: np.ndarray) -> Setpoints:
    v = np.gradient(p, t, axis=0)
    return Setpoints(t=t, position=p[:, None, :], velocity=v[:, None, :])


def test_setpoints_within_limits_pass_unchanged(caplog: pytest.LogCaptureFixture) -> None:
    t = np.linspace(0.0, 1.0, 51)
    sp = _setpoints(t, np.array([0.45, 0.0, 0.6]) + np.outer(t, [0.2, 0.0, -0.1]))
    with caplog.at_level(logging.WARNING):
        out, report = clamp_setpoints(sp, BOX, 1.8)
    assert out is sp and not report.changed
    assert report.max_speed_m_s == pytest.approx(np.hypot(0.2, 0.1))
    assert not caplog.records


def test_positions_are_clamped_into_the_box(caplog: pytest.LogCaptureFixture) -> None:
    t = np.linspace(0.0, 1.0, 101)
    p = np.array([0.45, 0.0, 0.6]) + np.outer(t, [0.0, 0.0, -0.7])  # ends at z = -0.1, below the box
    with caplog.at_level(logging.WARNING):
        out, report = clamp_setpoints(_setpoints(t, p), BOX, 1.8)
    assert np.all(BOX.contains(out.position))
    assert report.positions_moved_into_box == int(np.count_nonzero(p[:, 2] < 0.1))
    assert report.max_box_excess_m == pytest.approx(0.2)
    np.testing.assert_allclose(out.position[-1, 0], [0.45, 0.0, 0.1])
    # Velocities where the TCP is held at the floor of the box are zero, not the original -0.7 m/s.
    assert np.allclose(out.velocity[p[:, 2] < 0.095, 0, 2], 0.0)
    assert "outside the workspace box" in caplog.text


def test_a_jump_becomes_a_ramp_at_the_speed_limit(caplog: pytest.LogCaptureFixture) -> None:
    t = np.linspace(0.0, 0.5, 126)
    p = np.tile([0.45, 0.0, 0.6], (t.size, 1))
    p[10:, 0] = 0.75  # a 0.3 m step
    start = TcpState(position=np.array([[0.45, 0.0, 0.6]]), velocity=np.zeros((1, 3)), t=-0.004)
    with caplog.at_level(logging.WARNING):
        out, report = clamp_setpoints(_setpoints(t, p), BOX, 1.0, start)
    speed = np.linalg.norm(np.diff(out.position[:, 0], axis=0), axis=1) / np.diff(t)
    assert np.max(speed) <= 1.0 + 1e-9
    assert np.all(np.linalg.norm(out.velocity[:, 0], axis=1) <= 1.0 + 1e-9)
    assert out.position[-1, 0, 0] == pytest.approx(0.75)  # it gets there, 0.3 s later
    # 0.3 m at 4 mm per step: 74 shortened steps, the 75th lands exactly; 75 m/s asked for by the jump.
    assert report.steps_rate_limited == 74 and report.max_speed_m_s == pytest.approx(75.0)
    assert "over the TCP speed limit 1.00 m/s" in caplog.text


def test_first_setpoint_is_limited_from_the_current_state() -> None:
    t = np.array([0.0, 0.01])
    p = np.array([[0.6, 0.0, 0.6], [0.6, 0.0, 0.6]])
    start = TcpState(position=np.array([[0.45, 0.0, 0.6]]), velocity=np.zeros((1, 3)), t=-0.01)
    out, _ = clamp_setpoints(_setpoints(t, p), BOX, 1.0, start)
    np.testing.assert_allclose(out.position[:, 0, 0], [0.46, 0.47])


def test_clamp_rejects_bad_limits() -> None:
    with pytest.raises(ValueError, match="lower_m must be below upper_m"):
        WorkspaceBox((0.0, 0.0, 0.0), (1.0, -1.0, 1.0))
    t = np.array([0.0, 0.1])
    with pytest.raises(ValueError, match="max_speed_m_s"):
        clamp_setpoints(_setpoints(t, np.zeros((2, 3))), BOX, 0.0)


class _RecordingRobot:
    def __init__(self) -> None:
        self.sent: list[Setpoints] = []
        self.stopped = 0

    def connect(self) -> None: ...

    def state(self) -> TcpState:
        return TcpState(position=np.array([[0.45, 0.0, 0.6]]), velocity=np.zeros((1, 3)), t=0.0)

    def send(self, setpoints: Setpoints) -> None:
        self.sent.append(setpoints)

    def stop(self) -> None:
        self.stopped += 1

    def close(self) -> None: ...


def test_clamped_robot_wraps_any_robot() -> None:
    inner = _RecordingRobot()
    robot = ClampedRobot(inner, BOX, 1.8)
    assert isinstance(robot, Robot)
    t = np.linspace(0.004, 0.4, 100)
    robot.send(_setpoints(t, np.tile([1.2, 0.0, 0.6], (t.size, 1))))
    assert np.all(BOX.contains(inner.sent[0].position))
    assert robot.last_report.positions_moved_into_box == 100
    robot.stop()
    assert inner.stopped == 1


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_watchdog_fires_once_with_a_log_line(caplog: pytest.LogCaptureFixture) -> None:
    clock, calls = _Clock(), []
    dog = Watchdog({"camera frames": 0.2, "robot state": 0.1}, calls.append, clock=clock)
    clock.now += 0.08
    dog.feed("robot state")
    clock.now += 0.08  # state 0.08 s old, frames 0.16 s old: fine
    assert dog.check() is None and not calls
    dog.feed("robot state")
    clock.now += 0.05  # frames 0.21 s old
    with caplog.at_level(logging.ERROR):
        reason = dog.check()
    assert reason == "no camera frames for 0.210 s (timeout 0.200 s)"
    assert calls == [reason]
    assert "watchdog: no camera frames for 0.210 s (timeout 0.200 s); stopping" in caplog.text
    clock.now += 1.0
    assert dog.check() == reason and len(calls) == 1  # latched: one stop
    dog.reset()
    assert dog.fired is None and dog.check() is None
    with pytest.raises(ValueError, match="unknown watchdog channel"):
        dog.feed("lidar")


def test_watchdog_fires_for_a_channel_that_never_delivers() -> None:
    clock, calls = _Clock(), []
    dog = Watchdog({"robot state": 0.1}, calls.append, clock=clock)
    clock.now += 0.1001
    assert dog.check() is not None and len(calls) == 1


def test_watchdog_survives_a_failing_stop_callback(caplog: pytest.LogCaptureFixture) -> None:
    clock = _Clock()

    def broken(reason: str) -> None:
        raise RuntimeError("robot already gone")

    dog = Watchdog({"robot state": 0.1}, broken, clock=clock)
    clock.now += 1.0
    with caplog.at_level(logging.ERROR):
        assert dog.check() is not None
    assert "stop callback raised" in caplog.text


def test_watchdog_thread_stops_the_robot_when_feeding_ends() -> None:
    robot = _RecordingRobot()
    fired = threading.Event()

    def stop(reason: str) -> None:
        robot.stop()
        fired.set()

    with Watchdog({"robot state": 0.05}, stop, name="loop watchdog") as dog:
        for _ in range(5):
            dog.feed("robot state")
        assert fired.wait(timeout=10.0)  # generous: the thread polls every 12.5 ms
    assert robot.stopped == 1 and dog.fired is not None


# Boxes built inside the tests (a box built at import, as BOX above, is made before any code under test runs).
def test_a_box_is_normalised_and_checked_when_built() -> None:
    box = WorkspaceBox([0, -1, 0], [1, 1, 2])  # type: ignore[arg-type]
    assert box.lower_m == (0.0, -1.0, 0.0) and box.upper_m == (1.0, 1.0, 2.0)
    assert all(type(v) is float for v in box.lower_m + box.upper_m)
    for lower, upper in (((0.0, 0.0), (1.0, 1.0, 1.0)), ((0.0, 0.0, 0.0), (1.0, 1.0)),
                         ((0.0, np.nan, 0.0), (1.0, 1.0, 1.0)), ((0.0, 0.0, 0.0), (1.0, np.inf, 1.0))):
        with pytest.raises(ValueError, match=r"^WorkspaceBox corners must be 3 finite numbers each, got"):
            WorkspaceBox(lower, upper)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^WorkspaceBox lower_m must be below upper_m on every axis, got"):
        WorkspaceBox((0.0, 0.5, 0.0), (1.0, 0.5, 1.0))  # an empty (flat) box


def test_a_box_contains_its_boundary_point_by_point() -> None:
    box = WorkspaceBox((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    pts = np.array([[0.0, 0.5, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0 + 1e-9], [-1e-9, 0.5, 0.5]])
    np.testing.assert_array_equal(box.contains(pts), [True, True, False, False])
    assert box.contains([0, 0, 0]) and box.contains(pts[None]).shape == (1, 4)


def test_a_velocity_exactly_at_the_limit_is_not_clipped_and_one_over_is_scaled_to_it() -> None:
    box = WorkspaceBox((-1.0, -1.0, -1.0), (2.0, 2.0, 2.0))
    t = np.array([0.0, 0.1])
    p = np.zeros((2, 1, 3))
    v = np.array([[[0.3, 0.4, 0.0]], [[0.6, 0.8, 0.0]]])  # 0.5 m/s, then 1.0 m/s
    out, report = clamp_setpoints(Setpoints(t=t, position=p, velocity=v), box, 0.5)
    np.testing.assert_array_equal(out.velocity[0], v[0])
    np.testing.assert_allclose(out.velocity[1, 0], [0.3, 0.4, 0.0])
    assert report.velocities_clipped == 1 and report.max_speed_m_s == pytest.approx(1.0)
    out, report = clamp_setpoints(Setpoints(t=t, position=p, velocity=v[:1].repeat(2, axis=0)), box, 0.5)
    assert out.velocity is not None and not report.changed and report.max_speed_m_s == pytest.approx(0.5)


def test_the_current_state_is_clamped_into_the_box_from_above_too() -> None:
    box = WorkspaceBox((0.0, -0.5, 0.1), (0.9, 0.5, 0.9))
    start = TcpState(position=np.array([[0.45, 0.0, 1.2]]), velocity=np.zeros((1, 3)), t=0.0)
    sp = Setpoints(t=np.array([0.01]), position=np.array([[[0.45, 0.0, 0.9]]]), velocity=np.zeros((1, 1, 3)))
    out, report = clamp_setpoints(sp, box, 1.0, start)
    # From the box's top (where the TCP is taken to be), the setpoint on the top is reached at once.
    np.testing.assert_allclose(out.position[0, 0], [0.45, 0.0, 0.9])
    with pytest.raises(ValueError, match=r"^start\.position must have shape \(1, 3\), got \(2, 3\)$"):
        clamp_setpoints(sp, box, 1.0, TcpState(np.zeros((2, 3)), np.zeros((2, 3)), 0.0))


def test_without_a_start_the_first_setpoint_is_the_ramps_start() -> None:
    box = WorkspaceBox((-1.0, -1.0, -1.0), (2.0, 2.0, 2.0))
    t = np.array([5.0, 5.1, 5.2])
    p = np.array([[[0.0, 0.0, 0.0]], [[0.05, 0.0, 0.0]], [[0.5, 0.0, 0.0]]])  # 0.5 m/s, then 4.5 m/s
    v = np.array([[[0.1, 0.2, 0.0]], [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]])
    out, report = clamp_setpoints(Setpoints(t=t, position=p, velocity=v), box, 1.0)
    np.testing.assert_allclose(out.position[:, 0, 0], [0.0, 0.05, 0.15])
    assert report.steps_rate_limited == 1 and report.max_speed_m_s == pytest.approx(4.5)
    # The moved setpoint's velocity is the ramp's; the others keep their feed-forward (the first one too).
    np.testing.assert_allclose(out.velocity[:, 0], [[0.1, 0.2, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])


def test_a_moved_first_setpoint_gets_the_velocity_from_the_current_state() -> None:
    box = WorkspaceBox((-1.0, -1.0, -1.0), (2.0, 2.0, 2.0))
    start = TcpState(position=np.array([[0.0, 0.0, 0.0]]), velocity=np.zeros((1, 3)), t=3.0)
    sp = Setpoints(t=np.array([3.1, 3.2]), position=np.array([[[0.5, 0.0, 0.0]], [[0.5, 0.0, 0.0]]]),
                   velocity=np.zeros((2, 1, 3)))
    out, report = clamp_setpoints(sp, box, 1.0, start)
    np.testing.assert_allclose(out.position[:, 0, 0], [0.1, 0.2])
    np.testing.assert_allclose(out.velocity[:, 0, 0], [1.0, 1.0])  # (0.1 - 0) / (3.1 - 3.0) for the first
    # A setpoint at the state's own time may not move, and no speed is made up for it.
    sp0 = Setpoints(t=np.array([3.0]), position=np.array([[[0.5, 0.0, 0.0]]]), velocity=np.zeros((1, 1, 3)))
    out, report = clamp_setpoints(sp0, box, 1.0, start)
    np.testing.assert_allclose(out.position[0, 0], [0.0, 0.0, 0.0])
    assert report.max_speed_m_s == 0.0 and report.steps_rate_limited == 1


def test_a_clamped_robot_needs_a_positive_speed_limit_and_starts_with_an_empty_report() -> None:
    with pytest.raises(ValueError, match=r"^max_speed_m_s must be > 0, got 0\.0$"):
        ClampedRobot(_RecordingRobot(), BOX, 0.0)
    robot = ClampedRobot(_RecordingRobot(), BOX, 1.8)
    assert robot.last_report == ClampReport() and not robot.last_report.changed


def test_a_box_with_a_missing_coordinate_is_refused_as_not_finite() -> None:
    for lower, upper in (((None, 0.0, 0.0), (1.0, 1.0, 1.0)), ((0.0, 0.0, 0.0), (1.0, None, 1.0))):
        with pytest.raises(ValueError, match=r"^WorkspaceBox corners must be 3 finite numbers each, got"):
            WorkspaceBox(lower, upper)  # type: ignore[arg-type]


def test_a_velocity_under_one_metre_per_second_is_still_scaled_to_the_limit() -> None:
    box = WorkspaceBox((-1.0, -1.0, -1.0), (2.0, 2.0, 2.0))
    v = np.array([[[0.48, 0.64, 0.0]]])  # 0.8 m/s against a 0.5 m/s limit
    sp = Setpoints(t=np.array([0.0]), position=np.zeros((1, 1, 3)), velocity=v)
    out, report = clamp_setpoints(sp, box, 0.5)
    np.testing.assert_allclose(out.velocity[0, 0], [0.3, 0.4, 0.0])
    assert report.velocities_clipped == 1 and report.max_speed_m_s == pytest.approx(0.8)


def test_a_single_setpoint_outside_the_box_lands_on_its_faces() -> None:
    sp = Setpoints(t=np.array([2.0]), position=np.array([[[1.2, 0.0, 0.05]]]), velocity=np.zeros((1, 1, 3)))
    out, report = clamp_setpoints(sp, BOX, 1.8)
    np.testing.assert_array_equal(out.position[0, 0], [0.9, 0.0, 0.1])  # on the x = 0.9 and z = 0.1 faces
    np.testing.assert_array_equal(out.t, [2.0])
    assert report.positions_moved_into_box == 1 and report.steps_rate_limited == 0
    assert report.max_box_excess_m == pytest.approx(np.hypot(0.3, 0.05))


def test_setpoints_in_whole_seconds_and_metres_come_back_as_floats() -> None:
    box = WorkspaceBox((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    p = np.array([[[0, 0, 0]], [[2, 0, 0]], [[2, 0, 0]]])  # boxed to x = 1, reached at 0.5 m/s
    sp = Setpoints(t=np.array([0, 1, 2]), position=p, velocity=np.zeros((3, 1, 3), dtype=int))
    out, report = clamp_setpoints(sp, box, 0.5)
    assert out.t.dtype == out.position.dtype == out.velocity.dtype == np.float64
    np.testing.assert_array_equal(out.t, [0.0, 1.0, 2.0])
    np.testing.assert_allclose(out.position[:, 0, 0], [0.0, 0.5, 1.0])
    np.testing.assert_allclose(out.velocity[:, 0, 0], [0.0, 0.5, 0.5])
    assert report.positions_moved_into_box == 2 and report.steps_rate_limited == 1  # the last at the limit


def test_setpoints_for_no_gripper_pass_unchanged() -> None:
    sp = Setpoints(t=np.array([0.0, 0.1]), position=np.zeros((2, 0, 3)), velocity=np.zeros((2, 0, 3)))
    out, report = clamp_setpoints(sp, BOX, 1.8)
    assert out is sp and report == ClampReport()
