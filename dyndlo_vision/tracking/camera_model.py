"""Pinhole camera model with OpenCV conventions, JSON calibration files and MuJoCo conversion.

Conventions (used everywhere in :mod:`dyndlo_vision.tracking`):

* World to camera: ``x_cam = R @ x_world + t``.
* Camera axes as in OpenCV: x right, y down, z forward (along the optical axis).
* Pixel coordinates ``(u, v)``: u along image columns, v along rows, and the *centre* of the
  pixel in row ``r`` and column ``c`` is at ``(u, v) = (c, r)`` (OpenCV's convention). The
  image therefore spans ``u in [-0.5, width - 0.5]``.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PinholeCamera", "CalibrationError"]

#: Distortion vector lengths OpenCV accepts.
_VALID_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)
_ROTATION_TOL = 1e-6
_JSON_KEYS_REQUIRED = ("width", "height", "K", "dist", "R", "t")
_JSON_KEYS_OPTIONAL = ("fps",)

# Tight criteria so that undistortion inverts cv2.projectPoints to ~1e-12 (the default of 5
# iterations leaves errors of 1e-3 px with strong distortion).
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)


class CalibrationError(ValueError):
    """A camera calibration is malformed (missing key, wrong shape, not a rotation, ...)."""


def _fmt_px(uv: NDArray[np.float64]) -> str:
    return f"({uv[0]:.6g},{uv[1]:.6g})"


def _as_matrix(value: Any, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{name} must be numeric with shape {shape}, got {value!r}") from exc
    if arr.shape != shape:
        raise CalibrationError(f"{name} must have shape {shape}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{name} contains non-finite numbers: {arr.tolist()}")
    return arr


def _readonly(arr: NDArray[np.float64]) -> NDArray[np.float64]:
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """A calibrated pinhole camera with optional OpenCV lens distortion.

    Attributes:
        width: Image width in pixels.
        height: Image height in pixels.
        K: 3x3 intrinsic matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (no skew).
        dist: OpenCV distortion coefficients, length 0, 4, 5, 8, 12 or 14.
        R: 3x3 rotation world -> camera.
        t: Translation world -> camera, ``x_cam = R @ x_world + t``.
        fps: Frame rate of the camera stream, if known.
    """

    width: int
    height: int
    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    fps: float | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise CalibrationError(f"{name} must be a positive int, got {value!r}")
            object.__setattr__(self, name, int(value))
        K = _as_matrix(self.K, (3, 3), "K")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CalibrationError(
                f"K must have positive focal lengths, got fx={K[0, 0]:.6g}, fy={K[1, 1]:.6g}"
            )
        if K[0, 1] != 0 or K[1, 0] != 0 or not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-12):
            raise CalibrationError(
                f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {K.tolist()}"
            )
        try:
            dist = np.array(self.dist, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"dist must be a list of numbers, got {self.dist!r}") from exc
        if sum(n > 1 for n in dist.shape) > 1:
            raise CalibrationError(f"dist must be a flat list, got shape {dist.shape}")
        dist = dist.reshape(-1)
        if dist.size not in _VALID_DIST_LENGTHS:
            raise CalibrationError(
                f"dist must have one of the lengths {_VALID_DIST_LENGTHS}, got {dist.size}"
            )
        if not np.all(np.isfinite(dist)):
            raise CalibrationError(f"dist contains non-finite numbers: {dist.tolist()}")
        R = _as_matrix(self.R, (3, 3), "R")
        ortho_err = float(np.max(np.abs(R @ R.T - np.eye(3))))
        if ortho_err > _ROTATION_TOL:
            raise CalibrationError(
                f"R is not a rotation matrix: R @ R.T deviates from identity by {ortho_err:.3g} "
                f"(tolerance {_ROTATION_TOL:g})"
            )
        det = float(np.linalg.det(R))
        if abs(det - 1.0) > _ROTATION_TOL:
            raise CalibrationError(
                f"R is not a rotation matrix: det(R) = {det:.9g}, expected +1 (a reflection?)"
            )
        # Accept OpenCV's (3,1) column vectors as well as flat (3,).
        t_in = self.t
        if np.shape(t_in) in ((3, 1), (1, 3)):
            t_in = np.asarray(t_in).reshape(3)
        t = _as_matrix(t_in, (3,), "t")
        fps = self.fps
        if fps is not None:
            if isinstance(fps, bool) or not isinstance(fps, int | float | np.number):
                raise CalibrationError(f"fps must be a positive number or null, got {fps!r}")
            fps = float(fps)
            if not math.isfinite(fps) or fps <= 0:
                raise CalibrationError(f"fps must be a positive finite number, got {fps!r}")
        object.__setattr__(self, "K", _readonly(K))
        object.__setattr__(self, "dist", _readonly(dist))
        object.__setattr__(self, "R", _readonly(R))
        object.__setattr__(self, "t", _readonly(t))
        object.__setattr__(self, "fps", fps)

    # ------------------------------------------------------------------ geometry

    @property
    def center(self) -> NDArray[np.float64]:
        """Camera optical centre in world coordinates, ``-R.T @ t``."""
        return -self.R.T @ self.t

    @property
    def has_distortion(self) -> bool:
        """Whether any distortion coefficient is non-zero."""
        return bool(self.dist.size) and bool(np.any(self.dist != 0))

    def world_to_camera(self, points_world: ArrayLike) -> NDArray[np.float64]:
        """Transforms world points (N,3) into the camera frame (N,3)."""
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        return p @ self.R.T + self.t

    def camera_to_world(self, points_cam: ArrayLike) -> NDArray[np.float64]:
        """Transforms camera-frame points (N,3) into the world frame (N,3)."""
        p = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        return (p - self.t) @ self.R

    def project(self, points_world: ArrayLike) -> NDArray[np.float64]:
        """Projects world points to pixels, applying lens distortion.

        Args:
            points_world: (N,3) or (3,) points in the world frame.

        Returns:
            (N,2) pixel coordinates; rows of points at or behind the camera plane (z <= 0) are NaN.
        """
        pc = self.world_to_camera(points_world)
        out = np.full((pc.shape[0], 2), np.nan)
        front = pc[:, 2] > 0
        if not np.any(front):
            return out
        if self.has_distortion:
            # Points are already in the camera frame, so pass the identity pose.
            uv, _ = cv2.projectPoints(
                pc[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.asarray(self.K), self.dist
            )
            out[front] = uv.reshape(-1, 2)
        else:
            xn = pc[front, :2] / pc[front, 2:3]
            out[front, 0] = self.K[0, 0] * xn[:, 0] + self.K[0, 2]
            out[front, 1] = self.K[1, 1] * xn[:, 1] + self.K[1, 2]
        return out

    def normalized_coords(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Undistorted normalised image coordinates ``(x/z, y/z)`` (N,2) of pixels (N,2)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self.has_distortion and uv.shape[0]:
            xn = cv2.undistortPoints(
                uv.reshape(-1, 1, 2), np.asarray(self.K), self.dist, criteria=_UNDISTORT_CRITERIA
            ).reshape(-1, 2)
            # undistortPoints leaves NaN inputs as garbage on some builds; keep NaN in, NaN out.
            xn[~np.all(np.isfinite(uv), axis=1)] = np.nan
            return xn
        return np.column_stack(
            ((uv[:, 0] - self.K[0, 2]) / self.K[0, 0], (uv[:, 1] - self.K[1, 2]) / self.K[1, 1])
        )

    def pixel_rays(self, uv: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Back-projects pixels to rays in the world frame.

        Args:
            uv: (N,2) or (2,) pixel coordinates (distorted, as observed).

        Returns:
            ``(origins, directions)``, both (N,3) in the world frame; origins are the camera
            centre, directions are unit vectors pointing away from the camera.
        """
        xn = self.normalized_coords(uv)
        d_cam = np.column_stack((xn, np.ones(xn.shape[0])))
        d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
        directions = d_cam @ self.R  # R.T @ d for each row
        origins = np.broadcast_to(self.center, directions.shape).copy()
        return origins, directions

    def intersect_plane(self, uv: ArrayLike, normal: ArrayLike, d: float) -> NDArray[np.float64]:
        """Intersects the rays through pixels with the world plane ``normal . x + d = 0``.

        Args:
            uv: (N,2) or (2,) pixel coordinates.
            normal: (3,) plane normal in the world frame (need not be unit length).
            d: Plane offset.

        Returns:
            (N,3) intersection points in the world frame.

        Raises:
            ValueError: If the plane is (nearly) parallel to a ray, or lies behind the camera
                along a ray. The message names the plane and the pixel.
        """
        n = np.asarray(normal, dtype=np.float64).reshape(-1)
        if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) == 0:
            raise ValueError(f"plane normal must be a finite non-zero 3-vector, got {normal!r}")
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        origins, dirs = self.pixel_rays(uv)
        n_norm = float(np.linalg.norm(n))
        denom = dirs @ n
        numer = -(origins @ n + float(d))
        parallel = np.abs(denom) < 1e-9 * n_norm
        if np.any(parallel):
            i = int(np.argmax(parallel))
            raise ValueError(
                f"plane normal {n.tolist()} (d={float(d):g}) is parallel to the camera ray through "
                f"pixel {_fmt_px(uv[i])}: no intersection"
            )
        s = numer / denom
        behind = ~(s > 0)
        if np.any(behind):
            i = int(np.argmax(behind))
            raise ValueError(
                f"plane normal {n.tolist()} (d={float(d):g}) is behind the camera along the ray "
                f"through pixel {_fmt_px(uv[i])} (ray parameter {s[i]:.6g} m <= 0)"
            )
        return origins + s[:, None] * dirs

    # ------------------------------------------------------------------ I/O

    def to_dict(self) -> dict[str, Any]:
        """The JSON-serialisable calibration dictionary (keys as in :meth:`to_json`)."""
        out: dict[str, Any] = {
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
        }
        if self.fps is not None:
            out["fps"] = self.fps
        return out

    @classmethod
    def from_dict(cls, data: Any, source: str = "calibration") -> PinholeCamera:
        """Builds a camera from a calibration dictionary, validating every field.

        Args:
            data: Mapping with keys ``width, height, K, dist, R, t`` and optional ``fps``.
            source: Where the data came from, for error messages.

        Raises:
            CalibrationError: On a missing or unknown key or any invalid value.
        """
        if not isinstance(data, dict):
            raise CalibrationError(f"{source}: expected a JSON object, got {type(data).__name__}")
        missing = [k for k in _JSON_KEYS_REQUIRED if k not in data]
        if missing:
            raise CalibrationError(f"{source}: missing key(s) {missing}")
        unknown = sorted(set(data) - set(_JSON_KEYS_REQUIRED) - set(_JSON_KEYS_OPTIONAL))
        if unknown:
            raise CalibrationError(
                f"{source}: unknown key(s) {unknown}; allowed: "
                f"{list(_JSON_KEYS_REQUIRED + _JSON_KEYS_OPTIONAL)}"
            )
        try:
            return cls(
                width=data["width"],
                height=data["height"],
                K=data["K"],
                dist=data["dist"],
                R=data["R"],
                t=data["t"],
                fps=data.get("fps"),
            )
        except CalibrationError as exc:
            raise CalibrationError(f"{source}: {exc}") from None

    def to_json(self, path: str | os.PathLike[str]) -> None:
        """Writes the calibration as JSON, atomically (temporary file + ``os.replace``)."""
        path = Path(path)
        text = json.dumps(self.to_dict(), indent=2)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text + "\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @classmethod
    def from_json(cls, path: str | os.PathLike[str]) -> PinholeCamera:
        """Reads and validates a calibration written by :meth:`to_json`.

        Raises:
            CalibrationError: On malformed JSON or any invalid field (the message names the
                file and the field).
        """
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise CalibrationError(f"{path}: not valid JSON: {exc}") from None
        return cls.from_dict(data, source=str(path))

    # ------------------------------------------------------------------ MuJoCo

    @classmethod
    def from_mujoco(
        cls,
        fovy_deg: float,
        width: int,
        height: int,
        cam_pos: ArrayLike,
        cam_xmat: ArrayLike,
        fps: float | None = None,
    ) -> PinholeCamera:
        """Converts a MuJoCo camera (``model.cam_fovy``, ``data.cam_xpos``, ``data.cam_xmat``).

        MuJoCo's camera frame has x right, y up and looks along its -z; ``cam_xmat`` (row-major,
        9 numbers or 3x3) holds that frame's axes as columns in world coordinates. OpenCV's frame
        is the same frame with y and z negated, so ``R = diag(1, -1, -1) @ cam_xmat.T`` and
        ``t = -R @ cam_pos``.

        Intrinsics: MuJoCo's vertical field of view spans the full image height, edge to edge
        (the OpenGL frustum maps to pixel *edges*), so ``fx = fy = (height / 2) / tan(fovy / 2)``
        and the principal point is the image centre. In OpenCV's convention pixel centres are at
        integer coordinates, so the image centre is ``cx = (width - 1) / 2``,
        ``cy = (height - 1) / 2`` (not ``width / 2``: that would shift every projection by half
        a pixel). Verified against rendered MuJoCo images in the tests.

        Only ``fovy`` cameras are handled; cameras defined with ``focal``/``sensorsize``/
        ``principal`` need their own intrinsics.

        Args:
            fovy_deg: Vertical field of view in degrees (``model.cam_fovy[i]``).
            width: Rendered image width in pixels.
            height: Rendered image height in pixels.
            cam_pos: (3,) camera position in the world (``data.cam_xpos[i]``).
            cam_xmat: Camera orientation (``data.cam_xmat[i]``), 9 numbers row-major or 3x3.
            fps: Optional frame rate.
        """
        if not (0 < float(fovy_deg) < 180):
            raise CalibrationError(f"fovy_deg must be in (0, 180), got {fovy_deg!r}")
        xmat = np.asarray(cam_xmat, dtype=np.float64).reshape(3, 3)
        pos = np.asarray(cam_pos, dtype=np.float64).reshape(3)
        R = np.diag([1.0, -1.0, -1.0]) @ xmat.T
        # MuJoCo stores xmat in float64 but it is the product of quaternion conversions;
        # re-orthonormalise so that tiny round-off never trips the rotation check.
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
        f = 0.5 * height / math.tan(math.radians(float(fovy_deg)) / 2.0)
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(width=width, height=height, K=K, dist=np.zeros(0), R=R, t=-R @ pos, fps=fps)
