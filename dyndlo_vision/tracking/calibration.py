"""Camera calibration from checkerboard images: intrinsics, lens distortion, the pose in the robot's frame.

Pure computation on OpenCV's calibration functions (``dyndlo-vision calibrate`` is the command around it):

* :func:`find_board` detects a checkerboard's inner corners to sub-pixel accuracy; :func:`find_charuco` the
  corners a ChArUco board shows (any part of it, each corner known by its id);
* :func:`calibrate_intrinsics` fits ``K`` and the distortion to several views of the board, and refuses too
  few views and views that cannot fix the focal length (all at nearly the same orientation);
* :func:`pose_from_board` (checkerboard) and :func:`pose_from_points` (ChArUco) place the camera in the world
  (the robot's base frame) from one view of the board lying at a known pose there;
* :func:`board_pose_from_touches` finds that pose from board corners touched with the robot's TCP.

The board frame: origin at the first inner corner, x along a row of corners (``cols`` of them, ``square_m``
apart), y along a column (``rows`` corners), z = x cross y (into the board for a board seen from its printed
side with x to the right and y down). A checkerboard looks the same turned by 180 degrees or seen from behind,
so the detector may number its corners from any end; for the pose, the corner numbered first is the one
nearest a pixel the user gives (``origin_uv``, :func:`orient_corners`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Fewest views of the board that :func:`calibrate_intrinsics` accepts.
MIN_VIEWS = 4
#: Foreshortening (:func:`foreshortening`) a view needs to count as tilted: about 0.05 for a 20 cm board
#: tilted 7 degrees at 30 cm.
MIN_FORESHORTENING = 0.05
#: Tilted views must include two whose tilt directions in the image differ by at least this (degrees):
#: fronto-parallel views, or views all tilted about the same axis, leave the focal length undetermined.
MIN_TILT_DIRECTION_SPREAD_DEG = 30.0
#: Distortion models: coefficients estimated (OpenCV's order k1, k2, p1, p2, k3).
DISTORTION_MODELS = ("none", "radial", "full")


class CalibrationInputError(ValueError):
    """A calibration input that cannot give a calibration; the message says which and why."""


@dataclass(frozen=True)
class Checkerboard:
    """A checkerboard by its inner corners: ``cols`` x ``rows`` of them, ``square_m`` apart."""

    cols: int
    rows: int
    square_m: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise CalibrationInputError(
                f"a checkerboard needs at least 3 x 3 inner corners, got {self.cols} x {self.rows}"
            )
        if self.cols == self.rows:
            raise CalibrationInputError(
                f"use a checkerboard with different numbers of inner corners per row and column (got "
                f"{self.cols} x {self.rows}): a square one has no orientation"
            )
        if not (math.isfinite(self.square_m) and self.square_m > 0):
            raise CalibrationInputError(
                f"the square size must be a positive length in m, got {self.square_m}"
            )

    #: Board-frame position of inner corner (0, 0): the origin.
    first_corner_m = (0.0, 0.0)

    @property
    def points(self) -> NDArray[np.float64]:
        """(cols * rows, 3) corner positions in the board frame, in OpenCV's detection order (row by row)."""
        ij = np.stack(np.meshgrid(np.arange(self.cols), np.arange(self.rows)), axis=-1).reshape(-1, 2)
        return np.column_stack([ij * self.square_m, np.zeros(len(ij))]).astype(np.float64)


def find_board(gray: NDArray[np.uint8], board: Checkerboard) -> NDArray[np.float64] | None:
    """The board's inner corners, (cols * rows, 2) pixels in detection order, or None if it is not found."""
    import cv2

    size = (board.cols, board.rows)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, size, flags=flags)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)
    return corners.reshape(-1, 2).astype(np.float64)


#: ArUco dictionaries ``--charuco`` accepts (OpenCV's predefined ones, by their suffix).
CHARUCO_DICTIONARIES = ("4X4_50", "4X4_100", "5X5_50", "5X5_100", "6X6_50", "6X6_100", "6X6_250")
#: Fewest ChArUco corners a view must show to be used (OpenCV's pose needs 4; more keep a view well-posed).
MIN_CHARUCO_CORNERS = 6


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board: ``squares_x`` x ``squares_y`` squares of ``square_m``, ArUco markers of ``marker_m``
    in the white ones, from ``dictionary`` (one of :data:`CHARUCO_DICTIONARIES`), as OpenCV's ``CharucoBoard``
    (its board frame: origin at the board's outer corner by the first marker, x along the first row).

    Each inner corner has an id from the markers around it, so a view may show part of the board, and no
    numbering is ambiguous (no ``--board-origin``).
    """

    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str = "5X5_100"

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise CalibrationInputError(
                f"a ChArUco board needs at least 3 x 3 squares, got {self.squares_x} x {self.squares_y}"
            )
        if not (math.isfinite(self.square_m) and self.square_m > 0):
            raise CalibrationInputError(
                f"the square size must be a positive length in m, got {self.square_m}"
            )
        if not (math.isfinite(self.marker_m) and 0 < self.marker_m < self.square_m):
            raise CalibrationInputError(
                f"the marker size must be positive and smaller than the square ({self.square_m} m), got "
                f"{self.marker_m}"
            )
        if self.dictionary not in CHARUCO_DICTIONARIES:
            raise CalibrationInputError(
                f"ArUco dictionary {self.dictionary!r}; expected one of {list(CHARUCO_DICTIONARIES)}"
            )

    def opencv_board(self) -> Any:
        """OpenCV's ``cv2.aruco.CharucoBoard`` of this board."""
        import cv2

        aruco = cv2.aruco
        dictionary = aruco.getPredefinedDictionary(getattr(aruco, f"DICT_{self.dictionary}"))
        return aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)

    @property
    def cols(self) -> int:
        """Inner corners per row."""
        return self.squares_x - 1

    @property
    def rows(self) -> int:
        """Inner corners per column."""
        return self.squares_y - 1

    @property
    def first_corner_m(self) -> tuple[float, float]:
        """Board-frame position of inner corner (0, 0) (id 0): one square in from the outer corner."""
        return (self.square_m, self.square_m)

    @property
    def points(self) -> NDArray[np.float64]:
        """(n, 3) the inner corners in the board frame, indexed by their ChArUco id."""
        return np.asarray(self.opencv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)


@dataclass(frozen=True)
class BoardView:
    """The board corners one image shows: their board-frame positions and their pixels."""

    object_points: NDArray[np.float64]  # (N, 3)
    image_points: NDArray[np.float64]  # (N, 2)


def find_charuco(gray: NDArray[np.uint8], board: CharucoBoard) -> BoardView | None:
    """The ChArUco corners an image shows (at least :data:`MIN_CHARUCO_CORNERS`), or None."""
    import cv2

    cv_board = board.opencv_board()
    corners, ids, _markers, _marker_ids = cv2.aruco.CharucoDetector(cv_board).detectBoard(gray)
    if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
        return None
    points = np.asarray(cv_board.getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
    pixels = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    return BoardView(points[np.asarray(ids).reshape(-1)], pixels)


@dataclass(frozen=True)
class Intrinsics:
    """The result of :func:`calibrate_intrinsics`.

    Attributes:
        K: 3x3 camera matrix.
        dist: Distortion coefficients (k1, k2, p1, p2, k3).
        rms_px: RMS reprojection error over all corners of all views.
        per_view_rms_px: RMS reprojection error of each view.
        tilt_spread_deg: Largest angle between the tilt directions of two tilted views
            (:func:`foreshortening`).
    """

    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    rms_px: float
    per_view_rms_px: NDArray[np.float64]
    tilt_spread_deg: float


def foreshortening(corners: NDArray[np.float64], board: Checkerboard) -> tuple[float, float]:
    """How tilted a view of the board is, from its homography alone (no calibration needed).

    The homography's projective depth ``w`` varies across a tilted board and is constant on a fronto-parallel
    one. Returns ``(strength, direction_deg)``: the relative spread of ``w`` over the board's corners, and
    the direction in the image in which ``w`` grows (the tilt's direction).
    """
    return _foreshortening(board.points[:, :2], corners)


def _foreshortening(xy: NDArray[np.float64], corners: NDArray[np.float64]) -> tuple[float, float]:
    """:func:`foreshortening` of any view: board-frame (N, 2) points and their (N, 2) pixels."""
    import cv2

    h, _ = cv2.findHomography(np.asarray(xy, dtype=np.float64), np.asarray(corners, dtype=np.float64), 0)
    ends = np.array([[xy[:, 0].min(), xy[:, 1].min()], [xy[:, 0].max(), xy[:, 1].min()],
                     [xy[:, 0].min(), xy[:, 1].max()], [xy[:, 0].max(), xy[:, 1].max()]])
    w = np.column_stack([ends, np.ones(4)]) @ h[2]
    uv_h = np.column_stack([ends, np.ones(4)]) @ h.T
    uv = uv_h[:, :2] / uv_h[:, 2:]
    strength = float((w.max() - w.min()) / abs(w.mean()))
    # w fitted as a linear function of the pixel (1/w is the exact affine one; the direction is the same up
    # to sign, and only the axis counts): its gradient is the tilt's direction in the image.
    (a, b, _c), *_ = np.linalg.lstsq(np.column_stack([uv, np.ones(4)]), w / w.mean(), rcond=None)
    return strength, float(np.degrees(np.arctan2(b, a)))


def _distortion_flags(model: str) -> int:
    import cv2

    if model not in DISTORTION_MODELS:
        raise CalibrationInputError(f"distortion model {model!r}; expected one of {list(DISTORTION_MODELS)}")
    fixed = {
        "none": cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
        "radial": cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
        "full": 0,
    }
    return fixed[model]


def calibrate_intrinsics(
    views: list[NDArray[np.float64]] | list[BoardView],
    board: Checkerboard | CharucoBoard,
    image_size: tuple[int, int],
    distortion: str = "radial",
) -> Intrinsics:
    """``K`` and distortion from several views of the board (``fx`` and ``fy`` fitted separately).

    Args:
        views: Each view's detected corners: (N, 2) arrays in the checkerboard's order (:func:`find_board`),
            or :class:`BoardView` (:func:`find_charuco`, a part of the board each).
        board: The board.
        image_size: (width, height) of the images.
        distortion: ``"none"``, ``"radial"`` (k1, k2; default) or ``"full"`` (k1, k2, p1, p2, k3).

    Raises:
        CalibrationInputError: Fewer than :data:`MIN_VIEWS` views, or too few tilted ones, tilted different
            ways (:data:`MIN_FORESHORTENING`, :data:`MIN_TILT_DIRECTION_SPREAD_DEG`): the focal length is then
            not determined.
    """
    import cv2

    flags = _distortion_flags(distortion)
    if len(views) < MIN_VIEWS:
        raise CalibrationInputError(
            f"the board was found in {len(views)} image(s); calibration needs at least {MIN_VIEWS}, showing "
            f"the board tilted different ways"
        )
    pairs = [(v.object_points, v.image_points) if isinstance(v, BoardView) else (board.points, v)
             for v in views]
    tilts = [_foreshortening(obj[:, :2], img) for obj, img in pairs]
    directions = np.array([d for strength, d in tilts if strength >= MIN_FORESHORTENING])
    spread = 0.0
    if directions.size >= 2:
        diff = np.abs(directions[:, None] - directions[None, :]) % 180.0
        spread = float(np.max(np.minimum(diff, 180.0 - diff)))
    if spread < MIN_TILT_DIRECTION_SPREAD_DEG:
        raise CalibrationInputError(
            f"degenerate views: {directions.size} of {len(views)} show the board tilted (foreshortening at "
            f"least {MIN_FORESHORTENING:g}), and their tilt directions span {spread:.0f} degrees (at least "
            f"{MIN_TILT_DIRECTION_SPREAD_DEG:g} are needed to fix the focal length); tilt the board by 20-45 "
            f"degrees in different directions between photos"
        )
    objects = [obj.astype(np.float32) for obj, _ in pairs]
    images = [np.asarray(img, dtype=np.float32).reshape(-1, 1, 2) for _, img in pairs]
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(objects, images, image_size, None, None, flags=flags)
    per_view = []
    for obj, img, r, t in zip(objects, images, rvecs, tvecs, strict=True):
        proj, _j = cv2.projectPoints(obj, r, t, K, dist)
        per_view.append(float(np.sqrt(np.mean(np.sum((proj - img).reshape(-1, 2) ** 2, axis=1)))))
    dist5 = np.zeros(5)
    flat = np.asarray(dist, dtype=np.float64).reshape(-1)
    dist5[: min(5, flat.size)] = flat[:5]
    return Intrinsics(np.asarray(K, dtype=np.float64), dist5, float(rms), np.array(per_view), spread)


def rotation_rpy(roll_deg: float, pitch_deg: float, yaw_deg: float) -> NDArray[np.float64]:
    """Rotation ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (angles in degrees; ROS's roll-pitch-yaw)."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def orient_corners(
    corners: NDArray[np.float64], board: Checkerboard, origin_uv: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The detected corners renumbered so that the first is the one nearest ``origin_uv``.

    The detector returns ``rows`` rows of ``cols`` corners, but may start from any of the grid's four
    corners (the pattern looks the same turned by 180 degrees, and a planar grid seen from either side is the
    same grid mirrored). Of the four numberings that keep rows of ``cols`` corners, the one starting nearest
    the given pixel is returned; its rows run along the board's x axis from the origin.
    """
    grid = np.asarray(corners, dtype=np.float64).reshape(board.rows, board.cols, 2)
    candidates = (grid, grid[::-1, ::-1], grid[::-1, :], grid[:, ::-1])
    best = min(candidates, key=lambda g: float(np.linalg.norm(g[0, 0] - np.asarray(origin_uv, float))))
    return np.ascontiguousarray(best.reshape(-1, 2))


def pose_from_board(
    corners: NDArray[np.float64],
    board: Checkerboard,
    K: NDArray[np.float64],
    dist: NDArray[np.float64],
    board_rotation: NDArray[np.float64],
    board_origin_m: NDArray[np.float64],
    origin_uv: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The camera's pose in the world from one view of the board at a known world pose.

    Args:
        corners: The view's detected corners (:func:`find_board`).
        board, K, dist: The board and the camera's intrinsics.
        board_rotation: 3x3 rotation of the board frame in the world (``x_world = R_wb x_board + o``).
        board_origin_m: (3,) world position ``o`` of the board's origin corner.
        origin_uv: A pixel near the board's origin corner in this image (:func:`orient_corners`).

    Returns:
        ``(R, t, rms_px)``: ``x_cam = R @ x_world + t``, and the reprojection error of the view.
    """
    uv = orient_corners(corners, board, origin_uv)
    return pose_from_points(board.points, uv, K, dist, board_rotation, board_origin_m)


def pose_from_points(
    object_points: NDArray[np.float64],
    image_points: NDArray[np.float64],
    K: NDArray[np.float64],
    dist: NDArray[np.float64],
    board_rotation: NDArray[np.float64],
    board_origin_m: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """:func:`pose_from_board` for corners already matched: (N, 3) board-frame points and their (N, 2) pixels
    (a :class:`BoardView`)."""
    import cv2

    obj = np.asarray(object_points, dtype=np.float64)
    uv = np.asarray(image_points, dtype=np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, uv, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationInputError("the board's pose could not be solved from the extrinsic image")
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv) ** 2, axis=1))))
    r_cb = cv2.Rodrigues(rvec)[0]
    r_wb = np.asarray(board_rotation, dtype=np.float64)
    R = r_cb @ r_wb.T
    t = tvec.reshape(3) - R @ np.asarray(board_origin_m, dtype=np.float64)
    return R, t, rms


#: Touched corners must fit the board to this RMS (m): more means a wrong index, square size or touch.
MAX_TOUCH_RMS_M = 0.005


def board_pose_from_touches(
    board: Checkerboard | CharucoBoard, corners_ij: NDArray[np.float64], points_world: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The board's pose in the world from corners touched with the robot's TCP.

    The rigid transform that best maps the touched corners' board positions onto the TCP positions
    (least squares, Kabsch's SVD solution with the reflection excluded).

    Args:
        board: The board.
        corners_ij: (N, 2) the touched inner corners' indices: column (along the board's x) and row (along
            y), from 0 at the first inner corner (a checkerboard's origin; a ChArUco board's corner id 0).
        points_world: (N, 3) the TCP positions touching them, in the robot's base frame (m).

    Returns:
        ``(R_wb, origin_m, rms_m)``: ``x_world = R_wb @ x_board + origin_m``, and the fit's RMS residual.

    Raises:
        CalibrationInputError: Fewer than 3 corners, corners on one line, an index outside the board, or
            a residual above :data:`MAX_TOUCH_RMS_M`.
    """
    ij = np.asarray(corners_ij, dtype=np.float64)
    world = np.asarray(points_world, dtype=np.float64)
    if ij.ndim != 2 or ij.shape[1] != 2 or world.shape != (len(ij), 3):
        raise CalibrationInputError(f"need (N, 2) corner indices and (N, 3) points, got {ij.shape} and "
                                    f"{world.shape}")
    if len(ij) < 3:
        raise CalibrationInputError(f"touch at least 3 corners not on one line, got {len(ij)}")
    bad = np.flatnonzero((ij[:, 0] < 0) | (ij[:, 0] > board.cols - 1) | (ij[:, 1] < 0)
                         | (ij[:, 1] > board.rows - 1) | (ij != np.round(ij)).any(axis=1))
    if bad.size:
        raise CalibrationInputError(
            f"touched corner {ij[bad[0]].tolist()} is not an inner corner of a "
            f"{board.cols}x{board.rows} board (columns 0-{board.cols - 1}, rows 0-{board.rows - 1})"
        )
    local = np.column_stack([np.asarray(board.first_corner_m) + ij * board.square_m, np.zeros(len(ij))])
    spread = np.linalg.svd(local[:, :2] - local[:, :2].mean(axis=0), compute_uv=False)
    if spread[-1] < 0.5 * board.square_m:
        raise CalibrationInputError(
            "the touched corners lie on one line (or nearly): they do not fix the board's rotation about it; "
            "touch corners spread over both directions of the board"
        )
    a, b = local - local.mean(axis=0), world - world.mean(axis=0)
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    r_wb = u @ np.diag([1.0, 1.0, d]) @ vt
    origin = world.mean(axis=0) - r_wb @ local.mean(axis=0)
    residual = world - (local @ r_wb.T + origin)
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    if rms > MAX_TOUCH_RMS_M:
        worst = int(np.argmax(np.linalg.norm(residual, axis=1)))
        raise CalibrationInputError(
            f"the touched points do not fit the board: RMS {rms * 1e3:.1f} mm (at most "
            f"{MAX_TOUCH_RMS_M * 1e3:.0f} mm), worst at corner {ij[worst].astype(int).tolist()} "
            f"({np.linalg.norm(residual[worst]) * 1e3:.1f} mm); check the indices, --square and the touches"
        )
    return r_wb, origin, rms

