"""What a real-robot run recorded, and the metrics of its report."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.control.episode import p_dlo_trace
from dyndlo_vision.control.horizon import HorizonRobot
from dyndlo_vision.control.loop import CycleRecord
from dyndlo_vision.control.run_config import RunConfig

__all__ = ["RunResult", "moving_targets_lost", "robot_series", "run_metrics", "simulated_outcome"]

FloatArray = NDArray[np.float64]


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


def simulated_outcome(base: Any, goal: FloatArray, records: list[CycleRecord], truth_t: list[float],
                      truth: list[FloatArray], replan_end_t: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """A dry run's outcome, judged on its simulation as it stands, and the P_DLO plot's data.

    ``truth_t``, ``truth``: the simulation's P_DLO at each cycle; the final one (now) is appended.
    """
    _, success, info = base.outcome()
    final = base.p_dlo()
    truth = truth + [np.asarray(final, dtype=float)]
    outcome = {"success": bool(success), "truth": "the dry run's simulation (cable following the robot)",
               "final_distance_m": float(np.linalg.norm(final - goal)),
               "min_distance_m": float(info["min_distance_m"]), "avoid": info["avoid"],
               "final_p_dlo_m": np.asarray(final).tolist()}
    return outcome, p_dlo_trace(records, truth_t, truth, goal, base.task, replan_end_t, success,
                                info["min_distance_m"])


def robot_series(driver: Any, goal: FloatArray, arm: str) -> dict[str, Any]:
    """Measured and target joints over time (the targets sent while moving), for the robot plot."""
    rec = driver.targets
    return {
        "t_measured": [m[0] for m in driver.measured], "q_measured": [m[1].tolist() for m in driver.measured],
        "t_target": [r[0] for r in rec if r[2]], "q_target": [r[1].tolist() for r in rec if r[2]],
        "goal": goal.tolist(), "arm": arm,
    }


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


def run_metrics(cfg: RunConfig, dry_run: bool, name: str, note: str | None, multi_step: bool, exit_code: int,
             stop_reason: str, records: list[CycleRecord], outcome: dict[str, Any],
             first_plan: dict[str, Any],
             robot: HorizonRobot, driver: Any, fake: Any, kin: Any, true_model: Any, limit_usage: Any,
             source: Any) -> dict[str, Any]:
    """``metrics.json`` of a run: the configuration, the outcome, cycle times, the setpoints sent and
    received, and the joint limits used."""
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
