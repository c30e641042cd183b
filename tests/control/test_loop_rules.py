"""The control loop's rules on scripted parts (no simulator): the deadline, the lost estimate, the brake, the
end of a run, the setpoints sent, pacing on a wall-clock robot.

The robot is a fake whose clock advances one period per ``send`` (as the simulated robot's does) unless told
otherwise; the state source answers scripted readings; the loop's clock is replaced by a scripted one, so
the policy's and the planner's times, and hence the controller's time, are exact.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np
import pytest

from dyndlo_vision.control import loop as loop_module
from dyndlo_vision.control.loop import CONTROLLER_STAGES, ControlLoop, CycleRecord, LoopReport
from dyndlo_vision.control.state_sources import PDloReading
from dyndlo_vision.robots.protocol import Setpoints, TcpState
from dyndlo_vision.trajectory import ActionSpec, Replanner

HOME = np.array([[0.45, 0.0, 0.6]])
GOAL = np.array([0.8, 0.0, 0.4])
SPEC = ActionSpec(num_points=1, planar=True, dx_m=(-0.2, 0.2), dz_m=(-0.2, 0.2), dt_s=(0.1, 0.3))


class FakeRobot:
    def __init__(self, t0: float = 10.0, period: float | None = 0.04) -> None:
        self.t = t0
        self.period = period  # the clock's advance per send (None: it does not advance)
        self.sent: list[Setpoints] = []
        self.stops = 0

    def connect(self) -> None:
        pass

    def state(self) -> TcpState:
        position = HOME + [0.0, 0.0, 0.01 * len(self.sent)]
        return TcpState(position=position, velocity=np.zeros((1, 3)), t=self.t)

    def send(self, setpoints: Setpoints) -> None:
        self.sent.append(setpoints)
        if self.period is not None:
            self.t += self.period

    def stop(self) -> None:
        self.stops += 1

    def close(self) -> None:
        pass


class ScriptedSource:
    """Answers the readings given, in turn (the last one again when they run out)."""

    def __init__(self, *readings: dict) -> None:
        self.readings = list(readings)
        self.calls: list[tuple[float, TcpState]] = []

    def read(self, t: float, tcp: TcpState) -> PDloReading:
        spec = self.readings[min(len(self.calls), len(self.readings) - 1)]
        self.calls.append((t, tcp))
        position = np.array(spec.get("position", [0.7, 0.0, 0.3]))
        return PDloReading(position, t, measured=spec.get("measured", True), lost=spec.get("lost", False),
                           stage_ms=dict(spec.get("stage_ms", {})), pixel=spec.get("pixel"),
                           continued=spec.get("continued", False), observed_tcp=spec.get("observed_tcp"))


class Policy:
    def __init__(self, action: float = 0.5) -> None:
        self.seen: list[np.ndarray] = []
        self.action = action

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self.seen.append(obs)
        return np.full(SPEC.size, self.action)


class ScriptedClock:
    """``perf_counter`` steps through the given increments (seconds), ``monotonic`` likewise; ``sleep`` is
    recorded, not slept."""

    def __init__(self, perf_steps: Iterator[float], monotonic_steps: Iterator[float] | None = None) -> None:
        self._perf, self._mono = 0.0, 0.0
        self.perf_steps, self.monotonic_steps = perf_steps, monotonic_steps
        self.slept: list[float] = []

    def perf_counter(self) -> float:
        self._perf += next(self.perf_steps, 0.0)
        return self._perf

    def monotonic(self) -> float:
        if self.monotonic_steps is not None:
            self._mono += next(self.monotonic_steps, 0.0)
        return self._mono

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)


def _loop(source: ScriptedSource, robot: FakeRobot, policy: Policy | None = None, **kwargs) -> ControlLoop:
    return ControlLoop(source, robot, policy or Policy(), Replanner(SPEC, HOME), GOAL, **kwargs)


@pytest.mark.parametrize(
    ("track_ms", "missed"), [(4.9, False), (5.0, False), (5.1, True)],
)
def test_the_deadline_is_the_period_on_the_controllers_own_stages(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, track_ms: float, missed: bool
) -> None:
    """Controller time = camera + track + filter + policy + plan (not sending, not other stages): missed when
    it exceeds the period, not when it equals it."""
    # perf_counter: before the policy, after it (+10 ms), after planning (+5 ms), around sending (+7 ms).
    clock = ScriptedClock(iter([0.0, 0.010, 0.005, 0.0, 0.007]))
    monkeypatch.setattr(loop_module, "time", clock)
    stages = {"camera": 20.0, "track": track_ms, "filter": 0.0, "render": 500.0}
    loop = _loop(ScriptedSource({"stage_ms": stages}), FakeRobot())
    with caplog.at_level(logging.WARNING):
        record = loop.cycle(3)
    assert record.stage_ms["policy"] == pytest.approx(10.0) and record.stage_ms["plan"] == pytest.approx(5.0)
    assert record.controller_ms == pytest.approx(20.0 + track_ms + 10.0 + 5.0)
    assert record.send_ms == pytest.approx(7.0)
    assert record.deadline_missed == missed
    assert ("cycle 3 missed its 40 ms deadline" in caplog.text) == missed
    if missed:
        assert "controller took 40.1 ms (camera 20.0, track 5.1, filter 0.0, render 500.0" in caplog.text
    assert set(CONTROLLER_STAGES) == {"camera", "track", "filter", "policy", "plan"}


def test_a_cycle_observes_plans_and_sends_one_period_of_setpoints() -> None:
    robot = FakeRobot(t0=10.0)
    policy = Policy(0.5)
    truth = np.array([0.1, 0.2, 0.3])
    source = ScriptedSource({"position": [0.7, 0.0, 0.3], "pixel": np.array([3.0, 4.0]), "continued": True})
    loop = _loop(source, robot, policy, setpoint_period_s=0.004, truth=lambda: truth)
    record = loop.cycle(0)
    # The observation: gripper position and velocity, P_DLO, P* (table II).
    np.testing.assert_allclose(policy.seen[0], [0.45, 0.0, 0.6, 0.0, 0.0, 0.0, 0.7, 0.0, 0.3, 0.8, 0.0, 0.4])
    assert loop.samples_per_cycle == 10
    (sent,) = robot.sent
    np.testing.assert_allclose(sent.t, 10.0 + 0.004 * np.arange(10), atol=1e-12)
    p, v = loop.replanner.references(sent.t)
    np.testing.assert_array_equal(sent.position, p)
    np.testing.assert_array_equal(sent.velocity, v)
    assert loop.replanner.trajectory.t_start == 10.0
    assert (record.index, record.t, record.measured, record.lost) == (0, 10.0, True, False)
    assert record.continued
    np.testing.assert_array_equal(record.action, np.full(SPEC.size, 0.5, np.float32))
    assert record.action.dtype == np.float32
    np.testing.assert_array_equal(record.p_dlo_estimate, [0.7, 0.0, 0.3])
    np.testing.assert_array_equal(record.p_dlo_true, truth)
    np.testing.assert_array_equal(record.tcp_position, HOME[0])
    np.testing.assert_array_equal(record.pixel, [3.0, 4.0])


def test_the_policy_sees_the_sources_gripper_when_it_gives_one() -> None:
    seen = TcpState(position=np.array([[0.5, 0.1, 0.7]]), velocity=np.array([[0.2, 0.0, -0.1]]), t=10.0)
    policy = Policy()
    _loop(ScriptedSource({"observed_tcp": seen}), FakeRobot(), policy).cycle(0)
    np.testing.assert_allclose(policy.seen[0][:6], [0.5, 0.1, 0.7, 0.2, 0.0, -0.1])


def test_a_lost_estimate_is_not_planned_from_nor_sent(caplog: pytest.LogCaptureFixture) -> None:
    robot, policy = FakeRobot(), Policy()
    loop = _loop(ScriptedSource({"lost": True, "measured": False}), robot, policy)
    with caplog.at_level(logging.ERROR):
        record = loop.cycle(0)
    assert policy.seen == [] and robot.sent == [] and loop.replanner.trajectory is None
    assert record.lost and record.action is None
    assert "no P_DLO estimate to plan from at t=10.000 s" in caplog.text


def test_multi_step_stops_the_robot_when_the_estimate_is_lost(caplog: pytest.LogCaptureFixture) -> None:
    robot = FakeRobot()
    source = ScriptedSource({}, {}, {"lost": True, "measured": False}, {})
    with caplog.at_level(logging.ERROR):
        report = _loop(source, robot).run(duration_s=1.0)
    assert report.stop_reason == "lost" and len(report.cycles) == 3 and robot.stops == 1
    assert len(robot.sent) == 2  # nothing sent in the lost cycle
    assert "P_DLO estimate lost at t=10.080 s" in caplog.text


def test_single_step_keeps_its_plan_running_when_the_estimate_is_lost_later() -> None:
    """A single-step policy planned in the first cycle: losing the estimate later does not stop the robot, the
    open-loop plan goes on being sent. Lost in the first cycle, there is no plan: it stops."""
    robot, policy = FakeRobot(), Policy()
    source = ScriptedSource({}, {"lost": True, "measured": False})
    report = _loop(source, robot, policy).run(duration_s=0.2, replan_every_cycle=False)
    assert report.stop_reason == "duration" and len(report.cycles) == 5 and robot.stops == 0
    assert len(policy.seen) == 1 and len(robot.sent) == 5
    assert [c.lost for c in report.cycles] == [False, True, True, True, True]
    robot = FakeRobot()
    report = _loop(ScriptedSource({"lost": True}), robot).run(duration_s=0.2, replan_every_cycle=False)
    assert report.stop_reason == "lost" and len(report.cycles) == 1 and robot.stops == 1 and robot.sent == []


def test_a_single_step_policy_is_asked_once_and_its_plan_followed() -> None:
    robot, policy = FakeRobot(), Policy()
    loop = _loop(ScriptedSource({}), robot, policy, setpoint_period_s=0.04)
    report = loop.run(duration_s=0.12, replan_every_cycle=False)
    assert len(policy.seen) == 1 and [c.action is not None for c in report.cycles] == [True, False, False]
    assert [s.t[0] for s in robot.sent] == pytest.approx([10.0, 10.04, 10.08])
    assert loop.replanner.trajectory.t_start == 10.0


@pytest.mark.parametrize(("duration", "cycles"), [(0.12, 3), (0.12 + 5e-10, 3), (0.1201, 4), (0.04, 1)])
def test_a_run_lasts_its_duration_in_robot_time(duration: float, cycles: int) -> None:
    robot = FakeRobot()
    report = _loop(ScriptedSource({}), robot).run(duration_s=duration)
    assert report.stop_reason == "duration" and len(report.cycles) == cycles
    assert [c.index for c in report.cycles] == list(range(cycles))
    assert robot.stops == 0


def test_done_ends_the_run_after_the_cycle_it_turns_true() -> None:
    robot = FakeRobot()
    seen: list[CycleRecord] = []
    report = _loop(ScriptedSource({}), robot).run(
        duration_s=1.0, done=lambda: len(robot.sent) >= 2, on_cycle=lambda record, frame: seen.append(record)
    )
    assert report.stop_reason == "done" and len(report.cycles) == 2 and robot.stops == 0
    assert seen == report.cycles


def test_any_exception_stops_the_robot_and_propagates(caplog: pytest.LogCaptureFixture) -> None:
    class Interrupting(Policy):
        def __call__(self, obs: np.ndarray) -> np.ndarray:
            raise KeyboardInterrupt

    robot = FakeRobot()
    with caplog.at_level(logging.ERROR), pytest.raises(KeyboardInterrupt):
        _loop(ScriptedSource({}), robot, Interrupting()).run(duration_s=1.0)
    assert robot.stops == 1 and "control loop failed: stopping the robot" in caplog.text


def test_the_loop_waits_out_the_period_only_on_a_robot_whose_clock_runs_with_the_wall(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # monotonic: the cycle started at 0 s, and 15 ms have passed when pacing asks.
    clock = ScriptedClock(iter([]), iter([0.015]))
    monkeypatch.setattr(loop_module, "time", clock)
    wall_robot = FakeRobot(period=None)
    loop = _loop(ScriptedSource({}), wall_robot)
    loop._pace(wall_robot.t, 0.0)
    assert clock.slept == [pytest.approx(0.025)]
    sim_robot = FakeRobot(period=0.04)
    loop = _loop(ScriptedSource({}), sim_robot)
    t_before = sim_robot.t
    sim_robot.t += 0.04 - 1e-10  # the robot's clock already advanced a period (to rounding)
    loop._pace(t_before, 0.0)
    assert clock.slept == [pytest.approx(0.025)]  # no second sleep
    # Late already: nothing to wait.
    clock2 = ScriptedClock(iter([]), iter([0.050]))
    monkeypatch.setattr(loop_module, "time", clock2)
    loop = _loop(ScriptedSource({}), FakeRobot(period=None))
    loop._pace(10.0, 0.0)
    assert clock2.slept == []


def test_finish_plan_sends_the_rest_of_the_plan_without_replanning() -> None:
    robot, policy = FakeRobot(), Policy()
    loop = _loop(ScriptedSource({}), robot, policy, setpoint_period_s=0.004)
    loop.cycle(0)
    loop.finish_plan(0.1)
    assert len(policy.seen) == 1 and len(robot.sent) == 2
    sent = robot.sent[1]
    np.testing.assert_allclose(sent.t, 10.04 + 0.004 * np.arange(25), atol=1e-12)
    np.testing.assert_array_equal(sent.position, loop.replanner.references(sent.t)[0])
    loop.finish_plan(0.001)  # less than half a setpoint period: nothing to send
    assert len(robot.sent) == 2
    for bad in (0.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match=r"duration_s must be > 0, got"):
            loop.finish_plan(bad)


@pytest.mark.parametrize(
    ("period", "setpoint_period"), [(0.0, 0.001), (-0.04, 0.001), (0.04, 0.0), (0.04, -0.001), (0.04, 0.05)]
)
def test_bad_periods_are_refused(period: float, setpoint_period: float) -> None:
    with pytest.raises(ValueError, match=r"need 0 < setpoint_period_s <= period_s, got"):
        _loop(ScriptedSource({}), FakeRobot(), period_s=period, setpoint_period_s=setpoint_period)


def test_a_setpoint_period_equal_to_the_period_is_one_setpoint_per_cycle() -> None:
    loop = _loop(ScriptedSource({}), FakeRobot(), period_s=0.04, setpoint_period_s=0.04)
    assert loop.samples_per_cycle == 1


def test_the_reports_figures() -> None:
    def cycle(k: int, stages: dict, controller: float, estimate: list[float], truth: list[float] | None,
              lost: bool = False) -> CycleRecord:
        return CycleRecord(k, 0.04 * k, np.array(estimate), None if truth is None else np.array(truth),
                           measured=not lost, lost=lost, tcp_position=np.zeros(3), action=None,
                           stage_ms=stages, controller_ms=controller, send_ms=0.0, deadline_missed=False)

    report = LoopReport([
        cycle(0, {"camera": 10.0, "policy": 2.0}, 12.0, [0.0, 0.03, 0.04], [0.0, 0.0, 0.0]),
        cycle(1, {"camera": 30.0}, 30.0, [1.0, 0.0, 0.0], None),
        cycle(2, {"camera": 20.0, "policy": 4.0}, 24.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.1]),
    ])
    np.testing.assert_array_equal(report.controller_ms(), [12.0, 30.0, 24.0])
    # A stage a cycle did not run counts as 0 ms there.
    assert report.stage_percentiles(0) == {"camera": 10.0, "policy": 0.0}
    assert report.stage_percentiles(50) == {"camera": 20.0, "policy": 2.0}
    assert report.stage_percentiles(100) == {"camera": 30.0, "policy": 4.0}
    np.testing.assert_allclose(report.estimate_errors(), [0.05, 0.1])
