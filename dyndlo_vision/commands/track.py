"""``dyndlo-vision track``: track a cable through a video file or an image folder, one CSV row per frame.

Per frame: segment the cable (automatic background model, or an HSV range), extract its ordered centreline
(node 0 at the held end), take the tracked point (the free tip, or a fraction of the cable from the held end),
and filter it with a constant-velocity Kalman filter: in world coordinates when a calibration and the motion
plane are given (rays through the pixels are intersected with the plane), else in pixels.

The automatic background is by default the per-pixel median of frames sampled across the video (any static
background, a moving cable), or one colour per frame for videos too short for it. Segmented regions too thick
to be cable (a floor the background model does not describe, or a blob several times the cable's own width: a
gripper, a box; :class:`~dyndlo_vision.tracking.masks.CableShapedMask`) are ignored, and a cable end that runs
into one is not taken for the tip: the tool reports the point unmeasured rather than following such a region.
With ``--tcp-log`` the gripper's logged pose masks it in every frame and gives the held end.

CSV columns ``frame,time_s,visible,u,v,x,y,z,x_meas,y_meas,z_meas``: ``visible`` is 1 when the tracked
point was measured in that frame; ``u,v`` is the measured pixel (raw, unfiltered; empty when not measured);
``x,y,z`` is the filtered world position (m) at the frame's time, empty without ``--calib``, before the first
measurement and while the filter is lost (no measurement for longer than its coasting limit);
``x_meas,y_meas,z_meas`` is this frame's measured world position, unfiltered (empty when not measured or
without ``--calib``). A whipped tip accelerates at hundreds of m/s^2, which the filter's default smoothing
(``--sigma-accel``) lags behind: there the measured position is the closer one (docs/RESULTS.md, session 19).
The tracked point is not measured where the centreline cannot place it: the point's nodes are invisible, or
the cable runs out of the image (or into a region too thick to be cable) at the end the point is measured
from. Without a calibration the filter runs in
pixels and only draws the annotated video's point and uncertainty ellipse. With ``--cable-length`` (world
mode, the tip) a polyline shorter than the cable ends where the cable disappears: the tip is placed by
continuing it straight by the missing length (``u,v`` is that point's pixel), and with under half the cable in
view it is not measured (:func:`~dyndlo_vision.tracking.tracker.tip_from_polyline`).

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
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.tracking.masks import (
    MAX_WIDTH_RATIO,
    MIN_CUT_RADIUS_PX,
    CableShapedMask,
    GripperMaskedSegmenter,
)
from dyndlo_vision.tracking.networks import check_network
from dyndlo_vision.tracking.params import FilterParams

if TYPE_CHECKING:
    from dyndlo_vision.cameras.protocol import Frame
    from dyndlo_vision.tracking.camera_model import PinholeCamera
    from dyndlo_vision.tracking.tracker import Measurement

T = TypeVar("T")

HELP = "track a cable in a video or image folder and write the tracked point per frame to CSV"

#: Pixel-mode filter settings are the world ones times this scale (a cable filling a 640 px wide image from
#: about a metre away spans roughly 500 px per metre).
_PX_PER_M_NOMINAL = 500.0
#: The filter in world units (m) with a calibration, else in pixels.
_WORLD_FILTER = FilterParams()
_PIXEL_FILTER = _WORLD_FILTER.scaled(_PX_PER_M_NOMINAL)
#: Frames sampled across the video for ``--background median`` (and ``auto``).
_MEDIAN_FRAMES = 64
#: ``--background auto`` learns the median background from videos with at least this many frames: from fewer,
#: a moving cable covers a pixel in too large a share of them for the median to be background.
_AUTO_MIN_FRAMES = 8
#: Mask regions thicker than this share of the image's shorter side are not cable (at 640x480: 48 px). A
#: per-frame background colour segments a whole floor in front of a dark backdrop, and its skeleton is a line
#: the tracker would otherwise follow with confidence.
_MAX_CABLE_WIDTH_SHARE = 0.1
#: ``--gripper-radius`` default: the simulator's 2 cm gripper sphere plus a margin (the loop masks the same).
_GRIPPER_RADIUS_M = 0.03
CSV_COLUMNS = ("frame", "time_s", "visible", "u", "v", "x", "y", "z", "x_meas", "y_meas", "z_meas")
NODE_CSV_COLUMNS = ("frame", "time_s", "node", "visible", "u", "v", "x", "y", "z")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``track``."""
    p.add_argument("video", metavar="VIDEO", help="video file OpenCV can read, or a folder of images")
    p.add_argument("--out", required=True, metavar="TRACK.csv", help="CSV to write (folder must exist)")
    p.add_argument(
        "--calib", metavar="CALIB.json",
        help="camera calibration (PinholeCamera JSON); needs --plane, or a second camera (--second-video)"
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
    p.add_argument("--second-calib", metavar="CALIB2.json",
                   help="the second camera's calibration, in the same world frame as --calib (e.g. both from "
                   "`dyndlo-vision calibrate --extrinsic` with one board lying at one pose)")
    p.add_argument("--second-anchor", metavar="U,V", help="--anchor for the second video")
    p.add_argument(
        "--segmenter",
        choices=("background", "learned"),
        default="background",
        help="'background' (default): contrast with a background model (--background); 'learned': the "
        "shipped CNN of `dyndlo-vision segment` (or --segmenter-model), each frame on its own, for textured "
        "or cluttered scenes; an HSV range (--hsv-lower/--hsv-upper) replaces either",
    )
    p.add_argument(
        "--short-side",
        type=int,
        default=None,
        help="learned: each frame's shorter side is resized to this before the network (default: the "
        "network's own: 240 for cable-segmenter, 480 for the other two). For a cable 1-3 px wide, enlarge: "
        "720 for a 640x480 video (docs/RESULTS.md, \"The loop network at 1.5x\")",
    )
    p.add_argument(
        "--segmenter-model",
        metavar="FILE.onnx",
        help="learned: an ONNX file from seg-train, or a shipped network by name: cable-segmenter (default) "
        "or cable-segmenter-fine (full resolution, for cables 1-3 px wide; cable-segmenter-loop: the same "
        "fine-tuned on the simulated loop's scenes)",
    )
    p.add_argument("--hsv-lower", metavar="H,S,V", help="lower HSV bound (OpenCV: H 0-179, S, V 0-255)")
    p.add_argument("--hsv-upper", metavar="H,S,V", help="upper HSV bound; H lower > upper wraps through red")
    p.add_argument(
        "--point",
        default="tip",
        metavar="tip|FRACTION",
        help="tracked point: the free tip (default) or a fraction of the length from the held end, in [0, 1]",
    )
    p.add_argument(
        "--anchor",
        metavar="U,V",
        help="pixel near the held end in the first frame with a cable: the end nearest it is the held end, "
        "followed from frame to frame after that. Without it the upper end there is (a hanging cable's; "
        "printed)",
    )
    p.add_argument(
        "--background",
        choices=("auto", "median", "frame"),
        default=None,
        help="automatic segmentation's background: 'median' learns a per-pixel median from frames sampled "
        "across the whole video (any static background, e.g. MuJoCo renders; the cable must move; reads the "
        "video twice); 'frame' estimates one colour from each frame (uniform backgrounds, a still cable); "
        f"'auto' (default) is 'median' for videos of at least {_AUTO_MIN_FRAMES} frames, else 'frame'",
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
        help="length of the cable in metres from where it leaves the held end (the gripper) to its tip; with "
        "--point tip, a polyline shorter than that is continued straight by the missing length (the tip "
        "hidden behind something), and under half of it the tip is not measured (visible=0); with two "
        "cameras, --point FRACTION is then that share of the length along the triangulated cable",
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
        help=f"filter acceleration noise, m/s^2 (default {_WORLD_FILTER.sigma_accel:g}; in pixel mode "
        f"{_PIXEL_FILTER.sigma_accel:g} px/s^2)",
    )
    p.add_argument(
        "--sigma-meas",
        type=float,
        help=f"filter measurement noise, m (default {_WORLD_FILTER.sigma_meas:g}; in pixel mode "
        f"{_PIXEL_FILTER.sigma_meas:g} px)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


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


def parse_hsv(text: str, option: str) -> NDArray[np.int64]:
    """An OpenCV HSV triple ``H,S,V`` with H in 0..179 and S, V in 0..255.

    Raises:
        ValueError: On anything else, naming the option and the text.
    """
    values = parse_floats(text, 3, option)
    if np.any(values != np.round(values)):
        raise ValueError(f"{option} must be three integers H,S,V, got {text!r}")
    hsv = values.astype(np.int64)
    if not (0 <= hsv[0] <= 179 and 0 <= hsv[1] <= 255 and 0 <= hsv[2] <= 255):
        raise ValueError(f"{option} must have H in 0..179 and S, V in 0..255 (OpenCV's HSV), got {text!r}")
    return hsv


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


def point_on_nodes(
    nodes: NDArray[np.float64], visible: NDArray[np.bool_], fraction: float
) -> NDArray[np.float64] | None:
    """The point at ``fraction`` of the node chain (linear between the two nearest nodes), or None.

    Nodes are equally spaced along the cable, so node ``i`` of ``N`` is at fraction ``i / (N - 1)``.
    The point is measured only where the nodes it is interpolated from are visible and finite.
    """
    n = nodes.shape[0]
    s = fraction * (n - 1)
    i0 = min(int(math.floor(s)), n - 2)
    w = s - i0
    used = [i0] if w == 0 else ([i0 + 1] if w == 1 else [i0, i0 + 1])
    if not all(visible[i] and np.all(np.isfinite(nodes[i])) for i in used):
        return None
    return (1.0 - w) * nodes[i0] + w * nodes[i0 + 1]


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


def tcp_at(times: NDArray[np.float64], positions: NDArray[np.float64], t: float,
           tolerance_s: float) -> NDArray[np.float64] | None:
    """The TCP at time ``t``, linear between log rows; None more than ``tolerance_s`` outside the log."""
    if t < times[0] - tolerance_s or t > times[-1] + tolerance_s:
        return None
    return np.array([np.interp(t, times, positions[:, k]) for k in range(3)])


# ------------------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class _Settings:
    video: Path
    out: Path
    annotated: Path | None
    nodes_out: Path | None
    second_video: Path | None
    second_calib: Path | None
    second_anchor: NDArray[np.float64] | None
    fraction: float
    plane: tuple[NDArray[np.float64], float] | None
    hsv: tuple[NDArray[np.int64], NDArray[np.int64]] | None
    background: str
    segmenter: str
    segmenter_model: Path | None
    short_side: int | None
    open_radius: int
    anchor: NDArray[np.float64] | None
    nodes: int
    cable_length_m: float | None
    tcp_log: Path | None
    gripper_radius_m: float
    max_width_ratio: float | None
    fps: float | None
    filter: FilterParams
    quiet: bool


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
    if (args.hsv_lower is None) != (args.hsv_upper is None):
        raise ValueError("--hsv-lower and --hsv-upper go together; give both or neither")
    hsv = None
    if args.hsv_lower is not None:
        hsv = (parse_hsv(args.hsv_lower, "--hsv-lower"), parse_hsv(args.hsv_upper, "--hsv-upper"))
        lo, hi = hsv
        if np.any(lo[1:] > hi[1:]):
            raise ValueError(
                f"--hsv-lower S,V must not exceed --hsv-upper S,V: {args.hsv_lower} vs {args.hsv_upper}"
            )
    if hsv is not None and args.background is not None:
        raise ValueError(
            "--background applies to automatic segmentation; it cannot be used with an HSV range"
        )
    if args.segmenter == "learned" and (hsv is not None or args.background is not None):
        raise ValueError(
            "--segmenter learned segments each frame on its own: it takes neither --background nor an HSV "
            "range"
        )
    model = None if args.segmenter_model is None else Path(args.segmenter_model)
    if model is not None and args.segmenter != "learned":
        raise ValueError("--segmenter-model is for --segmenter learned")
    if model is not None:
        check_network(model, "--segmenter-model")
    if args.short_side is not None and args.segmenter != "learned":
        raise ValueError("--short-side is for --segmenter learned")
    if args.short_side is not None and args.short_side < 16:
        raise ValueError(f"--short-side must be at least 16 pixels, got {args.short_side}")
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
    defaults = _WORLD_FILTER if world else _PIXEL_FILTER
    filter_params = replace(
        defaults,
        sigma_accel=_positive(args.sigma_accel, "--sigma-accel") or defaults.sigma_accel,
        sigma_meas=_positive(args.sigma_meas, "--sigma-meas") or defaults.sigma_meas,
    )
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
    return _Settings(
        video=video,
        out=out,
        annotated=annotated,
        nodes_out=nodes_out,
        second_video=second_video,
        second_calib=None if args.second_calib is None else Path(args.second_calib),
        second_anchor=None if args.second_anchor is None else parse_floats(
            args.second_anchor, 2, "--second-anchor"),
        fraction=parse_point(args.point),
        plane=plane,
        hsv=hsv,
        background=str(args.background or "auto"),
        segmenter=str(args.segmenter),
        segmenter_model=model,
        short_side=args.short_side,
        open_radius=int(args.open_radius),
        anchor=None if args.anchor is None else parse_floats(args.anchor, 2, "--anchor"),
        nodes=int(args.nodes),
        cable_length_m=cable_length,
        tcp_log=tcp_log,
        gripper_radius_m=float(gripper_radius or _GRIPPER_RADIUS_M),
        max_width_ratio=None if args.max_width_ratio == 0 else float(args.max_width_ratio),
        fps=_positive(args.fps, "--fps"),
        filter=filter_params,
        quiet=bool(args.quiet),
    )


def _check_plane_visible(camera: PinholeCamera, plane: tuple[NDArray[np.float64], float], text: str) -> None:
    """Every image corner and the centre must see the plane in front of the camera (else ValueError).

    The tracking core raises the same error for a single pixel mid-video; checking before the first frame
    gives the clear message at once, before any output file is opened.
    """
    w, h = camera.width, camera.height
    probes = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, (h - 1) / 2]], float)
    try:
        camera.intersect_plane(probes, plane[0], plane[1])
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


def _segmenter(cfg: _Settings, video: Path) -> tuple[Callable[[NDArray[np.uint8]], NDArray[np.bool_]], str]:
    """The frame -> mask function the settings ask for, and its kind: 'median', 'frame', 'hsv' or 'learned'.

    Learns ``video``'s median background when asked ('median', or 'auto' on a video long enough).
    """
    from dyndlo_vision.cameras.files import VideoFileCamera
    from dyndlo_vision.tracking.segmentation import BackgroundSegmenter, segment_hsv

    if cfg.hsv is not None:
        lo, hi = cfg.hsv
        return (lambda rgb: segment_hsv(rgb, lo, hi, clean=True)), "hsv"
    if cfg.segmenter == "learned":
        from dyndlo_vision.tracking.learned import LearnedSegmenter
        from dyndlo_vision.tracking.networks import onnx_bytes

        short_side = "auto" if cfg.short_side is None else cfg.short_side
        return LearnedSegmenter(onnx_bytes(cfg.segmenter_model), short_side=short_side), "learned"
    segmenter = BackgroundSegmenter(open_radius=cfg.open_radius)
    if cfg.background == "frame":
        return segmenter, "frame"
    with VideoFileCamera(video, fps=cfg.fps) as first_pass:
        samples = sample_evenly((f.rgb for f in first_pass), _MEDIAN_FRAMES)
    if cfg.background == "auto" and len(samples) < _AUTO_MIN_FRAMES:
        print(
            f"note: {video} has {len(samples)} frames, too few to learn its background from "
            f"(--background auto needs {_AUTO_MIN_FRAMES}); estimating one background colour per frame",
            file=sys.stderr,
        )
        return segmenter, "frame"
    if samples:  # no frames: the tracking pass reports the empty video
        segmenter.learn(samples)
    return segmenter, "median"


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


#: Two views: a point past the held end is measured only if the triangulated cable's far end lies this close
#: to the far end of the cable in each image (px), plus two of the matching's sample spacings along the longer
#: of the two centrelines: else one view hides part of the cable and the far end is not the cable's.
_STEREO_END_TOL_PX = 3.0


class _View:
    """One camera's part of a run: its segmenter stack (gripper mask, shape test), tracker and held end."""

    def __init__(self, cfg: _Settings, video: Path, calib: PinholeCamera | None,
                 anchor: NDArray[np.float64] | None, anchor_option: str = "--anchor") -> None:
        from dyndlo_vision.tracking.tracker import CableTracker, Plane

        self.video = video
        self.anchor_option = anchor_option
        self.calib = calib
        self.anchor = anchor
        segment, self.background = _segmenter(cfg, video)
        #: With --tcp-log: the gripper's disk is cleared before the shape test (it is no cable either way).
        self.gripper_mask: GripperMaskedSegmenter | None = None
        if cfg.tcp_log is not None:
            self.gripper_mask = GripperMaskedSegmenter(segment, 0.0)
            segment = self.gripper_mask
        self.shape_filter = CableShapedMask(segment, _MAX_CABLE_WIDTH_SHARE, cfg.max_width_ratio)
        # One view lifts the nodes onto the plane; two views triangulate the 2D centrelines instead.
        self.tracker = CableTracker(
            camera=calib,
            segmenter=self.shape_filter,
            n_nodes=cfg.nodes,
            plane=None if cfg.plane is None else Plane(cfg.plane[0], cfg.plane[1]),
        )
        self.held_end_found = False
        #: Frames whose point was not measured because the cable ran into a region too thick to be cable.
        self.n_cut_by_zone = 0

    def mask_gripper(self, tcp: NDArray[np.float64] | None, t: float, radius_m: float) -> None:
        """Moves the gripper mask to the TCP's projection (None: no mask this frame)."""
        if self.gripper_mask is None:
            return
        if tcp is None:
            self.gripper_mask.center_uv = None
            return
        assert self.calib is not None
        depth = float(self.calib.world_to_camera(tcp[None])[0, 2])
        if depth <= 0:
            raise ValueError(f"--tcp-log: the gripper at {np.round(tcp, 3).tolist()} m (t = {t:.3f} s) is "
                             f"behind the camera of {self.video}; is the log in the calibration's world "
                             "frame?")
        self.gripper_mask.center_uv = self.calib.project(tcp[None])[0]
        self.gripper_mask.radius_px = radius_m * float(self.calib.K[0, 0]) / depth

    def measure(self, frame: Frame,
                first_view_held: tuple[PinholeCamera, NDArray[np.float64]] | None = None) -> Measurement:
        """The tracker's measurement of one frame, with the held end chosen as the options say.

        ``first_view_held``: for the second camera without an anchor of its own, the first camera and the
        pixel where it sees the held end: of the two cable ends, the held end is the one nearer that pixel's
        epipolar line (the same point, seen from here), else the upper one."""
        # The anchor picks the held end until the cable is first seen; from then on the tracker follows node 0
        # from frame to frame, because a held end that moves (a robot's gripper) can come closer to a fixed
        # anchor pixel than the swinging tip does.
        anchor = None if self.held_end_found else self.anchor
        if self.gripper_mask is not None and self.gripper_mask.center_uv is not None:
            anchor = self.gripper_mask.center_uv
        try:
            meas = self.tracker.process(frame.rgb, frame.t_capture, anchor_uv=anchor)
        except ValueError as exc:
            raise ValueError(f"{self.video} frame {frame.index}: {exc}") from exc
        cl = meas.centerline
        if not self.held_end_found and cl is not None and cl.any_visible:
            self.held_end_found = True
            if self.anchor is None and self.gripper_mask is None:
                # Either end could be node 0 (the walk's start), and a tip taken for the held end is a
                # confident wrong answer: take the end on the held end's epipolar line, or else the upper
                # end, a hanging cable's held end.
                rule = "the upper cable end"
                flip = cl.path_uv[-1, 1] < cl.path_uv[0, 1]
                if first_view_held is not None and self.calib is not None:
                    gaps = _epipolar_gaps(*first_view_held, self.calib, cl.path_uv[[0, -1]])
                    if abs(gaps[0] - gaps[1]) > 1e-3:  # normalised units: about half a pixel at f = 500
                        flip = bool(gaps[1] < gaps[0])
                        rule = "the cable end on the epipolar line of the first view's held end"
                if flip:
                    meas = self.tracker.process(frame.rgb, frame.t_capture, anchor_uv=cl.path_uv[-1])
                    cl = meas.centerline
                u0, v0 = meas.nodes_uv[0]
                print(
                    f"note: no {self.anchor_option}; took {rule}, at pixel ({u0:.0f}, {v0:.0f}) in frame "
                    f"{frame.index} of {self.video}, as the held end",
                    file=sys.stderr,
                )
        return meas

    def cut(self, meas: Measurement, fraction: float) -> bool:
        """Whether arc-length fractions mean nothing in this frame: the cable runs out of the image, or into
        a region too thick to be cable, at the end they are counted from (the last pixel there is not the
        tip)."""
        cl = meas.centerline
        if cl is None or not cl.any_visible:
            return False
        start_in_zone, end_in_zone = self.shape_filter.ends_in_zone(cl.path_uv, cl.width_px,
                                                                    self.tracker.last_mask)
        ends = ((cl.end_at_border, end_in_zone), (cl.start_at_border, start_in_zone))
        need = (fraction > 0, fraction < 1)
        cut_border = any(n and e[0] for n, e in zip(need, ends, strict=True))
        cut = cut_border or any(n and e[1] for n, e in zip(need, ends, strict=True))
        self.n_cut_by_zone += int(cut and not cut_border)
        return cut


def _epipolar_gaps(cam_a: PinholeCamera, uv_a: NDArray[np.float64], cam_b: PinholeCamera,
                   uv_b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances (normalised image units of ``cam_b``) of the pixels ``uv_b`` (K, 2) from the epipolar line
    of ``uv_a`` (a pixel of ``cam_a``)."""
    from dyndlo_vision.tracking.stereo import essential_matrix

    xa = np.append(cam_a.normalized_coords(np.asarray(uv_a, dtype=float).reshape(1, 2))[0], 1.0)
    line = essential_matrix(cam_a, cam_b) @ xa
    xb = np.column_stack([cam_b.normalized_coords(np.asarray(uv_b, dtype=float).reshape(-1, 2)),
                          np.ones(len(uv_b))])
    return np.asarray(np.abs(xb @ line) / max(float(np.linalg.norm(line[:2])), 1e-300), dtype=np.float64)


def _path_end(cl: Any, last: bool = True) -> NDArray[np.float64] | None:
    """The last (or first) finite pixel of a centreline's path; None if it has none."""
    path = np.asarray(cl.path_uv, dtype=np.float64).reshape(-1, 2)
    finite = np.flatnonzero(np.all(np.isfinite(path), axis=1))
    if not finite.size:
        return None
    return path[finite[-1] if last else finite[0]]


def _overlay_masks(rgb: NDArray[np.uint8], view: _View) -> NDArray[np.uint8]:
    """The frame with the regions too thick to be cable tinted and the masked gripper outlined."""
    import cv2

    zone = view.shape_filter.zone
    if zone is not None:  # shows where the cable cannot be seen: regions too thick to be cable
        rgb = rgb.copy()
        rgb[zone] = (0.6 * rgb[zone] + np.array([0.0, 0.0, 100.0])).astype(np.uint8)
    mask = view.gripper_mask
    if mask is not None and mask.center_uv is not None:  # the masked gripper, outlined
        u, v = mask.center_uv
        rgb = cv2.circle(rgb.copy(), (int(round(u)), int(round(v))), int(round(mask.radius_px)), (0, 0, 255),
                         1, cv2.LINE_AA)
    return rgb


def _reaches_far_ends(nodes_xyz: NDArray[np.float64], views: list[_View], measurements: list[Measurement],
                      samples: int) -> bool:
    """Whether the triangulated cable's last node projects onto the far end of the cable in every view."""
    last = nodes_xyz[np.all(np.isfinite(nodes_xyz), axis=1)]
    if len(last) == 0:
        return False
    longest = max(float(m.centerline.length_px) for m in measurements)
    tol = _STEREO_END_TOL_PX + 2.0 * longest / max(samples - 1, 1)
    for view, m in zip(views, measurements, strict=True):
        end = _path_end(m.centerline)
        assert view.calib is not None
        if end is None or float(np.linalg.norm(view.calib.project(last[-1:])[0] - end)) > tol:
            return False
    return True


class _PointTracker:
    """One frame (or one pair) at a time: cable tracker(s) -> tracked point -> Kalman filter -> CSV row and
    overlay."""

    def __init__(self, cfg: _Settings, calib: PinholeCamera | None,
                 second_calib: PinholeCamera | None = None) -> None:
        from dyndlo_vision.tracking.filter import PointFilter

        self.cfg = cfg
        self.calib = calib
        self.world = calib is not None
        self.views = [_View(cfg, cfg.video, calib, cfg.anchor)]
        if cfg.second_video is not None:
            self.views.append(
                _View(cfg, cfg.second_video, second_calib, cfg.second_anchor, anchor_option="--second-anchor")
            )
        self.stereo = len(self.views) == 2
        self.background = self.views[0].background
        self.shape_filter = self.views[0].shape_filter
        self.tcp_log = None if cfg.tcp_log is None else read_tcp_log(cfg.tcp_log)
        self.filter = PointFilter(cfg.filter)
        #: The video's frame rate (set by the run; how far outside the TCP log a frame may lie).
        self.fps = 25.0
        self.n_frames = 0
        self.n_measured = 0
        #: With --cable-length: frames whose tip was continued past the polyline's end, and frames with too
        #: little of the cable in view to place the tip.
        self.n_continued = 0
        self.n_too_short = 0
        #: With --tcp-log: frames outside the log's time span (no gripper mask, no held end there).
        self.n_without_tcp = 0
        #: Two views: frames whose triangulated cable did not reach the far end in both images.
        self.n_not_both = 0
        #: The last frame's measurement the tracked point came from (the triangulated one with two views).
        self.last_nodes: Measurement | None = None

    def node_rows(self, frame: Frame) -> list[list[object]]:
        """``--nodes-out`` rows of the last stepped frame: each node's measured pixel and world position."""
        meas = self.last_nodes
        rows: list[list[object]] = []
        for k in range(len(meas.visible)):
            seen = bool(meas.visible[k])
            uv = meas.nodes_uv[k] if seen else np.full(2, np.nan)
            xyz = meas.nodes_xyz[k] if seen and self.world else np.full(3, np.nan)
            rows.append([frame.index, f"{frame.t_capture:.6f}", k, int(seen and np.all(np.isfinite(uv)))]
                        + [_fmt(float(c), 3) for c in uv] + [_fmt(float(c), 6) for c in xyz])
        return rows

    @property
    def n_cut_by_zone(self) -> int:
        return sum(v.n_cut_by_zone for v in self.views)

    @property
    def frames_with_zone(self) -> int:
        return max(v.shape_filter.frames_with_zone for v in self.views)

    def _gripper(self, t: float) -> NDArray[np.float64] | None:
        """With --tcp-log: the TCP at ``t``, its disk set in every view's gripper mask (None: no log, or
        outside it)."""
        if self.tcp_log is None:
            return None
        # Frames up to half a period outside the log still get its end row.
        tcp = tcp_at(*self.tcp_log, t, tolerance_s=0.5 / max(self.fps, 1e-9))
        self.n_without_tcp += int(tcp is None)
        for view in self.views:
            view.mask_gripper(tcp, t, self.cfg.gripper_radius_m)
        return tcp

    def _triangulated(self, measurements: list[Measurement],
                      tcp: NDArray[np.float64] | None) -> tuple[Measurement, NDArray[np.float64]] | None:
        """Two views: the 3D measurement (nodes spread over the triangulated cable) and the held end, or None
        when the views give no cable."""
        from dyndlo_vision.tracking.stereo import StereoParams, stereo_measurement, triangulate

        first, second = measurements
        cams = [v.calib for v in self.views]
        assert cams[0] is not None and cams[1] is not None
        starts = [None if m.centerline is None else _path_end(m.centerline, last=False) for m in measurements]
        if starts[0] is None or starts[1] is None:
            return None
        held = tcp
        if held is None:  # where the two centrelines start
            held = triangulate(cams[0], starts[0][None], cams[1], starts[1][None])[0][0]
            if not np.all(np.isfinite(held)):
                return None
        # With the cable's length, an inner point is that share of it along the triangulated cable (a material
        # point, as in the vault loop); the tip keeps the polyline's own end, continued below if short.
        length = self.cfg.cable_length_m if self.cfg.fraction < 1 else None
        meas = stereo_measurement(first, cams[0], second, cams[1], held, length, StereoParams())
        return meas, held

    def step(self, frames: list[Frame], draw: bool) -> tuple[list[object], NDArray[np.uint8] | None]:
        """Tracks one frame (one per view); returns its CSV row and, when ``draw``, the annotated RGB
        image."""
        from dyndlo_vision.tracking.annotate import annotate_frame, project_point_covariance
        from dyndlo_vision.tracking.stereo import StereoParams

        cfg = self.cfg
        frame = frames[0]
        tcp = self._gripper(frame.t_capture)
        measurements = [self.views[0].measure(frame)]
        if self.stereo:
            cl = measurements[0].centerline
            start = None if cl is None or not cl.any_visible else _path_end(cl, last=False)
            held_seen = None if start is None else (self.views[0].calib, start)
            measurements.append(self.views[1].measure(frames[1], held_seen))
        cut = any([view.cut(m, cfg.fraction) for view, m in zip(self.views, measurements, strict=True)])
        meas, held = measurements[0], tcp
        if self.stereo and not cut:
            found = self._triangulated(measurements, tcp)
            if found is None:
                cut = True
            else:
                meas, held = found
                # Without the cable's length, the nodes spread over what both views saw: only if that reaches
                # the cable's far end in both images are fractions of it fractions of the cable.
                if cfg.cable_length_m is None and cfg.fraction > 0 and not _reaches_far_ends(
                        meas.nodes_xyz, self.views, measurements, StereoParams().samples):
                    cut = True
                    self.n_not_both += 1
        self.last_nodes = meas
        uv = None if cut else point_on_nodes(meas.nodes_uv, meas.visible, cfg.fraction)
        z = None  # what the filter measures: world metres, or (u, v, 0) pixels without a calibration
        if uv is not None:
            z = (
                point_on_nodes(meas.nodes_xyz, meas.visible, cfg.fraction)
                if self.world
                else np.append(uv, 0.0)
            )
        if z is not None and self.world and cfg.cable_length_m is not None and cfg.fraction == 1:
            # The polyline's end is the tip only if the polyline is as long as the cable; otherwise the cable
            # disappears there (behind something) and goes on, or too little of it is seen to place the tip.
            from dyndlo_vision.tracking.tracker import tip_from_polyline

            if held is None:
                held = meas.nodes_xyz[np.flatnonzero(meas.lifted)[0]]
            tip = tip_from_polyline(meas, held, cfg.cable_length_m)
            if tip is None:
                uv = z = None
                self.n_too_short += 1
            elif not np.array_equal(tip, z):
                z = tip
                assert self.calib is not None
                uv = self.calib.project(tip[None])[0]
                self.n_continued += 1
        measured = z is not None
        self.filter.update(z, frame.t_capture)
        est = self.filter.estimate(frame.t_capture)
        uv_out = uv if (measured and uv is not None) else np.full(2, np.nan)
        xyz_out = est.position if (self.world and not est.lost) else np.full(3, np.nan)
        meas_out = z if (measured and self.world) else np.full(3, np.nan)
        row: list[object] = [frame.index, f"{frame.t_capture:.6f}", int(measured)]
        row += [_fmt(float(c), 3) for c in uv_out] + [_fmt(float(c), 6) for c in (*xyz_out, *meas_out)]
        self.n_frames += 1
        self.n_measured += int(measured)
        if not draw:
            return row, None
        state = "measured" if measured else ("lost" if est.lost else "predicted")
        images = []
        for k, (view, f, m) in enumerate(zip(self.views, frames, measurements, strict=True)):
            point_uv = cov_uv = None
            if not est.lost:
                if view.calib is not None:
                    point_uv, cov_uv = project_point_covariance(view.calib, est.position,
                                                                est.covariance[:3, :3])
                else:
                    point_uv, cov_uv = est.position[:2], est.covariance[:2, :2]
            nodes = meas if k == 0 else m
            images.append(annotate_frame(
                _overlay_masks(f.rgb, view),
                nodes.nodes_uv,
                nodes.visible,
                point_uv=point_uv,
                point_cov_uv=cov_uv,
                point_measured=measured,
                t=f.t_capture if k == 0 else None,
                status=f"frame {frame.index}  point {state}  nodes {int(meas.visible.sum())}/{cfg.nodes}"
                if k == 0 else "",
            ))
        image = images[0]
        if self.stereo:
            from dyndlo_vision.tracking.annotate import inset_view

            image = inset_view(image, images[1])
        return row, image


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
            if cfg.plane is not None:
                _check_plane_visible(calib, cfg.plane, args.plane)
        _check_anchor(cfg.anchor, "--anchor", args.anchor, source)
        pipeline = _PointTracker(cfg, calib, second_calib)
        pipeline.fps = source.fps
        destinations = [cfg.out] + ([cfg.annotated] if cfg.annotated is not None else [])
        destinations += [cfg.nodes_out] if cfg.nodes_out is not None else []
        outputs = _AtomicOutputs(destinations)
        with outputs as temps:
            writer = None
            if cfg.annotated is not None:
                size = (source.width, source.height)
                from dyndlo_vision._video import VideoWriter  # H.264 through PyAV, else mp4v

                writer = VideoWriter(temps[1], source.fps, size)
            try:
                with (
                    open(temps[0], "w", newline="", encoding="utf-8") as f,
                    (open(temps[-1], "w", newline="", encoding="utf-8") if cfg.nodes_out is not None
                     else contextlib.nullcontext()) as nodes_file,
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
                        row, image = pipeline.step(frames, draw=writer is not None)
                        rows.writerow(row)
                        if node_rows is not None:
                            node_rows.writerows(pipeline.node_rows(frames[0]))
                        if writer is not None and image is not None:
                            writer.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
                        progress.update(1)
            finally:
                if writer is not None:
                    writer.release()
            if pipeline.n_frames == 0:
                raise ValueError(f"{cfg.video} has no frames that OpenCV can decode")
            outputs.commit()
    share = 100.0 * pipeline.n_measured / pipeline.n_frames
    zone_frames = pipeline.frames_with_zone
    shape_rule = (
        "" if cfg.max_width_ratio is None
        else f", or than {cfg.max_width_ratio:g} times the cable's width (--max-width-ratio)"
    )
    if zone_frames:
        hint = (
            "; if the background is static, try --background median" if pipeline.background == "frame" else ""
        )
        print(
            f"note: in {zone_frames} of {pipeline.n_frames} frames the segmentation ({pipeline.background}) "
            f"found regions too thick to be cable (wider than {100 * _MAX_CABLE_WIDTH_SHARE:g}% of the "
            f"image's shorter side{shape_rule}), which were ignored; the point was not measured in "
            f"{pipeline.n_cut_by_zone} frames where the cable ran into them{hint}",
            file=sys.stderr,
        )
    if cfg.tcp_log is not None:
        print(
            f"note: --tcp-log: the gripper was masked and taken as the held end in "
            f"{pipeline.n_frames - pipeline.n_without_tcp} of {pipeline.n_frames} frames"
            + (f"; {pipeline.n_without_tcp} frames lie outside the log's time span" if pipeline.n_without_tcp
               else ""),
            file=sys.stderr,
        )
    if cfg.cable_length_m is not None:
        print(
            f"note: --cable-length {cfg.cable_length_m:g} m: the tip was continued past the polyline's end "
            f"in {pipeline.n_continued} frames, and not measured in {pipeline.n_too_short} frames that "
            "showed less than half the cable",
            file=sys.stderr,
        )
    if pipeline.stereo and pipeline.n_not_both:
        print(
            f"note: two views: in {pipeline.n_not_both} frames the triangulated cable did not reach the "
            "cable's far end in both images (one view hid part of it), so the point was not measured there",
            file=sys.stderr,
        )
    if pipeline.n_measured == 0 and pipeline.background == "median":
        print(
            "note: the point was never measured; a cable that hardly moves is part of the median background "
            "(try --background frame on a uniform background, or an HSV range)",
            file=sys.stderr,
        )
    mode = "world, m, two views" if pipeline.stereo else "world, m" if calib is not None else "pixels"
    print(
        f"tracked {pipeline.n_frames} {'frame pairs' if pipeline.stereo else 'frames'} ({mode}); point "
        f"measured in {pipeline.n_measured} ({share:.1f}%); wrote {', '.join(str(p) for p in destinations)}"
    )
    return 0
