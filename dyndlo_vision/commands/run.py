"""``dyndlo-vision run CONFIG.yaml --out DIR [--dry-run]``: tip control on a real arm, from the camera.

The configuration (:mod:`dyndlo_vision.control.run_config`; ``examples/run-*-dry.yaml`` document it field by
field) names the driver and arm (ABB GoFa over EGM, UR5e over RTDE), the camera and its calibration, the
target, the policy and the safety limits. Before anything moves everything is checked: the file, the policy,
the connection (a robot that does not answer within ``robot.connect_timeout_s`` is an error), the TCP at the
task's home, the cable's tip in the first frame, and the whole first plan on the arm's joint limits, exactly
as the driver will judge it. Any failure: exit status 2, the reason on one line, no output folder.

Then the 25 Hz loop (:mod:`dyndlo_vision.control.robot_run`) runs until the plan and the settle time are over,
``safety.duration_s``, a lost estimate, a silent robot, a refused plan or Ctrl-C; each of the early ends
brakes the arm, closes the driver, writes the report so far and exits non-zero (1; 130 for Ctrl-C) with the
reason.

``--dry-run`` runs the same code with no hardware: the driver talks to the fake controller of its protocol on
loopback, and with ``camera.source: simulated`` the camera renders the task's MuJoCo scene, from the
calibration's pose, with the cable's held end following the fake robot's measured joints; the simulation then
also says whether the tip hit the target.

Outputs in ``--out``: ``run.mp4`` (the camera with the tracked cable, the estimate, the target and, when
simulated, the true tip), ``p_dlo.png`` (true vs estimated tip; simulated camera only), ``robot.png`` (TCP
commanded and measured, joint velocity use), ``metrics.json`` (outcome, stop reason, cycle times, deadline
misses, joint targets sent and received, joint-limit margins of what was streamed, the first plan's check).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np

from dyndlo_vision._atomic import check_output_folder, staged_folder, write_atomic
from dyndlo_vision._video import write_video_atomic

HELP = "tip control on a real arm (ABB EGM / UR RTDE) from a YAML config; --dry-run against fake controllers"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``run``."""
    p.add_argument("config", metavar="CONFIG.yaml", help="the run's configuration (see examples/run-*.yaml)")
    p.add_argument("--out", required=True, help="output folder (video, plots, metrics.json)")
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="no hardware: the fake controller of the configured protocol on loopback; camera.source "
        "'simulated' renders the task's scene following the fake robot",
    )
    p.add_argument("--no-video", action="store_true", help="write no run.mp4 (saves memory on long runs)")


def _annotator(legend: Any) -> Any:
    from dyndlo_vision.commands.demo import _annotate, _annotate_truth

    def annotate(rgb: np.ndarray, record: Any, calib: Any, goal: np.ndarray, status: str | None = None,
                 t: float | None = None, truth: Any = None) -> np.ndarray:
        if record is not None:
            return _annotate(rgb, record, calib, goal, legend)
        return _annotate_truth(rgb, float(t or 0.0), truth, calib, goal, status or "", legend)

    return annotate


def run(args: argparse.Namespace) -> int:
    """Check, connect, run and report (see the module docstring)."""
    from dyndlo_vision.control.robot_run import run_session
    from dyndlo_vision.control.run_config import load_run_config

    cfg = load_run_config(args.config)
    out = Path(args.out)
    check_output_folder(out)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from dyndlo_vision.commands.demo import LEGEND

    result = run_session(cfg, args.dry_run, say=lambda line: print(line, flush=True),
                         annotate=None if args.no_video else _annotator(LEGEND))
    write_report(out, result)
    m = result.metrics
    summary = {k: m.get(k) for k in ("stop_reason", "success", "final_distance_m", "min_distance_m", "cycles",
                                     "cycle_ms_p50", "cycle_ms_p95", "deadline_misses")}
    print(json.dumps(summary))
    print(f"wrote {out}: " + ", ".join(sorted(p.name for p in out.iterdir())))
    if result.exit_code:
        print(f"dyndlo-vision run: stopped early: {result.stop_reason}", file=sys.stderr)
    return result.exit_code


def write_report(out: Path, result: Any) -> None:
    """The report folder, all files together (``_atomic.staged_folder``)."""
    from dyndlo_vision.commands.demo import _write_plot
    from dyndlo_vision.tasks.base import CONTROL_PERIOD_S

    metrics = dict(result.metrics)
    with staged_folder(out) as stage:
        if result.frames:
            fps = 1.0 / CONTROL_PERIOD_S
            codec = write_video_atomic(stage / "run.mp4", result.frames, fps=fps, rgb=False)
            metrics["video"] = {"file": "run.mp4", "frames": len(result.frames), "fps": fps, "codec": codec}
        if result.trace is not None and result.trace["t"]:
            _write_plot(stage / "p_dlo.png", result.trace)
        if result.robot.get("t_measured"):
            _robot_plot(stage / "robot.png", result.robot, metrics)
        text = json.dumps(metrics, indent=2)
        write_atomic(stage / "metrics.json", lambda p: Path(p).write_text(text))


def _robot_plot(path: Path, series: dict[str, Any], metrics: dict[str, Any]) -> None:
    """TCP x and z, commanded (joint targets) and measured, and each joint's speed over its limit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dyndlo_vision.robots.feasibility import ROBOT_ARMS

    arm = ROBOT_ARMS[series["arm"]]
    kin = arm.kinematics()
    model = kin.arm
    tm = np.asarray(series["t_measured"], dtype=float)
    qm = np.asarray(series["q_measured"], dtype=float).reshape(-1, 6)
    tt = np.asarray(series["t_target"], dtype=float)
    qt = np.asarray(series["q_target"], dtype=float).reshape(-1, 6)
    t0 = tm[0]
    # Relative joint motion is placement-independent: FK with the default placement shows the TCP's path
    # relative to its start, which is what is compared here (commanded vs measured).
    pm = kin.fk(qm)[0] - kin.fk(qm[0])[0]
    fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for ax, k, name in ((axes[0], 0, "x"), (axes[1], 2, "z")):
        ax.plot(tm - t0, pm[:, k], "-", color="black", lw=1.2, label="measured")
        if tt.size:
            pt = kin.fk(qt)[0] - kin.fk(qm[0])[0]
            ax.plot(tt - t0, pt[:, k], "--", color="tab:blue", lw=1, label="joint targets sent")
        ax.set_ylabel(f"TCP {name} - start (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    if tt.size >= 2:
        vel = np.abs(np.diff(qt, axis=0) / np.diff(tt)[:, None]) / np.array(model.max_velocity_rad_s)
        for j in range(6):
            axes[2].plot(tt[1:] - t0, vel[:, j], lw=1, label=f"axis {j + 1}")
        margin = (metrics.get("joint_limits") or {}).get("joint_margin", 1.0)
        axes[2].axhline(margin, color="red", ls="--", lw=1, label="margin")
        axes[2].legend(fontsize=7, ncol=4)
    axes[2].set_ylabel("|joint speed| / limit")
    axes[2].set_xlabel("robot time since start (s)")
    axes[2].grid(alpha=0.3)
    fig.suptitle(f"{series['arm']}: {metrics.get('stop_reason', '')}", fontsize=10)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=100, format="png"))
    plt.close(fig)
