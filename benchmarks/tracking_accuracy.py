"""Accuracy of the perception pipeline on rendered tip-control episodes, after TrackDLO's protocol.

Each episode is one random single-step tip-control action: uniform in the action box, or (share
``--whip-share``) a whip: wind up, throw forwards and down, follow through, each leg in 0.1-0.2 s. The
physics runs in 1 ms steps; every 40 ms (25 Hz) the "tracking" camera renders the scene, and the frame goes
through the control loop's :class:`~dyndlo_vision.tracking.pipeline.CablePipeline`, built as the loop builds
it (``control.sim_perception.loop_pipeline_config`` and ``view_segmenter``: the classical segmenter against
the episode's scene rendered without the cable, the gripper masked around the TCP, the cable's length known,
the motion plane y = 0), with the TCP as the held end (``held_world``). What the controller reads, the
filtered tip predicted ``--read-delay-ms`` after the capture (0: the loop, which renders and reads at the
same instant; 40: TrackDLO's protocol), is compared with the simulator's truth at that time.

Conditions, all on the same rendered episodes:

* ``sharp``: one render at the capture time; ``blur``: the mean of ``--subframes`` renders spread over a
  ``--exposure-ms`` exposure centred on the capture time;
* ``-occ25`` / ``-occ50``: the last 25 % / 50 % of the cable (from the tip) is painted over with the
  background, along the cable as it moves;
* ``sharp-notcp``: no robot pose; the held end clicked in the first frame (``track``'s ``--anchor``), the
  gripper not masked;
* ``sharp-stalebg``: the background image was taken under the previous episode's lighting;
* ``-learnedlen``: the cable's length not given; the pipeline learns it from the frames;
* lighting (headlight, key light intensity and direction) is drawn at random per episode.

Per frame: the measured nodes against the true cable, the share of frames whose tip is measured (status
``measured`` or ``continued``), the share *confidently wrong* (measured and more than 50 mm from the true
tip), head/tail flips, the tip filter's losses, and the errors of the raw and filtered tip (metrics:
``dyndlo_vision.tracking.metrics``), broken down by tip speed band. ``--fit-out`` fits an
``ObservationNoiseModel`` to the tip estimate read by the controller in one condition (the shipped
``noise_model_tracking.json`` names the command that made it in its ``source``).

    python benchmarks/tracking_accuracy.py --episodes 16 --seed 0 --out /tmp/tracking_accuracy.json \
        [--fit-out /tmp/noise_model.json] [--annotate-dir /tmp/annotated]
    python benchmarks/tracking_accuracy.py --quick --out /tmp/q.json    # 2 episodes (a smoke test)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

import dyndlo_vision  # noqa: E402, F401  (chooses the GL backend before mujoco is imported)
from dyndlo_vision.cameras import MujocoCamera, average_frames  # noqa: E402
from dyndlo_vision.control.sim_perception import (  # noqa: E402
    loop_pipeline_config,
    loop_segmenter,
    render_without_cable,
    view_segmenter,
)
from dyndlo_vision.tasks import make_env  # noqa: E402
from dyndlo_vision.tasks.base import DynDLOEnv  # noqa: E402
from dyndlo_vision.tasks.noise import ObservationNoiseModel  # noqa: E402
from dyndlo_vision.tracking import LOOP_FILTER, PinholeCamera  # noqa: E402
from dyndlo_vision.tracking.metrics import (  # noqa: E402
    SPEED_BAND_EDGES_M_S,
    error_summary,
    is_flipped,
    polyline_prefix,
    speed_band_index,
    speed_band_labels,
    symmetric_polyline_error,
)
from dyndlo_vision.tracking.pipeline import CablePipeline, FrameResult, Status  # noqa: E402

CAMERA = "tracking"
FRAME_PERIOD_S = 0.04  # 25 Hz camera = control rate
# TrackDLO's protocol reads the estimate 40 ms (one frame) after the capture; the simulated control loop
# renders and reads at the same instant (0).
READ_DELAYS_MS = (0, 40)
OCCLUDER_HALF_WIDTH_PX = 5
#: A measured tip farther than this from the truth is confidently wrong (m).
WRONG_M = 0.05


@dataclass(frozen=True)
class Condition:
    """One tracking condition applied to the rendered frames."""

    name: str
    blur: bool = False
    occlusion: float = 0.0  # share of the cable hidden, from the tip
    tcp: bool = True  # the robot reports the held end (else: clicked in the first frame)
    stale_background: bool = False  # background image from the previous episode's lighting
    known_length: bool = True  # the cable's length is given (else learned from the frames)


CONDITIONS = (
    Condition("sharp"),
    Condition("blur", blur=True),
    Condition("sharp-occ25", occlusion=0.25),
    Condition("sharp-occ50", occlusion=0.50),
    Condition("blur-occ25", blur=True, occlusion=0.25),
    Condition("blur-occ50", blur=True, occlusion=0.50),
    Condition("sharp-notcp", tcp=False),
    Condition("sharp-stalebg", stale_background=True),
    Condition("sharp-learnedlen", known_length=False),
    Condition("blur-learnedlen", blur=True, known_length=False),
)
QUICK_CONDITIONS = ("sharp", "blur-occ25", "sharp-notcp")


@dataclass(frozen=True)
class Lighting:
    """Scene lighting of one episode."""

    headlight_ambient: float
    headlight_diffuse: float
    key_diffuse: float
    key_dir: tuple[float, float, float]


def nominal_lighting(env: DynDLOEnv) -> Lighting:
    """The lighting the scene was built with."""
    m = env.model
    return Lighting(
        float(m.vis.headlight.ambient[0]),
        float(m.vis.headlight.diffuse[0]),
        float(m.light_diffuse[0, 0]),
        tuple(float(x) for x in m.light_dir[0]),  # type: ignore[arg-type]
    )


def sample_lighting(rng: np.random.Generator, nominal: Lighting) -> Lighting:
    """Random lighting around the nominal one: intensities x0.5-1.5, key light tilted by up to ~30 deg."""
    direction = np.asarray(nominal.key_dir) + rng.uniform(-0.5, 0.5, 3) * np.array([1.0, 1.0, 0.2])
    direction /= np.linalg.norm(direction)
    return Lighting(
        nominal.headlight_ambient * rng.uniform(0.5, 1.5),
        nominal.headlight_diffuse * rng.uniform(0.5, 1.5),
        nominal.key_diffuse * rng.uniform(0.5, 1.5),
        tuple(float(x) for x in direction),  # type: ignore[arg-type]
    )


def apply_lighting(env: DynDLOEnv, light: Lighting) -> None:
    """Sets the scene's headlight and key light (rendering only; physics unaffected)."""
    import mujoco

    m = env.model
    m.vis.headlight.ambient[:] = light.headlight_ambient
    m.vis.headlight.diffuse[:] = light.headlight_diffuse
    m.light_diffuse[0, :] = light.key_diffuse
    m.light_dir[0, :] = light.key_dir
    mujoco.mj_kinematics(m, env.data)
    mujoco.mj_camlight(m, env.data)  # world light directions (light_xdir) follow light_dir only from here


@dataclass
class EpisodeCapture:
    """Rendered frames and ground truth of one episode (K rendered frames, truth for K + 1 times).

    Attributes:
        times: (K + 1,) capture times (s); the last one has truth only (the read time of frame K - 1).
        sharp: K frames rendered at the capture times.
        blurred: K frames averaged over the exposure.
        nodes: (K + 1, N, 3) true cable nodes at the capture times.
        sub_nodes: (K, S, N, 3) true nodes at the sub-frame times of each exposure.
        tip_velocity: (K + 1, 3) true tip velocity (central difference over +-1 physics step).
        tcp: (K + 1, 3) true TCP position.
        background: Scene without the cable under this episode's lighting; ``stale_background`` under the
            previous episode's.
    """

    times: NDArray[np.float64]
    sharp: list[NDArray[np.uint8]]
    blurred: list[NDArray[np.uint8]]
    nodes: NDArray[np.float64]
    sub_nodes: NDArray[np.float64]
    tip_velocity: NDArray[np.float64]
    tcp: NDArray[np.float64]
    background: NDArray[np.uint8]
    stale_background: NDArray[np.uint8]
    diverged: bool = False


def subframe_offsets(exposure_s: float, n_sub: int, dt: float) -> list[int]:
    """Physics-step offsets of ``n_sub`` renders at the centres of equal slices of the exposure."""
    if n_sub < 1:
        raise ValueError(f"--subframes must be >= 1, got {n_sub}")
    centres = (np.arange(n_sub) + 0.5) / n_sub * exposure_s - exposure_s / 2
    return sorted({int(round(c / dt)) for c in centres} | {0})


def render_now(camera: MujocoCamera) -> NDArray[np.uint8]:
    """Renders the current state exactly: ``mj_forward`` first brings what MuJoCo draws (derived positions,
    lights) up to the state after a reset or a lighting change, without changing the state."""
    import mujoco

    mujoco.mj_forward(camera.model, camera.data)
    return camera.read().rgb


def simulate(env: DynDLOEnv, nsteps: int) -> None:
    """Follows the episode's planned trajectory for ``nsteps`` physics steps, one setpoint per step."""
    times = env.scene.time + env.scene.timestep * np.arange(nsteps)
    env.follow(times, *env.replanner.references(times))


def capture_episode(
    env: DynDLOEnv,
    camera: MujocoCamera,
    seed: int,
    action: NDArray[np.float32],
    lighting: Lighting,
    previous_lighting: Lighting,
    offsets: Sequence[int],
) -> EpisodeCapture:
    """Runs one single-step episode in 1 ms steps and renders it at 25 Hz (sharp and blurred)."""
    import mujoco

    env.reset(seed=seed)
    apply_lighting(env, previous_lighting)
    mujoco.mj_forward(env.model, env.data)
    stale = render_without_cable(camera)
    apply_lighting(env, lighting)
    mujoco.mj_forward(env.model, env.data)
    background = render_without_cable(camera)
    # Plan as env.step would, then step the physics ourselves, in slices between renders.
    env.replanner.replan(np.asarray(action, dtype=np.float64), env.scene.time)
    assert env.trajectory is not None
    dt = env.scene.timestep
    period = int(round(FRAME_PERIOD_S / dt))
    total_s = env.trajectory.t_end + env.task.settle_s
    n_frames = int(math.floor(total_s / FRAME_PERIOD_S + 1e-9)) + 1
    step_now = 0
    # Events per frame: sub-frame renders and the +-1 step samples of the tip velocity.
    sharp: list[NDArray[np.uint8]] = []
    blurred: list[NDArray[np.uint8]] = []
    nodes, sub_nodes, tip_vel, tcp, times = [], [], [], [], []
    diverged = False
    for k in range(n_frames + 1):
        centre = k * period
        render_frame = k < n_frames
        events = (
            sorted({max(centre + o, 0) for o in offsets} | {max(centre - 1, 0), centre + 1})
            if render_frame
            else sorted({max(centre - 1, 0), centre, centre + 1})
        )
        subs: list[NDArray[np.float64]] = []
        sub_imgs: list[NDArray[np.uint8]] = []
        tips: dict[int, NDArray[np.float64]] = {}
        for ev in events:
            if ev > step_now:
                simulate(env, ev - step_now)
                step_now = ev
            if not env.scene.is_finite():
                diverged = True
                break
            cable = env.cable_nodes()
            tips[ev] = cable[-1]
            if ev == centre:
                nodes.append(cable)
                tcp.append(env.scene.tcp_positions()[0])
                times.append(centre * dt)
            if render_frame and ev in {max(centre + o, 0) for o in offsets}:
                img = render_now(camera)
                # A clipped event (before t = 0) stands for several sub-frames of the cable at rest.
                repeat = sum(1 for o in offsets if max(centre + o, 0) == ev)
                sub_imgs.extend([img] * repeat)
                subs.extend([cable] * repeat)
                if ev == centre:
                    sharp.append(img)
        if diverged:
            break
        lo, hi = max(centre - 1, 0), centre + 1
        tip_vel.append((tips[hi] - tips[lo]) / ((hi - lo) * dt))
        if render_frame:
            blurred.append(average_frames(sub_imgs))
            sub_nodes.append(np.stack(subs))
    k_ok = min(len(sharp), len(nodes) - 1)
    return EpisodeCapture(
        times=np.asarray(times[: k_ok + 1]),
        sharp=sharp[:k_ok],
        blurred=blurred[:k_ok],
        nodes=np.asarray(nodes[: k_ok + 1]),
        sub_nodes=np.asarray(sub_nodes[:k_ok]),
        tip_velocity=np.asarray(tip_vel[: k_ok + 1]),
        tcp=np.asarray(tcp[: k_ok + 1]),
        background=background,
        stale_background=stale,
        diverged=diverged,
    )


def sample_action(rng: np.random.Generator, env: DynDLOEnv, whip: bool) -> NDArray[np.float32]:
    """A random single-step action: uniform in the action box, or a tip-control whip.

    A whip winds up backwards and up, throws forwards and down, and follows through, each leg in 0.1-0.2 s
    (the target lies ahead of and below the TCP). Uniform actions rarely move the tip faster than 5 m/s
    (1 % of frames); whips often do.
    """
    spec = env.spec_actions
    if not whip:
        return rng.uniform(-1.0, 1.0, spec.size).astype(np.float32)
    legs = np.array(
        [
            [rng.uniform(-0.25, -0.05), rng.uniform(0.0, 0.15)],  # wind up: back and up
            [rng.uniform(0.15, 0.25), rng.uniform(-0.25, 0.0)],  # throw: forward and down
            [rng.uniform(0.0, 0.25), rng.uniform(-0.25, 0.05)],  # follow through
        ]
    )
    start = env.scene.gripper_home[0]
    increments = np.column_stack((legs[:, 0], np.zeros(3), legs[:, 1]))
    points = np.vstack((start, start + np.cumsum(increments, axis=0)))
    times = np.concatenate(([0.0], np.cumsum(rng.uniform(0.1, 0.2, 3))))
    return spec.encode(points, times).astype(np.float32)


def occluder_mask(
    cam: PinholeCamera, node_sets: Sequence[NDArray[np.float64]], fraction: float, shape: tuple[int, int]
) -> NDArray[np.bool_]:
    """Pixels within ``OCCLUDER_HALF_WIDTH_PX`` of the last ``fraction`` of the cable in any node set."""
    mask = np.zeros(shape, dtype=np.uint8)
    for nodes in node_sets:
        tip_part = polyline_prefix(nodes[::-1], fraction)
        uv = cam.project(tip_part)
        uv = uv[np.all(np.isfinite(uv), axis=1)]
        if uv.shape[0] >= 2:
            cv2.polylines(mask, [np.rint(uv).astype(np.int32)], False, 1, 2 * OCCLUDER_HALF_WIDTH_PX + 1)
    return mask.astype(bool)


@dataclass
class TrackOutput:
    """One condition over one episode (K frames): the pipeline's frame results and the estimates read
    ``read_delay_s`` after each capture."""

    results: list[FrameResult] = field(default_factory=list)
    read: list[Any] = field(default_factory=list)


def episode_pipeline(env: DynDLOEnv, camera: MujocoCamera, cond: Condition, background: NDArray[np.uint8],
                     params: Any, anchor: NDArray[np.float64] | None = None) -> CablePipeline:
    """The loop's pipeline for one episode under ``cond`` (the classical segmenter against ``background``;
    ``anchor``: the held end's pixel clicked in the first frame)."""
    config = loop_pipeline_config(env.scene, 1.0, loop_segmenter("background"), params)
    if not cond.known_length:
        config = replace(config, cable_length_m=None)
    if not cond.tcp:
        config = replace(config, gripper_radius_m=None)
    cam = camera.calibration
    return CablePipeline(config, [cam], [view_segmenter(config, camera, cam, background)], anchors=[anchor])


def track_episode(
    env: DynDLOEnv,
    camera: MujocoCamera,
    cap: EpisodeCapture,
    cond: Condition,
    params: Any,
    read_delay_s: float,
    annotate: Path | None = None,
    episode: int = 0,
) -> TrackOutput:
    """Runs one condition's pipeline over the frames of an episode."""
    cam = camera.calibration
    background = cap.stale_background if cond.stale_background else cap.background
    # Without the robot's pose the held end is clicked where the gripper is in the first frame.
    anchor = None if cond.tcp else cam.project(cap.tcp[:1])[0]
    pipeline = episode_pipeline(env, camera, cond, background, params, anchor)
    frames = cap.blurred if cond.blur else cap.sharp
    out = TrackOutput()
    for k, frame in enumerate(frames):
        img = frame
        if cond.occlusion > 0:
            sets = list(cap.sub_nodes[k]) if cond.blur else [cap.nodes[k]]
            occ = occluder_mask(cam, sets, cond.occlusion, img.shape[:2])
            img = img.copy()
            img[occ] = background[occ]
        t = float(cap.times[k])
        result = pipeline.step([img], t, held_world=cap.tcp[k] if cond.tcp else None)
        out.results.append(result)
        out.read.append(pipeline.estimate(t + read_delay_s))
        if annotate is not None and k % 5 == 0:
            write_annotated(annotate / f"ep{episode:03d}_{cond.name}_f{k:03d}.png", img, cam, cap, k, result)
    return out


def write_annotated(path: Path, img: NDArray[np.uint8], cam: PinholeCamera, cap: EpisodeCapture, k: int,
                    result: FrameResult) -> None:
    """Frame with the true cable (green), the measured nodes (blue), the measured tip (red) and its status."""
    canvas = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    true_uv = cam.project(cap.nodes[k])
    cv2.polylines(canvas, [np.rint(true_uv).astype(np.int32)], False, (0, 200, 0), 1)
    meas = result.measurement
    for p, vis in zip(meas.nodes_uv, meas.visible, strict=True):
        if vis and np.all(np.isfinite(p)):
            cv2.circle(canvas, (int(round(p[0])), int(round(p[1]))), 3, (255, 80, 0), 1)
    if result.point_uv is not None:
        u, v = (int(round(c)) for c in result.point_uv)
        cv2.circle(canvas, (u, v), 5, (0, 0, 255), 2)
    speed = float(np.linalg.norm(cap.tip_velocity[k]))
    cv2.putText(canvas, f"t={cap.times[k]:.2f}s tip {speed:.1f} m/s {result.status.value}", (10, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), canvas)


def frame_records(
    cap: EpisodeCapture,
    track: TrackOutput,
    cond: Condition,
    episode: int,
    read_frames: int,
) -> dict[str, NDArray[Any]]:
    """Per-frame errors of one condition over one episode (metres); the estimate read ``read_frames`` on."""
    k_frames = len(track.results)
    visible_share = 1.0 - cond.occlusion
    truth_now, truth_read = cap.nodes[:k_frames], cap.nodes[read_frames : k_frames + read_frames]
    tip_true_now, tip_true_read = truth_now[:, -1], truth_read[:, -1]
    nodes = np.array([np.where(r.measurement.visible[:, None], r.measurement.nodes_xyz, np.nan)
                      for r in track.results])
    seen = np.array([r.status.seen for r in track.results])
    continued = np.array([r.status is Status.CONTINUED for r in track.results])
    raw_tip = np.array([r.point if r.point is not None and s else np.full(3, np.nan)
                        for r, s in zip(track.results, seen, strict=True)])
    lost = np.array([bool(e.lost) for e in track.read])
    filtered = np.array([np.full(3, np.nan) if e.lost else np.asarray(e.position, dtype=float)
                         for e in track.read])
    n_nodes = nodes.shape[1]
    n_unoccluded = int(math.floor((n_nodes - 1) * visible_share + 1e-9)) + 1
    cable_raw = np.array([
        symmetric_polyline_error(nodes[k], polyline_prefix(truth_now[k], visible_share))
        if np.isfinite(nodes[k]).all(axis=1).sum() >= 2 else np.nan
        for k in range(k_frames)
    ])
    coverage = np.mean(np.all(np.isfinite(nodes[:, :n_unoccluded]), axis=2), axis=1)
    flipped = np.array([np.isfinite(nodes[k]).all(axis=1).sum() >= 2 and is_flipped(nodes[k], truth_now[k])
                        for k in range(k_frames)])
    tip_err = np.linalg.norm(raw_tip - tip_true_now, axis=1)
    # P_DLO speed over the control step that ends at the read time (what the noise wrapper can compute).
    tips = cap.nodes[:, -1]
    step = np.vstack((np.zeros((1, 3)), np.diff(tips, axis=0))) / FRAME_PERIOD_S
    read_speed = np.linalg.norm(step[read_frames : k_frames + read_frames], axis=1)
    return {
        "episode": np.full(k_frames, episode),
        "t": cap.times[:k_frames],
        "tip_speed": np.linalg.norm(cap.tip_velocity[:k_frames], axis=1),
        "cable_raw": cable_raw,
        "coverage": coverage,
        "tip_raw_capture": tip_err,
        "tip_raw_read": np.linalg.norm(raw_tip - tip_true_read, axis=1),
        "tip_filtered_read": np.linalg.norm(filtered - tip_true_read, axis=1),
        "tip_measured": seen,
        "tip_continued": continued,
        "wrong": seen & (tip_err > WRONG_M),
        "wrong_continued": continued & (tip_err > WRONG_M),
        "lost": lost,
        "lost_onset": lost & ~np.concatenate(([False], lost[:-1])),
        "flipped": flipped,
        "flip_onset": flipped & ~np.concatenate(([False], flipped[:-1])),
        # For the noise-model fit: the read estimate (a dropout where this frame's tip was not measured), the
        # truth then, its velocity and last-step speed.
        "fit_estimate": np.where(seen[:, None], filtered, np.nan),
        "fit_raw_estimate": raw_tip,
        "fit_truth": tip_true_read,
        "fit_velocity": cap.tip_velocity[read_frames : k_frames + read_frames],
        "fit_speed": read_speed,
        "ms": np.array([r.stage_ms.get("track", np.nan) + r.stage_ms.get("filter", np.nan)
                        for r in track.results]),
    }


def summarise(rec: dict[str, NDArray[Any]], select: NDArray[np.bool_]) -> dict[str, Any]:
    """Summary of the selected frames of one condition."""

    def mm(key: str) -> dict[str, Any]:
        return error_summary(rec[key][select] * 1e3, thresholds=(10.0, 20.0))

    n = int(np.count_nonzero(select))

    def share(key: str) -> float:
        return float(np.mean(rec[key][select])) if n else float("nan")

    return {
        "frames": n,
        "cable_raw_mm": mm("cable_raw"),
        "coverage": share("coverage"),
        "tip_raw_capture_mm": mm("tip_raw_capture"),
        "tip_raw_read_mm": mm("tip_raw_read"),
        "tip_filtered_read_mm": mm("tip_filtered_read"),
        "tip_filtered_read_when_seen_mm": error_summary(
            np.where(rec["tip_measured"], rec["tip_filtered_read"], np.nan)[select] * 1e3,
            thresholds=(10.0, 20.0),
        ),
        "tip_measured": share("tip_measured"),
        "wrong_frames": int(np.count_nonzero(rec["wrong"][select])),
        "wrong_share": share("wrong"),
        "tip_continued": share("tip_continued"),
        "wrong_continued_frames": int(np.count_nonzero(rec["wrong_continued"][select])),
        "lost_events": int(np.count_nonzero(rec["lost_onset"][select])),
        "lost_frames": share("lost"),
        "flip_events": int(np.count_nonzero(rec["flip_onset"][select])),
        "flipped_frames": share("flipped"),
    }


def concat(records: list[dict[str, NDArray[Any]]]) -> dict[str, NDArray[Any]]:
    """Concatenates per-episode records key by key."""
    return {k: np.concatenate([r[k] for r in records]) for k in records[0]}


def print_table(results: dict[str, Any], labels: list[str]) -> None:
    """The per-condition, per-speed-band table (errors in mm: mean/median)."""
    columns = ("frames", "cable", "cover", "tip seen", "continued", "wrong", "of them c.", "tip@cap",
               "hold@rd", "filt|seen", "filt@rd")
    header = f"{'condition':<19}{'band m/s':>9}" + "".join(f" {c:>11}" for c in columns)
    print(header + "  <10mm  <20mm  lost flips")

    def mm(s: dict[str, Any]) -> str:
        return f"{s['mean']:.1f}/{s['median']:.1f}"

    for name, res in results.items():
        for band in ["all", *labels]:
            s = res["all"] if band == "all" else res["bands"][band]
            if s["frames"] == 0:
                continue
            tf = s["tip_filtered_read_mm"]
            cells = (
                str(s["frames"]),
                mm(s["cable_raw_mm"]),
                f"{s['coverage']:.2f}",
                f"{s['tip_measured']:.2f}",
                f"{s['tip_continued']:.2f}",
                str(s["wrong_frames"]),
                str(s["wrong_continued_frames"]),
                mm(s["tip_raw_capture_mm"]),
                mm(s["tip_raw_read_mm"]),
                mm(s["tip_filtered_read_when_seen_mm"]),
                mm(tf),
            )
            print(
                f"{name:<19}{band:>9}"
                + "".join(f" {c:>11}" for c in cells)
                + f" {tf['under'][10.0]:>6.2f} {tf['under'][20.0]:>6.2f}"
                + f" {s['lost_events']:>5} {s['flip_events']:>5}"
            )


def fit_noise_model(
    rec: dict[str, NDArray[Any]], source: str, pipeline: str, args: argparse.Namespace
) -> ObservationNoiseModel:
    """Fits the observation-noise model to one condition's tip estimates at the read time.

    ``source="filtered"``: the tip filter's estimate, a dropout where this frame's tip was not measured (or
    the filter rejected it); ``"raw"``: the raw measurement held until the read (no filter), a dropout where
    it is missing.
    """
    estimate = rec["fit_estimate"] if source == "filtered" else rec["fit_raw_estimate"]
    return ObservationNoiseModel.fit(
        rec["fit_truth"],
        estimate,
        rec["fit_velocity"],
        episode=rec["episode"],
        speed=rec["fit_speed"],
        source=(
            f"benchmarks/tracking_accuracy.py --episodes {args.episodes} --seed {args.seed} "
            f"--whip-share {args.whip_share:g}: the loop's CablePipeline, condition {pipeline!r}, {source} "
            f"tip estimate read {args.read_delay_ms:g} ms after capture, filter sigma_accel "
            f"{args.sigma_accel:g} m/s^2"
        ),
    )


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--episodes", type=int, default=20, help="rendered episodes (default 20)")
    ap.add_argument("--seed", type=int, default=0, help="seed of episode 0; episode i uses seed + i")
    ap.add_argument("--out", type=Path, required=True, help="JSON file for the results")
    ap.add_argument("--fit-out", type=Path, default=None, help="write the fitted noise model (JSON) here")
    ap.add_argument("--fit-condition", default="sharp",
                    help="condition whose tip estimates the model is fitted to (default: the simulated "
                    "control loop's: sharp renders, the TCP, the cable's length known)")
    ap.add_argument("--fit-source", choices=("filtered", "raw"), default="filtered",
                    help="fit the filtered estimate at the read time (default) or the raw measurement held "
                    "until then")
    ap.add_argument("--read-delay-ms", type=int, choices=READ_DELAYS_MS, default=0,
                    help="when the controller reads the estimate after the capture (0: the simulated control "
                    "loop, which renders and reads at the same instant; 40: TrackDLO's protocol)")
    ap.add_argument("--whip-share", type=float, default=0.5, help="share of episodes with fast whip actions")
    ap.add_argument("--exposure-ms", type=float, default=10.0, help="exposure of the blurred frames (ms)")
    ap.add_argument("--subframes", type=int, default=5, help="renders averaged per blurred frame")
    ap.add_argument("--sigma-accel", type=float, default=LOOP_FILTER.sigma_accel,
                    help=f"filter process noise (m/s^2; default {LOOP_FILTER.sigma_accel:g}, the loop's)")
    ap.add_argument("--sigma-meas", type=float, default=LOOP_FILTER.sigma_meas,
                    help=f"filter measurement noise (m; default {LOOP_FILTER.sigma_meas:g})")
    ap.add_argument("--conditions", default="",
                    help="comma-separated subset of: " + ",".join(c.name for c in CONDITIONS))
    ap.add_argument("--annotate-dir", type=Path, default=None,
                    help="write every 5th frame, annotated, as PNG")
    ap.add_argument("--quick", action="store_true",
                    help=f"2 episodes (one whip), conditions {','.join(QUICK_CONDITIONS)} (a smoke test)")
    args = ap.parse_args(argv)
    if args.quick:
        args.episodes = 2
        args.conditions = args.conditions or ",".join(QUICK_CONDITIONS)
    if args.episodes < 1:
        ap.error(f"--episodes must be >= 1, got {args.episodes}")
    if not args.exposure_ms >= 0:
        ap.error(f"--exposure-ms must be >= 0, got {args.exposure_ms}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    cv2.setNumThreads(1)
    conditions = list(CONDITIONS)
    if args.conditions:
        wanted = [s.strip() for s in args.conditions.split(",") if s.strip()]
        unknown = sorted(set(wanted) - {c.name for c in CONDITIONS})
        if unknown:
            raise SystemExit(f"unknown condition(s) {unknown}; choose from {[c.name for c in CONDITIONS]}")
        conditions = [c for c in CONDITIONS if c.name in wanted]
    if args.fit_out is not None and args.fit_condition not in {c.name for c in conditions}:
        raise SystemExit(f"--fit-condition {args.fit_condition!r} is not among the conditions run")
    env = make_env("tip-control").unwrapped
    env.reset(seed=args.seed)
    try:
        camera = MujocoCamera(env.model, env.data, CAMERA, *env.scene.config.image_size, fps=25.0)
        camera.read()
    except (RuntimeError, ValueError) as exc:
        print(f"SKIP: cannot render the {CAMERA!r} camera: {exc}", file=sys.stderr)
        return 2
    offsets = subframe_offsets(args.exposure_ms * 1e-3, args.subframes, env.scene.timestep)
    delay_s = args.read_delay_ms * 1e-3
    params = replace(LOOP_FILTER, sigma_accel=args.sigma_accel, sigma_meas=args.sigma_meas)
    read_frames = int(round(delay_s / FRAME_PERIOD_S))  # truth is recorded at the frame times
    nominal = nominal_lighting(env)
    rng = np.random.default_rng(args.seed)
    labels = speed_band_labels(SPEED_BAND_EDGES_M_S)
    per_cond: dict[str, list[dict[str, NDArray[Any]]]] = {c.name: [] for c in conditions}
    episodes_info = []
    previous = nominal
    t_start = time.perf_counter()
    for e in range(args.episodes):
        lighting = sample_lighting(rng, nominal)
        # --quick: one uniform action and one whip, whatever the seed draws.
        whip = bool(e % 2) if args.quick else bool(rng.random() < args.whip_share)
        action = sample_action(rng, env, whip)
        cap = capture_episode(env, camera, args.seed + e, action, lighting, previous, offsets)
        previous = lighting
        info = {
            "seed": args.seed + e,
            "whip": whip,
            "action": action.tolist(),
            "lighting": asdict(lighting),
            "frames": len(cap.sharp),
            "diverged": cap.diverged,
            "max_tip_speed_m_s": float(np.max(np.linalg.norm(cap.tip_velocity, axis=1))),
        }
        episodes_info.append(info)
        if cap.diverged or len(cap.sharp) < 2:
            print(f"episode {e}: simulation diverged, skipped", flush=True)
            continue
        for cond in conditions:
            track = track_episode(env, camera, cap, cond, params, delay_s, args.annotate_dir, e)
            per_cond[cond.name].append(frame_records(cap, track, cond, e, read_frames))
        elapsed = time.perf_counter() - t_start
        print(
            f"episode {e + 1}/{args.episodes}: {len(cap.sharp)} frames, max tip speed "
            f"{info['max_tip_speed_m_s']:.1f} m/s, {elapsed:.0f} s elapsed",
            flush=True,
        )
    camera.close()
    env.close()
    if not any(per_cond.values()):
        raise SystemExit("no episode could be evaluated (all diverged)")
    results: dict[str, Any] = {}
    merged: dict[str, dict[str, NDArray[Any]]] = {}
    for name, recs in per_cond.items():
        rec = concat(recs)
        merged[name] = rec
        band = speed_band_index(rec["tip_speed"])
        results[name] = {
            "all": summarise(rec, np.ones(band.size, bool)),
            "bands": {lab: summarise(rec, band == i) for i, lab in enumerate(labels)},
            "pipeline_ms_median": float(np.median(rec["ms"])),
            "pipeline_ms_p95": float(np.percentile(rec["ms"], 95)),
        }
    print(f"command: {' '.join([os.path.basename(sys.executable), *sys.argv])}")
    print(
        f"episodes: {args.episodes} (seed {args.seed}), {sum(i['frames'] for i in episodes_info)} frames "
        f"at 25 Hz; camera {CAMERA!r} 640x480; exposure {args.exposure_ms:g} ms ({len(offsets)} renders); "
        f"filter sigma_accel {args.sigma_accel:g} m/s^2, sigma_meas {args.sigma_meas * 1e3:g} mm; estimate "
        f"read {args.read_delay_ms:g} ms after capture"
    )
    print(
        "errors mean/median in mm. cable = symmetric point-to-polyline error of the measured nodes at "
        "capture (visible part vs the unoccluded truth); cover = share of unoccluded nodes seen; tip seen = "
        "share of frames whose tip is measured (or continued); continued = share continued past where the "
        "cable disappears; wrong = frames measured (or continued) more than 50 mm from the true tip; of them "
        "c. = of those, continued; tip@cap = measured tip at capture; hold@rd = measured tip held to read "
        "time; "
        "filt|seen = tip filter at read time on the frames whose tip was measured; filt@rd = tip filter at "
        "read time, all frames; <10mm/<20mm = share of all frames with filt@rd under 10/20 mm; lost = "
        "tip-filter lost events; flips = head/tail flip events"
    )
    print_table(results, labels)
    fits: dict[str, dict[str, Any]] = {}
    for name, rec in merged.items():
        fits[name] = {}
        for source in ("filtered", "raw"):
            try:
                fits[name][source] = fit_noise_model(rec, source, name, args).to_dict()
            except ValueError as exc:  # too few frames with a tip estimate (occluded tip)
                fits[name][source] = {"error": str(exc)}
    print("noise model fits (bias mm | std mm | std per m/s (mm) | latency ms | dropout | mean run):")
    for name, by_source in fits.items():
        for source, fit in by_source.items():
            if "error" not in fit:
                print(
                    f"  {name:<19}{source:<9}"
                    f"{np.round(np.asarray(fit['bias_m']) * 1e3, 1).tolist()} | "
                    f"{np.round(np.asarray(fit['std_m']) * 1e3, 1).tolist()} | "
                    f"{fit['std_per_speed_s'] * 1e3:.1f} | {fit['latency_s'] * 1e3:.1f} | "
                    f"{fit['dropout_prob']:.2f} | {fit['dropout_mean_run']:.2f}"
                )
    model = None
    if args.fit_out is not None:
        model = fit_noise_model(merged[args.fit_condition], args.fit_source, args.fit_condition, args)
        args.fit_out.parent.mkdir(parents=True, exist_ok=True)
        model.save(args.fit_out)
        print(f"noise model -> {args.fit_out}: {json.dumps(model.to_dict())}")
    payload = {
        "command": " ".join([os.path.basename(sys.executable), *sys.argv]),
        "machine": platform.platform(),
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "camera": camera.calibration.to_dict(),
        "speed_bands_m_s": list(SPEED_BAND_EDGES_M_S),
        "episodes": episodes_info,
        "conditions": results,
        "noise_model": model.to_dict() if model is not None else None,
        "noise_model_fits": fits,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=1, default=float), encoding="utf-8")
    print(f"results -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
