"""The real-robot loop of ``dyndlo-vision run``: checks, connection, the first plan's joint check, the 25 Hz
loop, braking, and what the report needs.

Order (:func:`run_session`): the policy is resolved and loaded, the arm placed (``robot.base_pose``,
``robot.tool_offset``; joint velocity and acceleration limits scaled by ``safety.joint_margin``), the driver
connects (failing after ``robot.connect_timeout_s``), the TCP must be at the task's home, the camera's first
frame must show the cable's tip, and the first plan (from that first observation) is checked *whole* on the
arm's joint limits exactly as the driver checks it (IK with the tool down, joined to the joints the arm is
at, the driver's braking tail; after the workspace and speed clamps). Any of these failing raises
:class:`RunRefused` (a ``ValueError``): nothing has moved. Then :class:`~dyndlo_vision.control.loop.
ControlLoop` runs at 25 Hz: the driver behind :class:`~dyndlo_vision.control.horizon.HorizonRobot`, the
policy's first action being the one checked.

The pieces: :mod:`~.robot_setup` (the checks before anything moves), :mod:`~.robot_perception` (the camera
and tracker), :mod:`~.horizon` (plans streamed to the driver), :mod:`~.robot_report` (the metrics).

Ends: the plan's end plus the task's settle time, ``safety.duration_s``, a lost estimate (multi-step), a
silent or faulted robot (``driver.fault``), a plan the driver refuses, any exception, Ctrl-C. Each brakes
(``stop``), closes the driver and returns what was recorded so far, with the reason.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.control.horizon import HorizonRobot
from dyndlo_vision.control.loop import ControlLoop, CycleRecord
from dyndlo_vision.control.robot_perception import build_source, camera_calibration
from dyndlo_vision.control.robot_report import RunResult, robot_series, run_metrics, simulated_outcome
from dyndlo_vision.control.robot_setup import (
    RunRefused,
    arm_kinematics,
    check_first_plan,
    describe_robot,
    load_policy,
    resolve_policy,
    start_driver,
)
from dyndlo_vision.control.run_config import RunConfig
from dyndlo_vision.robots.safety import WorkspaceBox
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S, observation_vector

__all__ = ["HorizonRobot", "RunRefused", "RunResult", "run_session"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
#: Exit statuses of a run that started moving and ended early.
EXIT_STOPPED, EXIT_INTERRUPTED = 1, 130


class _FirstAction:
    """The policy, except that its first answer is the action whose plan was checked before the start."""

    def __init__(self, policy: Callable[[Any], Any], first: NDArray[np.float32]) -> None:
        self.policy, self.first, self.calls = policy, first, 0

    def __call__(self, obs: Any) -> Any:
        self.calls += 1
        return self.first if self.calls == 1 else self.policy(obs)


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
    from dyndlo_vision.control.sim_env import as_sim_env
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
    policy = load_policy(name, env, kin, box)
    driver, fake = start_driver(cfg, arm, kin, true_model, home, dry_run)
    say(f"connecting to {describe_robot(cfg, dry_run)} (timeout {cfg.robot.connect_timeout_s:g} s)")
    try:
        try:
            driver.connect()
        except (TimeoutError, OSError) as exc:
            raise RunRefused(f"robot unreachable: {describe_robot(cfg, dry_run)}: {exc}") from None
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
    source, camera = build_source(cfg, env, driver, calib)
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
        outcome, trace = simulated_outcome(base, goal, records, truth_t + [camera.robot_time()], truth,
                                           replan_end_t)
        film(None, None, f"{'HIT' if outcome['success'] else 'miss'}, tip "
             f"{100 * outcome['final_distance_m']:.1f} cm from target centre")
    metrics = run_metrics(cfg, dry_run, name, note, multi_step, exit_code, stop_reason, records, outcome,
                          first_plan, robot, driver, fake, kin, true_model, limit_usage, source)
    return RunResult(exit_code, stop_reason, records, frames, metrics, trace,
                     robot_series(driver, goal, cfg.robot.arm))
