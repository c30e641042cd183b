"""Streaming a re-planned trajectory to a real arm's driver: :class:`HorizonRobot`.

Sending a streaming driver one 40 ms window per cycle, as the simulated robot is sent, would make it brake at
the end of every window whenever a cycle runs late; :class:`HorizonRobot` sends the rest of the current plan
instead (from the last joint target sent on), so a late cycle changes nothing and a lost one leaves the robot
finishing a plan that ends at rest.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.robots.kinematics import JointLimitError
from dyndlo_vision.robots.protocol import Setpoints, TcpState
from dyndlo_vision.robots.safety import ClampedRobot, WorkspaceBox
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
from dyndlo_vision.tracking.params import LOOP_FILTER

__all__ = ["HorizonRobot"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
#: Plans start this far ahead of the robot's measured time (two control periods): longer than a cycle takes
#: from reading the robot to the driver accepting the plan (see :class:`HorizonRobot`).
PLAN_LEAD_S = 2 * CONTROL_PERIOD_S
#: The first plan starts this far ahead: its cycle also simulates or waits for the first frames and the driver
#: solves IK for the whole plan; the arm is at rest until then, so a long lead costs nothing.
FIRST_PLAN_LEAD_S = 0.25
#: The shortest span of setpoints sent: a plan that has (nearly) ended is held this long, longer than the
#: driver may take to accept it on a loaded machine.
MIN_HORIZON_S = 0.25
#: The lead grows to this multiple of the longest cycle latency (reading the robot to the driver accepting the
#: plan) among the last :data:`LEAD_WINDOW` plans, between ``lead_s`` and :data:`MAX_PLAN_LEAD_S`.
LEAD_FACTOR, LEAD_WINDOW = 1.5, 12
#: A plan is sent only if it starts later than the driver's last target plus this multiple of the longest of
#: the last sends, plus a driver period (a send's IK takes that long before the driver joins the plan).
SEND_MARGIN = 1.25
#: The most the lead adapts to: P_DLO is predicted a lead past the newest frame, and the loop's filter reports
#: it lost past ``max_coast_s`` (0.3 s), so a longer lead would lose it whenever a frame or two is missed.
#: Plans that still arrive late are dropped (the robot goes on with the plans it has, which end at rest).
MAX_PLAN_LEAD_S = round(LOOP_FILTER.max_coast_s - 2 * CONTROL_PERIOD_S, 6)
#: Tries at the first plan: each starts it later, by twice what the failed try took (the arm is at rest).
FIRST_PLAN_TRIES = 4


class _CommandedView:
    """The driver seen from its last joint target: the clamps start from where the robot was *told* to be."""

    def __init__(self, driver: Any) -> None:
        self.driver = driver
        #: The commanded state the setpoints being sent were made from (None: the driver's latest).
        self.snapshot: TcpState | None = None

    def connect(self) -> None:
        self.driver.connect()

    def state(self) -> TcpState:
        return self.snapshot if self.snapshot is not None else self.driver.commanded_state()

    def send(self, setpoints: Setpoints) -> None:
        self.driver.send(setpoints)

    def stop(self) -> None:
        self.driver.stop()

    def close(self) -> None:
        self.driver.close()


class HorizonRobot:
    """The loop's robot: a state ``lead_s`` ahead for the controller, the rest of the plans for the driver.

    Latency: a cycle reads the robot's state, then grabs and tracks a frame, asks the policy, plans, and the
    driver solves IK for the plan before it takes over; all that takes tens of milliseconds, during which the
    robot goes on following the plans it has. So :meth:`state` reports the measured TCP at the time
    ``measured t + lead_s`` (never before the current plan's start): the loop plans from there (P_DLO
    predicted to it, the new plan starting there from where the current plan is then, as the environment's
    plans join and as ``PlanFeasibility`` judges them in training). With a lead longer than the period
    several plans are pending at once; what is sent follows, at each instant, the newest plan that has started
    by then.

    A loaded computer: the lead adapts. After each plan it becomes :data:`LEAD_FACTOR` times the longest
    latency of the last :data:`LEAD_WINDOW` plans (robot time from :meth:`state` to the driver accepting the
    plan), never below ``lead_s`` nor above ``max_lead_s``. A plan that would still arrive after its start
    (the driver has sent targets past it, or will have by the time its IK is done, judged from the last sends)
    would join mid-way, with a jump, so it is not sent:

    * the first plan is started later (the arm is at rest at home until it starts, so this is exact);
    * a later plan is dropped: the replanner goes back to the last plan sent, the robot goes on with the plans
      it has, and the next cycle plans again. :attr:`plans_late` counts them.

    A send slower than the recent ones can still deliver a plan after its start. The driver then joins it only
    if the joined targets keep every joint limit; if they do not, the plan is handled as above (the first
    tried again later, a later one dropped). :attr:`max_late_s` records, over the plans sent, (driver's last
    target time at acceptance) - (plan's start): negative when every plan arrived in time.

    ``send`` ignores the loop's one-period window except as a signal: when there is a new plan it sends, from
    the driver's last target on, that piecewise plan to the newest plan's end (at least :data:`MIN_HORIZON_S`,
    holding the end), on the driver's cycle, through the workspace and speed clamps; without one it sends
    nothing (the driver has it all, ending at rest: a single-step plan is sent once).

    Args:
        driver: The connected streaming driver.
        replanner: The loop's replanner (its current trajectory is the newest plan).
        box: Workspace box of the TCP.
        max_speed_m_s: TCP speed limit.
        lead_s: How far ahead of the measured time plans start, at least (the lead adapts above it).
        first_lead_s: The same for the first plan (the arm at rest); at least ``lead_s``.
        replans: The loop re-plans every cycle (multi-step); without, the state is the measured one once the
            single plan is made (nothing more is planned, and the estimate is then for the present).
        max_lead_s: The most the lead adapts to; at least ``lead_s``.
    """

    def __init__(self, driver: Any, replanner: Any, box: WorkspaceBox, max_speed_m_s: float,
                 lead_s: float = PLAN_LEAD_S, first_lead_s: float = FIRST_PLAN_LEAD_S,
                 replans: bool = True, max_lead_s: float = MAX_PLAN_LEAD_S) -> None:
        if not lead_s >= 0.0:
            raise ValueError(f"lead_s must be >= 0, got {lead_s}")
        self.first_lead_s = max(float(first_lead_s), float(lead_s))
        self.replans = bool(replans)
        self.driver = driver
        self.replanner = replanner
        self._view = _CommandedView(driver)
        self.clamped = ClampedRobot(self._view, box, max_speed_m_s)
        self.period_s = float(driver.period_s)
        #: The configured (smallest) lead, and the lead now (adapted to the cycle latency).
        self.min_lead_s = float(lead_s)
        self.max_lead_s = max(float(max_lead_s), self.min_lead_s)
        self.lead_s = self.min_lead_s
        #: The largest the lead became.
        self.lead_max_used_s = self.lead_s
        self.sends = 0
        self.unchanged = 0  # cycles that had no new plan to send
        self.clamped_sends = 0
        #: Plans dropped because they would have arrived after their start (see the class docstring).
        self.plans_late = 0
        #: How much later than planned the first plan started (0 when it was in time).
        self.first_plan_delay_s = 0.0
        #: Largest (time the driver had sent targets up to when it accepted a new plan) - (the plan's start).
        self.max_late_s = -math.inf
        self._plans: list[Any] = []  # sent plans, oldest first, with non-decreasing start times
        self._state_t = math.nan  # the measured time of the latest state() (the cycle's start)
        self._latencies: list[float] = []  # robot time from state() to a plan's acceptance, latest last
        self._send_s: list[float] = []  # robot time each send took, latest last

    def connect(self) -> None:
        """The driver is connected before the loop starts."""

    def state(self) -> TcpState:
        """The measured TCP, stamped ``lead_s`` ahead (see the class docstring)."""
        s = self.driver.state()
        self._state_t = float(s.t)
        traj = self.replanner.trajectory
        if traj is None:
            return TcpState(s.position, s.velocity, float(s.t) + self.first_lead_s)
        if not self.replans:
            return s
        return TcpState(s.position, s.velocity, max(float(s.t) + self.lead_s, float(traj.t_start)))

    def references(self, times: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Positions and velocities (K, 1, 3) of what is sent: at each time the newest plan started by then
        (before the first plan starts, the replanner's home at rest)."""
        if not self._plans:
            return self.replanner.references(times)
        starts = np.array([float(p.t_start) for p in self._plans])
        which = np.searchsorted(starts, times, side="right") - 1
        p = np.empty((times.size, 3))
        v = np.zeros((times.size, 3))
        before = which < 0
        if np.any(before):  # the arm at rest where the first plan starts (only before the first plan)
            p[before] = np.asarray(self._plans[0].points[0], dtype=float)
        for k in np.unique(which[~before]):
            sel = which == k
            p[sel] = self._plans[k].position(times[sel])
            v[sel] = self._plans[k].velocity(times[sel])
        return p[:, None, :], v[:, None, :]

    def send(self, setpoints: Setpoints) -> None:
        """Send the plans' rest (see the class docstring)."""
        traj = self.replanner.trajectory
        new_plan = traj is not None and (not self._plans or traj is not self._plans[-1])
        if not new_plan and self.sends:
            # The driver holds the whole of the plans already (they end at rest): nothing new to send.
            self.unchanged += 1
            return
        if not new_plan:
            self._send_rest()
            return
        first = not self._plans
        tries = FIRST_PLAN_TRIES if first else 1
        delay = self._send_allowance()
        for attempt in range(tries):
            t_join = float(self.driver.commanded_state().t) + delay
            if traj.t_start < t_join:  # it would reach the robot after its start
                if not first:
                    self._drop_late(traj)
                    return
                traj = self._start_first_plan_later(traj, t_join)
            t_before = float(self.driver.commanded_state().t)
            self._plans.append(traj)
            try:
                self._send_rest()
                break
            except JointLimitError as exc:
                self._plans.pop()
                now = float(self.driver.commanded_state().t)
                if not (exc.at_join and now >= traj.t_start) or (first and attempt == tries - 1):
                    raise  # the plan itself breaks a limit (not a matter of time), or no try was in time
                if not first:
                    self._drop_late(traj)
                    return
                delay = 2.0 * max(now - t_before, self.period_s)
                log.warning("first plan reached the robot after its start (sending took %.3f s): "
                            "starting it later", now - t_before)
        t_after = float(self.driver.commanded_state().t)
        self._send_s = (self._send_s + [t_after - t_before])[-LEAD_WINDOW:]
        self.max_late_s = max(self.max_late_s, t_after - float(traj.t_start))
        if math.isfinite(self._state_t):
            self._latencies = (self._latencies + [t_after - self._state_t])[-LEAD_WINDOW:]
            self.lead_s = min(self.max_lead_s, max(self.min_lead_s, LEAD_FACTOR * max(self._latencies)))
            self.lead_max_used_s = max(self.lead_max_used_s, self.lead_s)

    def _send_allowance(self) -> float:
        """Robot time a send is expected to take: the longest recent send, with margin, plus a period."""
        return SEND_MARGIN * max(self._send_s, default=0.0) + self.period_s

    def _start_first_plan_later(self, traj: Any, t_start: float) -> Any:
        """The first plan, starting at ``t_start`` instead (exact: the arm rests at its start until then)."""
        self.first_plan_delay_s += t_start - float(traj.t_start)
        later = traj.shifted(t_start - float(traj.t_start))
        self.replanner.trajectory = later
        return later

    def _drop_late(self, traj: Any) -> None:
        """Not send a plan that would arrive after its start; go back to the last plan sent."""
        self.plans_late += 1
        self.replanner.trajectory = self._plans[-1]
        log.warning("plan for t=%.3f s dropped: it would reach the robot after its start (lead %.0f ms); "
                    "the robot goes on with the plans it has", traj.t_start, 1e3 * self.lead_s)

    def _send_rest(self) -> None:
        """Send the plans from the driver's last target on (see the class docstring)."""
        traj = self.replanner.trajectory
        commanded = self.driver.commanded_state()
        self._view.snapshot = commanded  # the clamps start from the state the setpoints start after
        t0 = float(commanded.t)
        while len(self._plans) > 1 and self._plans[1].t_start <= t0:
            self._plans.pop(0)  # superseded before the first time still to send
        t_end = max(t0 if traj is None else float(traj.t_end), t0 + MIN_HORIZON_S)
        times = t0 + self.period_s * np.arange(1, math.ceil((t_end - t0) / self.period_s - 1e-9) + 1)
        p, v = self.references(times)
        self.clamped.send(Setpoints(times, p, v))
        self.sends += 1
        self.clamped_sends += int(self.clamped.last_report.changed)

    def stop(self) -> None:
        """Brake."""
        self.driver.stop()

    def close(self) -> None:
        """Brake and close the driver."""
        self.driver.close()
