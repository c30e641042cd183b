"""``dyndlo-vision demo``: closed-loop tip control in simulation, on P_DLO estimated from rendered images.

The loop (``dyndlo_vision.control.loop``) reads the "tracking" camera at 25 Hz, tracks the cable, filters the
tip, builds the observation from the *estimate*, queries the shipped policy, re-plans the B-spline from the
commanded TCP state and sends the setpoints to the simulated robot. Outputs in ``--out``: ``demo.mp4`` (camera
view with the tracked polyline, the true and estimated P_DLO and the target), ``p_dlo.png`` (true vs estimated
P_DLO over time), ``metrics.json`` (the aggregate over the episodes at the top, one row per episode under
``"episodes"``).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np

from dyndlo_vision._atomic import check_output_folder, staged_folder, write_atomic, write_video_atomic

HELP = "closed-loop tip control in simulation on tracked state: video, plot and metrics"
DEFAULT_POLICIES = ("tip-control-multi-step", "tip-control-single-step")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``demo``."""
    p.add_argument(
        "--policy",
        default=None,
        help=f"shipped policy name or .zip (default: the first shipped of {list(DEFAULT_POLICIES)})",
    )
    p.add_argument(
        "--observation",
        choices=["tracked", "true", "noisy"],
        default="tracked",
        help="where P_DLO comes from: camera + tracker + filter (default), the simulator, or the "
        "simulator through the fitted noise model",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=1,
        help="episodes to run; the video and plot show the first, metrics.json aggregates all (default 1)",
    )
    p.add_argument("--seed", type=int, default=100_000, help="seed of the first episode (default 100000)")
    p.add_argument("--camera", default="tracking", help="MuJoCo camera to track from (default: tracking)")
    p.add_argument(
        "--latency-ms",
        type=float,
        default=0.0,
        help="tracked observation: the tracker sees each frame this long after it was rendered, like a real "
        "camera pipeline; the filter predicts across it (default 0; at most 250; a multiple of the 40 ms "
        "period is exact, other values round up to one)",
    )
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    p.add_argument(
        "--quiet", action="store_true", help="no progress bar on stderr (shown for --episodes > 1)"
    )


def _default_policy() -> str:
    from dyndlo_vision import policies

    shipped = policies.available()
    for name in DEFAULT_POLICIES:
        if name in shipped:
            return name
    raise ValueError(f"no shipped tip-control policy found (have {shipped}); pass --policy PATH.zip")


def check_camera(env: Any, camera_name: str) -> None:
    """Raise ValueError unless ``camera_name`` is a camera of the environment's scene (the names listed)."""
    model = env.unwrapped.model
    names = [model.camera(i).name for i in range(model.ncam)]
    if camera_name not in names:
        raise ValueError(f"--camera {camera_name!r} is not a camera of the scene; expected one of {names}")


def run(args: argparse.Namespace) -> int:
    """Run the episodes and write the outputs.

    Everything that can be checked before the episodes is (options, the output folder, the camera), and the
    outputs are written together at the end: a run that fails leaves no new folder and no partial output.
    """
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    from dyndlo_vision.control.sim_perception import MAX_LATENCY_S

    if not 0.0 <= args.latency_ms <= 1000.0 * MAX_LATENCY_S:
        raise ValueError(f"--latency-ms must be in [0, {1000.0 * MAX_LATENCY_S:g}] ms, got {args.latency_ms}")
    if args.latency_ms and args.observation != "tracked":
        raise ValueError(f"--latency-ms applies to the tracked observation, not to {args.observation!r}")
    out = Path(args.out)
    check_output_folder(out)

    import gymnasium as gym
    from tqdm import tqdm

    import dyndlo_vision  # noqa: F401  (registers the environments)
    from dyndlo_vision import policies

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    name = args.policy or _default_policy()
    _, meta = policies.resolve(name)
    if meta.get("task", "tip-control") != "tip-control":
        raise ValueError(f"the demo runs tip control; policy {name} is for {meta.get('task')}")
    multi_step = bool(meta.get("multi_step", False))
    env = gym.make("DynDLO/TipControl-v0", multi_step=multi_step, render_mode=None)
    check_camera(env, args.camera)
    model = policies.load(name, env=env)

    episodes = []
    video: list[np.ndarray] = []
    bar = tqdm(total=args.episodes, desc="demo episodes", unit="episode", file=sys.stderr,
               disable=args.quiet or args.episodes == 1)
    with bar:
        for i in range(args.episodes):
            record = run_episode(
                env,
                model,
                args.seed + i,
                args.observation,
                args.camera,
                video if i == 0 else None,
                latency_s=1e-3 * args.latency_ms,
            )
            episodes.append(record)
            bar.update(1)
            # tqdm.write keeps the line and the bar apart on a terminal (plain print otherwise).
            rmse = record["estimate_rmse_m"]
            tqdm.write(
                f"episode {i} (seed {record['seed']}): success={record['success']} "
                f"min_distance={record['min_distance_m']:.3f} m "
                f"estimate_rmse={'n/a' if rmse is None else f'{rmse:.4f} m'}",
                file=sys.stdout,
            )
    trace = episodes[0]["trace"]
    metrics: dict[str, Any] = {
        "policy": str(name),
        "multi_step": multi_step,
        "observation": args.observation,
        "latency_ms": args.latency_ms,
        **summarize(episodes),
        "cycle_ms_note": "controller time per 40 ms cycle: camera render + tracking + filter + policy + "
        "planning (the simulated robot's physics is timed apart as send_ms); percentiles over the cycles of "
        "all episodes",
    }
    with staged_folder(out) as stage:
        write_video_atomic(stage / "demo.mp4", video, rgb=False)  # annotated frames are BGR
        _write_plot(stage / "p_dlo.png", trace)
        text = json.dumps(metrics, indent=2)
        write_atomic(stage / "metrics.json", lambda p: Path(p).write_text(text))
    if args.episodes > 1:
        lo, hi = metrics["success_ci95"]
        print(f"success rate {metrics['successes']}/{args.episodes} (95% CI {lo:.2f}-{hi:.2f})")
    keys = ("success", "final_distance_m", "estimate_rmse_m") if args.episodes == 1 else (
        "success_rate", "success_ci95", "final_distance_m_median", "estimate_rmse_m_median")
    print(json.dumps({k: metrics[k] for k in (*keys, "cycle_ms_p50", "cycle_ms_p95")}))
    print(f"wrote {out / 'demo.mp4'}, {out / 'p_dlo.png'}, {out / 'metrics.json'}")
    return 0


def summarize(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """The top-level metrics of a run: aggregates over all episodes, then the per-episode rows.

    Success rate with its Wilson 95% interval, medians of the per-episode distances and estimate errors, and
    controller-time percentiles over the cycles of all episodes pooled. With one episode its own values
    (``success``, ``final_distance_m``, ...) are at the top level too; with more they are only in the rows,
    so that no one episode's numbers pass for the run's.
    """
    from dyndlo_vision.learning.evaluate import wilson_interval

    n = len(episodes)
    successes = sum(bool(e["success"]) for e in episodes)
    lo, hi = wilson_interval(successes, n)
    cycle_ms = np.concatenate([np.asarray(e["_cycle_ms"], dtype=float) for e in episodes])
    stage_ms: dict[str, list[float]] = {}
    for e in episodes:
        for key, values in e["_stage_ms"].items():
            stage_ms.setdefault(key, []).extend(values)
    rmse = [e["estimate_rmse_m"] for e in episodes if e["estimate_rmse_m"] is not None]

    def median(key: str) -> float:
        return float(np.median([e[key] for e in episodes]))

    metrics: dict[str, Any] = {
        "num_episodes": n,
        "seeds": [e["seed"] for e in episodes],
        "successes": successes,
        "success_rate": successes / n,
        "success_ci95": [lo, hi],
        "final_distance_m_median": median("final_distance_m"),
        "min_distance_m_median": median("min_distance_m"),
        "estimate_rmse_m_median": float(np.median(rmse)) if rmse else None,
        "cycle_ms_p50": float(np.percentile(cycle_ms, 50)),
        "cycle_ms_p95": float(np.percentile(cycle_ms, 95)),
        "stage_ms_p50": {k: float(np.percentile(v, 50)) for k, v in sorted(stage_ms.items())},
        "stage_ms_p95": {k: float(np.percentile(v, 95)) for k, v in sorted(stage_ms.items())},
        "deadline_misses": int(sum(e["deadline_misses"] for e in episodes)),
        "cycles": int(sum(e["cycles"] for e in episodes)),
    }
    if n == 1:
        only = episodes[0]
        metrics.update({k: only[k] for k in ("success", "final_distance_m", "min_distance_m",
                                             "estimate_rmse_m", "stop_reason")})
    metrics["episodes"] = [{k: v for k, v in e.items() if k != "trace" and not k.startswith("_")}
                           for e in episodes]
    return metrics


def run_episode(
    env: Any,
    model: Any,
    seed: int,
    observation: str,
    camera_name: str,
    video: list[np.ndarray] | None,
    latency_s: float = 0.0,
    point_filter: Any = None,
) -> dict[str, Any]:
    """One closed-loop episode; appends annotated frames to ``video`` when given.

    ``latency_s`` and ``point_filter`` (tracked observation): the camera's delay and the tip filter (default:
    ``tracked_state``'s). With a delay the video shows the present, with the polyline the tracker found in
    the delayed frame.
    """
    from dyndlo_vision.control.loop import ControlLoop
    from dyndlo_vision.control.sim_robot import SimRobot
    from dyndlo_vision.control.state_sources import TrueState

    base = env.unwrapped
    env.reset(seed=seed)
    camera = None
    if observation == "tracked":
        from dyndlo_vision.control.sim_perception import tracked_state

        source, camera = tracked_state(env, camera_name, point_filter=point_filter, latency_s=latency_s)
    elif observation == "noisy":
        from dyndlo_vision.control.state_sources import NoisyState

        source = NoisyState(env, seed=seed)
    else:
        source = TrueState(env)
    if video is not None and camera is None:
        from dyndlo_vision.control.cameras import MujocoCamera

        camera = MujocoCamera(base.model, base.data, camera_name)
    robot = SimRobot(env)
    robot.connect()
    loop = ControlLoop(
        source,
        robot,
        lambda obs: model.predict(obs, deterministic=True)[0],
        base.replanner,
        base.goal,
        period_s=0.04,
        setpoint_period_s=base.scene.timestep,
        truth=base.p_dlo,
    )
    calib = camera.calibration if camera is not None else None

    def on_cycle(record: Any, frame: Any) -> None:
        if video is None or calib is None:
            return
        rgb = frame.rgb if frame is not None and not latency_s else camera.read().rgb
        video.append(_annotate(rgb, record, calib, base.goal))

    if base.multi_step:
        report = loop.run(base.task.episode_s, done=base.is_done_early, on_cycle=on_cycle)
        if report.stop_reason == "duration":
            # As in the environment: after the last re-plan the TCP follows that plan (it ends at rest).
            loop.finish_plan(base.task.settle_s)
    else:
        report = loop.run(
            10.0,
            done=lambda: base.scene.time >= base.trajectory.t_end + base.task.settle_s - 1e-9,
            on_cycle=on_cycle,
            replan_every_cycle=False,
        )
    _, success, info = base.outcome()
    if camera is not None:
        camera.close()
    errors = report.estimate_errors()
    controller = report.controller_ms()
    trace = {
        "t": [c.t for c in report.cycles],
        "true": [c.p_dlo_true.tolist() for c in report.cycles],
        "estimate": [c.p_dlo_estimate.tolist() for c in report.cycles],
        "measured": [c.measured for c in report.cycles],
        "goal": base.goal.tolist(),
    }
    return {
        "seed": seed,
        "success": bool(success),
        "final_distance_m": float(np.linalg.norm(base.p_dlo() - base.goal)),
        "min_distance_m": float(info["min_distance_m"]),
        "estimate_rmse_m": float(np.sqrt(np.mean(errors**2))) if errors.size else None,
        "cycle_ms_p50": float(np.percentile(controller, 50)),
        "cycle_ms_p95": float(np.percentile(controller, 95)),
        "stage_ms_p50": report.stage_percentiles(50),
        "stage_ms_p95": report.stage_percentiles(95),
        "deadline_misses": int(sum(c.deadline_missed for c in report.cycles)),
        "cycles": len(report.cycles),
        "stop_reason": report.stop_reason,
        "avoid": info["avoid"],
        "trace": trace,
        "_cycle_ms": controller.tolist(),
        "_stage_ms": {
            k: [c.stage_ms.get(k, 0.0) for c in report.cycles]
            for k in sorted({k for c in report.cycles for k in c.stage_ms})
        },
    }


def _annotate(rgb: np.ndarray, record: Any, calib: Any, goal: np.ndarray) -> np.ndarray:
    """BGR frame: the tracker's drawing (polyline, estimate, status) plus the true P_DLO and the target."""
    import cv2

    from dyndlo_vision.tracking.annotate import annotate_frame

    def pixel(p: Any) -> np.ndarray | None:
        if p is None or not np.all(np.isfinite(p)):
            return None
        uv = calib.project(np.asarray(p, dtype=float)[None])[0]
        return uv if np.all(np.isfinite(uv)) else None

    state = "measured" if record.measured else "predicted"
    img = annotate_frame(rgb, record.polyline_uv, None, point_uv=pixel(record.p_dlo_estimate),
                         point_measured=record.measured, t=record.t,
                         status=f"{state}  ctrl {record.controller_ms:.1f} ms")
    for p, color, radius in ((goal, (255, 220, 0), 14), (record.p_dlo_true, (0, 200, 0), 5)):
        uv = pixel(p)
        if uv is not None:
            cv2.circle(img, (int(round(uv[0])), int(round(uv[1]))), radius, color, 2, cv2.LINE_AA)
    legend = "cyan: tracked cable  magenta: estimate (filled: measured)  green: true P_DLO  yellow: target"
    cv2.putText(img, legend, (10, img.shape[0] - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1,
                cv2.LINE_AA)
    return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)


def _write_plot(path: Path, trace: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(trace["t"])
    true = np.asarray(trace["true"])
    est = np.asarray(trace["estimate"])
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for k, (ax, name) in enumerate(zip(axes, ("x", "y", "z"), strict=True)):
        ax.plot(t, true[:, k], "g-", label="true P_DLO")
        ax.plot(t, est[:, k], "b.--", ms=4, label="estimated (tracked + filtered)")
        ax.axhline(trace["goal"][k], color="orange", lw=1, label="target")
        ax.set_ylabel(f"{name} (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("simulated time (s)")
    fig.suptitle("Tip position: simulator truth vs the controller's estimate")
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=100, format="png"))
    plt.close(fig)
