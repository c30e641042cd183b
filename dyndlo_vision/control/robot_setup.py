"""Before the real-robot loop moves anything: the policy, the placed arm, the driver, the first plan's check.

Each check that fails raises :class:`RunRefused` (a ``ValueError``): nothing has moved.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from dyndlo_vision.control.dry_run import JointRecorder
from dyndlo_vision.control.run_config import SCRIPTED_PREFIX, RunConfig
from dyndlo_vision.robots.egm import EgmRobot
from dyndlo_vision.robots.protocol import Setpoints, TcpState
from dyndlo_vision.robots.rtde import RtdeRobot
from dyndlo_vision.robots.safety import WorkspaceBox, clamp_setpoints

__all__ = [
    "RunRefused", "arm_kinematics", "check_first_plan", "describe_robot", "load_policy", "make_driver",
    "resolve_policy", "start_driver",
]

#: How long a dry run's driver waits for the fake controller before it faults (the fake shares this
#: process's CPU; a real robot gets the driver's default of 0.5 s).
DRY_RUN_ANSWER_TIMEOUT_S = 2.0


class RunRefused(ValueError):
    """The run cannot start (nothing has moved): the message says why."""


class RecordingEgmRobot(JointRecorder, EgmRobot):
    """:class:`EgmRobot` that records what it received and answered."""


class RecordingRtdeRobot(JointRecorder, RtdeRobot):
    """:class:`RtdeRobot` that records what it received and answered."""


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


def make_driver(cfg: RunConfig, arm: Any, kin: Any, dry_run: bool,
                fake_ports: tuple[int, int] | None) -> Any:
    """The recording driver of ``cfg.robot.driver``; a dry run's points at the fake controller on
    loopback (``fake_ports``: its RTDE and script ports)."""
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


def start_driver(cfg: RunConfig, arm: Any, kin: Any, true_model: Any, home: Any,
                 dry_run: bool) -> tuple[Any, Any]:
    """The driver, not yet connected, and in a dry run the fake controller it talks to (else None), its arm
    (``true_model``) at rest with the TCP at ``home``."""
    if not dry_run:
        return make_driver(cfg, arm, kin, False, None), None
    from dyndlo_vision.control.dry_run import start_fake_controller

    q0 = kin.ik(home).q
    if cfg.robot.driver == "egm":
        driver = make_driver(cfg, arm, kin, True, None)
        fake = start_fake_controller("egm", true_model, q0, egm_port=driver.bind())
    else:
        fake = start_fake_controller("rtde", true_model, q0)
        driver = make_driver(cfg, arm, kin, True, (fake.rtde_port, fake.script_port))
    return driver, fake


def load_policy(name: str, env: Any, kin: Any, box: WorkspaceBox) -> Callable[[Any], Any]:
    """The policy ``name`` (:func:`resolve_policy`) as ``observation -> action``, deterministic; a scripted
    one plans only to points the arm reaches with the tool down inside ``box``."""
    import dyndlo_vision.policies as policies
    from dyndlo_vision.control.scripted import scripted_policy
    from dyndlo_vision.control.sim_env import as_sim_env
    from dyndlo_vision.policies.actor import deterministic_policy

    def reachable(p: Any) -> bool:
        try:
            kin.ik(np.asarray(p, dtype=float))
        except ValueError:
            return False
        return bool(box.contains(p))

    if name.startswith(SCRIPTED_PREFIX):
        return scripted_policy(name[len(SCRIPTED_PREFIX):], as_sim_env(env).spec_actions, reachable)
    model = policies.load(name, env=env)
    if hasattr(model, "reset"):
        model.reset()  # a policy with a P_DLO history (one run is one episode)
    return deterministic_policy(model)


def describe_robot(cfg: RunConfig, dry_run: bool) -> str:
    """Where the driver connects to, for the progress lines."""
    if dry_run:
        return f"the fake {cfg.robot.driver.upper()} controller on loopback"
    if cfg.robot.driver == "egm":
        return f"an ABB controller sending EGM to UDP port {cfg.robot.port}"
    return f"the UR controller at {cfg.robot.host}:{cfg.robot.port} (RTDE)"


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
