"""``dyndlo-vision calibrate``: a real camera's calibration JSON from checkerboard photos (``track --calib``).

Intrinsics and lens distortion come from several photos of a checkerboard held at different tilts
(:func:`~dyndlo_vision.tracking.calibration.calibrate_intrinsics`, OpenCV's ``calibrateCamera``). The pose in
the robot's base frame comes from one more photo (``--extrinsic``) of the board lying at a known pose there
(``--board-pose``), or at a pose found by touching 3 or more of its corners with the robot's TCP
(``--touch``), with a pixel near the board's origin corner (``--board-origin``), since a checkerboard's
corners can be numbered from either end. Without ``--extrinsic`` the camera's own frame is the world
(``R = I``, ``t = 0``): fine for tracking in pixels, not for the loop.

The file has the fields ``track --calib`` reads (``width``, ``height``, ``K``, ``dist``, ``R``, ``t``,
``fps``); it is written atomically, and nothing is written after any error. (``dyndlo-vision calib`` writes
the same file for a *simulated* camera, from the scene.)
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

HELP = "calibrate a real camera from checkerboard photos: intrinsics, distortion, pose in the robot's frame"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``calibrate``."""
    from dyndlo_vision.tracking.calibration import CHARUCO_DICTIONARIES, DISTORTION_MODELS, MIN_VIEWS

    p.add_argument(
        "images",
        nargs="+",
        metavar="IMAGE",
        help=f"photos of the checkerboard at different tilts (files or folders of them; at least {MIN_VIEWS} "
        "with the board found)",
    )
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument(
        "--board",
        metavar="COLSxROWS",
        help="a checkerboard: inner corners per row and per column, e.g. 9x6 for a board of 10x7 squares",
    )
    target.add_argument(
        "--charuco",
        metavar="SQUARESxSQUARES",
        help="a ChArUco board (OpenCV's): squares across and down, e.g. 7x5; the photos may show part of it, "
        "and the extrinsic photo needs no --board-origin (needs --marker)",
    )
    p.add_argument("--marker", type=float, metavar="M",
                   help="with --charuco: the ArUco markers' side in metres")
    p.add_argument("--dictionary", choices=CHARUCO_DICTIONARIES, default="5X5_100",
                   help="with --charuco: the markers' ArUco dictionary")
    p.add_argument("--square", required=True, type=float, metavar="M", help="square side in metres")
    p.add_argument(
        "--distortion",
        choices=DISTORTION_MODELS,
        default="radial",
        help="distortion coefficients to fit: none, radial (k1, k2) or full (k1, k2, p1, p2, k3)",
    )
    p.add_argument(
        "--extrinsic",
        metavar="IMAGE",
        help="a photo of the board lying at --board-pose in the robot's base frame (may be one of IMAGES)",
    )
    p.add_argument(
        "--board-pose",
        metavar="X,Y,Z,ROLL,PITCH,YAW",
        help="with --extrinsic: the board's origin corner in the robot's base frame (m) and its orientation "
        "(degrees, R = Rz(yaw) Ry(pitch) Rx(roll)); the board's x runs along a row of corners from the "
        "origin, y along a column",
    )
    p.add_argument(
        "--touch",
        metavar="CSV",
        help="with --extrinsic, instead of --board-pose: corners of the board, lying as in that photo, "
        "touched with the robot's TCP; a CSV with the header col,row,x,y,z (inner corner column and row from "
        "the first inner corner; TCP position in m in the robot's base frame), at least 3 corners not on one "
        "line",
    )
    p.add_argument(
        "--board-origin",
        metavar="U,V",
        help="with --extrinsic and --board: a pixel near the board's origin corner in that photo",
    )
    p.add_argument("--fps", type=float, help="frame rate to write to the file (optional)")
    p.add_argument(
        "--out", required=True, metavar="CAMERA.json", help="file to write (its folder must exist)"
    )


@dataclass(frozen=True)
class _Settings:
    images: list[Path]
    charuco: bool
    cols: int  # checkerboard: inner corners; ChArUco: squares
    rows: int
    square_m: float
    marker_m: float | None
    dictionary: str
    distortion: str
    extrinsic: Path | None
    board_pose: NDArray[np.float64] | None
    touch: Path | None
    board_origin: NDArray[np.float64] | None
    fps: float | None
    out: Path


def _numbers(text: str, count: int, option: str) -> NDArray[np.float64]:
    parts = str(text).split(",")
    try:
        values = np.array([float(v) for v in parts])
    except ValueError:
        values = np.zeros(0)
    if values.size != count or not np.all(np.isfinite(values)):
        raise ValueError(f"{option} must be {count} comma-separated finite numbers, got {text!r}")
    return values


def _settings(args: argparse.Namespace) -> _Settings:
    """Validates every argument (raises ValueError naming the bad one)."""
    charuco = args.charuco is not None
    option, text = ("--charuco", args.charuco) if charuco else ("--board", args.board)
    board = str(text).lower().split("x")
    if len(board) != 2 or not all(b.strip().isdigit() for b in board):
        what = "SQUARESxSQUARES, e.g. 7x5" if charuco else "COLSxROWS inner corners, e.g. 9x6"
        raise ValueError(f"{option} must be {what}, got {text!r}")
    cols, rows = (int(b) for b in board)
    if charuco and args.marker is None:
        raise ValueError("--charuco needs --marker, the markers' side in metres")
    if not charuco and args.marker is not None:
        raise ValueError("--marker goes with --charuco; a checkerboard has no markers")
    if charuco and args.board_origin is not None:
        raise ValueError(
            "--board-origin is for a checkerboard; a ChArUco board's corners are known by their ids"
        )
    if not (math.isfinite(args.square) and args.square > 0):
        raise ValueError(f"--square must be a positive length in metres, got {args.square!r}")
    if args.square > 0.5:
        raise ValueError(f"--square {args.square:g} m is not a checkerboard square; give the side in metres")
    touch = args.touch
    if args.board_pose is not None and touch is not None:
        raise ValueError("--board-pose and --touch both give the board's pose: give one")
    extrinsic_given = [args.extrinsic is not None, args.board_pose is not None or touch is not None]
    if not charuco:
        extrinsic_given.append(args.board_origin is not None)
    if any(extrinsic_given) and not all(extrinsic_given):
        raise ValueError(
            "--extrinsic, --board-pose (or --touch) and --board-origin go together: give all three or none"
            if not charuco else "--extrinsic and --board-pose (or --touch) go together: give both or neither"
        )
    if touch is not None and not Path(touch).is_file():
        raise FileNotFoundError(f"--touch {touch} does not exist")
    if args.fps is not None and not (math.isfinite(args.fps) and args.fps > 0):
        raise ValueError(f"--fps must be a positive number, got {args.fps!r}")
    from dyndlo_vision._atomic import check_output_file

    out = check_output_file(Path(args.out), "--out", "camera.json")
    from dyndlo_vision.cameras.files import image_files

    extrinsic = None if args.extrinsic is None else Path(args.extrinsic)
    if extrinsic is not None and not extrinsic.is_file():
        raise FileNotFoundError(f"--extrinsic {extrinsic} does not exist")
    return _Settings(
        images=image_files(args.images),
        charuco=charuco,
        cols=cols,
        rows=rows,
        square_m=float(args.square),
        marker_m=None if args.marker is None else float(args.marker),
        dictionary=str(args.dictionary),
        distortion=str(args.distortion),
        extrinsic=extrinsic,
        board_pose=None if args.board_pose is None else _numbers(args.board_pose, 6, "--board-pose"),
        touch=None if touch is None else Path(touch),
        board_origin=None if args.board_origin is None else _numbers(args.board_origin, 2, "--board-origin"),
        fps=None if args.fps is None else float(args.fps),
        out=out,
    )


def read_touches(path: Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A touch file: CSV, header ``col,row,x,y,z`` (corner indices; TCP position in m), one corner a row.

    Raises:
        CalibrationInputError: A missing column, a non-number, or no rows (naming the file and line).
    """
    import csv

    from dyndlo_vision.tracking.calibration import CalibrationInputError

    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        need = ["col", "row", "x", "y", "z"]
        if reader.fieldnames is None or any(c not in reader.fieldnames for c in need):
            raise CalibrationInputError(f"{path}: expected a CSV header with columns {','.join(need)}, got "
                                        f"{reader.fieldnames}")
        ij, xyz = [], []
        for line, row in enumerate(reader, start=2):
            try:
                values = [float(row[c]) for c in need]
            except (TypeError, ValueError):
                raise CalibrationInputError(
                    f"{path} line {line}: expected numbers in {need}, got {row}"
                ) from None
            if not np.all(np.isfinite(values)):
                raise CalibrationInputError(f"{path} line {line}: non-finite value in {row}")
            ij.append(values[:2])
            xyz.append(values[2:])
    if not ij:
        raise CalibrationInputError(f"{path}: no touched corners")
    return np.array(ij), np.array(xyz)


def _read_gray(path: Path) -> NDArray[np.uint8]:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"{path} is not an image OpenCV can read")
    return image


def run(args: argparse.Namespace) -> int:
    """Detect the board, calibrate, and write the JSON."""
    from dyndlo_vision.tracking.calibration import (
        BoardView,
        CharucoBoard,
        Checkerboard,
        board_pose_from_touches,
        calibrate_intrinsics,
        find_board,
        find_charuco,
        pose_from_board,
        pose_from_points,
        rotation_rpy,
    )
    from dyndlo_vision.tracking.camera_model import PinholeCamera

    cfg = _settings(args)
    board: Checkerboard | CharucoBoard
    if cfg.charuco:
        assert cfg.marker_m is not None
        board = CharucoBoard(cfg.cols, cfg.rows, cfg.square_m, cfg.marker_m, cfg.dictionary)
        name = f"{cfg.cols}x{cfg.rows} ChArUco"
    else:
        board = Checkerboard(cfg.cols, cfg.rows, cfg.square_m)
        name = f"{cfg.cols}x{cfg.rows}"

    def detect(gray: NDArray[np.uint8]) -> BoardView | None:
        if isinstance(board, CharucoBoard):
            return find_charuco(gray, board)
        corners = find_board(gray, board)
        return None if corners is None else BoardView(board.points, corners)

    touch_rms = None
    if cfg.touch is not None:  # checked before the (slower) corner detection
        board_rotation, board_origin_m, touch_rms = board_pose_from_touches(board, *read_touches(cfg.touch))
    elif cfg.board_pose is not None:
        board_rotation, board_origin_m = rotation_rpy(*cfg.board_pose[3:]), cfg.board_pose[:3]
    size: tuple[int, int] | None = None
    views, missed = [], []
    for path in cfg.images:
        gray = _read_gray(path)
        shape = (gray.shape[1], gray.shape[0])
        if size is None:
            size = shape
        elif shape != size:
            raise ValueError(
                f"{path} is {shape[0]}x{shape[1]}, but {cfg.images[0]} is {size[0]}x{size[1]}: one camera, "
                "one image size"
            )
        found = detect(gray)
        (views if found is not None else missed).append((path, found))
    assert size is not None
    if missed:
        names = ", ".join(str(p) for p, _ in missed[:5]) + (" ..." if len(missed) > 5 else "")
        print(
            f"note: no {name} board found in {len(missed)} of {len(cfg.images)} images "
            f"({names}); they are not used",
            file=sys.stderr,
        )
    intrinsics = calibrate_intrinsics([c for _, c in views], board, size, cfg.distortion)
    R, t, extrinsic_rms = np.eye(3), np.zeros(3), None
    if cfg.extrinsic is not None:
        gray = _read_gray(cfg.extrinsic)
        if (gray.shape[1], gray.shape[0]) != size:
            raise ValueError(
                f"--extrinsic {cfg.extrinsic} is {gray.shape[1]}x{gray.shape[0]}, the other images "
                f"{size[0]}x{size[1]}"
            )
        view = detect(gray)
        if view is None:
            raise ValueError(f"--extrinsic {cfg.extrinsic}: no {name} board found")
        if isinstance(board, CharucoBoard):
            R, t, extrinsic_rms = pose_from_points(view.object_points, view.image_points, intrinsics.K,
                                                   intrinsics.dist, board_rotation, board_origin_m)
        else:
            assert cfg.board_origin is not None
            w, h = size
            if not (0 <= cfg.board_origin[0] < w and 0 <= cfg.board_origin[1] < h):
                raise ValueError(f"--board-origin {args.board_origin} is outside the {w}x{h} image")
            R, t, extrinsic_rms = pose_from_board(view.image_points, board, intrinsics.K, intrinsics.dist,
                                                  board_rotation, board_origin_m, cfg.board_origin)
    camera = PinholeCamera(
        width=size[0], height=size[1], K=intrinsics.K, dist=intrinsics.dist, R=R, t=t, fps=cfg.fps
    )
    camera.to_json(cfg.out)
    k = intrinsics.K
    print(
        f"{len(views)} views, reprojection RMS {intrinsics.rms_px:.3f} px (worst view "
        f"{intrinsics.per_view_rms_px.max():.3f} px), tilt directions spanning "
        f"{intrinsics.tilt_spread_deg:.0f} deg"
    )
    print(
        f"fx {k[0, 0]:.2f} px, fy {k[1, 1]:.2f} px, principal point ({k[0, 2]:.1f}, {k[1, 2]:.1f}), "
        f"distortion {np.round(intrinsics.dist, 5).tolist()}"
    )
    if touch_rms is not None:
        print(f"board pose from {cfg.touch}: touched corners fit the board to {touch_rms * 1e3:.2f} mm RMS")
    if extrinsic_rms is not None:
        centre = ", ".join(f"{c:.4f}" for c in camera.center)
        print(
            f"pose from {cfg.extrinsic}: reprojection RMS {extrinsic_rms:.3f} px, camera centre ({centre}) m "
            "in the robot's frame"
        )
    else:
        print(
            "note: no --extrinsic: the camera's own frame is the world frame (R = I, t = 0)", file=sys.stderr
        )
    if intrinsics.rms_px > 1.0:
        print(
            f"note: a reprojection RMS of {intrinsics.rms_px:.2f} px is high; check --board and --square, "
            "and that the board is flat and the photos sharp",
            file=sys.stderr,
        )
    print(f"wrote {cfg.out}")
    return 0
