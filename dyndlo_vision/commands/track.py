"""``dyndlo-vision track``: track a cable through a video file or an image folder, one CSV row per frame.

The command reads the options and the files and writes the outputs; the tracking is
:class:`~dyndlo_vision.tracking.pipeline.CablePipeline` (the one the control loop runs): segment the cable,
extract its ordered centreline, identify its held end again in every frame (continuity of the held end's
motion and the last frame's nodes registered to the new centreline; with ``--tcp-log`` the logged gripper),
lift it onto the motion plane (or triangulate it from two views), take the tracked point (the free tip, or a
fraction of the cable from the held end), and filter it with a constant-velocity Kalman filter: in world
coordinates when a calibration and the motion plane are given, else in pixels.

A frame whose two cable ends cannot be told apart, whose cable runs out of the image or into a region too
thick to be cable at the point, or whose cable is shorter or longer than the cable (its length given with
``--cable-length``, else learned from the frames where both ends are seen) is not measured: the filter
predicts, and ``visible`` is 0. The automatic background is by default the per-pixel median of frames sampled
across the video (any static background, a moving cable), or one colour per frame for videos too short for
it.

CSV columns ``frame,time_s,visible,u,v,x,y,z,x_meas,y_meas,z_meas,status``: ``status`` is ``measured`` (this
frame's measurement of the point, accepted by the filter), ``continued`` (this frame's cable continued
straight to a hidden tip by the missing length, with ``--cable-length``), ``predicted`` (the filter's
prediction: no accepted measurement this frame) or ``lost`` (no estimate); ``visible`` is 1 exactly when the
status is measured or continued. ``u,v`` is the measured pixel (empty when not measured); ``x,y,z`` is the
filtered world position (m) at the frame's time, empty without ``--calib`` and while lost;
``x_meas,y_meas,z_meas`` is this frame's measured world position, unfiltered (empty when not measured or
without ``--calib``).

**Two cameras** (``--second-video`` with ``--second-calib``): a cable that leaves any one plane (thrown,
vaulted, whipped out of plane) cannot be placed by one camera. With a second camera's video of the same
motion, recorded in sync (frame k of both videos at the same time), the cable is tracked in both and its
centreline is triangulated (:func:`~dyndlo_vision.tracking.stereo.stereo_measurement`): no ``--plane`` is
needed. The held end is the logged gripper (``--tcp-log``) or else triangulated from where the two
centrelines start; without ``--second-anchor`` the second view's held end is the cable end on the epipolar
line of the first view's. Without ``--cable-length`` a point past the held end is measured only when the
triangulated cable reaches the far end of the cable in both images (one view may hide the tip). With it, the
tip is placed from the triangulated polyline as in one view, and ``--point FRACTION`` is that share of the
length along the triangulated cable. ``u,v`` stay in the first video's pixels; the annotated video insets the
second.

Outputs are written to temporary files beside their destinations and renamed at the end, so after any error
neither the CSV nor the video exists.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import tempfile
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.tracking.masks import MAX_WIDTH_RATIO, MIN_CUT_RADIUS_PX
from dyndlo_vision.tracking.params import TRACK_FILTER
from dyndlo_vision.tracking.segmenters import MIN_BACKGROUND_FRAMES

if TYPE_CHECKING:
    from dyndlo_vision.cameras.protocol import Frame
    from dyndlo_vision.tracking.camera_model import PinholeCamera
    from dyndlo_vision.tracking.pipeline import CablePipeline, FrameResult, PipelineConfig

T = TypeVar("T")

HELP = "track a cable in a video or image folder and write the tracked point per frame to CSV"

#: Pixel-mode filter settings are the world ones times this scale (a cable filling a 640 px wide image from
#: about a metre away spans roughly 500 px per metre;
#: :data:`~dyndlo_vision.tracking.pipeline.NOMINAL_PX_PER_M`).
_PX_PER_M_NOMINAL = 500.0
#: Frames sampled across the video for ``--background median`` (and ``auto``).
_MEDIAN_FRAMES = 64
#: Mask regions thicker than this share of the image's shorter side are not cable (at 640x480: 48 px). A
#: per-frame background colour segments a whole floor in front of a dark backdrop, and its skeleton is a line
#: the tracker would otherwise follow with confidence.
_MAX_CABLE_WIDTH_SHARE = 0.1
#: ``--gripper-radius`` default: the simulator's 2 cm gripper sphere plus a margin (the loop masks the same).
_GRIPPER_RADIUS_M = 0.03
CSV_COLUMNS = ("frame", "time_s", "visible", "u", "v", "x", "y", "z", "x_meas", "y_meas", "z_meas", "status")
NODE_CSV_COLUMNS = ("frame", "time_s", "node", "visible", "u", "v", "x", "y", "z")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``track``."""
    from dyndlo_vision.commands import _options as options
    from dyndlo_vision.tracking.networks import SHIPPED_NAME

    p.add_argument("video", metavar="VIDEO", help="video file OpenCV can read, or a folder of images")
    p.add_argument("--out", required=True, metavar="TRACK.csv", help="CSV to write (folder must exist)")
    p.add_argument(
        "--calib",
        metavar="CALIB.json",
        help="camera calibration (PinholeCamera JSON); needs --plane, or a second camera (--second-video)",
    )
    p.add_argument(
        "--plane",
        metavar="NX,NY,NZ,D",
        help="world plane n.x + d = 0 the cable moves in, e.g. 0,1,0,0 for y = 0; needs --calib",
    )
    p.add_argument(
        "--second-video",
        metavar="VIDEO2",
        help="a second camera's video (or image folder) of the same motion, recorded in sync: frame k of "
        "both at the same time, at the same frame rate. The cable is tracked in both and triangulated, so it "
        "may move in 3D; needs --calib and --second-calib, and replaces --plane",
    )
    p.add_argument(
        "--second-calib",
        metavar="CALIB2.json",
        help="the second camera's calibration, in the same world frame as --calib (e.g. both from "
        "`dyndlo-vision calibrate --extrinsic` with one board lying at one pose)",
    )
    p.add_argument("--second-anchor", metavar="U,V", help="--anchor for the second video")
    options.add_segmenter(p, ("learned", "background", "hsv"), "background")
    options.add_segmenter_model(p, default=SHIPPED_NAME)
    options.add_short_side(p)
    options.add_hsv_bounds(p)
    p.add_argument(
        "--point",
        default="tip",
        metavar="tip|FRACTION",
        help="tracked point: the free tip (default) or a fraction of the length from the held end, in [0, 1]",
    )
    p.add_argument(
        "--anchor",
        metavar="U,V",
        help="pixel of the held end (the gripper) in the first frame with a cable: the cable end nearest it "
        "is the held end; after that its identity is checked in every frame (its motion, the last frame's "
        "nodes), and a frame whose ends cannot be told apart is not measured. Without it the upper end is "
        "taken (a hanging cable's; printed)",
    )
    p.add_argument(
        "--background",
        choices=("auto", "median", "frame"),
        default=None,
        help="with --segmenter background: the background model. 'median' learns a per-pixel median from "
        "frames sampled across the whole video (any static background, e.g. MuJoCo renders; the cable must "
        "move; reads the video twice); 'frame' estimates one colour from each frame (uniform backgrounds, a "
        "still cable); "
        f"'auto' (default) is 'median' for videos of at least {MIN_BACKGROUND_FRAMES} frames, else 'frame'",
    )
    p.add_argument(
        "--open-radius",
        type=int,
        default=0,
        help="radius of the mask opening that removes speckle (default 0, none: an opening erases cables "
        "only 1-2 px wide, like the simulator's; 1 for noisy footage of thicker cables)",
    )
    p.add_argument(
        "--cable-length",
        type=float,
        metavar="L",
        help="length of the cable in metres from where it leaves the held end (the gripper) to its tip; the "
        "tip is measured from the first frame (without it, once the length is learned from the video). With "
        "--point tip and the held end placed by --tcp-log or the clicked gripper's appearance, a polyline "
        "shorter than that is continued straight by the missing length (status continued) when at least 80%% "
        "of it is seen; otherwise a short one is not measured (visible=0). With two cameras, --point "
        "FRACTION "
        "is that share of the length along the triangulated cable",
    )
    p.add_argument(
        "--tcp-log",
        metavar="TCP.csv",
        help="the gripper's position over time, a CSV with columns time_s,x,y,z (s on the video's clock, m "
        "in the calibration's world frame; other columns are ignored); needs --calib/--plane. The gripper "
        "is masked out of every frame (a disk of --gripper-radius around its projection), its projection "
        "is the held end, and with --cable-length the tip is continued from it",
    )
    p.add_argument(
        "--gripper-radius",
        type=float,
        default=None,
        metavar="R",
        help=f"with --tcp-log: radius in m of the sphere around the TCP that is masked (default "
        f"{_GRIPPER_RADIUS_M:g})",
    )
    p.add_argument(
        "--max-width-ratio",
        type=float,
        default=MAX_WIDTH_RATIO,
        metavar="K",
        help=f"mask regions thicker than K times the cable's width measured in the frame (at least "
        f"{2 * MIN_CUT_RADIUS_PX:g} px) are not cable: a gripper or a box is removed, and a cable end that "
        f"runs into one is not taken for the tip (default {MAX_WIDTH_RATIO:g}; 0: off, only regions wider "
        f"than {100 * _MAX_CABLE_WIDTH_SHARE:g}%% of the image are removed)",
    )
    p.add_argument("--nodes", type=int, default=20, help="centreline nodes (default 20)")
    p.add_argument("--annotated", metavar="OUT.mp4", help="also write an annotated MP4")
    p.add_argument(
        "--nodes-out",
        metavar="NODES.csv",
        help="also write the whole tracked cable: one row per frame and node (--nodes of them, node 0 at the "
        "held end), columns frame,time_s,node,visible,u,v,x,y,z; the measured, unfiltered positions (x,y,z "
        "lifted onto --plane or triangulated from two cameras; empty in pixel mode and where not measured)",
    )
    p.add_argument("--fps", type=float, help="frame rate; overrides the video's time stamps (folders: 25)")
    p.add_argument(
        "--sigma-accel",
        type=float,
        help=f"the filter's acceleration noise, m/s^2, in pixel mode px/s^2 (default: a continuous white "
        f"acceleration of {TRACK_FILTER.sigma_accel:g} m/s^2 per 40 ms, what a whipped tip does; in pixel "
        f"mode "
        f"{TRACK_FILTER.sigma_accel * _PX_PER_M_NOMINAL:g} px/s^2). A value given here is a "
        f"piecewise-constant "
        "acceleration of that deviation: lower values smooth more and lag a fast tip",
    )
    p.add_argument(
        "--sigma-meas",
        type=float,
        help=f"the filter's measurement noise, m (default {TRACK_FILTER.sigma_meas:g}; in pixel mode "
        f"{TRACK_FILTER.sigma_meas * _PX_PER_M_NOMINAL:g} px)",
    )
    options.add_quiet(p)


# ------------------------------------------------------------------------------------------- parsing


def parse_floats(text: str, count: int, option: str) -> NDArray[np.float64]:
    """``count`` finite comma-separated numbers, e.g. ``"0,1,0,0"``.

    Raises:
        ValueError: Naming the option and the text when it is not ``count`` finite numbers.
    """
    parts = [s.strip() for s in str(text).split(",")]
    try:
        values = np.array([float(s) for s in parts], dtype=np.float64)
    except ValueError:
        values = np.zeros(0)
    if values.size != count or len(parts) != count or not np.all(np.isfinite(values)):
        raise ValueError(f"{option} must be {count} comma-separated finite numbers, got {text!r}")
    return values


def parse_point(text: str) -> float:
    """``"tip"`` -> 1.0, else a fraction of the cable length from the held end in [0, 1].

    Raises:
        ValueError: If it is neither ``tip`` nor a number in [0, 1].
    """
    if str(text).strip().lower() == "tip":
        return 1.0
    try:
        fraction = float(text)
    except ValueError:
        fraction = math.nan
    if not 0.0 <= fraction <= 1.0:  # also rejects NaN
        raise ValueError(f"--point must be 'tip' or a fraction of the cable length in [0, 1], got {text!r}")
    return fraction


def read_tcp_log(path: Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Times (K,) and TCP positions (K, 3) from a CSV with columns ``time_s,x,y,z`` (any others ignored).

    Raises:
        ValueError: Naming the file and the problem: a missing column, a value that is not a finite number
            (with its line), no rows, or times that do not increase.
    """
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        columns = ("time_s", "x", "y", "z")
        missing = [c for c in columns if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(
                f"--tcp-log {path}: missing column(s) {', '.join(missing)}; expected a header with "
                f"time_s,x,y,z, got {reader.fieldnames}"
            )
        rows = []
        for line, row in enumerate(reader, start=2):
            try:
                values = [float(row[c]) for c in columns]
            except (TypeError, ValueError):
                values = [math.nan]
            if not all(math.isfinite(v) for v in values):
                raise ValueError(
                    f"--tcp-log {path} line {line}: expected finite numbers in time_s,x,y,z, got "
                    f"{[row.get(c) for c in columns]}"
                )
            rows.append(values)
    if not rows:
        raise ValueError(f"--tcp-log {path} has no rows")
    table = np.array(rows, dtype=np.float64)
    bad = np.flatnonzero(np.diff(table[:, 0]) <= 0)
    if bad.size:
        raise ValueError(
            f"--tcp-log {path}: time_s must increase from row to row; line {bad[0] + 3} has "
            f"{table[bad[0] + 1, 0]!r} after {table[bad[0], 0]!r}"
        )
    return table[:, 0], table[:, 1:]


def tcp_at(
    times: NDArray[np.float64], positions: NDArray[np.float64], t: float, tolerance_s: float
) -> NDArray[np.float64] | None:
    """The TCP at time ``t``, linear between log rows; None more than ``tolerance_s`` outside the log."""
    if t < times[0] - tolerance_s or t > times[-1] + tolerance_s:
        return None
    return np.array([np.interp(t, times, positions[:, k]) for k in range(3)])


# ------------------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class _Settings:
    """The checked options: the pipeline's configuration, and the files and clicks around it."""

    video: Path
    out: Path
    annotated: Path | None
    nodes_out: Path | None
    second_video: Path | None
    second_calib: Path | None
    anchor: NDArray[np.float64] | None
    second_anchor: NDArray[np.float64] | None
    tcp_log: Path | None
    fps: float | None
    quiet: bool
    pipeline: PipelineConfig


def _positive(value: float | None, option: str) -> float | None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ValueError(f"{option} must be a positive finite number, got {value!r}")
    return value


def _settings(args: argparse.Namespace) -> _Settings:
    """Validates every argument that needs no file (raises ValueError naming the bad one)."""
    second_video = None if args.second_video is None else Path(args.second_video)
    if second_video is None:
        for option, value in (("--second-calib", args.second_calib), ("--second-anchor", args.second_anchor)):
            if value is not None:
                raise ValueError(f"{option} is for the second camera; it needs --second-video")
        if (args.calib is None) != (args.plane is None):
            raise ValueError(
                "--calib and --plane go together: world positions come from intersecting the camera rays "
                "with the motion plane (a video has no depth); give both, or neither to track in pixels (or "
                "a second camera, --second-video, to triangulate)"
            )
    else:
        if args.calib is None or args.second_calib is None:
            raise ValueError(
                "--second-video needs --calib and --second-calib: the cable is triangulated from the two "
                "calibrated cameras"
            )
        if args.plane is not None:
            raise ValueError(
                "--plane is for one camera; with --second-video the cable is triangulated from the two views "
                "and may leave any plane: drop --plane"
            )
        if second_video.exists() and second_video.resolve() == Path(args.video).resolve():
            raise ValueError(f"--second-video {second_video} is the first video; the two views must differ")
    world = args.calib is not None
    plane = None
    if args.plane is not None:
        values = parse_floats(args.plane, 4, "--plane")
        if np.linalg.norm(values[:3]) == 0:
            raise ValueError(f"--plane normal must be non-zero, got {args.plane!r}")
        plane = (values[:3], float(values[3]))
    if args.background is not None and args.segmenter != "background":
        raise ValueError(
            f"--background {args.background} is for --segmenter background, not {args.segmenter}"
        )
    if args.open_radius < 0:
        raise ValueError(f"--open-radius must be >= 0, got {args.open_radius}")
    if args.nodes < 2:
        raise ValueError(f"--nodes must be at least 2, got {args.nodes}")
    cable_length = _positive(args.cable_length, "--cable-length")
    if cable_length is not None and not world:
        raise ValueError(
            "--cable-length needs --calib and --plane (or a second camera): the cable's length is measured "
            "in metres"
        )
    if cable_length is not None and parse_point(args.point) != 1.0 and second_video is None:
        raise ValueError(
            f"--cable-length places the free tip with one camera; it cannot be used with --point "
            f"{args.point} (with two cameras it can: the point is then that share of the length along the "
            "triangulated cable)"
        )
    tcp_log = None if args.tcp_log is None else Path(args.tcp_log)
    if tcp_log is not None and not world:
        raise ValueError(
            "--tcp-log needs --calib and --plane (or a second camera): the gripper's positions are in the "
            "world frame"
        )
    for option, value in (("--anchor", args.anchor), ("--second-anchor", args.second_anchor)):
        if tcp_log is not None and value is not None:
            raise ValueError(
                f"--tcp-log gives the held end in every frame (the projected gripper); drop {option}"
            )
    gripper_radius = _positive(args.gripper_radius, "--gripper-radius")
    if gripper_radius is not None and tcp_log is None:
        raise ValueError("--gripper-radius is masked around the logged gripper; it needs --tcp-log")
    if not (math.isfinite(args.max_width_ratio) and (args.max_width_ratio == 0 or args.max_width_ratio > 1)):
        raise ValueError(
            f"--max-width-ratio must be 0 (off) or a number above 1, got {args.max_width_ratio!r}"
        )
    sigma_accel = _positive(args.sigma_accel, "--sigma-accel")
    sigma_meas = _positive(args.sigma_meas, "--sigma-meas")
    if not world:  # the options are in pixels; the pipeline's filter is in metres, scaled to pixels
        sigma_accel = None if sigma_accel is None else sigma_accel / _PX_PER_M_NOMINAL
        sigma_meas = None if sigma_meas is None else sigma_meas / _PX_PER_M_NOMINAL
    filter_params = TRACK_FILTER
    if sigma_accel is not None:  # a piecewise-constant white acceleration of that deviation
        filter_params = replace(filter_params, sigma_accel=sigma_accel, accel_psd=None)
    if sigma_meas is not None:
        filter_params = replace(filter_params, sigma_meas=sigma_meas)
    out = Path(args.out)
    annotated = None if args.annotated is None else Path(args.annotated)
    nodes_out = None if getattr(args, "nodes_out", None) is None else Path(args.nodes_out)
    video = Path(args.video)
    for path, option in ((out, "--out"), (annotated, "--annotated"), (nodes_out, "--nodes-out")):
        if path is None:
            continue
        if not path.parent.is_dir():
            raise ValueError(f"{option}: folder {path.parent} does not exist")
        if path.is_dir():
            raise ValueError(f"{option}: {path} is a folder, expected a file name")
        for source in (video, second_video):
            if source is not None and source.exists() and path.resolve() == source.resolve():
                raise ValueError(f"{option} {path} is an input video; refusing to overwrite it")
    if annotated is not None:
        if annotated.suffix.lower() != ".mp4":
            raise ValueError(f"--annotated must be an .mp4 file name, got {annotated}")
        if annotated.resolve() == out.resolve():
            raise ValueError(f"--out and --annotated are the same file: {out}")
    others = {p.resolve() for p in (out, annotated) if p is not None}
    if nodes_out is not None and nodes_out.resolve() in others:
        raise ValueError(f"--nodes-out {nodes_out} is another output's file")
    from dyndlo_vision.commands._options import segmenter_config
    from dyndlo_vision.tracking.pipeline import PipelineConfig
    from dyndlo_vision.tracking.tracker import Plane

    segmenter = segmenter_config(args, background=str(args.background or "auto"),
                                 open_radius=int(args.open_radius))
    pipeline = PipelineConfig(
        segmenter=segmenter,
        nodes=int(args.nodes),
        point=parse_point(args.point),
        cable_length_m=cable_length,
        plane=None if plane is None else Plane(plane[0], plane[1]),
        filter=filter_params,
        gripper_radius_m=None if tcp_log is None else float(gripper_radius or _GRIPPER_RADIUS_M),
        max_width_share=_MAX_CABLE_WIDTH_SHARE,
        max_width_ratio=None if args.max_width_ratio == 0 else float(args.max_width_ratio),
    )
    return _Settings(
        video=video,
        out=out,
        annotated=annotated,
        nodes_out=nodes_out,
        second_video=second_video,
        second_calib=None if args.second_calib is None else Path(args.second_calib),
        anchor=None if args.anchor is None else parse_floats(args.anchor, 2, "--anchor"),
        second_anchor=None
        if args.second_anchor is None
        else parse_floats(args.second_anchor, 2, "--second-anchor"),
        tcp_log=tcp_log,
        fps=_positive(args.fps, "--fps"),
        quiet=bool(args.quiet),
        pipeline=pipeline,
    )


def _check_plane_visible(camera: PinholeCamera, plane: Any, text: str) -> None:
    """Every image corner and the centre must see the plane in front of the camera (else ValueError).

    The tracking core raises the same error for a single pixel mid-video; checking before the first frame
    gives the clear message at once, before any output file is opened.
    """
    w, h = camera.width, camera.height
    probes = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, (h - 1) / 2]], float)
    try:
        camera.intersect_plane(probes, plane.normal, plane.d)
    except ValueError as exc:
        raise ValueError(
            f"--plane {text} cannot be used with this camera: {exc}; the cable's "
            "motion plane must be seen in front of the camera across the whole image"
        ) from exc


# ------------------------------------------------------------------------------------------- the run


def sample_evenly(items: Iterable[T], max_items: int) -> list[T]:
    """At most ``max_items`` items spread evenly over an iterable of unknown length (bounded memory).

    Keeps every ``stride``-th item; whenever more than ``max_items`` are kept, every second one is dropped
    and the stride doubles.
    """
    if max_items < 1:
        raise ValueError(f"max_items must be >= 1, got {max_items}")
    kept: list[T] = []
    stride = 1
    for i, item in enumerate(items):
        if i % stride == 0:
            kept.append(item)
            if len(kept) > max_items:
                kept = kept[::2]
                stride *= 2
    return kept


class _AtomicOutputs:
    """Temporary files beside their destinations, renamed over them only by :meth:`commit`.

    On an exception inside the ``with`` block (or in :meth:`commit`) every temporary file is removed, and so
    is any destination already renamed: after a failure none of the outputs exists.
    """

    def __init__(self, destinations: list[Path]) -> None:
        self.destinations = destinations
        self.temps: list[Path] = []

    def __enter__(self) -> list[Path]:
        for path in self.destinations:
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
            os.close(fd)
            self.temps.append(Path(tmp))
        return self.temps

    def commit(self) -> None:
        """Renames every temporary file onto its destination."""
        done: list[Path] = []
        try:
            for tmp, final in zip(self.temps, self.destinations, strict=True):
                os.replace(tmp, final)
                done.append(final)
        except BaseException:
            for final in done:
                final.unlink(missing_ok=True)
            raise

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        for tmp in self.temps:
            tmp.unlink(missing_ok=True)  # no-op after a commit


def _fmt(value: float, digits: int) -> str:
    """Fixed-point text, empty for NaN; ``+ 0.0`` turns a rounded ``-0.0`` into ``0.0``."""
    return f"{round(value, digits) + 0.0:.{digits}f}" if math.isfinite(value) else ""


def _print_note(message: Warning | str, *_: object, **__: object) -> None:
    """Shows a library warning (e.g. an assumed frame rate) as a one-line note on stderr."""
    print(f"note: {message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """Track every frame of ``VIDEO`` and write the CSV (and the annotated MP4)."""
    with warnings.catch_warnings():
        warnings.simplefilter("once")
        warnings.showwarning = _print_note
        return _run(args)


def _check_calibration(calib: PinholeCamera, option: str, path: str, source: Any, video: Path) -> None:
    if (calib.width, calib.height) != (source.width, source.height):
        raise ValueError(
            f"{option} {path} is for {calib.width}x{calib.height} images, but {video} has "
            f"{source.width}x{source.height} frames"
        )


def _check_anchor(anchor: NDArray[np.float64] | None, option: str, text: str, source: Any) -> None:
    if anchor is not None and not (
        -0.5 <= anchor[0] <= source.width - 0.5 and -0.5 <= anchor[1] <= source.height - 0.5
    ):
        raise ValueError(f"{option} {text} is outside the {source.width}x{source.height} image")


def _frame_pairs(first: Any, second: Any, cfg: _Settings) -> Iterable[list[Frame]]:
    """Frames of one video (lists of one), or frame k of both (the views are recorded in sync).

    Raises:
        ValueError: When one video ends before the other: the two were not recorded frame for frame.
    """
    if second is None:
        for frame in first:
            yield [frame]
        return
    frames2 = iter(second)
    n = 0
    for frame in first:
        frame2 = next(frames2, None)
        if frame2 is None:
            raise ValueError(
                f"--second-video {cfg.second_video} ended after {n} frames, but {cfg.video} goes on: the two "
                "views must be recorded in sync, frame for frame"
            )
        n += 1
        yield [frame, frame2]
    if next(frames2, None) is not None:
        raise ValueError(
            f"{cfg.video} ended after {n} frames, but --second-video {cfg.second_video} goes on: the two "
            "views must be recorded in sync, frame for frame"
        )


def _build_pipeline(
    cfg: _Settings, cameras: list[Any], sources: list[Any]
) -> tuple[CablePipeline, list[str]]:
    """The pipeline of the run and each view's background kind; a median background is learned from frames
    sampled across each video (read once more)."""
    from dyndlo_vision.cameras.files import VideoFileCamera
    from dyndlo_vision.tracking.pipeline import CablePipeline
    from dyndlo_vision.tracking.segmenters import build_segmenter, build_view_segmenter

    seg = cfg.pipeline.segmenter
    segmenters, kinds = [], []
    for video, source in zip([cfg.video, cfg.second_video][: len(cameras)], sources, strict=True):
        frames = None
        if seg.kind == "background" and seg.background in ("auto", "median"):
            with VideoFileCamera(video, fps=cfg.fps) as first_pass:
                frames = sample_evenly((f.rgb for f in first_pass), _MEDIAN_FRAMES)
            if seg.background == "auto" and 0 < len(frames) < MIN_BACKGROUND_FRAMES:
                print(
                    f"note: {video} has {len(frames)} frames, too few to learn its background from "
                    f"(--background auto needs {MIN_BACKGROUND_FRAMES}); estimating one background colour "
                    f"per "
                    "frame",
                    file=sys.stderr,
                )
            if not frames:  # no frames: the tracking pass reports the empty video
                frames = None
        if frames is None and seg.kind == "background" and seg.background == "median":
            base, kind = build_segmenter(replace(seg, background="frame"))
        else:
            base, kind = build_segmenter(
                seg, frame_size=(source.width, source.height), background_frames=frames
            )
        gripper = 0.0 if cfg.tcp_log is not None else None  # its radius follows the gripper's depth
        segmenters.append(
            build_view_segmenter(
                base,
                gripper_radius_px=gripper,
                max_width_share=cfg.pipeline.max_width_share,
                max_width_ratio=cfg.pipeline.max_width_ratio,
            )
        )
        kinds.append(kind)
    anchors = [cfg.anchor, cfg.second_anchor][: len(cameras)]
    return CablePipeline(cfg.pipeline, cameras, segmenters, anchors), kinds


def _csv_row(frame: Frame, result: FrameResult, world: bool) -> list[object]:
    """The frame's CSV row (:data:`CSV_COLUMNS`)."""
    seen = result.status.seen
    est = result.estimate
    uv = result.point_uv if seen and result.point_uv is not None else np.full(2, np.nan)
    xyz = est.position if (world and not est.lost) else np.full(3, np.nan)
    meas = result.point if (seen and world) else np.full(3, np.nan)
    return (
        [frame.index, f"{frame.t_capture:.6f}", int(seen)]
        + [_fmt(float(c), 3) for c in uv]
        + [_fmt(float(c), 6) for c in (*xyz, *meas)]
        + [result.status.value]
    )


def _node_rows(frame: Frame, result: FrameResult, world: bool) -> list[list[object]]:
    """``--nodes-out`` rows of a frame: each node's measured pixel and world position."""
    meas = result.measurement
    rows: list[list[object]] = []
    for k in range(len(meas.visible)):
        seen = bool(meas.visible[k])
        uv = meas.nodes_uv[k] if seen else np.full(2, np.nan)
        xyz = meas.nodes_xyz[k] if seen and world else np.full(3, np.nan)
        rows.append(
            [frame.index, f"{frame.t_capture:.6f}", k, int(seen and np.all(np.isfinite(uv)))]
            + [_fmt(float(c), 3) for c in uv]
            + [_fmt(float(c), 6) for c in xyz]
        )
    return rows


def _annotated(frames: list[Frame], result: FrameResult, pipeline: CablePipeline) -> NDArray[np.uint8]:
    """The first view with the tracked cable, the estimate and its status drawn (the second inset)."""
    import cv2

    from dyndlo_vision.tracking.annotate import annotate_frame, inset_view, project_point_covariance

    est = result.estimate
    images = []
    for k, (view, frame, vr) in enumerate(zip(pipeline.views, frames, result.views, strict=True)):
        rgb = frame.rgb
        zone = view.segmenter.zone
        if zone is not None:  # where the cable cannot be seen: regions too thick to be cable
            rgb = rgb.copy()
            rgb[zone] = (0.6 * rgb[zone] + np.array([0.0, 0.0, 100.0])).astype(np.uint8)
        gripper = view.segmenter.gripper
        if gripper is not None and gripper.center_uv is not None:  # the masked gripper, outlined
            u, v = gripper.center_uv
            rgb = cv2.circle(
                rgb.copy(),
                (int(round(u)), int(round(v))),
                int(round(gripper.radius_px)),
                (0, 0, 255),
                1,
                cv2.LINE_AA,
            )
        point_uv = cov_uv = None
        if not est.lost:
            if view.camera is not None:
                point_uv, cov_uv = project_point_covariance(view.camera, est.position, est.covariance[:3, :3])
            else:
                point_uv, cov_uv = est.position[:2], est.covariance[:2, :2]
        if k == 0:
            nodes, visible = result.measurement.nodes_uv, result.measurement.visible
        elif vr.centerline is not None:
            nodes, visible = vr.centerline.nodes_uv, vr.centerline.visible
        else:
            nodes = visible = None
        why = f" ({result.reason})" if result.reason else ""
        status = (
            (
                f"frame {frame.index}  point {result.status.value}{why}  nodes "
                f"{int(result.measurement.visible.sum())}/{len(result.measurement.visible)}"
            )
            if k == 0
            else ""
        )
        images.append(
            annotate_frame(
                rgb,
                nodes,
                visible,
                point_uv=point_uv,
                point_cov_uv=cov_uv,
                point_measured=result.status.seen,
                t=frame.t_capture if k == 0 else None,
                status=status,
            )
        )
    return images[0] if len(images) == 1 else inset_view(images[0], images[1])


def _run(args: argparse.Namespace) -> int:
    import contextlib

    import cv2
    from tqdm import tqdm

    from dyndlo_vision.cameras.files import VideoFileCamera
    from dyndlo_vision.tracking.camera_model import PinholeCamera

    cfg = _settings(args)
    calib = None if args.calib is None else PinholeCamera.from_json(args.calib)
    second_calib = None if cfg.second_calib is None else PinholeCamera.from_json(cfg.second_calib)
    with contextlib.ExitStack() as stack:
        source = stack.enter_context(VideoFileCamera(cfg.video, fps=cfg.fps))
        second = None
        if cfg.second_video is not None:
            second = stack.enter_context(VideoFileCamera(cfg.second_video, fps=cfg.fps))
            assert second_calib is not None
            _check_calibration(second_calib, "--second-calib", args.second_calib, second, cfg.second_video)
            if abs(second.fps - source.fps) > 1e-3 * source.fps:
                raise ValueError(
                    f"--second-video {cfg.second_video} runs at {second.fps:g} fps and {cfg.video} at "
                    f"{source.fps:g} fps: the two views must be recorded in sync, frame for frame"
                )
            _check_anchor(cfg.second_anchor, "--second-anchor", args.second_anchor, second)
            from dyndlo_vision.tracking.stereo import essential_matrix

            assert calib is not None
            try:
                essential_matrix(calib, second_calib)
            except ValueError as exc:
                raise ValueError(
                    f"--calib {args.calib} and --second-calib {args.second_calib}: {exc}"
                ) from exc
        if calib is not None:
            _check_calibration(calib, "calibration", args.calib, source, cfg.video)
            if cfg.pipeline.plane is not None:
                _check_plane_visible(calib, cfg.pipeline.plane, args.plane)
        _check_anchor(cfg.anchor, "--anchor", args.anchor, source)
        cameras = [calib] if second is None else [calib, second_calib]
        sources = [source] if second is None else [source, second]
        pipeline, kinds = _build_pipeline(cfg, cameras, sources)
        tcp_log = None if cfg.tcp_log is None else read_tcp_log(cfg.tcp_log)
        world = calib is not None
        destinations = [cfg.out] + ([cfg.annotated] if cfg.annotated is not None else [])
        destinations += [cfg.nodes_out] if cfg.nodes_out is not None else []
        outputs = _AtomicOutputs(destinations)
        n_without_tcp = 0
        with outputs as temps:
            writer = None
            if cfg.annotated is not None:
                size = (source.width, source.height)
                from dyndlo_vision._video import VideoWriter  # H.264 through PyAV, else mp4v

                writer = VideoWriter(temps[1], source.fps, size)
            try:
                with (
                    open(temps[0], "w", newline="", encoding="utf-8") as f,
                    (
                        open(temps[-1], "w", newline="", encoding="utf-8")
                        if cfg.nodes_out is not None
                        else contextlib.nullcontext()
                    ) as nodes_file,
                    tqdm(
                        total=source.frame_count,
                        unit="frame",
                        desc="track",
                        file=sys.stderr,
                        disable=cfg.quiet or not sys.stderr.isatty(),
                    ) as progress,
                ):
                    rows = csv.writer(f)
                    rows.writerow(CSV_COLUMNS)
                    node_rows = None if nodes_file is None else csv.writer(nodes_file)
                    if node_rows is not None:
                        node_rows.writerow(NODE_CSV_COLUMNS)
                    for frames in _frame_pairs(source, second, cfg):
                        frame = frames[0]
                        tcp = None
                        if tcp_log is not None:  # frames up to half a period outside the log get its end row
                            tcp = tcp_at(*tcp_log, frame.t_capture, tolerance_s=0.5 / max(source.fps, 1e-9))
                            n_without_tcp += int(tcp is None)
                        try:
                            result = pipeline.step([f.rgb for f in frames], frame.t_capture, held_world=tcp)
                        except ValueError as exc:
                            raise ValueError(f"{cfg.video} frame {frame.index}: {exc}") from exc
                        if pipeline.n_frames == 1 or (
                            pipeline.first_view_rule
                            and not getattr(pipeline, "_rule_printed", False)
                            and result.views[0].centerline is not None
                        ):
                            _note_first_rule(pipeline, result, frame, cfg)
                        rows.writerow(_csv_row(frame, result, world))
                        if node_rows is not None:
                            node_rows.writerows(_node_rows(frame, result, world))
                        if writer is not None:
                            writer.write(
                                cv2.cvtColor(_annotated(frames, result, pipeline), cv2.COLOR_RGB2BGR)
                            )
                        progress.update(1)
            finally:
                if writer is not None:
                    writer.release()
            if pipeline.n_frames == 0:
                raise ValueError(f"{cfg.video} has no frames that OpenCV can decode")
            outputs.commit()
    _print_summary(cfg, pipeline, kinds, n_without_tcp, destinations, calib is not None)
    return 0


def _note_first_rule(pipeline: CablePipeline, result: FrameResult, frame: Frame, cfg: _Settings) -> None:
    """Prints, once, which end was taken for the held end without a click."""
    if not pipeline.first_view_rule or getattr(pipeline, "_rule_printed", False):
        return
    cl = result.views[0].centerline
    if cl is None:
        return
    u0, v0 = cl.path_uv[0]
    print(
        f"note: no --anchor; took {pipeline.first_view_rule}, at pixel ({u0:.0f}, {v0:.0f}) in frame "
        f"{frame.index} of {cfg.video}, as the held end",
        file=sys.stderr,
    )
    if len(pipeline.views) == 2 and pipeline.views[1].first_rule and len(result.views) == 2:
        second = result.views[1].centerline
        if second is not None:
            u1, v1 = second.path_uv[0]
            print(f"note: no --second-anchor; took {pipeline.views[1].first_rule}, at pixel ({u1:.0f}, "
                  f"{v1:.0f}) in frame {frame.index} of {cfg.second_video}, as the held end", file=sys.stderr)
    pipeline._rule_printed = True  # type: ignore[attr-defined]


def _print_summary(
    cfg: _Settings,
    pipeline: CablePipeline,
    kinds: list[str],
    n_without_tcp: int,
    destinations: list[Path],
    world: bool,
) -> None:
    """What the run did, and why frames were not measured."""
    n = pipeline.n_frames
    zone_frames = max(
        (v.segmenter.shape.frames_with_zone for v in pipeline.views if v.segmenter.shape), default=0
    )
    if zone_frames:
        shape_rule = (
            ""
            if cfg.pipeline.max_width_ratio is None
            else f", or than {cfg.pipeline.max_width_ratio:g} times the cable's width (--max-width-ratio)"
        )
        hint = "; if the background is static, try --background median" if kinds[0] == "frame" else ""
        print(
            f"note: in {zone_frames} of {n} frames the segmentation ({kinds[0]}) found regions too thick to "
            f"be "
            f"cable (wider than {100 * _MAX_CABLE_WIDTH_SHARE:g}% of the image's shorter side{shape_rule}), "
            f"which were ignored{hint}",
            file=sys.stderr,
        )
    if cfg.tcp_log is not None:
        print(
            f"note: --tcp-log: the gripper was masked and taken as the held end in {n - n_without_tcp} of "
            f"{n} "
            "frames" + (f"; {n_without_tcp} frames lie outside the log's time span" if n_without_tcp else ""),
            file=sys.stderr,
        )
    if cfg.pipeline.cable_length_m is not None:
        print(
            f"note: --cable-length {cfg.pipeline.cable_length_m:g} m: the tip was continued past the "
            f"polyline's end in {pipeline.n_continued} frames",
            file=sys.stderr,
        )
    if pipeline.reasons:
        why = "; ".join(f"{reason} ({count})" for reason, count in pipeline.reasons.most_common())
        print(f"note: not measured in {sum(pipeline.reasons.values())} frames: {why}", file=sys.stderr)
    if pipeline.n_measured == 0 and kinds[0] == "median":
        print(
            "note: the point was never measured; a cable that hardly moves is part of the median background "
            "(try --background frame on a uniform background, or an HSV range)",
            file=sys.stderr,
        )
    share = 100.0 * pipeline.n_measured / n
    mode = "world, m, two views" if pipeline.stereo else "world, m" if world else "pixels"
    print(
        f"tracked {n} {'frame pairs' if pipeline.stereo else 'frames'} ({mode}); point measured in "
        f"{pipeline.n_measured} ({share:.1f}%); wrote {', '.join(str(p) for p in destinations)}"
    )
