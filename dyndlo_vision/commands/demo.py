"""``dyndlo-vision demo``: the closed loop in simulation (tip control or vaulting), on P_DLO estimated from
rendered images.

The loop (``dyndlo_vision.control.loop``) reads the "tracking" camera at 25 Hz, tracks the cable, filters the
tip, builds the observation from the *estimate*, queries the shipped policy, re-plans the B-spline from the
commanded TCP state and sends the setpoints to the simulated robot. Outputs in ``--out``: ``demo.mp4`` (camera
view of the first episode with the tracked polyline, the true and estimated P_DLO and the target),
``p_dlo.png`` (true vs estimated P_DLO and the distance to the target over time), ``metrics.json`` (the
aggregate over the episodes at the top, one row per episode under ``"episodes"``).

The video and the plot run until the episode's outcome is decided, the instant ``final_distance_m`` is
measured: one frame at the start of every 40 ms period, including the periods in which the robot finishes
its last plan without re-planning, and a last frame at the outcome.
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

HELP = "closed-loop tip control or vaulting in simulation on tracked state: video, plot and metrics"
#: Tasks the demo runs: their scenes have a "tracking" camera placed for them and a shipped policy.
DEMO_TASKS = ("tip-control", "vaulting")
#: What the yellow ring marks: the task's P* (table II).
GOAL_NAMES = {"tip-control": "target", "vaulting": "obstacle"}

# Overlay colours (RGB). ``tracking.annotate`` draws the tracked cable cyan and the estimate magenta. The
# scene renders the cable red, the target as a green sphere, the sky black and the floor light grey, so the
# true tip is a white ring with a black rim (a green one vanished into the sphere at the hit, a red one into
# the cable) and the target sphere is ringed in yellow. The plot uses the same colours where a white
# background allows: black for the truth, a darker yellow for the target.
CABLE_RGB = (0, 230, 255)
ESTIMATE_RGB = (255, 0, 220)
TRUE_RGB = (255, 255, 255)
TARGET_RGB = (255, 220, 0)


def make_legend(tracked: bool, goal_name: str = "target") -> tuple[tuple[str, Any], ...]:
    """The video's legend. Without the tracker nothing is tracked, and the magenta cross is the P_DLO the
    policy is given."""
    if tracked:
        return (("cyan: tracked cable", CABLE_RGB),
                ("magenta +: estimate (dot filled: measured)", ESTIMATE_RGB),
                ("white o: true P_DLO", TRUE_RGB), (f"yellow ring: {goal_name}", TARGET_RGB))
    return (("magenta +: P_DLO given to the policy", ESTIMATE_RGB), ("white o: true P_DLO", TRUE_RGB),
            (f"yellow ring: {goal_name}", TARGET_RGB))


LEGEND = make_legend(True)
LEGEND_UNTRACKED = make_legend(False)
_PLOT_TRUE = "black"
_PLOT_TARGET = "#c8a000"
#: A coordinate panel of ``p_dlo.png`` spans at least this much (m): a coordinate that stays put (y in the
#: motion plane) would otherwise be drawn on an axis of rounding noise (1e-17 m).
_PLOT_MIN_SPAN_M = 0.05


def parse_push(text: str | None) -> Any:
    """``--push T,IX,IY,IZ`` as a :class:`~dyndlo_vision.tasks.base.CablePush` (None: no push).

    Raises:
        ValueError: Not four numbers, or a negative time or non-finite value (naming what was given).
    """
    if text is None:
        return None
    from dyndlo_vision.tasks.base import CablePush

    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4:
        raise ValueError(f"--push must be T,IX,IY,IZ (seconds, then an impulse in N s), got {text!r}")
    return CablePush(values[0], (values[1], values[2], values[3]))


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``demo``."""
    from dyndlo_vision.commands import _options as options
    from dyndlo_vision.tasks.registry import task_entry
    from dyndlo_vision.tracking.networks import LOOP_NAME

    p.epilog = ("The video and the plot show the first episode; metrics.json aggregates all of them, and "
                "records each episode's cable and the ranges it was drawn from.")
    options.add_task(p, choices=DEMO_TASKS)
    defaults = "; ".join(f"{t}: {list(task_entry(t).shipped_policies)}" for t in DEMO_TASKS)
    p.add_argument(
        "--policy",
        default=None,
        help=f"shipped policy name or .zip (default: the task's first shipped one of {defaults})",
    )
    p.add_argument(
        "--observation",
        choices=["tracked", "true", "noisy", "frozen"],
        default="tracked",
        help="where P_DLO comes from: camera + tracker + filter (default), the simulator, the simulator "
        "through a noise model (--obs-noise; it also perturbs the gripper state the policy sees), or the "
        "simulator's P_DLO frozen at reset (the ablation: what the policy does without "
        "feedback)",
    )
    options.add_obs_noise(p, default="with --observation noisy, the task's own loop tracker's "
                          "('vaulting-two-cameras' for vaulting, 'packaged' for tip control)")
    options.add_cable_options(p)
    options.add_episodes(p, default=1)
    options.add_first_seed(p)
    options.add_camera(p)
    p.add_argument(
        "--latency-ms",
        type=float,
        default=0.0,
        help="tracked observation: the tracker sees each frame this long after it was rendered, like a real "
        "camera pipeline; the filter predicts across it (default 0; at most 250; a multiple of the 40 ms "
        "period is exact, other values round up to one)",
    )
    p.add_argument(
        "--actuation-latency-ms",
        type=float,
        default=0.0,
        help="a disturbance: the simulated arm executes every setpoint this long after it was planned for, "
        "while the planner goes on from the state it commanded (default 0; at most 1000)",
    )
    p.add_argument(
        "--push",
        default=None,
        metavar="T,IX,IY,IZ",
        help="a disturbance in every episode: an impulse (IX, IY, IZ) in N s on the cable's middle node at "
        "T s of episode time, e.g. 0.3,0.01,0,0 (the momentum of tip control's whole 10 g cable at 1 m/s); "
        "chain cable only (default: none)",
    )
    # The loop's segmenters (control.sim_perception.LOOP_SEGMENTERS; not imported here: it loads MuJoCo).
    options.add_segmenter(
        p, ("learned", "background"), None,
        default_text="the scene's own, learned where it has one camera (tip control), background where it "
        "has two (vaulting, where the network loses the cable on the floor and two networks overrun the "
        "cycle); the loop's background is its scene rendered without the cable; with --observation tracked "
        "only",
    )
    options.add_segmenter_model(p, default=LOOP_NAME)
    p.add_argument(
        "--segmenter-scale",
        type=float,
        default=None,
        metavar="S",
        help="with --segmenter learned: the network sees each frame enlarged S times, 0.5-3 (default 1.5: "
        "the loop camera's 1.6 px cable as 2.4 px; 1 is about 1.5x as fast and about 6x less accurate)",
    )
    p.add_argument(
        "--views",
        type=int,
        choices=[1, 2],
        default=None,
        help="tracked observation: cameras the cable is tracked in. 1: the --camera view, the cable lifted "
        "onto the motion plane; 2: also the scene's second camera, the cable triangulated (vaulting, whose "
        "cable leaves the plane). Default: as many as the task's scene has (tip control 1, vaulting 2)",
    )
    p.add_argument(
        "--raw-videos",
        action="store_true",
        help="also write the first episode's unannotated camera frames, the inputs of `dyndlo-vision "
        "track`: raw/ and camera.json (the --camera view's frames as lossless PNG files, and its "
        "calibration), raw2/ and camera2.json (the scene's second tracking camera, where it has one), "
        "tcp.csv (the gripper, time_s,x,y,z) and truth.csv (the true P_DLO), one row per frame",
    )
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    options.add_quiet(p)


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
    from dyndlo_vision.commands._options import LOOP_CAMERA, ObservationChoice, random_cables

    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    task = args.task
    observation = ObservationChoice.from_args(args, task)
    push = parse_push(args.push)
    if args.raw_videos and (observation.kind != "tracked" or observation.latency_ms):
        raise ValueError(
            "--raw-videos records the frames the loop's tracker is given, at the instants its truth is read: "
            f"it needs --observation tracked without --latency-ms (got --observation {observation.kind}, "
            f"--latency-ms {observation.latency_ms:g})"
        )
    if not 0.0 <= args.actuation_latency_ms <= 1000.0:
        raise ValueError(f"--actuation-latency-ms must be in [0, 1000] ms, got {args.actuation_latency_ms}")
    cables = random_cables(args)
    cable_options = {} if cables is None else cables.env_options(task)
    camera = args.camera or LOOP_CAMERA
    out = Path(args.out)
    check_output_folder(out)

    from tqdm import tqdm

    from dyndlo_vision import policies
    from dyndlo_vision.tasks.registry import make_env

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    name = args.policy or policies.default_for(task)
    _, meta = policies.resolve(name)
    if meta.get("task", "tip-control") != task:
        raise ValueError(f"policy {name} is for {meta.get('task')}, not --task {task}")
    multi_step = bool(meta.get("multi_step", False))
    env = make_env(task, multi_step=multi_step, **cable_options)
    check_camera(env, camera)
    perception = observation.perception(env, task)
    if push is not None:
        if env.unwrapped.task.cable.model != "chain":
            raise ValueError("--push needs the chain cable; this policy's environment has the rod")
        env.unwrapped.cable_push = push
    model = policies.load(name, env=env)

    episodes = []
    video: list[np.ndarray] = []
    raw = RawRecording(env, perception.views) if args.raw_videos and perception is not None else None
    bar = tqdm(total=args.episodes, desc="demo episodes", unit="episode", file=sys.stderr,
               disable=args.quiet or args.episodes == 1)
    with bar:
        for i in range(args.episodes):
            record = film_episode(
                env,
                model,
                args.seed + i,
                observation.kind,
                camera,
                video if i == 0 else None,
                perception=perception,
                goal_name=GOAL_NAMES[task],
                actuation_latency_s=1e-3 * args.actuation_latency_ms,
                raw=raw if i == 0 else None,
                noise_model=observation.noise_model,
            )
            episodes.append(record)
            bar.update(1)
            # tqdm.write keeps the line and the bar apart on a terminal (plain print otherwise).
            rmse = record["estimate_rmse_m"]
            tqdm.write(
                f"episode {i} (seed {record['seed']}): success={record['success']} "
                f"final_distance={record['final_distance_m']:.3f} m "
                f"min_distance={record['min_distance_m']:.3f} m "
                f"estimate_rmse={'n/a' if rmse is None else f'{rmse:.4f} m'}",
                file=sys.stdout,
            )
    trace = episodes[0]["trace"]
    metrics: dict[str, Any] = {
        "task": task,
        "policy": str(name),
        "multi_step": multi_step,
        "observation": observation.kind,
        "randomize_cable": cables is not None,
        "cable_ranges": None if cables is None else cables.ranges,
        "cable_range_factors": cable_options.get("cable_ranges"),
        "latency_ms": observation.latency_ms,
        "actuation_latency_ms": args.actuation_latency_ms,
        "push": None if push is None else {"time_s": push.time_s, "impulse_n_s": list(push.impulse_n_s),
                                           "node": "middle"},
        "obs_noise": observation.noise,
        "segmenter": None if perception is None else perception.segmenter.kind,
        "segmenter_model": observation.segmenter_model,
        "segmenter_scale": None if perception is None else perception.segmenter.scale,
        "views": None if perception is None else perception.views,
        **summarize(episodes),
        "cycle_ms_note": "controller time per 40 ms cycle: camera render + tracking + filter + policy + "
        "planning (the simulated robot's physics is timed apart as send_ms); percentiles over the cycles of "
        "all episodes",
    }
    from dyndlo_vision.tasks.base import CONTROL_PERIOD_S

    fps = 1.0 / CONTROL_PERIOD_S  # one frame per control period
    with staged_folder(out) as stage:
        codec = write_video_atomic(stage / "demo.mp4", video, fps=fps, rgb=False)  # annotated frames are BGR
        rows = metrics.pop("episodes")  # kept last, after the run's numbers
        metrics["video"] = {"episode": 0, "seed": episodes[0]["seed"], "frames": len(video), "fps": fps,
                            "codec": codec}
        metrics["episodes"] = rows
        _write_plot(stage / "p_dlo.png", trace, GOAL_NAMES[task])
        if raw is not None:
            metrics["raw_videos"] = raw.write(stage, fps)
        text = json.dumps(metrics, indent=2)
        write_atomic(stage / "metrics.json", lambda p: Path(p).write_text(text))
    if args.episodes > 1:
        lo, hi = metrics["success_ci95"]
        print(f"success rate {metrics['successes']}/{args.episodes} (95% CI {lo:.2f}-{hi:.2f})")
    keys = ("success", "final_distance_m", "estimate_rmse_m") if args.episodes == 1 else (
        "success_rate", "success_ci95", "final_distance_m_median", "estimate_rmse_m_median")
    print(json.dumps({k: metrics[k] for k in (*keys, "cycle_ms_p50", "cycle_ms_p95")}))
    note = "" if codec == "h264" else " (MPEG-4 Part 2: PyAV could not encode H.264 here)"
    print(f"wrote {out / 'demo.mp4'} ({len(video)} frames, {codec}{note}), {out / 'p_dlo.png'}, "
          f"{out / 'metrics.json'}")
    if raw is not None:
        print(f"wrote the raw camera frames for `dyndlo-vision track`: "
              f"{', '.join(str(out / f) for f in metrics['raw_videos']['files'])}")
    return 0


def summarize(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """The top-level metrics of a run: aggregates over all episodes, then the per-episode rows.

    Success rate with its Wilson 95% interval; the clean successes, those whose episode met no avoid
    condition (a vault can land with the TCP over v_max: a success that the paper's avoid term penalises), and
    how many episodes met each condition; medians of the per-episode distances and estimate errors, and
    controller-time percentiles over the cycles of all episodes pooled. With one episode its own values
    (``success``, ``final_distance_m``, ...) are at the top level too; with more they are only in the rows,
    so that no one episode's numbers pass for the run's.
    """
    from dyndlo_vision.learning.evaluate import wilson_interval

    n = len(episodes)
    successes = sum(bool(e["success"]) for e in episodes)
    lo, hi = wilson_interval(successes, n)
    clean = sum(bool(e["success"]) and not any(e["avoid"].values()) for e in episodes)
    avoid_episodes = {key: sum(bool(e["avoid"].get(key)) for e in episodes)
                      for key in sorted({k for e in episodes for k in e["avoid"]})}
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
        "clean_successes": clean,
        "clean_success_rate": clean / n,
        "avoid_episodes": {k: v for k, v in avoid_episodes.items() if v},
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
                                             "estimate_rmse_m", "stop_reason", "end_time_s")})
    metrics["episodes"] = [{k: v for k, v in e.items() if k != "trace" and not k.startswith("_")}
                           for e in episodes]
    return metrics


def film_episode(
    env: Any,
    model: Any,
    seed: int,
    observation: str,
    camera_name: str,
    video: list[np.ndarray] | None,
    perception: Any = None,
    goal_name: str = "target",
    actuation_latency_s: float = 0.0,
    raw: RawRecording | None = None,
    noise_model: Any = None,
) -> dict[str, Any]:
    """One closed-loop episode (:func:`~dyndlo_vision.control.episode.run_loop_episode`), filmed.

    When ``video`` is given, an annotated BGR frame is appended at the start of every control period until
    the outcome, and once more at the outcome, where ``final_distance_m`` is measured. Without re-planning
    there is nothing new to track, so those frames show the truth and the target only. With a camera delay
    the video shows the present, with the polyline the tracker found in the delayed frame.
    """
    from dyndlo_vision.control.episode import run_loop_episode
    from dyndlo_vision.policies.actor import deterministic_policy

    shown_legend = make_legend(observation == "tracked", goal_name)

    def film(moment: Any) -> None:
        assert video is not None and moment.camera is not None
        calib = moment.camera.calibration
        rgb = moment.frame.rgb if moment.frame is not None else moment.camera.read().rgb
        if raw is not None:
            raw.add(moment, rgb)
        if moment.cycle is not None:
            video.append(_annotate(rgb, moment.cycle, calib, moment.goal, shown_legend))
            if moment.second_view is not None:
                _draw_second_view(video[-1], moment.second_view, moment.cycle)
        else:
            video.append(_annotate_truth(rgb, moment.t, moment.p_dlo_true, calib, moment.goal, moment.status,
                                         shown_legend))

    if hasattr(model, "reset"):
        model.reset()  # a policy with a P_DLO history starts the episode afresh
    return run_loop_episode(
        env,
        deterministic_policy(model),
        seed,
        observation,
        camera_name,
        perception=perception,
        watch=film if video is not None else None,
        open_camera=video is not None,
        actuation_latency_s=actuation_latency_s,
        noise_model=noise_model,
    )


class RawRecording:
    """The first episode's unannotated camera frames at every filmed instant, with the gripper's and the true
    P_DLO's positions at the same instants: what ``dyndlo-vision track`` reads (one or two views).

    In a control cycle the frames are the ones the loop's trackers were given, rendered at the cycle's start,
    where the cycle's truth and TCP were read (the simulator has moved on by a period when the cycle is
    reported); at the other filmed instants (after the last plan, the outcome) they are rendered then.
    """

    def __init__(self, env: Any, views: int) -> None:
        self.env = env
        self.views = views
        self.frames: list[np.ndarray] = []
        self.frames2: list[np.ndarray] = []
        self.rows: list[tuple[float, Any, Any]] = []
        self.calibs: list[Any] = []
        self._second: Any = None

    def add(self, moment: Any, rgb: np.ndarray) -> None:
        """Keeps this instant's frame(s), TCP and true P_DLO; ``rgb`` is the loop camera's frame the video
        shows (the trackers' frame in a cycle, the present otherwise)."""
        from dyndlo_vision.cameras.simulated import MujocoCamera
        from dyndlo_vision.sim.scene import SECOND_TRACKING_CAMERA_NAME

        base = self.env.unwrapped
        if not self.calibs:
            self.calibs.append(moment.camera.calibration)
            if self.views == 2:
                self._second = MujocoCamera(base.model, base.data, SECOND_TRACKING_CAMERA_NAME,
                                            width=moment.camera.width, height=moment.camera.height)
                self.calibs.append(self._second.calibration)
        self.frames.append(np.array(rgb, copy=True))
        if moment.cycle is not None:
            if moment.frame is None or (self.views == 2 and moment.second_view is None):
                raise RuntimeError("a control cycle without its camera frame(s) cannot be recorded raw")
            if self.views == 2:
                self.frames2.append(np.array(moment.second_view.rgb, copy=True))
            tcp = np.asarray(moment.cycle.tcp_position, dtype=float).reshape(3)
        else:
            if self._second is not None:
                self.frames2.append(self._second.read().rgb.copy())
            tcp = np.asarray(base.scene.tcp_positions())[0].copy()
        self.rows.append((float(moment.t), tcp, np.asarray(moment.p_dlo_true, dtype=float).copy()))

    def write(self, folder: Path, fps: float) -> dict[str, Any]:
        """Writes the frame folders, calibrations and the two CSVs into ``folder``; returns what it wrote."""
        import csv

        import cv2

        if self._second is not None:
            self._second.close()
            self._second = None

        written = {"frames": len(self.frames), "fps": fps, "files": []}
        views = [("raw", "camera.json", self.frames)]
        if self.frames2:
            views.append(("raw2", "camera2.json", self.frames2))
        # PNG, not MP4: video codecs smear a cable 1-2 px wide (the loop cameras'), which is what is tracked.
        for (frames_name, calib_name, frames), calib in zip(views, self.calibs, strict=True):
            (folder / frames_name).mkdir()
            for k, rgb in enumerate(frames):
                if not cv2.imwrite(str(folder / frames_name / f"frame_{k:05d}.png"),
                                   cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
                    raise RuntimeError(f"OpenCV cannot write PNG files into {folder / frames_name}")
            calib.to_json(folder / calib_name)
            written["files"] += [frames_name + "/", calib_name]
        for name, column in (("tcp.csv", 1), ("truth.csv", 2)):
            with open(folder / name, "w", newline="", encoding="utf-8") as f:
                w = csv.writer(f)
                w.writerow(["time_s", "x", "y", "z", "sim_time_s"])
                for k, row in enumerate(self.rows):
                    # Frame k's time on the video's clock (k / fps, as `track` reads it), the position when
                    # the frame was rendered, and that instant's simulated time (the last frame, at the
                    # outcome, is less than a period after the one before it).
                    w.writerow([f"{k / fps:.6f}", *(f"{c:.6f}" for c in row[column]), f"{row[0]:.6f}"])
            written["files"].append(name)
        return written


def _pixel(calib: Any, p: Any) -> tuple[int, int] | None:
    """Integer pixel of world point ``p``, None if it is missing or does not project."""
    if p is None or not np.all(np.isfinite(p)):
        return None
    uv = calib.project(np.asarray(p, dtype=float)[None])[0]
    return (int(round(uv[0])), int(round(uv[1]))) if np.all(np.isfinite(uv)) else None


def _draw_truth_and_target(
    img: np.ndarray, true_p: Any, calib: Any, goal: np.ndarray, legend: tuple[tuple[str, Any], ...]
) -> None:
    """Draw (RGB, in place) the yellow ring around the target sphere, the white true P_DLO and the legend."""
    import cv2

    uv = _pixel(calib, goal)
    if uv is not None:
        cv2.circle(img, uv, 14, TARGET_RGB, 2, cv2.LINE_AA)
    uv = _pixel(calib, true_p)
    if uv is not None:
        cv2.circle(img, uv, 6, (0, 0, 0), 4, cv2.LINE_AA)  # the rim keeps it visible on the light floor
        cv2.circle(img, uv, 6, TRUE_RGB, 2, cv2.LINE_AA)
    # The legend on a dark band: in its own colours, readable over the light floor.
    h, w = img.shape[:2]
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    line_h = 16
    lines: list[list[tuple[str, tuple[int, int, int]]]] = [[]]
    x = 8
    for text, color in legend:
        tw = cv2.getTextSize(text, font, scale, 1)[0][0]
        if x + tw > w - 8 and lines[-1]:
            lines.append([])
            x = 8
        lines[-1].append((text, color))
        x += tw + 14
    top = h - line_h * len(lines) - 6
    img[top:] = (img[top:] * 0.25).astype(np.uint8)
    for row, items in enumerate(lines):
        x = 8
        y = top + line_h * (row + 1)
        for text, color in items:
            cv2.putText(img, text, (x, y), font, scale, color, 1, cv2.LINE_AA)
            x += cv2.getTextSize(text, font, scale, 1)[0][0] + 14


def estimate_state(record: Any) -> str:
    """What a control cycle's P_DLO estimate rests on, for the video's status line.

    - ``"lost"``: no usable estimate.
    - ``"measured"``: this cycle's frame gave the tip.
    - ``"measured, continued"``: it gave P_DLO only by continuing the tracked cable past where it
      disappears (the loop knows the cable's length).
    - ``"predicted"``: the filter's prediction, without a measurement this cycle.
    """
    if record.lost:
        return "lost"
    if record.measured:
        return "measured, continued" if getattr(record, "continued", False) else "measured"
    return "predicted"


def _annotate(
    rgb: np.ndarray, record: Any, calib: Any, goal: np.ndarray, legend: tuple[tuple[str, Any], ...] = LEGEND
) -> np.ndarray:
    """BGR frame of a control cycle: the tracker's drawing (polyline, estimate, status), truth and target."""
    import cv2

    from dyndlo_vision.tracking.annotate import annotate_frame

    est = _pixel(calib, record.p_dlo_estimate)
    img = annotate_frame(rgb, record.polyline_uv, None, point_uv=None if est is None else np.asarray(est),
                         point_measured=record.measured, t=record.t,
                         status=f"{estimate_state(record)}  ctrl {record.controller_ms:.1f} ms")
    _draw_truth_and_target(img, record.p_dlo_true, calib, goal, legend)
    return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)


#: The second tracking camera's inset: this share of the frame's width, in its top-right corner.
INSET_FRACTION = 1 / 3


def _draw_second_view(bgr: np.ndarray, view: Any, record: Any) -> None:
    """Inset (in place, top right) the second tracking camera's frame: the cable its tracker found (cyan),
    and the triangulated estimate (magenta) and true P_DLO (white) drawn into it."""
    import cv2

    img = np.ascontiguousarray(view.rgb).copy()
    pts = np.asarray(view.polyline_uv, dtype=float)
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        if np.all(np.isfinite(a)) and np.all(np.isfinite(b)):
            cv2.line(img, tuple(np.round(a).astype(int)), tuple(np.round(b).astype(int)), CABLE_RGB, 3,
                     cv2.LINE_AA)
    for p, color, radius in ((record.p_dlo_true, TRUE_RGB, 9), (record.p_dlo_estimate, ESTIMATE_RGB, 5)):
        uv = _pixel(view.calibration, p)
        if uv is not None:
            cv2.circle(img, uv, radius, color, 3, cv2.LINE_AA)
    h, w = bgr.shape[:2]
    iw = int(round(w * INSET_FRACTION))
    ih = int(round(iw * img.shape[0] / img.shape[1]))
    small = cv2.cvtColor(cv2.resize(img, (iw, ih), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2BGR)
    cv2.putText(small, "second camera", (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    bgr[0:ih, w - iw:w] = small
    cv2.rectangle(bgr, (w - iw, 0), (w - 1, ih), (255, 255, 255), 1)


def _annotate_truth(rgb: np.ndarray, t: float, true_p: np.ndarray, calib: Any, goal: np.ndarray,
                    status: str, legend: tuple[tuple[str, Any], ...] = LEGEND) -> np.ndarray:
    """BGR frame without a control cycle (nothing tracked): the truth, the target and a status line."""
    import cv2

    from dyndlo_vision.tracking.annotate import annotate_frame

    img = annotate_frame(rgb, None, None, t=t, status=status)
    _draw_truth_and_target(img, true_p, calib, goal, legend)
    return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)


def _widened(lo: float, hi: float, min_span: float) -> tuple[float, float]:
    """Axis limits ``(lo, hi)`` widened about their middle to span at least ``min_span``."""
    if hi - lo >= min_span:
        return lo, hi
    mid = 0.5 * (lo + hi)
    return mid - 0.5 * min_span, mid + 0.5 * min_span


def _write_plot(path: Path, trace: dict[str, Any], goal_name: str = "target") -> None:
    """P_DLO (x, y, z) and its distance to the goal over time: truth vs estimate, up to the outcome."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def rgb(c: tuple[int, int, int]) -> tuple[float, ...]:
        return tuple(v / 255.0 for v in c)

    t = np.asarray(trace["t"], dtype=float)
    est = np.asarray(trace["estimate"], dtype=float).reshape(-1, 3)
    measured = np.asarray(trace["measured"], dtype=bool)
    truth_t = np.asarray(trace["truth_t"], dtype=float)
    truth = np.asarray(trace["truth"], dtype=float).reshape(-1, 3)
    goal = np.asarray(trace["goal"], dtype=float)
    end_t = float(truth_t[-1])
    final = float(np.linalg.norm(truth[-1] - goal))
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    series = [(truth[:, k], est[:, k], goal[k], f"{name} (m)") for k, name in enumerate("xyz")]
    series.append((np.linalg.norm(truth - goal, axis=1), np.linalg.norm(est - goal, axis=1), None,
                   f"distance to\n{goal_name} centre (m)"))
    for ax, (true_k, est_k, goal_k, label) in zip(axes, series, strict=True):
        ax.plot(truth_t, true_k, "-", color=_PLOT_TRUE, lw=1.5, label="true P_DLO")
        ax.plot(t, est_k, "--", color=rgb(ESTIMATE_RGB), lw=1)
        ax.plot(t[measured], est_k[measured], "o", color=rgb(ESTIMATE_RGB), ms=4,
                label="estimate, measured")
        ax.plot(t[~measured], est_k[~measured], "o", mfc="none", color=rgb(ESTIMATE_RGB), ms=4,
                label="estimate, predicted")
        if goal_k is not None:
            ax.axhline(goal_k, color=_PLOT_TARGET, lw=1.2, label=goal_name)
        if trace["replan_end_t"] < end_t - 1e-9:
            ax.axvspan(trace["replan_end_t"], end_t, color="0.9", label="last plan, no re-planning")
        ax.axvline(end_t, color="0.4", ls=":", lw=1)
        if goal_k is not None:  # a coordinate panel
            ax.set_ylim(*_widened(*ax.get_ylim(), _PLOT_MIN_SPAN_M))
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    dist_ax = axes[-1]
    if trace.get("success_radius_m"):
        dist_ax.axhline(trace["success_radius_m"], color=_PLOT_TARGET, ls="--", lw=1.2,
                        label=f"success radius {100 * trace['success_radius_m']:.1f} cm")
    dist_ax.plot([end_t], [final], "o", color=_PLOT_TRUE, ms=6)
    # The closest approach is checked every 2 ms on the swept path; the 25 Hz samples drawn can miss it.
    if trace.get("success_radius_m"):
        outcome = (f"{'hit' if trace['success'] else 'miss'}; final distance {100 * final:.1f} cm, "
                   f"closest {100 * trace['min_distance_m']:.1f} cm")
    else:
        outcome = trace.get("outcome", "success" if trace["success"] else "failure")
    dist_ax.set_title(f"outcome at {end_t:.2f} s: {outcome}", fontsize=9, loc="right")
    dist_ax.set_ylim(bottom=0.0)
    handles, labels = axes[0].get_legend_handles_labels()
    # One legend for all panels, below them: the distance panel's success radius joins the others'.
    for h, lab in zip(*dist_ax.get_legend_handles_labels(), strict=True):
        if lab not in labels:
            handles.append(h)
            labels.append(lab)
    axes[-1].set_xlabel("simulated time (s)")
    point = {"target": "tip", "obstacle": "cable's middle"}.get(goal_name, "point")
    fig.suptitle(f"P_DLO ({point}): simulator truth vs the controller's estimate, up to the outcome")
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    write_atomic(path, lambda p: fig.savefig(p, dpi=100, format="png"))
    plt.close(fig)
