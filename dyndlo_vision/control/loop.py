"""One control loop for simulation and hardware: perceive, observe, decide, re-plan, send, at 25 Hz.

    source -> PDloReading (P_DLO for the controller's time) -> observation (table II) -> policy -> action
           -> Replanner (B-spline from the commanded position and velocity) -> Setpoints -> Robot.send

The loop depends only on a state source (true state, noise model, or camera + tracker + filter), a policy
(``obs -> action``), a :class:`~dyndlo_vision.trajectory.Replanner` and a :class:`Robot`. Every cycle records
the wall time of each stage; the controller's own time (perception including rendering, policy, planning) is
compared with the period and a missed deadline is logged, never silent. Sending is timed apart: a real driver
returns at once (its robot moves in the background), while the simulated robot steps the physics inside
``send``.

Degradation: when the source has no fresh measurement the filter's prediction is used; when it reports the
estimate lost (coasted longer than its limit, or the camera stopped) the loop stops the robot and says why.
Any exception stops the robot before it propagates.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.robots.protocol import Robot, Setpoints
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S, observation_vector
from dyndlo_vision.trajectory import Replanner

log = logging.getLogger(__name__)

CONTROLLER_STAGES = ("camera", "track", "filter", "policy", "plan")


@dataclass
class CycleRecord:
    """What one cycle saw and did."""

    index: int
    t: float
    p_dlo_estimate: NDArray[np.float64]
    p_dlo_true: NDArray[np.float64] | None
    measured: bool
    lost: bool
    tcp_position: NDArray[np.float64]
    action: NDArray[np.float32] | None
    stage_ms: dict[str, float]
    controller_ms: float
    send_ms: float
    deadline_missed: bool
    pixel: NDArray[np.float64] | None = None
    polyline_uv: NDArray[np.float64] | None = None
    #: The measured tip was continued past where the tracked cable disappears (see ``PDloReading``).
    continued: bool = False


@dataclass
class LoopReport:
    """The cycles of a run and why it ended."""

    cycles: list[CycleRecord] = field(default_factory=list)
    stop_reason: str = ""

    def controller_ms(self) -> NDArray[np.float64]:
        """Controller time of every cycle (ms)."""
        return np.array([c.controller_ms for c in self.cycles])

    def stage_percentiles(self, q: float) -> dict[str, float]:
        """Percentile ``q`` of each stage's time over the cycles (ms)."""
        keys = sorted({k for c in self.cycles for k in c.stage_ms})
        return {k: float(np.percentile([c.stage_ms.get(k, 0.0) for c in self.cycles], q)) for k in keys}

    def estimate_errors(self) -> NDArray[np.float64]:
        """|estimate - truth| per cycle where both exist and the source had an estimate (not lost), m.

        A lost source's position is a prediction coasted past its limit, which the loop does not act on (a
        multi-step loop stops there; a single-step one has planned already): no estimate to score.
        """
        errors = [
            np.linalg.norm(c.p_dlo_estimate - c.p_dlo_true)
            for c in self.cycles
            if c.p_dlo_true is not None and not c.lost and np.all(np.isfinite(c.p_dlo_estimate))
        ]
        return np.asarray(errors)


class ControlLoop:
    """Closed-loop re-planning at a fixed period.

    Args:
        source: Gives P_DLO for the controller's time (``read(t, tcp_state)``).
        robot: The robot (simulated or real).
        policy: ``obs -> action`` (normalised, the task's action space).
        replanner: Turns actions into gripper trajectories from the commanded state.
        goal: P* of the task (3,).
        period_s: Control period (the paper's 40 ms, :data:`~dyndlo_vision.tasks.base.CONTROL_PERIOD_S`).
        setpoint_period_s: Spacing of the setpoints sent per cycle (the simulator's timestep, or the driver's
            rate: 4 ms for ABB EGM, 2 ms for UR RTDE).
        truth: Optional ``() -> (3,)`` true P_DLO (simulation), recorded next to the estimate.
    """

    def __init__(
        self,
        source: Any,
        robot: Robot,
        policy: Callable[[NDArray[np.float32]], Any],
        replanner: Replanner,
        goal: NDArray[np.float64],
        period_s: float = CONTROL_PERIOD_S,
        setpoint_period_s: float = 0.001,
        truth: Callable[[], NDArray[np.float64]] | None = None,
    ) -> None:
        if period_s <= 0 or setpoint_period_s <= 0 or setpoint_period_s > period_s:
            raise ValueError(
                f"need 0 < setpoint_period_s <= period_s, got {setpoint_period_s} and {period_s}"
            )
        self.source = source
        self.robot = robot
        self.policy = policy
        self.replanner = replanner
        self.goal = np.asarray(goal, dtype=float)
        self.period_s = float(period_s)
        self.setpoint_period_s = float(setpoint_period_s)
        self.truth = truth
        self.samples_per_cycle = int(round(self.period_s / self.setpoint_period_s))

    def cycle(self, index: int, replan: bool = True) -> CycleRecord:
        """Run one cycle: read the state, decide, re-plan (if ``replan``) and send the next period."""
        state = self.robot.state()
        reading = self.source.read(state.t, state)
        stage = dict(reading.stage_ms)
        truth = None if self.truth is None else np.asarray(self.truth(), dtype=float)
        action = None
        if replan and reading.lost:
            log.error("no P_DLO estimate to plan from at t=%.3f s", state.t)
        if replan and not reading.lost:
            seen = state if reading.observed_tcp is None else reading.observed_tcp
            obs = observation_vector(seen.position, seen.velocity, reading.position, self.goal)
            t0 = time.perf_counter()
            action = np.asarray(self.policy(obs), dtype=np.float32)
            t1 = time.perf_counter()
            self.replanner.replan(action, state.t)
            stage["policy"] = 1e3 * (t1 - t0)
            stage["plan"] = 1e3 * (time.perf_counter() - t1)
        controller_ms = sum(stage.get(k, 0.0) for k in CONTROLLER_STAGES)
        missed = controller_ms > 1e3 * self.period_s
        if missed:
            log.warning(
                "cycle %d missed its %.0f ms deadline: controller took %.1f ms (%s)",
                index,
                1e3 * self.period_s,
                controller_ms,
                ", ".join(f"{k} {v:.1f}" for k, v in stage.items()),
            )
        send_ms = 0.0
        # Without a usable estimate nothing new is planned; an open-loop plan (single-step) keeps running.
        if not reading.lost or (not replan and self.replanner.trajectory is not None):
            t_grid = state.t + self.setpoint_period_s * np.arange(self.samples_per_cycle)
            p, v = self.replanner.references(t_grid)
            t2 = time.perf_counter()
            self.robot.send(Setpoints(t_grid, p, v))
            send_ms = 1e3 * (time.perf_counter() - t2)
        return CycleRecord(
            index,
            state.t,
            np.asarray(reading.position, dtype=float),
            truth,
            reading.measured,
            reading.lost,
            np.asarray(state.position[0]),
            action,
            stage,
            controller_ms,
            send_ms,
            missed,
            reading.pixel,
            reading.polyline_uv,
            reading.continued,
        )

    def _pace(self, t_robot_before: float, wall_before: float) -> None:
        """Keep the period on a real robot: wait out the rest of it in wall time.

        A simulated robot advances its own clock by a period inside ``send`` and needs no waiting; a real
        driver returns at once and its clock runs with the wall clock.
        """
        advanced = self.robot.state().t - t_robot_before
        if advanced >= self.period_s - 1e-9:
            return
        remaining = self.period_s - (time.monotonic() - wall_before)
        if remaining > 0:
            time.sleep(remaining)

    def finish_plan(self, duration_s: float) -> None:
        """Send the rest of the current plan for ``duration_s`` of robot time, without re-planning.

        This is what the environment does after a multi-step episode's last decision (the plan ends at rest),
        so a loop episode ends like the environment's. No frames are read; the robot's safety layers apply.
        """
        if not duration_s > 0:
            raise ValueError(f"duration_s must be > 0, got {duration_s!r}")
        t0 = self.robot.state().t
        times = t0 + self.setpoint_period_s * np.arange(int(round(duration_s / self.setpoint_period_s)))
        if times.size:
            self.robot.send(Setpoints(times, *self.replanner.references(times)))

    def run(
        self,
        duration_s: float,
        done: Callable[[], bool] | None = None,
        on_cycle: Callable[[CycleRecord, Any], None] | None = None,
        replan_every_cycle: bool = True,
    ) -> LoopReport:
        """Cycle until ``duration_s`` of robot time has passed, ``done()`` is true, or the estimate is lost.

        Args:
            duration_s: How long to re-plan, in robot time.
            done: Optional early end (e.g. the task's goal was reached).
            on_cycle: Called after every cycle with the record and the source's latest frame (for videos).
            replan_every_cycle: Multi-step policies re-plan every cycle; a single-step policy plans once, in
                the first cycle, and the loop then keeps perceiving and sending the same trajectory.
        """
        report = LoopReport()
        t_start = self.robot.state().t
        index = 0
        try:
            while True:
                t = self.robot.state().t
                if t - t_start >= duration_s - 1e-9:
                    report.stop_reason = "duration"
                    break
                wall0 = time.monotonic()
                record = self.cycle(index, replan=replan_every_cycle or index == 0)
                self._pace(t, wall0)
                report.cycles.append(record)
                if on_cycle is not None:
                    on_cycle(record, getattr(self.source, "last_frame", None))
                index += 1
                if record.lost and (replan_every_cycle or index == 1):
                    log.error(
                        "P_DLO estimate lost at t=%.3f s (no usable measurement): stopping the robot",
                        record.t,
                    )
                    self.robot.stop()
                    report.stop_reason = "lost"
                    break
                if done is not None and done():
                    report.stop_reason = "done"
                    break
        except BaseException:
            log.exception("control loop failed: stopping the robot")
            self.robot.stop()
            raise
        return report
