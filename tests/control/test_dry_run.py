"""The pieces of `dyndlo-vision run`: the config schema, the scripted plan, the simulated camera placed from a
calibration, the plan splicing of HorizonRobot, and IK over spans whose coarse grid rounds past the end."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dyndlo_vision.control.horizon import LEAD_FACTOR, HorizonRobot
from dyndlo_vision.control.run_config import ConfigError, parse_run_config
from dyndlo_vision.control.scripted import SlowReach
from dyndlo_vision.robots.kinematics import ArmKinematics, IKOptions, abb_gofa_crb15000
from dyndlo_vision.robots.protocol import Setpoints, TcpState
from dyndlo_vision.robots.safety import WorkspaceBox
from dyndlo_vision.tasks.tip_control import TCP_HOME_M, TipControl
from dyndlo_vision.tracking.camera_model import PinholeCamera
from dyndlo_vision.trajectory import Replanner

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def minimal(**robot: Any) -> dict[str, Any]:
    return {
        "robot": {"driver": "egm", "arm": "gofa", **robot},
        "camera": {"source": "simulated", "calibration": "tracking-camera.json"},
        "target": [0.7, 0.0, 0.3],
        "policy": "scripted:slow-reach",
        "safety": {"workspace": {"min": [0, -1, 0], "max": [1, 1, 1]}, "max_tcp_speed": 1.0, "duration_s": 5},
    }


def test_config_defaults_and_paths() -> None:
    cfg = parse_run_config(minimal(), EXAMPLES / "x.yaml")
    assert cfg.robot.port == 6510 and cfg.robot.connect_timeout_s == 3.0 and cfg.robot.base_pose is None
    assert cfg.robot.tool_offset == (0.0, 0.0, 0.0) and cfg.robot.plan_lead_s == 0.08
    assert cfg.camera.calibration == EXAMPLES / "tracking-camera.json"
    assert cfg.camera.segmenter == "learned" and cfg.task == "tip-control"  # sim or real: the network
    assert cfg.safety.joint_margin == 0.9


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ([1, 2], "the top level: expected a mapping of keys, got [1, 2]"),
        ({**minimal(), "robot": "gofa"}, "robot: expected a mapping of keys, got 'gofa'"),
        ({k: v for k, v in minimal().items() if k != "policy"}, "missing key policy"),
        (minimal(port=True), "robot.port: got True; expected an integer in [1, 65535]"),
        (minimal(base_pose=[0, 0, 0]), "robot.base_pose: got [0, 0, 0]; expected a list of 6 finite numbers"),
        ({**minimal(), "camera": {"source": "video", "calibration": "tracking-camera.json",
                                  "path": "missing.mp4"}}, "camera.path: file not found"),
        ({**minimal(), "camera": {"source": "device", "calibration": "tracking-camera.json"}},
         None),
        ({**minimal(), "camera": {"source": "device", "segmenter": "background",
                                  "calibration": "tracking-camera.json"}}, "missing key camera.background"),
        ({**minimal(), "task": "vaulting"}, "task: got 'vaulting'; expected one of ['tip-control']"),
    ],
)
def test_config_errors_name_the_key(data: Any, message: str | None) -> None:
    if message is None:
        parse_run_config(data, EXAMPLES / "x.yaml")  # a device camera defaults to the learned segmenter
        return
    with pytest.raises((ConfigError, FileNotFoundError)) as err:
        parse_run_config(data, EXAMPLES / "x.yaml")
    assert message in str(err.value)


def test_slow_reach_plans_to_the_hanging_tip_at_the_target() -> None:
    spec = TipControl(planar=True).action_spec()
    home = np.array(TCP_HOME_M)
    goal = np.array([0.62, 0.0, 0.2])
    obs = np.concatenate([home, np.zeros(3), home - [0.0, 0.0, 0.5], goal])
    action = SlowReach(spec)(obs)
    assert action.shape == (spec.size,) and np.all(np.abs(action) <= 1.0)
    points, times = spec.decode(action.astype(float), home, 0.0)
    np.testing.assert_allclose(points[-1], goal + [0.0, 0.0, 0.5], atol=1e-6)
    np.testing.assert_allclose(np.diff(times), 0.5)  # the slowest segments
    # Out of reach: as far along the line as reachable, less the margin.
    limit = 0.7

    def reachable(p: np.ndarray) -> bool:
        return bool(np.linalg.norm(p - [0.0, 0.0, 0.265]) <= limit)

    dest = SlowReach(spec, reachable).destination(np.concatenate([home, np.zeros(3), home - [0, 0, 0.5],
                                                                  [0.85, 0.0, 0.45]]))
    assert reachable(dest)
    assert np.linalg.norm(dest - [0.0, 0.0, 0.265]) == pytest.approx(limit - 0.03, abs=0.01)


def test_scene_camera_placed_from_a_calibration() -> None:
    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.control.dry_run import place_scene_camera
    from dyndlo_vision.tasks.registry import make_env

    env = make_env("tip-control")
    env.reset(seed=0)
    base = env.unwrapped
    shipped = PinholeCamera.from_json(EXAMPLES / "tracking-camera.json")
    # Another pose and focal length than the scene's camera: moved 20 cm, turned 10 degrees, zoomed.
    from dyndlo_vision.robots.kinematics import rotation_x

    R = shipped.R @ rotation_x(np.radians(10.0)).T
    center = shipped.center + [0.2, 0.1, -0.05]
    K = shipped.K.copy()
    K[0, 0] = K[1, 1] = 500.0
    calib = PinholeCamera(width=640, height=480, K=K, dist=np.zeros(0), R=R, t=-R @ center)
    place_scene_camera(base.model, base.data, "tracking", calib)
    cam = MujocoCamera(base.model, base.data, "tracking")
    try:
        points = np.array([[0.45, 0.0, 0.6], [0.8, 0.0, 0.4], [0.6, 0.2, 0.1]])
        np.testing.assert_allclose(cam.calibration.project(points), calib.project(points), atol=1e-6)
    finally:
        cam.close()
    distorted = PinholeCamera(width=640, height=480, K=K, dist=[0.1, 0, 0, 0], R=R, t=-R @ center)
    with pytest.raises(ValueError, match="cannot reproduce this calibration: lens distortion"):
        place_scene_camera(base.model, base.data, "tracking", distorted)


class _Driver:
    """Just what HorizonRobot uses of a driver."""

    period_s = 0.004

    def __init__(self) -> None:
        self.t = 1.0
        self.position = np.array([TCP_HOME_M])
        self.sent: list[Setpoints] = []

    def state(self) -> TcpState:
        return TcpState(self.position, np.zeros((1, 3)), self.t)

    commanded_state = state

    def send(self, setpoints: Setpoints) -> None:
        self.sent.append(setpoints)


def test_horizon_robot_sends_the_old_plan_until_the_new_one_starts() -> None:
    spec = TipControl(planar=True).action_spec()
    replanner = Replanner(spec, np.array([TCP_HOME_M]))
    driver = _Driver()
    robot = HorizonRobot(driver, replanner, WorkspaceBox((-2, -2, -2), (2, 2, 2)), 10.0, lead_s=0.08,
                         first_lead_s=0.25)
    assert robot.state().t == pytest.approx(1.25)  # the first plan: the long lead
    first = replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(Setpoints(np.array([0.0]), np.zeros((1, 1, 3)), np.zeros((1, 1, 3))))
    sent = driver.sent[-1]
    assert sent.t[0] == pytest.approx(1.004) and sent.t[-1] >= first.t_end - 1e-9
    np.testing.assert_allclose(np.diff(sent.t), 0.004)
    held = sent.t <= 1.25
    np.testing.assert_allclose(sent.position[held, 0], np.tile(TCP_HOME_M, (held.sum(), 1)))
    driver.t, driver.position = 1.5, first.position(np.array([1.5]))
    assert robot.state().t == pytest.approx(1.58)  # re-plans: the short lead
    second = replanner.replan(np.full(spec.size, -0.3), robot.state().t)
    robot.send(Setpoints(np.array([0.0]), np.zeros((1, 1, 3)), np.zeros((1, 1, 3))))
    sent = driver.sent[-1]
    before = sent.t < second.t_start
    np.testing.assert_allclose(sent.position[before, 0], first.position(sent.t[before]))
    np.testing.assert_allclose(sent.position[~before, 0], second.position(sent.t[~before]))
    assert robot.max_late_s == pytest.approx(1.5 - 1.58)


class _SlowDriver(_Driver):
    """A driver on a loaded computer: each send takes ``send_s`` of robot time (its IK); the first
    ``refuse_joins`` sends are refused at the join, as the real driver refuses setpoints that start after
    targets it has already sent."""

    def __init__(self, send_s: float = 0.0, refuse_joins: int = 0) -> None:
        super().__init__()
        self.send_s, self.refuse_joins = send_s, refuse_joins

    def send(self, setpoints: Setpoints) -> None:
        from dyndlo_vision.robots.kinematics import JointLimitError, LimitReport

        self.t += self.send_s
        if self.refuse_joins > 0:
            self.refuse_joins -= 1
            raise JointLimitError(LimitReport(), "(at the join)", at_join=True)
        super().send(setpoints)


def _horizon(driver: _Driver) -> tuple[HorizonRobot, Replanner, Any]:
    spec = TipControl(planar=True).action_spec()
    replanner = Replanner(spec, np.array([TCP_HOME_M]))
    robot = HorizonRobot(driver, replanner, WorkspaceBox((-2, -2, -2), (2, 2, 2)), 10.0, lead_s=0.08,
                         first_lead_s=0.25)
    return robot, replanner, spec


NOTHING = Setpoints(np.array([0.0]), np.zeros((1, 1, 3)), np.zeros((1, 1, 3)))


def test_a_late_first_plan_starts_later_and_unchanged() -> None:
    """The first cycle took longer than the first lead: the arm is still at rest at home, so the plan is sent
    whole, later by what it would have missed (never joined mid-way)."""
    driver = _SlowDriver()
    robot, replanner, spec = _horizon(driver)
    planned = replanner.replan(np.full(spec.size, 0.3), robot.state().t)  # starts at 1.25
    driver.t = 1.4  # the cycle took 0.4 s
    robot.send(NOTHING)
    sent = driver.sent[-1]
    started = replanner.trajectory
    assert started.t_start >= 1.4 + driver.period_s and robot.first_plan_delay_s > 0.15
    np.testing.assert_allclose(started.points, planned.points)
    np.testing.assert_allclose(started.position(sent.t), planned.position(sent.t - robot.first_plan_delay_s))
    np.testing.assert_allclose(sent.position[:, 0], started.position(sent.t))
    held = sent.t <= started.t_start
    np.testing.assert_allclose(sent.position[held, 0], np.tile(TCP_HOME_M, (held.sum(), 1)))
    assert robot.max_late_s < 0.0 and robot.plans_late == 0


def test_a_late_plan_is_dropped_and_the_robot_keeps_the_plans_it_has() -> None:
    driver = _SlowDriver()
    robot, replanner, spec = _horizon(driver)
    first = replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)
    driver.t, driver.position = 1.5, first.position(np.array([1.5]))
    replanner.replan(np.full(spec.size, -0.3), robot.state().t)  # starts at 1.58
    driver.t = 1.6  # ... but the cycle took 0.1 s
    robot.send(NOTHING)
    assert len(driver.sent) == 1 and robot.plans_late == 1 and replanner.trajectory is first
    # The next cycle plans from the plan the robot follows, and is in time: it is sent.
    driver.position = first.position(np.array([1.6]))
    third = replanner.replan(np.full(spec.size, 0.1), robot.state().t)
    np.testing.assert_allclose(third.points[0], first.position(np.array([third.t_start]))[0])
    robot.send(NOTHING)
    assert len(driver.sent) == 2 and robot.plans_late == 1 and robot.max_late_s < 0.0


def test_the_lead_grows_with_the_cycle_latency_and_is_bounded() -> None:
    driver = _SlowDriver(send_s=0.1)
    robot, replanner, spec = _horizon(driver)
    replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)  # 0.1 s from state() to acceptance
    assert robot.lead_s == pytest.approx(LEAD_FACTOR * 0.1) and LEAD_FACTOR > 1.0
    driver.t = 1.3
    assert robot.state().t == pytest.approx(1.3 + LEAD_FACTOR * 0.1)
    driver.send_s = 0.6
    replanner.replan(np.full(spec.size, 0.1), robot.state().t + 0.7)  # in time, however long the send
    robot.send(NOTHING)
    assert robot.lead_s == robot.max_lead_s == robot.lead_max_used_s == pytest.approx(0.22)


def test_a_first_plan_refused_at_the_join_is_tried_later_and_a_limit_of_its_own_is_not() -> None:
    from dyndlo_vision.robots.kinematics import JointLimitError, LimitReport

    driver = _SlowDriver(send_s=0.3, refuse_joins=1)  # the first send takes longer than the first lead
    robot, replanner, spec = _horizon(driver)
    replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)
    assert len(driver.sent) == 1 and robot.first_plan_delay_s > 0.3 and robot.max_late_s < 0.0

    class _Refusing(_Driver):
        """Refuses the ``accept``-th plan on, for a limit of the plan's own, after its start passed."""

        def __init__(self, accept: int) -> None:
            super().__init__()
            self.accept, self.refused = accept, 0

        def send(self, setpoints: Setpoints) -> None:
            if len(self.sent) >= self.accept:
                self.t += 0.3
                self.refused += 1
                raise JointLimitError(LimitReport())  # the plan itself: not at the join
            super().send(setpoints)

    for accept in (0, 1):  # the first plan, then a later one
        driver = _Refusing(accept)
        robot, replanner, spec = _horizon(driver)
        if accept:
            replanner.replan(np.full(spec.size, 0.3), robot.state().t)
            robot.send(NOTHING)
        replanner.replan(np.full(spec.size, -0.3), robot.state().t)
        with pytest.raises(JointLimitError):  # stops the run: neither dropped nor tried again
            robot.send(NOTHING)
        assert driver.refused == 1 and robot.plans_late == 0


def test_joint_trajectory_when_the_coarse_grid_rounds_past_the_end() -> None:
    """np.arange(t0, t1, 0.02) can end a rounding error past t1; the IK used to index past its samples."""
    kin = ArmKinematics(abb_gofa_crb15000(), options=IKOptions(coarse_step_s=0.02))
    q0 = kin.ik(np.array(TCP_HOME_M)).q
    starts = np.arange(0.5, 0.7, 0.004)
    for t0 in starts:
        ts = np.linspace(t0, t0 + 1.32, 331)
        traj = kin.joint_trajectory(ts, np.tile(TCP_HOME_M, (ts.size, 1)), q0)
        np.testing.assert_allclose(traj.q, np.tile(q0, (ts.size, 1)), atol=1e-6)
    assert any(np.arange(t0, t0 + 1.32, 0.02)[-1] > np.linspace(t0, t0 + 1.32, 331)[-1] for t0 in starts)


def test_horizon_robot_with_plans_pending() -> None:
    """A lead longer than the period: the newest plan that has started by each instant is what is sent."""
    spec = TipControl(planar=True).action_spec()
    replanner = Replanner(spec, np.array([TCP_HOME_M]))
    driver = _Driver()
    robot = HorizonRobot(driver, replanner, WorkspaceBox((-2, -2, -2), (2, 2, 2)), 10.0, lead_s=0.08,
                         first_lead_s=0.25)
    nothing = Setpoints(np.array([0.0]), np.zeros((1, 1, 3)), np.zeros((1, 1, 3)))
    plans = [replanner.replan(np.full(spec.size, 0.3), robot.state().t)]  # starts at 1.25
    robot.send(nothing)
    driver.t = 1.04
    assert robot.state().t == pytest.approx(1.25)  # never before the current plan's start: it replaces it
    driver.t = 1.30
    driver.position = plans[0].position(np.array([1.30]))
    plans.append(replanner.replan(np.full(spec.size, -0.2), robot.state().t))  # starts at 1.38
    robot.send(nothing)
    driver.t = 1.34
    driver.position = plans[0].position(np.array([1.34]))
    plans.append(replanner.replan(np.full(spec.size, 0.1), robot.state().t))  # starts at 1.42, 2nd pending
    robot.send(nothing)
    sent = driver.sent[-1]
    assert sent.t[0] == pytest.approx(1.344)
    for k, (lo, hi) in enumerate([(1.34, 1.38), (1.38, 1.42), (1.42, 9.0)]):
        sel = (sent.t >= lo) & (sent.t < hi)
        assert sel.any()
        np.testing.assert_allclose(sent.position[sel, 0], plans[k].position(sent.t[sel]))
    # Each plan starts where and how fast the previous is then: the whole is continuous in velocity.
    v = np.diff(sent.position[:, 0], axis=0) / 0.004
    assert np.max(np.abs(np.diff(v, axis=0))) / 0.004 < 20.0  # m/s^2: no step at the joins


def test_moving_targets_lost_counts_what_never_arrived() -> None:
    from dyndlo_vision.control.robot_report import moving_targets_lost

    q = [np.full(6, 0.01 * k) for k in range(10)]
    rest = [q[-1], q[-1]]
    assert moving_targets_lost(q + rest, q + rest[:1]) == 0  # the last repeat overwritten: not a loss
    assert moving_targets_lost(q, q[:4] + q[5:]) == 1  # one moving target overwritten
    assert moving_targets_lost(q, list(reversed(q))) == 9  # out of order: only one matches in order


HOME = np.array(TCP_HOME_M)
BIG_BOX = WorkspaceBox((-2, -2, -2), (2, 2, 2))


class _Hold:
    """A plan that holds the point ``dx`` (m, along x) from home between ``t_start`` and ``t_end``: what is
    sent follows from it by hand."""

    def __init__(self, dx: float, t_start: float, t_end: float) -> None:
        self.points = np.tile(HOME + [dx, 0.0, 0.0], (2, 1))
        self.t_start, self.t_end = t_start, t_end

    def position(self, t: np.ndarray) -> np.ndarray:
        return np.tile(self.points[0], (np.size(t), 1))

    def velocity(self, t: np.ndarray) -> np.ndarray:
        return np.zeros((np.size(t), 3))

    def shifted(self, dt: float) -> _Hold:
        return _Hold(self.points[0, 0] - HOME[0], self.t_start + dt, self.t_end + dt)


class _Planner:
    """A replanner whose plans the test sets (home at rest before any)."""

    def __init__(self) -> None:
        self.trajectory: _Hold | None = None

    def references(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = np.tile(HOME, (np.size(t), 1, 1))
        return p, np.zeros_like(p)


def _dx(sent: Setpoints) -> np.ndarray:
    return sent.position[:, 0, 0] - HOME[0]


def test_horizon_robot_switches_to_a_plan_at_its_start_and_forgets_superseded_ones() -> None:
    driver, planner = _Driver(), _Planner()
    robot = HorizonRobot(driver, planner, BIG_BOX, 10.0, lead_s=0.08)
    k = np.arange(1, 200)
    planner.trajectory = _Hold(0.0, 1.0 + 0.004 * 10, 1.6)
    robot.send(NOTHING)
    planner.trajectory = _Hold(0.01, 1.0 + 0.004 * 20, 1.6)  # starts on the 20th setpoint exactly
    robot.send(NOTHING)
    sent = driver.sent[-1]
    np.testing.assert_array_equal(sent.t, 1.0 + 0.004 * k[:150])
    np.testing.assert_allclose(_dx(sent), np.where(k[:150] >= 20, 0.01, 0.0), atol=1e-12)
    # The second plan has started: the first is superseded, the second followed until the third starts.
    driver.t = 1.0 + 0.004 * 25
    planner.trajectory = _Hold(0.02, 1.0 + 0.004 * 40, 1.6)
    robot.send(NOTHING)
    sent = driver.sent[-1]
    np.testing.assert_allclose(sent.t[[0, -1]], [1.104, 1.6])
    np.testing.assert_allclose(_dx(sent), np.where(k[25:150] >= 40, 0.02, 0.01), atol=1e-12)
    assert robot.sends == 3 and robot.plans_late == 0


def test_horizon_robot_sends_to_the_plans_end_or_holds_it_a_quarter_second() -> None:
    driver, planner = _Driver(), _Planner()
    robot = HorizonRobot(driver, planner, BIG_BOX, 10.0, lead_s=0.08)
    planner.trajectory = _Hold(0.01, 1.2, 1.5)  # ends 125 periods after the last target: no setpoint past it
    robot.send(NOTHING)
    sent = driver.sent[-1]
    assert sent.t.size == 125 and sent.t[-1] == pytest.approx(1.5)
    driver.t = 1.4
    planner.trajectory = _Hold(0.01, 1.45, 1.5)  # ends in 0.1 s: held at its end to 0.25 s on the grid
    robot.send(NOTHING)
    sent = driver.sent[-1]
    np.testing.assert_allclose(sent.t, 1.4 + 0.004 * np.arange(1, 64))
    np.testing.assert_allclose(_dx(sent), 0.01)
    np.testing.assert_array_equal(sent.velocity, 0.0)


def test_horizon_robot_before_any_plan_sends_home_at_rest_once_and_counts_its_cycles() -> None:
    driver = _Driver()
    robot, replanner, spec = _horizon(driver)
    robot.send(NOTHING)  # no plan yet (e.g. a loop that ended before planning): the arm held at home
    sent = driver.sent[-1]
    np.testing.assert_allclose(sent.t, 1.0 + 0.004 * np.arange(1, 64))  # 0.25 s, on the driver's grid
    np.testing.assert_array_equal(sent.position, np.tile(HOME, (63, 1, 1)))
    np.testing.assert_array_equal(sent.velocity, 0.0)
    assert (robot.sends, robot.unchanged) == (1, 0)
    robot.send(NOTHING)
    assert len(driver.sent) == 1 and (robot.sends, robot.unchanged) == (1, 1)
    replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)
    robot.send(NOTHING)
    robot.send(NOTHING)
    assert len(driver.sent) == 2 and (robot.sends, robot.unchanged, robot.clamped_sends) == (2, 3, 0)


def test_horizon_robot_counts_the_sends_the_clamps_changed() -> None:
    driver, planner = _Driver(), _Planner()
    box = WorkspaceBox((-2, -2, -2), (HOME[0] + 0.005, 2, 2))
    robot = HorizonRobot(driver, planner, box, 10.0, lead_s=0.08)
    planner.trajectory = _Hold(0.01, 1.04, 1.6)  # 5 mm outside the box
    robot.send(NOTHING)
    np.testing.assert_allclose(_dx(driver.sent[-1])[-1], 0.005)
    assert robot.clamped_sends == 1
    planner.trajectory = _Hold(0.01, 1.08, 1.6)
    robot.send(NOTHING)
    assert robot.clamped_sends == 2 and robot.sends == 2


def test_horizon_robot_reports_the_measured_tcp_stamped_ahead() -> None:
    driver = _Driver()
    velocity = np.array([[0.1, -0.2, 0.3]])
    driver.state = lambda: TcpState(driver.position, velocity, driver.t)  # type: ignore[method-assign]
    robot, replanner, spec = _horizon(driver)
    s = robot.state()
    np.testing.assert_array_equal(s.position, [TCP_HOME_M])
    np.testing.assert_array_equal(s.velocity, velocity)
    assert s.t == pytest.approx(1.25)
    replanner.replan(np.full(spec.size, 0.3), s.t)
    robot.send(NOTHING)
    driver.t, driver.position = 1.3, np.array([[0.5, 0.01, 0.55]])
    s = robot.state()  # a plan pending: still the measured TCP, at t + lead
    np.testing.assert_array_equal(s.position, [[0.5, 0.01, 0.55]])
    np.testing.assert_array_equal(s.velocity, velocity)
    assert s.t == pytest.approx(1.38)


def test_horizon_robot_lead_bounds() -> None:
    driver = _Driver()
    replanner = Replanner(TipControl(planar=True).action_spec(), np.array([TCP_HOME_M]))
    robot = HorizonRobot(driver, replanner, BIG_BOX, 10.0, lead_s=0.0)  # no lead: allowed
    assert robot.state().t == pytest.approx(1.25)  # the first plan still gets its own lead
    replanner.replan(np.full(replanner.spec.size, 0.3), 1.25)
    robot.send(NOTHING)
    driver.t = 1.3
    assert robot.state().t == 1.3
    for bad in (-0.01, float("nan")):
        with pytest.raises(ValueError, match="lead_s must be >= 0"):
            HorizonRobot(driver, replanner, BIG_BOX, 10.0, lead_s=bad)


def test_horizon_robot_sent_a_plan_without_reading_its_state_keeps_its_lead() -> None:
    driver = _SlowDriver(send_s=0.1)
    robot, replanner, spec = _horizon(driver)
    replanner.replan(np.full(spec.size, 0.3), 1.25)  # no state() read: no cycle latency to learn from
    robot.send(NOTHING)
    assert len(driver.sent) == 1 and robot.lead_s == robot.lead_max_used_s == 0.08


def test_a_plan_starting_exactly_when_the_driver_can_join_it_is_sent() -> None:
    driver = _Driver()  # sends take no time: a plan can start one driver period after the last target
    robot, replanner, spec = _horizon(driver)
    first = replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)
    driver.t = 1.5
    replanner.replan(np.full(spec.size, -0.3), 1.5 + 0.004 - 1e-6)  # just too early: dropped
    robot.send(NOTHING)
    assert len(driver.sent) == 1 and robot.plans_late == 1 and replanner.trajectory is first
    second = replanner.replan(np.full(spec.size, -0.3), 1.5 + 0.004)
    robot.send(NOTHING)
    assert len(driver.sent) == 2 and robot.plans_late == 1
    assert driver.sent[-1].t[0] == second.t_start and robot.max_late_s == pytest.approx(-0.004)


def test_a_plan_is_sent_only_if_it_starts_after_the_longest_recent_send_with_margin() -> None:
    driver = _SlowDriver(send_s=0.1)
    robot, replanner, spec = _horizon(driver)
    replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)  # took 0.1 s: the next plan must start 1.25 * 0.1 + 0.004 s after the last target
    driver.t, driver.send_s = 1.5, 0.0
    replanner.replan(np.full(spec.size, -0.3), 1.62)
    robot.send(NOTHING)
    assert len(driver.sent) == 1 and robot.plans_late == 1
    replanner.replan(np.full(spec.size, -0.3), 1.63)
    robot.send(NOTHING)
    assert len(driver.sent) == 2 and robot.plans_late == 1


def test_a_later_plan_refused_at_the_join_after_its_start_is_dropped(
        caplog: pytest.LogCaptureFixture) -> None:
    driver = _SlowDriver()
    robot, replanner, spec = _horizon(driver)
    first = replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)
    driver.t = 1.5
    replanner.replan(np.full(spec.size, -0.3), robot.state().t)  # starts at 1.58
    driver.send_s, driver.refuse_joins = 0.2, 1  # the send ends at 1.7: refused at the join
    with caplog.at_level("WARNING", logger="dyndlo_vision.control.horizon"):
        robot.send(NOTHING)
    assert len(driver.sent) == 1 and robot.plans_late == 1 and replanner.trajectory is first
    assert "plan for t=1.580 s dropped" in caplog.text and "(lead 80 ms)" in caplog.text
    replanner.replan(np.full(spec.size, 0.1), 1.7)  # the driver is at 1.7 already: late again
    robot.send(NOTHING)
    assert len(driver.sent) == 1 and robot.plans_late == 2 and replanner.trajectory is first


class _SlowerDriver(_SlowDriver):
    """Its k-th send takes ``send_s[k]`` of robot time."""

    def __init__(self, send_s: list[float], refuse_joins: int) -> None:
        super().__init__(refuse_joins=refuse_joins)
        self.durations, self.tries = list(send_s), 0

    def send(self, setpoints: Setpoints) -> None:
        self.send_s = self.durations[self.tries]
        self.tries += 1
        super().send(setpoints)


def test_a_first_plan_refused_at_the_join_at_its_start_is_tried_twice_the_send_later(
        caplog: pytest.LogCaptureFixture) -> None:
    driver = _SlowDriver(send_s=0.25, refuse_joins=1)
    robot, replanner, spec = _horizon(driver)
    replanner.replan(np.full(spec.size, 0.3), robot.state().t)  # starts at 1.25
    with caplog.at_level("WARNING", logger="dyndlo_vision.control.horizon"):
        robot.send(NOTHING)  # refused when the driver is at 1.25 exactly: too late, tried again from 1.75
    assert "sending took 0.250 s" in caplog.text
    assert len(driver.sent) == 1 and replanner.trajectory.t_start == pytest.approx(1.75)
    assert robot.first_plan_delay_s == pytest.approx(0.5) and robot.max_late_s == pytest.approx(1.5 - 1.75)


def test_a_first_plan_gets_four_tries_each_later_by_twice_the_last_send() -> None:
    from dyndlo_vision.robots.kinematics import JointLimitError

    durations = [0.3, 0.7, 1.5, 3.1, 0.1]
    driver = _SlowerDriver(durations, refuse_joins=3)
    robot, replanner, spec = _horizon(driver)
    planned = replanner.replan(np.full(spec.size, 0.3), robot.state().t)  # starts at 1.25
    robot.send(NOTHING)
    # Refused at 1.3, 2.0 and 3.5, each after the start it was sent for (1.25, 1.3 + 0.6, 2.0 + 1.4);
    # the fourth try starts at 3.5 + 3.0 and is accepted.
    assert driver.tries == 4 and len(driver.sent) == 1
    assert replanner.trajectory.t_start == pytest.approx(6.5)
    assert robot.first_plan_delay_s == pytest.approx(6.5 - 1.25)
    np.testing.assert_allclose(replanner.trajectory.points, planned.points)
    driver = _SlowerDriver(durations, refuse_joins=4)
    robot, replanner, spec = _horizon(driver)
    replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    with pytest.raises(JointLimitError):  # no try was in time: the run stops, nothing sent
        robot.send(NOTHING)
    assert driver.tries == 4 and not driver.sent


class _StreamingDriver(_Driver):
    """A driver that streams on while the cycle computes: its last target moves two periods on whenever it
    is read, along the setpoints it was sent."""

    def commanded_state(self) -> TcpState:
        self.t += 2 * self.period_s
        if not self.sent:
            return TcpState(self.position, np.zeros((1, 3)), self.t)
        s = self.sent[-1]
        p = [np.interp(self.t, s.t, s.position[:, 0, i]) for i in range(3)]
        return TcpState(np.array([p]), np.zeros((1, 3)), self.t)


def test_horizon_robot_clamps_from_the_target_its_setpoints_start_after() -> None:
    driver = _StreamingDriver()
    robot, replanner, spec = _horizon(driver)
    first = replanner.replan(np.full(spec.size, 0.3), robot.state().t)
    robot.send(NOTHING)
    driver.t = 1.6  # the arm moving at about 0.6 m/s along the first plan
    assert np.linalg.norm(first.velocity(np.array([1.6]))) > 0.3
    second = replanner.replan(np.full(spec.size, -0.3), robot.state().t)
    robot.send(NOTHING)
    sent = driver.sent[-1]
    assert robot.clamped_sends == 0
    expected = np.where((sent.t < second.t_start)[:, None], first.position(sent.t), second.position(sent.t))
    np.testing.assert_allclose(sent.position[:, 0], expected, atol=1e-12)
