"""ClampedRobot limits the very first step from the robot's current state; the clamps at their boundaries."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.robots.protocol import Setpoints, TcpState
from dyndlo_vision.robots.safety import ClampedRobot, WorkspaceBox, clamp_setpoints

BOX = WorkspaceBox((0.2, -0.4, 0.1), (0.9, 0.4, 0.9))
HOME = np.array([0.45, 0.0, 0.60])


class _Robot:
    """A robot standing still at ``position`` whose clock reads ``t``; records what it is sent."""

    def __init__(self, position: np.ndarray = HOME, t: float = 0.0) -> None:
        self.position = np.atleast_2d(np.asarray(position, dtype=float))
        self.t = t
        self.connected = False
        self.sent: list[Setpoints] = []

    def connect(self) -> None:
        self.connected = True

    def state(self) -> TcpState:
        return TcpState(position=self.position.copy(), velocity=np.zeros_like(self.position), t=self.t)

    def send(self, setpoints: Setpoints) -> None:
        self.sent.append(setpoints)
        self.position = setpoints.position[-1].copy()
        self.t = float(setpoints.t[-1])

    def stop(self) -> None: ...

    def close(self) -> None: ...


def _hold(t: np.ndarray, p: np.ndarray) -> Setpoints:
    """Setpoints holding ``p`` (n_g, 3) at rest at every time in ``t``."""
    p = np.atleast_2d(p)
    return Setpoints(t=t, position=np.repeat(p[None], t.size, axis=0), velocity=np.zeros((t.size, *p.shape)))


def test_first_send_after_connect_is_rate_limited_from_the_current_tcp() -> None:
    inner = _Robot(HOME, t=0.0)
    robot = ClampedRobot(inner, BOX, 1.8)
    robot.connect()
    assert inner.connected
    # Every setpoint is 0.3 m away from where the TCP is (inside the box): the first one 4 ms from now.
    t = 0.004 * np.arange(1, 11)
    robot.send(_hold(t, HOME + [0.3, 0.0, 0.0]))
    out = inner.sent[0].position[:, 0]
    # At 1.8 m/s the TCP may move 7.2 mm per 4 ms step: x = 0.45 + 0.0072 k, k = 1..10.
    np.testing.assert_allclose(out[:, 0], 0.45 + 0.0072 * np.arange(1, 11), atol=1e-12)
    np.testing.assert_allclose(out[:, 1:], np.tile([0.0, 0.6], (10, 1)), atol=1e-12)
    assert robot.last_report.steps_rate_limited == 10
    speed = np.linalg.norm(np.diff(np.vstack([HOME, out]), axis=0), axis=1) / 0.004
    assert speed.max() <= 1.8 + 1e-9
    # The feed-forward velocity of the moved setpoints is the ramp's, 1.8 m/s along x (the first one too).
    np.testing.assert_allclose(inner.sent[0].velocity[:, 0], np.tile([1.8, 0.0, 0.0], (10, 1)), atol=1e-9)


def test_each_send_continues_from_where_the_robot_is() -> None:
    inner = _Robot(HOME, t=0.0)
    robot = ClampedRobot(inner, BOX, 1.0)
    target = HOME + [0.0, 0.0, 0.2]
    for i in range(3):
        t = inner.t + 0.01 * np.arange(1, 6)
        robot.send(_hold(t, target))
        # 1 m/s: 1 cm per 10 ms step; 5 steps a send, from where the previous send left the TCP.
        np.testing.assert_allclose(inner.sent[-1].position[:, 0, 2], 0.6 + 0.01 * (5 * i + np.arange(1, 6)))
    assert inner.position[0, 2] == pytest.approx(0.75)


def test_first_setpoint_at_the_robots_time_may_not_move() -> None:
    # A setpoint stamped at the state's own time allows no motion (dt = 0): it is held at the current TCP.
    inner = _Robot(HOME, t=1.0)
    robot = ClampedRobot(inner, BOX, 1.8)
    robot.send(_hold(np.array([1.0, 1.01]), HOME + [0.0, 0.2, 0.0]))
    np.testing.assert_allclose(inner.sent[0].position[:, 0, 1], [0.0, 0.018], atol=1e-12)


def test_first_step_of_two_grippers_is_limited_per_gripper() -> None:
    start = np.array([[0.40, -0.12, 0.25], [0.40, 0.12, 0.25]])
    inner = _Robot(start, t=0.0)
    robot = ClampedRobot(inner, BOX, 1.8)
    goal = start.copy()
    goal[0, 2] = 0.55  # only the first gripper asked to jump 0.3 m up
    robot.send(_hold(np.array([0.01]), goal))
    np.testing.assert_allclose(inner.sent[0].position[0], [[0.40, -0.12, 0.268], start[1]], atol=1e-12)


def test_a_setpoint_within_the_limit_passes_unchanged() -> None:
    inner = _Robot(HOME, t=0.0)
    robot = ClampedRobot(inner, BOX, 1.8)
    sp = _hold(np.array([0.01]), HOME + [0.0179, 0.0, 0.0])  # 1.79 m/s from the current TCP
    robot.send(sp)
    assert inner.sent[0] is sp and not robot.last_report.changed


def test_speed_limit_is_on_the_3d_step() -> None:
    # 1.2 m/s along x and 1.4 m/s along z at once: each under 1.8 m/s, together 1.844 m/s, over it.
    start = TcpState(position=HOME[None], velocity=np.zeros((1, 3)), t=0.0)
    sp = _hold(np.array([0.01]), HOME + [0.012, 0.0, 0.014])
    out, report = clamp_setpoints(sp, BOX, 1.8, start)
    step = out.position[0, 0] - HOME
    assert np.linalg.norm(step) == pytest.approx(0.018, abs=1e-12)
    np.testing.assert_allclose(step / np.linalg.norm(step), [0.012, 0.0, 0.014] / np.hypot(0.012, 0.014))
    assert report.steps_rate_limited == 1


def test_feed_forward_velocity_is_clipped_by_its_norm_keeping_its_direction() -> None:
    t = np.array([0.0, 0.01])
    p = np.tile(HOME, (2, 1, 1))
    v = np.tile([1.2, 0.0, 1.4], (2, 1, 1))  # 1.844 m/s
    out, report = clamp_setpoints(Setpoints(t=t, position=p, velocity=v), BOX, 1.8)
    np.testing.assert_allclose(out.velocity[0, 0], np.array([1.2, 0.0, 1.4]) * 1.8 / np.hypot(1.2, 1.4))
    assert report.velocities_clipped == 2
    v_ok = np.tile([1.0, -1.0, 1.0], (2, 1, 1))  # sqrt(3) = 1.732 m/s: under the limit
    sp = Setpoints(t=t, position=p, velocity=v_ok)
    assert clamp_setpoints(sp, BOX, 1.8)[0] is sp


@pytest.mark.parametrize(
    ("point", "expected"),
    [
        ((0.95, 0.0, 0.5), (0.9, 0.0, 0.5)),
        ((0.1, 0.0, 0.5), (0.2, 0.0, 0.5)),
        ((0.5, -0.5, 0.5), (0.5, -0.4, 0.5)),
        ((0.5, 0.45, 0.5), (0.5, 0.4, 0.5)),
        ((0.5, 0.0, 0.05), (0.5, 0.0, 0.1)),
        ((0.5, 0.0, 1.0), (0.5, 0.0, 0.9)),
        ((1.0, 0.5, 1.0), (0.9, 0.4, 0.9)),
        ((0.9, 0.4, 0.9), (0.9, 0.4, 0.9)),  # the corner itself is inside
    ],
)
def test_workspace_clamp_per_axis(
    point: tuple[float, float, float], expected: tuple[float, float, float]
) -> None:
    # Held still for 1 s so that only the box moves the setpoint.
    sp = _hold(np.array([0.0, 1.0]), np.array(point))
    out, report = clamp_setpoints(sp, BOX, 1.8)
    np.testing.assert_allclose(out.position[:, 0], [expected, expected], atol=1e-12)
    moved = not np.allclose(point, expected)
    assert report.positions_moved_into_box == (2 if moved else 0)
    assert report.max_box_excess_m == pytest.approx(np.linalg.norm(np.subtract(point, expected)))
    assert BOX.contains(np.array(expected))


def test_workspace_box_contains_its_boundary_only() -> None:
    assert BOX.contains(np.array([[0.2, -0.4, 0.1], [0.9, 0.4, 0.9]])).all()
    assert not BOX.contains(np.array([0.2 - 1e-9, 0.0, 0.5]))
    assert not BOX.contains(np.array([0.5, 0.0, 0.9 + 1e-9]))


def test_the_current_state_outside_the_box_is_clamped_first() -> None:
    # A TCP measured 5 cm under the box's floor starts its ramp from the box's floor, not from below it.
    start = TcpState(position=np.array([[0.5, 0.0, 0.05]]), velocity=np.zeros((1, 3)), t=0.0)
    out, _ = clamp_setpoints(_hold(np.array([0.01]), np.array([0.5, 0.0, 0.5])), BOX, 1.0, start)
    np.testing.assert_allclose(out.position[0, 0], [0.5, 0.0, 0.11], atol=1e-12)


def test_clamped_sim_robot_first_jump_keeps_the_episode_under_v_max() -> None:
    # End to end: the simulated TCP behind the clamp, asked to jump 0.3 m at once. Clamped to 1 m/s from the
    # current TCP, the episode's monitor never sees the 1.8 m/s limit broken (table V, I_avoid).
    from dyndlo_vision.control.sim_robot import SimRobot
    from dyndlo_vision.tasks import make_env

    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": (0.8, 0.0, 0.4)})
    robot = ClampedRobot(SimRobot(env), BOX, 1.0)
    robot.connect()
    now = robot.state()
    home = now.position[0].copy()
    t = now.t + 0.001 * np.arange(1, 401)  # 0.4 s at the 1 ms physics step
    robot.send(_hold(t, home + [0.3, 0.0, 0.0]))
    assert robot.last_report.steps_rate_limited == 299  # 0.3 m at 1 mm a step: the 300th lands
    tcp = robot.state().position[0]
    np.testing.assert_allclose(tcp, home + [0.3, 0.0, 0.0], atol=0.01)
    _, _, info = env.outcome()
    assert not info["avoid"]["velocity"]
    assert env._monitor.max_tcp_speed_m_s < 1.2
