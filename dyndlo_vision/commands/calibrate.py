"""``dyndlo-vision calibrate``: a camera's calibration JSON (what ``track --calib`` and ``run``'s
``camera.calibration`` read), for a real camera from photos of a checkerboard, or for a simulated one from its
task's scene (``--scene``).

**A real camera.** Intrinsics and lens distortion come from several photos of a checkerboard held at different
tilts (:func:`~dyndlo_vision.tracking.calibration.calibrate_intrinsics`, OpenCV's ``calibrateCamera``). The
pose in the robot's base frame comes from one more photo (``--extrinsic``) of the board lying at a known pose
there (``--board-pose``), or at a pose found by touching 3 or more of its corners with the robot's TCP
(``--touch``), with a pixel near the board's origin corner (``--board-origin``), since a checkerboard's
corners can be numbered from either end. Without ``--extrinsic`` the camera's own frame is the world
(``R = I``, ``t = 0``): fine for tracking in pixels, not for the loop.

**A simulated camera** (``--scene TASK``). The task's scene is built as the other commands build it, and the
named MuJoCo camera's pinhole model is taken from :attr:`dyndlo_vision.cameras.MujocoCamera.calibration` (the
model the loop's tracker uses): ``fx = fy`` from the vertical field of view, the principal point at the image
centre, no lens distortion (MuJoCo renders without), and the camera's pose in the task's world.

The file has the fields ``track --calib`` reads (``width``, ``height``, ``K``, ``dist``, ``R``, ``t`` with
``x_cam = R @ x_world + t`` in OpenCV's camera axes, ``fps``); it is written atomically, and nothing is
written after any error.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

HELP = ("write a camera's calibration JSON: a real camera's from checkerboard photos (intrinsics, "
        "distortion, pose in the robot's frame), or with --scene a simulated one's from its task's scene")
#: The options of each mode, as they are named (the other mode refuses them).
PHOTO_OPTIONS = ("--board", "--charuco", "--marker", "--dictionary", "--square", "--distortion",
                 "--extrinsic", "--board-pose", "--touch", "--board-origin")
SCENE_OPTIONS = ("--camera", "--width", "--height")
#: A simulated camera's image size when not given: the loop's camera's.
SCENE_SIZE = (640, 480)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``calibrate``."""
    from dyndlo_vision.commands import _options as options
    from dyndlo_vision.tasks.registry import TASKS
    from dyndlo_vision.tracking.calibration import CHARUCO_DICTIONARIES, DISTORTION_MODELS, MIN_VIEWS

    p.add_argument(
        "images",
        nargs="*",
        metavar="IMAGE",
        help=f"photos of the checkerboard at different tilts (files or folders of them; at least {MIN_VIEWS} "
        "with the board found); none with --scene",
    )
    photos = p.add_argument_group("a real camera, from photos of a checkerboard")
    target = photos.add_mutually_exclusive_group()
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
    photos.add_argument("--marker", type=float, metavar="M",
                        help="with --charuco: the ArUco markers' side in metres")
    photos.add_argument("--dictionary", choices=CHARUCO_DICTIONARIES, default=None,
                        help="with --charuco: the markers' ArUco dictionary (default 5X5_100)")
    photos.add_argument("--square", type=float, metavar="M",
                        help="square side in metres (required with photos)")
    photos.add_argument(
        "--distortion",
        choices=DISTORTION_MODELS,
        default=None,
        help="distortion coefficients to fit: none, radial (k1, k2; the default) or full (k1, k2, p1, p2, "
        "k3)",
    )
    photos.add_argument(
        "--extrinsic",
        metavar="IMAGE",
        help="a photo of the board lying at --board-pose in the robot's base frame (may be one of IMAGES)",
    )
    photos.add_argument(
        "--board-pose",
        metavar="X,Y,Z,ROLL,PITCH,YAW",
        help="with --extrinsic: the board's origin corner in the robot's base frame (m) and its orientation "
        "(degrees, R = Rz(yaw) Ry(pitch) Rx(roll)); the board's x runs along a row of corners from the "
        "origin, y along a column",
    )
    photos.add_argument(
        "--touch",
        metavar="CSV",
        help="with --extrinsic, instead of --board-pose: corners of the board, lying as in that photo, "
        "touched with the robot's TCP; a CSV with the header col,row,x,y,z (inner corner column and row from "
        "the first inner corner; TCP position in m in the robot's base frame), at least 3 corners not on one "
        "line",
    )
    photos.add_argument(
        "--board-origin",
        metavar="U,V",
        help="with --extrinsic and --board: a pixel near the board's origin corner in that photo",
    )
    scene = p.add_argument_group("a simulated camera, from its task's scene")
    scene.add_argument(
        "--scene", choices=sorted(TASKS), metavar="TASK",
        help=f"the task whose MuJoCo scene holds the camera, one of {', '.join(sorted(TASKS))}",
    )
    options.add_camera(scene)
    options.add_image_size(scene, None, None, unless=(*SCENE_SIZE, "the loop camera's"))
    p.add_argument("--fps", type=float,
                   help="frame rate written to the file (default: none for photos; with --scene 25, one "
                   "frame per control period)")
    p.add_argument(
        "--out", required=True, metavar="CAMERA.json", help="file to write (its folder must exist)"
    )


def _check_mode(args: argparse.Namespace) -> None:
    """Each mode's options only in that mode, and what each mode needs (ValueError naming the option)."""
    def given(option: str) -> bool:
        return getattr(args, option[2:].replace("-", "_")) is not None

    if args.scene is not None:
        if args.images:
            raise ValueError(f"--scene {args.scene} takes its camera from the scene, not from photos; got "
                             f"{len(args.images)} image(s): {args.images[0]} ...")
        for option in PHOTO_OPTIONS:
            if given(option):
                raise ValueError(f"{option} is for photos of a board, not --scene")
        return
    for option in SCENE_OPTIONS:
        if given(option):
            raise ValueError(f"{option} is for a simulated camera: it needs --scene TASK")
    if not args.images:
        raise ValueError("give photos of a checkerboard (IMAGE ...), or --scene TASK for a simulated camera")
    if args.board is None and args.charuco is None:
        raise ValueError("the photos need the board they show: --board COLSxROWS or --charuco "
                         "SQUARESxSQUARES")
    if args.square is None:
        raise ValueError("the photos need --square, the board's square side in metres")


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
    """Validates every argument of a real camera's calibration (raises ValueError naming the bad one)."""
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
        dictionary=str(args.dictionary or "5X5_100"),
        distortion=str(args.distortion or "radial"),
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
    """A real camera's calibration from the photos, or with ``--scene`` a simulated camera's."""
    _check_mode(args)
    return _run_scene(args) if args.scene is not None else _run_photos(args)


def _run_photos(args: argparse.Namespace) -> int:
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


# ------------------------------------------------------------------------------------ a simulated camera


@dataclass(frozen=True)
class _SceneSettings:
    camera: str
    task: str
    width: int
    height: int
    fps: float
    out: Path


def _scene_settings(args: argparse.Namespace) -> _SceneSettings:
    """Validates every argument of a simulated camera's calibration that needs no scene (raises ValueError
    naming the bad one)."""
    from dyndlo_vision.commands._options import LOOP_CAMERA
    from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
    from dyndlo_vision.tasks.registry import TASKS

    if args.scene not in TASKS:
        raise ValueError(f"--scene {args.scene!r} is not a task; expected one of {sorted(TASKS)}")
    width = SCENE_SIZE[0] if args.width is None else args.width
    height = SCENE_SIZE[1] if args.height is None else args.height
    for option, value in (("--width", width), ("--height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ValueError(f"{option} must be a positive number of pixels, got {value!r}")
    fps = 1.0 / CONTROL_PERIOD_S if args.fps is None else args.fps  # the loop renders once per period
    if not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"--fps must be a positive finite number, got {fps!r}")
    from dyndlo_vision._atomic import check_output_file

    out = check_output_file(Path(args.out), "--out", "camera.json")
    return _SceneSettings(str(args.camera or LOOP_CAMERA), str(args.scene), width, height, float(fps), out)


def _run_scene(args: argparse.Namespace) -> int:
    """Build the task's scene, take the camera's calibration and write it."""
    cfg = _scene_settings(args)

    import mujoco

    from dyndlo_vision._atomic import write_atomic
    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.tasks.registry import make_env

    env = make_env(cfg.task)
    try:
        model, data = env.unwrapped.model, env.unwrapped.data
        names = [model.camera(i).name for i in range(model.ncam)]
        if cfg.camera not in names:
            raise ValueError(
                f"--camera {cfg.camera!r} is not a camera of the {cfg.task} scene; its cameras: {names}"
            )
        cam_id = int(model.camera(cfg.camera).id)
        # One file holds one pose: a camera that tracks a body, or rides on a moving one, has none.
        fixed = int(model.cam_mode[cam_id]) == int(mujoco.mjtCamLight.mjCAMLIGHT_FIXED)
        body = int(model.cam_bodyid[cam_id])
        if not fixed or int(model.body_weldid[body]) != 0:
            raise ValueError(
                f"--camera {cfg.camera!r} moves with the scene (body {model.body(body).name!r}, mode "
                f"{int(model.cam_mode[cam_id])}); a calibration file describes a camera fixed to the world"
            )
        # The file is for images the scene can render (MujocoCamera's limit too, with advice about the model
        # file that a user of a task cannot follow).
        largest = (int(model.vis.global_.offwidth), int(model.vis.global_.offheight))
        if cfg.width > largest[0] or cfg.height > largest[1]:
            raise ValueError(
                f"--width {cfg.width} --height {cfg.height} is larger than the {cfg.task} scene renders "
                f"(at most {largest[0]}x{largest[1]})"
            )
        mujoco.mj_forward(model, data)
        camera = MujocoCamera(model, data, cfg.camera, width=cfg.width, height=cfg.height, fps=cfg.fps)
        try:
            calib = camera.calibration
        finally:
            camera.close()
    finally:
        env.close()
    text = json.dumps(calib.to_dict(), indent=2) + "\n"
    write_atomic(cfg.out, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
    fx, cx, cy = calib.K[0, 0], calib.K[0, 2], calib.K[1, 2]
    centre = ", ".join(f"{c:.3f}" for c in calib.center)
    print(
        f"wrote {cfg.out}: camera {cfg.camera!r} of {cfg.task}, {cfg.width}x{cfg.height} px, "
        f"fx = fy = {fx:.2f} px, principal point ({cx:.1f}, {cy:.1f}), centre ({centre}) m, {cfg.fps:g} fps"
    )
    return 0
