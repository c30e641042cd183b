"""The real-robot loop of ``dyndlo-vision run``: checks, connection, the first plan's joint check, the 25 Hz
loop, braking, and what the report needs.

Order (:func:`run_session`): the policy is resolved and loaded, the arm placed (``robot.base_pose``,
``robot.tool_offset``; joint velocity and acceleration limits scaled by ``safety.joint_margin``), the driver
connects (failing after ``robot.connect_timeout_s``), the TCP must be at the task's home, the camera's first
frame must show the cable's tip, and the first plan (from that first observation) is checked *whole* on the
arm's joint limits exactly as the driver checks it (IK with the tool down, joined to the joints the arm is
at, the driver's braking tail; after the workspace and speed clamps). Any of these failing raises
:class:`RunRefused` (a ``ValueError``): nothing has moved. Then :class:`~dyndlo_vision.control.loop.
ControlLoop` runs at 25 Hz: the driver behind :class:`~dyndlo_vision.robots.safety.ClampedRobot`, the policy's
first action being the one checked.

Sending a streaming driver one 40 ms window per cycle, as the simulated robot is sent, would make it brake at
the end of every window whenever a cycle runs late; :class:`HorizonRobot` sends the rest of the current plan
instead (from the last joint target sent on), so a late cycle changes nothing and a lost one leaves the robot
finishing a plan that ends at rest.

Ends: the plan's end plus the task's settle time, ``safety.duration_s``, a lost estimate (multi-step), a
silent or faulted robot (``driver.fault``), a plan the driver refuses, any exception, Ctrl-C. Each brakes
(``stop``), closes the driver and returns what was recorded so far, with the reason.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.control.dry_run import JointRecorder
from dyndlo_vision.control.loop import ControlLoop, CycleRecord
from dyndlo_vision.control.run_config import SCRIPTED_PREFIX, RunConfig
from dyndlo_vision.robots.egm import EgmRobot
from dyndlo_vision.robots.kinematics import JointLimitError
from dyndlo_vision.robots.protocol import Setpoints, TcpState
from dyndlo_vision.robots.rtde import RtdeRobot
from dyndlo_vision.robots.safety import ClampedRobot, WorkspaceBox, clamp_setpoints
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S, observation_vector
from dyndlo_vision.tracking.params import LOOP_FILTER

__all__ = ["HorizonRobot", "RunRefused", "RunResult", "run_session"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
#: Exit statuses of a run that started moving and ended early.
EXIT_STOPPED, EXIT_INTERRUPTED = 1, 130
#: How long a dry run's driver waits for the fake controller before it faults (the fake shares this
#: process's CPU; a real robot gets the driver's default of 0.5 s).
DRY_RUN_ANSWER_TIMEOUT_S = 2.0
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


class RunRefused(ValueError):
    """The run cannot start (nothing has moved): the message says why."""


class RecordingEgmRobot(JointRecorder, EgmRobot):
    """:class:`EgmRobot` that records what it received and answered."""


class RecordingRtdeRobot(JointRecorder, RtdeRobot):
    """:class:`RtdeRobot` that records what it received and answered."""


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


class _FirstAction:
    """The policy, except that its first answer is the action whose plan was checked before the start."""

    def __init__(self, policy: Callable[[Any], Any], first: NDArray[np.float32]) -> None:
        self.policy, self.first, self.calls = policy, first, 0

    def __call__(self, obs: Any) -> Any:
        self.calls += 1
        return self.first if self.calls == 1 else self.policy(obs)


@dataclass
class RunResult:
    """What a run recorded, for the report."""

    exit_code: int
    stop_reason: str
    records: list[CycleRecord]
    frames: list[NDArray[np.uint8]]
    metrics: dict[str, Any]
    #: The demo's P_DLO plot data (``commands.demo._write_plot``) when the truth is known (simulated camera).
    trace: dict[str, Any] | None
    #: Robot time series: measured and target joints, for the robot plot.
    robot: dict[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------ set-up
def arm_kinematics(cfg: RunConfig) -> tuple[Any, Any, Any]:
    """(RobotArm entry, placed kinematics with the margin-scaled limits, the arm's own model)."""
    from dyndlo_vision.robots.feasibility import ROBOT_ARMS
    from dyndlo_vision.robots.kinematics import ArmKinematics, pose_matrix, rotation_x, rotation_y, rotation_z

    arm = ROBOT_ARMS[cfg.robot.arm]
    if cfg.robot.base_pose is None:
        base = pose_matrix(arm.base_in_world)
    else:
        x, y, z, roll, pitch, yaw = cfg.robot.base_pose
        rot = rotation_z(math.radians(yaw)) @ rotation_y(math.radians(pitch)) @ rotation_x(math.radians(roll))
        base = pose_matrix((x, y, z), rot)
    model = arm.model()
    margin = cfg.safety.joint_margin
    kin = ArmKinematics(model.scaled_limits(margin, margin), base_in_world=base,
                        tcp_in_flange=pose_matrix(cfg.robot.tool_offset))
    return arm, kin, model


def resolve_policy(cfg: RunConfig) -> tuple[str, dict[str, Any], str | None]:
    """The policy to run (``policy``, or ``fallback_policy`` when ``policy`` is not installed), its
    metadata, and a note when the fallback was taken.

    Raises:
        FileNotFoundError: Neither is installed (no fallback given).
        ValueError: A policy for another task.
    """
    import dyndlo_vision.policies as policies

    def meta_of(name: str) -> dict[str, Any]:
        if name.startswith(SCRIPTED_PREFIX):
            from dyndlo_vision.control.scripted import MULTI_STEP

            return {"task": "tip-control", "multi_step": name[len(SCRIPTED_PREFIX):] in MULTI_STEP,
                    "scripted": True}
        return policies.resolve(name)[1]

    name, note = cfg.policy, None
    try:
        meta = meta_of(name)
    except FileNotFoundError as exc:
        if cfg.fallback_policy is None:
            raise FileNotFoundError(f"{cfg.path}: policy: {exc}") from None
        note = (f"policy {cfg.policy!r} is not installed; running fallback_policy {cfg.fallback_policy!r}")
        name = cfg.fallback_policy
        meta = meta_of(name)
    if meta.get("task", "tip-control") != cfg.task:
        raise ValueError(f"{cfg.path}: policy {name!r} is for task {meta.get('task')!r}, not {cfg.task!r}")
    return name, meta, note


def _make_driver(cfg: RunConfig, arm: Any, kin: Any, dry_run: bool,
                 fake_ports: tuple[int, int] | None) -> Any:
    timeouts = {"connect_timeout_s": cfg.robot.connect_timeout_s}
    if dry_run:
        timeouts["answer_timeout_s"] = DRY_RUN_ANSWER_TIMEOUT_S
    if cfg.robot.driver == "egm":
        port = 0 if dry_run else cfg.robot.port
        return RecordingEgmRobot(kin, port=port, period_s=arm.period_s, **timeouts)
    host, rtde_port, script_port = cfg.robot.host or "", cfg.robot.port, cfg.robot.script_port
    if dry_run:
        assert fake_ports is not None
        host, (rtde_port, script_port) = "127.0.0.1", fake_ports
    return RecordingRtdeRobot(host, kin, rtde_port=rtde_port, script_port=script_port,
                              frequency_hz=1.0 / arm.period_s, **timeouts)


def _where(cfg: RunConfig, dry_run: bool) -> str:
    if dry_run:
        return f"the fake {cfg.robot.driver.upper()} controller on loopback"
    if cfg.robot.driver == "egm":
        return f"an ABB controller sending EGM to UDP port {cfg.robot.port}"
    return f"the UR controller at {cfg.robot.host}:{cfg.robot.port} (RTDE)"


def _build_source(cfg: RunConfig, env: Any, driver: Any, calib: Any) -> tuple[Any, Any]:
    """The P_DLO source and the camera the video is read from (see the module docstring): the loop's
    perception pipeline on the configured camera."""
    from dyndlo_vision.control.sim_perception import LoopPerception, loop_segmenter

    base = env.unwrapped
    segmenter = loop_segmenter(cfg.camera.segmenter)
    if cfg.camera.source == "simulated":
        from dyndlo_vision.control.dry_run import FollowingCamera, place_scene_camera
        from dyndlo_vision.control.sim_perception import tracked_state

        place_scene_camera(base.model, base.data, "tracking", calib)
        source, camera = tracked_state(env, "tracking", LoopPerception(segmenter, views=1), width=calib.width,
                                       height=calib.height)
        following = FollowingCamera(camera, env, driver)
        source.camera = following
        return source, following
    from dyndlo_vision.control.sim_perception import loop_pipeline_config
    from dyndlo_vision.control.state_sources import TrackedState
    from dyndlo_vision.tracking.params import LOOP_FILTER
    from dyndlo_vision.tracking.pipeline import CablePipeline
    from dyndlo_vision.tracking.segmenters import background_from, build_segmenter, build_view_segmenter

    camera: Any
    if cfg.camera.source == "video":
        from dyndlo_vision.cameras.files import VideoFileCamera

        camera = _RobotClockCamera(VideoFileCamera(cfg.camera.path, fps=cfg.camera.fps), driver)
    elif cfg.camera.source == "device":
        from dyndlo_vision.cameras.devices import OpenCVDeviceCamera

        camera = OpenCVDeviceCamera(cfg.camera.device, width=calib.width, height=calib.height)
    else:
        from dyndlo_vision.cameras.devices import RealSenseCamera

        camera = RealSenseCamera(width=calib.width, height=calib.height)
    background = None
    if segmenter.kind == "background":
        try:
            background = background_from(cfg.camera.background)
        except ValueError as exc:
            raise ValueError(f"{cfg.path}: camera.background: {exc}") from None
    # A real camera's frames are the calibration's own size: the shipped network at its own input size.
    if segmenter.kind == "learned":
        segmenter = replace(segmenter, model=None, scale=None)
    config = loop_pipeline_config(base.scene, 1.0, segmenter, LOOP_FILTER)
    config = replace(config, reach_margin_m=None, follow_px=None, floor=None)
    base_segmenter, _ = build_segmenter(segmenter, frame_size=(calib.width, calib.height),
                                        background_image=background)
    view = build_view_segmenter(base_segmenter, camera=calib, gripper_radius_px=0.0)
    source = TrackedState(camera, CablePipeline(config, [calib], [view]))
    return source, camera


class _RobotClockCamera:
    """A replayed video, each frame stamped with the robot's time when it is read (as if live)."""

    clock = "robot"

    def __init__(self, camera: Any, driver: Any) -> None:
        self.camera, self.driver = camera, driver

    def read(self) -> Any:
        from dyndlo_vision.cameras.protocol import Frame

        frame = self.camera.read()
        if frame is None:
            return None
        return Frame(rgb=frame.rgb, t_capture=float(self.driver.joints().t), index=frame.index,
                     depth=frame.depth)

    def close(self) -> None:
        self.camera.close()


def check_first_plan(kin: Any, period_s: float, replanner_factory: Callable[[], Any], action: Any,
                     state: TcpState, joints: Any, box: WorkspaceBox, max_speed: float) -> dict[str, Any]:
    """Check the whole first plan as the driver will receive it; returns its record.

    Raises:
        RunRefused: It leaves the arm's reach with the tool down, or breaks a joint limit.
    """
    from dyndlo_vision.robots.feasibility import joint_plan, limit_usage
    from dyndlo_vision.robots.kinematics import IKError

    trial = replanner_factory()
    traj = trial.replan(np.asarray(action, dtype=np.float64), state.t)
    t0 = float(joints.t)
    times = t0 + period_s * np.arange(1, math.ceil((traj.t_end - t0) / period_s - 1e-9) + 1)
    p, v = trial.references(times)
    clamped, clamp = clamp_setpoints(Setpoints(times, p, v), box, max_speed, state)
    hist_t, hist_q = np.array([t0 - period_s, t0]), np.array([joints.q, joints.q])
    record: dict[str, Any] = {
        "action": np.asarray(action, dtype=float).tolist(),
        "duration_s": float(traj.t_end - state.t),
        "clamped": {"positions_moved_into_box": clamp.positions_moved_into_box,
                    "steps_rate_limited": clamp.steps_rate_limited,
                    "max_speed_asked_m_s": clamp.max_speed_m_s},
    }
    try:
        plan = joint_plan(kin, clamped.t, clamped.position[:, 0], hist_t, hist_q, period_s)
    except IKError as exc:
        raise RunRefused(f"first plan refused, nothing sent: no joint solution with the tool down: {exc}"
                         ) from None
    record["joint_usage"] = limit_usage(kin.arm, plan.t, plan.q)
    if not plan.report.ok:
        worst = max(plan.report.violations, key=lambda v: abs(v.value) / max(abs(v.limit), 1e-12))
        raise RunRefused(
            f"first plan refused, nothing sent: {worst} (limits scaled by safety.joint_margin; "
            f"{len(plan.report.violations)} joint/quantity breaches in all; usage "
            + ", ".join(f"{k} {v:.3g}" for k, v in record["joint_usage"].items()) + ")"
        )
    return record


# ------------------------------------------------------------------------------------------------ the run
def run_session(cfg: RunConfig, dry_run: bool, say: Callable[[str], None] = print,
                annotate: Callable[..., NDArray[np.uint8]] | None = None) -> RunResult:
    """Run the configuration (see the module docstring).

    Args:
        cfg: The checked configuration.
        dry_run: Drive the fake controller of ``cfg.robot.driver`` on loopback instead of the robot.
        say: Progress lines.
        annotate: ``(rgb, record, calibration, goal) -> BGR frame`` for the video (None: no video).

    Raises:
        RunRefused, ValueError, FileNotFoundError: Before anything moved.
    """
    import dyndlo_vision.policies as policies
    from dyndlo_vision.control.scripted import scripted_policy
    from dyndlo_vision.control.sim_env import as_sim_env
    from dyndlo_vision.policies.actor import deterministic_policy
    from dyndlo_vision.tasks.registry import make_env
    from dyndlo_vision.tracking.camera_model import PinholeCamera
    from dyndlo_vision.trajectory import Replanner

    name, meta, note = resolve_policy(cfg)
    if note:
        say(f"note: {note}")
    multi_step = bool(meta.get("multi_step", False))
    calib = PinholeCamera.from_json(cfg.camera.calibration)
    arm, kin, true_model = arm_kinematics(cfg)
    env = make_env(cfg.task, multi_step=multi_step, **meta.get("env_options", {}))
    base = as_sim_env(env)
    goal = np.asarray(cfg.target, dtype=float)
    simulated = cfg.camera.source == "simulated"
    env.reset(seed=0, options={"goal": goal})
    home = np.asarray(base.scene.gripper_home[0], dtype=float)
    box = WorkspaceBox(cfg.safety.workspace_min, cfg.safety.workspace_max)
    if not box.contains(home):
        raise RunRefused(f"{cfg.path}: safety.workspace does not contain the task's home TCP {home.tolist()}")

    def reachable(p: FloatArray) -> bool:
        try:
            kin.ik(np.asarray(p, dtype=float))
        except ValueError:
            return False
        return bool(box.contains(p))

    if name.startswith(SCRIPTED_PREFIX):
        policy = scripted_policy(name[len(SCRIPTED_PREFIX):], base.spec_actions, reachable)
    else:
        model = policies.load(name, env=env)
        if hasattr(model, "reset"):
            model.reset()  # a policy with a P_DLO history (one run is one episode)
        policy = deterministic_policy(model)

    fake = None
    if dry_run:
        from dyndlo_vision.control.dry_run import start_fake_controller

        q0 = kin.ik(home).q
        if cfg.robot.driver == "egm":
            driver = _make_driver(cfg, arm, kin, True, None)
            fake = start_fake_controller("egm", true_model, q0, egm_port=driver.bind())
        else:
            fake = start_fake_controller("rtde", true_model, q0)
            driver = _make_driver(cfg, arm, kin, True, (fake.rtde_port, fake.script_port))
    else:
        driver = _make_driver(cfg, arm, kin, False, None)
    say(f"connecting to {_where(cfg, dry_run)} (timeout {cfg.robot.connect_timeout_s:g} s)")
    try:
        try:
            driver.connect()
        except (TimeoutError, OSError) as exc:
            raise RunRefused(f"robot unreachable: {_where(cfg, dry_run)}: {exc}") from None
        try:
            return _run_connected(cfg, dry_run, say, annotate, env, base, driver, fake, kin, true_model,
                                  arm, policy, name, note, multi_step, calib, goal, home, box, simulated,
                                  Replanner)
        finally:
            driver.close()  # brakes first; idempotent
    finally:
        if fake is not None:
            fake.close()


def _run_connected(cfg: RunConfig, dry_run: bool, say: Callable[[str], None], annotate: Any, env: Any,
                   base: Any, driver: Any, fake: Any, kin: Any, true_model: Any, arm: Any, policy: Any,
                   name: str, note: str | None, multi_step: bool, calib: Any, goal: FloatArray,
                   home: FloatArray, box: WorkspaceBox, simulated: bool, replanner_cls: Any) -> RunResult:
    from dyndlo_vision.robots.feasibility import limit_usage

    state = driver.state()
    tcp = state.position[0]
    off = float(np.linalg.norm(tcp - home))
    if off > cfg.robot.home_tolerance_m:
        raise RunRefused(
            f"the robot's TCP is at {np.round(tcp, 4).tolist()} m, {100 * off:.1f} cm from the task's home "
            f"{home.tolist()} (robot.home_tolerance_m {cfg.robot.home_tolerance_m:g}): move it there first "
            "(check robot.base_pose and robot.tool_offset)"
        )
    source, camera = _build_source(cfg, env, driver, calib)
    try:
        return _loop(cfg, dry_run, say, annotate, base, driver, fake, kin, true_model, arm, policy, name,
                     note, multi_step, camera, goal, box, simulated, replanner_cls, source, limit_usage)
    finally:
        camera.close()


def _loop(cfg: RunConfig, dry_run: bool, say: Callable[[str], None], annotate: Any, base: Any, driver: Any,
          fake: Any, kin: Any, true_model: Any, arm: Any, policy: Any, name: str, note: str | None,
          multi_step: bool, camera: Any, goal: FloatArray, box: WorkspaceBox, simulated: bool,
          replanner_cls: Any, source: Any, limit_usage: Any) -> RunResult:
    # ---------------------------------------------------------------- the first observation and plan
    state = driver.state()
    joints = driver.joints()
    reading = source.read(state.t, state)
    if reading.lost or not np.all(np.isfinite(reading.position)):
        raise RunRefused("no estimate of the cable's tip from the camera's first frame (is the cable in "
                         "view, the calibration right, the segmentation working?): nothing sent")
    obs = observation_vector(state.position, state.velocity, reading.position, goal)
    first_action = np.asarray(policy(obs), dtype=np.float32)

    def new_replanner() -> Any:
        return replanner_cls(base.spec_actions, state.position, base.task.final_point(goal))

    first_plan = check_first_plan(kin, arm.period_s, new_replanner, first_action, state, joints, box,
                                  cfg.safety.max_tcp_speed)
    say(f"first plan checked on the {cfg.robot.arm}'s joint limits: " +
        ", ".join(f"{k} {v:.3g}" for k, v in first_plan["joint_usage"].items()))
    # ---------------------------------------------------------------- the loop
    replanner = new_replanner()
    robot = HorizonRobot(driver, replanner, box, cfg.safety.max_tcp_speed, lead_s=cfg.robot.plan_lead_s,
                         replans=multi_step)
    t_start = float(robot.state().t)
    act = _FirstAction(policy, first_action)
    loop = ControlLoop(source, robot, act, replanner, goal, period_s=CONTROL_PERIOD_S,
                       setpoint_period_s=arm.period_s, truth=base.p_dlo if simulated else None)
    records: list[CycleRecord] = []
    frames: list[NDArray[np.uint8]] = []
    truth_t: list[float] = []
    truth: list[FloatArray] = []
    settle = float(base.task.settle_s)

    def film(record: CycleRecord | None, frame: Any, status: str | None = None) -> None:
        if annotate is None:
            return
        if frame is None and simulated:
            frame = camera.read()
        if frame is not None:
            frames.append(annotate(frame.rgb, record, camera_calibration(camera, source), goal, status=status,
                                   t=frame.t_capture, truth=base.p_dlo() if simulated else None))

    def on_cycle(record: CycleRecord, frame: Any) -> None:
        records.append(record)
        if simulated:
            truth_t.append(float(record.t))
            truth.append(np.asarray(record.p_dlo_true, dtype=float))
        film(record, frame)

    fault: list[str] = []

    def plan_over() -> bool:
        traj = replanner.trajectory
        return traj is not None and float(driver.state().t) >= traj.t_end + settle - 1e-9

    def done() -> bool:
        if driver.fault is not None:
            fault.append(driver.fault)
            return True
        if multi_step:
            return simulated and base.is_done_early()
        return plan_over()

    mode = "multi" if multi_step else "single"
    say(f"running {name} ({mode}-step) for at most {cfg.safety.duration_s:g} s")
    exit_code, stop_reason = 0, ""
    replan_end_t = t_start
    try:
        budget = cfg.safety.duration_s
        if multi_step:
            budget = min(budget, float(base.task.episode_s))
        report = loop.run(budget, done=done, on_cycle=on_cycle, replan_every_cycle=multi_step)
        replan_end_t = float(driver.state().t)
        stop_reason = report.stop_reason
        if fault:
            exit_code, stop_reason = EXIT_STOPPED, f"robot fault: {fault[0]}"
            driver.stop()
        elif stop_reason == "lost":
            exit_code, stop_reason = EXIT_STOPPED, "P_DLO estimate lost (the camera lost the cable)"
        elif stop_reason == "done" and not multi_step:
            stop_reason = "plan finished"
        elif stop_reason == "done":
            stop_reason = "target hit"
        elif multi_step and budget < cfg.safety.duration_s:
            stop_reason = "plan finished"  # the episode's re-planning time is over; its last plan runs out
        # Multi-step: the last plan runs out (it ends at rest), filmed, within the duration.
        while exit_code == 0 and multi_step and not plan_over():
            if driver.fault is not None:
                exit_code, stop_reason = EXIT_STOPPED, f"robot fault: {driver.fault}"
                break
            if float(robot.state().t) - t_start >= cfg.safety.duration_s:
                stop_reason = "duration"
                break
            wall = time.monotonic()
            film(None, None, "following the last plan")
            time.sleep(max(0.0, CONTROL_PERIOD_S - (time.monotonic() - wall)))
        if exit_code == 0 and stop_reason == "duration":
            stop_reason = "duration (safety.duration_s) before the plan finished"
    except KeyboardInterrupt:
        exit_code, stop_reason = EXIT_INTERRUPTED, "interrupted (Ctrl-C)"
        driver.stop()
    except Exception as exc:  # noqa: BLE001  (the loop stopped the robot; the report says why)
        exit_code = EXIT_STOPPED
        stop_reason = f"robot fault: {driver.fault}" if driver.fault else f"{type(exc).__name__}: {exc}"
        log.error("run stopped: %s", stop_reason)
    driver.close()  # brake to rest and wait for it
    # ---------------------------------------------------------------- what happened
    outcome: dict[str, Any] = {"success": None, "truth": "none: a real camera (no simulation)"}
    trace = None
    if simulated:
        camera.advance()  # the scene up to the robot's last state
        _, success, info = base.outcome()
        final = base.p_dlo()
        truth_t.append(camera.robot_time())
        truth.append(np.asarray(final, dtype=float))
        film(None, None, f"{'HIT' if success else 'miss'}, tip {100 * np.linalg.norm(final - goal):.1f} cm "
             "from target centre")
        outcome = {"success": bool(success), "truth": "the dry run's simulation (cable following the robot)",
                   "final_distance_m": float(np.linalg.norm(final - goal)),
                   "min_distance_m": float(info["min_distance_m"]), "avoid": info["avoid"],
                   "final_p_dlo_m": np.asarray(final).tolist()}
        trace = {
            "t": [r.t for r in records], "estimate": [r.p_dlo_estimate.tolist() for r in records],
            "measured": [r.measured for r in records], "truth_t": truth_t,
            "truth": [p.tolist() for p in truth],
            "goal": goal.tolist(), "success_radius_m": getattr(base.task, "success_radius_m", None),
            "replan_end_t": replan_end_t, "success": bool(success), "min_distance_m": info["min_distance_m"],
        }
    metrics = _metrics(cfg, dry_run, name, note, multi_step, exit_code, stop_reason, records, outcome,
                       first_plan, robot, driver, fake, kin, true_model, limit_usage, source)
    rec = driver.targets
    robot_series = {
        "t_measured": [m[0] for m in driver.measured], "q_measured": [m[1].tolist() for m in driver.measured],
        "t_target": [r[0] for r in rec if r[2]], "q_target": [r[1].tolist() for r in rec if r[2]],
        "goal": goal.tolist(), "arm": cfg.robot.arm,
    }
    return RunResult(exit_code, stop_reason, records, frames, metrics, trace, robot_series)


def camera_calibration(camera: Any, source: Any) -> Any:
    """The pinhole model the video overlay projects with (the tracker's)."""
    pipeline = getattr(source, "pipeline", None)
    return pipeline.views[0].camera if pipeline is not None else camera.calibration


def moving_targets_lost(sent: list[FloatArray], received: list[FloatArray], tol: float = 1e-9) -> int:
    """How many of the joint targets sent while moving (each differing from the one before) the robot never
    received. A target can be overwritten before the robot reads it (RTDE registers hold the latest value;
    the halt command on close overwrites the last, a repeat of the rest position, which is not counted)."""
    def distinct(qs: list[FloatArray]) -> list[FloatArray]:
        out: list[FloatArray] = []
        for q in qs:
            if not out or np.max(np.abs(q - out[-1])) > tol:
                out.append(np.asarray(q, dtype=float))
        return out

    sent_d, recv_d = distinct(sent), distinct(received)
    lost, k = 0, 0
    for q in sent_d:  # in order: the robot receives them in the order sent
        j = k
        while j < len(recv_d) and np.max(np.abs(recv_d[j] - q)) > tol:
            j += 1
        if j == len(recv_d):
            lost += 1
        else:
            k = j + 1
    return lost


def _metrics(cfg: RunConfig, dry_run: bool, name: str, note: str | None, multi_step: bool, exit_code: int,
             stop_reason: str, records: list[CycleRecord], outcome: dict[str, Any],
             first_plan: dict[str, Any],
             robot: HorizonRobot, driver: Any, fake: Any, kin: Any, true_model: Any, limit_usage: Any,
             source: Any) -> dict[str, Any]:
    controller = np.array([r.controller_ms for r in records]) if records else np.zeros(0)

    def pct(q: float) -> float | None:
        return float(np.percentile(controller, q)) if controller.size else None

    active = [(t, q) for t, q, a in driver.targets if a]
    sent_all = len(driver.targets)
    setpoints: dict[str, Any] = {
        "plans_sent": robot.sends,
        "cycles_without_new_plan": robot.unchanged,
        "plans_clamped": robot.clamped_sends,
        "plan_lead_s": robot.min_lead_s,
        "plan_lead_max_used_s": robot.lead_max_used_s,
        "plans_late": robot.plans_late,
        "first_plan_delay_s": robot.first_plan_delay_s,
        "plan_max_late_s": robot.max_late_s if math.isfinite(robot.max_late_s) else None,
        "joint_targets_sent": sent_all,
        "joint_targets_sent_moving": len(active),
        "robot_states_received": len(driver.measured),
    }
    if fake is not None:
        # The fake EGM controller records every answer, the fake UR script only the servo targets.
        expected = sent_all if cfg.robot.driver == "egm" else len(active)
        received = fake.received
        setpoints.update({"joint_targets_received_by_robot": len(received),
                          "joint_targets_expected": expected, "joint_targets_lost": expected - len(received),
                          "moving_targets_lost": moving_targets_lost([q for _, q in active],
                                                                     [r.q for r in received])})
    else:
        setpoints["joint_targets_received_by_robot"] = None  # the controller does not report it back
    usage: dict[str, Any] = {}
    if len(active) >= 3:
        t = np.array([a[0] for a in active])
        q = np.array([a[1] for a in active])
        usage = {"arm_limits": limit_usage(true_model, t, q), "margin_limits": limit_usage(kin.arm, t, q),
                 "joint_margin": cfg.safety.joint_margin, "samples": int(t.size)}
    errors = [np.linalg.norm(r.p_dlo_estimate - r.p_dlo_true) for r in records
              if r.p_dlo_true is not None and np.all(np.isfinite(r.p_dlo_estimate))]
    return {
        "config": str(cfg.path),
        "dry_run": dry_run,
        "driver": cfg.robot.driver,
        "arm": cfg.robot.arm,
        "camera": cfg.camera.source,
        "policy": name,
        "policy_requested": cfg.policy,
        "policy_note": note,
        "multi_step": multi_step,
        "target": list(cfg.target),
        "exit_status": exit_code,
        "stop_reason": stop_reason,
        **outcome,
        "estimate_rmse_m": float(np.sqrt(np.mean(np.square(errors)))) if errors else None,
        "estimate_note": (
            "each estimate is predicted to its plan's start (plan_lead_s after the frame); the truth is "
            "at the frame" if multi_step else
            "estimate and truth at the frame's time (the first estimate: predicted to the plan's start)"
        ),
        "cycles": len(records),
        "cycle_ms_p50": pct(50), "cycle_ms_p95": pct(95), "cycle_ms_p99": pct(99),
        "cycle_ms_max": float(controller.max()) if controller.size else None,
        "deadline_misses": int(sum(r.deadline_missed for r in records)),
        "send_ms_p95": float(np.percentile([r.send_ms for r in records], 95)) if records else None,
        "lost_cycles": int(sum(r.lost for r in records)),
        "measured_cycles": int(sum(r.measured for r in records)),
        "setpoints": setpoints,
        "joint_limits": usage,
        "first_plan": first_plan,
        "driver_fault": driver.fault,
        "safety": {"workspace_min": list(cfg.safety.workspace_min),
                   "workspace_max": list(cfg.safety.workspace_max),
                   "max_tcp_speed_m_s": cfg.safety.max_tcp_speed, "duration_s": cfg.safety.duration_s},
        "cycle_ms_note": "controller time per 40 ms cycle: camera (in a dry run: simulating the scene up to "
        "the robot's time and rendering) + tracking + filter + policy + planning",
    }
