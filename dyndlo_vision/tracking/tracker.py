"""One frame's cable measurement and its 3D lifting: the :class:`Measurement` of N ordered nodes, lifting
pixels onto a plane (:func:`lift_with_plane`) or with a depth image (:func:`lift_with_depth`), and the tip
of a polyline shorter than the cable (:func:`tip_from_polyline`). The pipeline that produces measurements
frame by frame is :class:`~dyndlo_vision.tracking.pipeline.CablePipeline`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .camera_model import PinholeCamera
from .centerline import Centerline

__all__ = ["Plane", "Measurement", "lift_with_depth", "lift_with_plane", "tip_from_polyline"]


@dataclass(frozen=True)
class Plane:
    """The world plane ``normal . x + d = 0``."""

    normal: NDArray[np.float64]
    d: float


@dataclass(frozen=True)
class Measurement:
    """One frame's cable measurement.

    Attributes:
        nodes_xyz: (N, 3) world positions (m), NaN where invisible or not liftable.
        nodes_uv: (N, 2) pixel positions, NaN beyond the observed cable.
        visible: (N,) bool per node.
        t_capture: Capture time of the frame (s).
        centerline: The 2D centreline the nodes came from (diagnostics, drawing).
    """

    nodes_xyz: NDArray[np.float64]
    nodes_uv: NDArray[np.float64]
    visible: NDArray[np.bool_]
    t_capture: float
    centerline: Centerline | None = field(default=None, repr=False)

    def point(self, index: int = -1) -> NDArray[np.float64] | None:
        """The 3D position of node ``index`` (default: the free tip), or None if not measured."""
        p = self.nodes_xyz[index]
        if not self.visible[index] or not np.all(np.isfinite(p)):
            return None
        return p.copy()

    @property
    def lifted(self) -> NDArray[np.bool_]:
        """(N,) nodes that are visible and have a finite world position."""
        return self.visible & np.all(np.isfinite(self.nodes_xyz), axis=1)

    def path_from(self, start_xyz: ArrayLike) -> NDArray[np.float64]:
        """``start_xyz`` (the held end) followed by the lifted nodes in order, ``(1 + K, 3)``."""
        return np.vstack([np.asarray(start_xyz, dtype=float).reshape(1, 3), self.nodes_xyz[self.lifted]])

    def length_from(self, start_xyz: ArrayLike) -> float:
        """World length of the measured cable: from ``start_xyz`` (the held end) through the visible, lifted
        nodes in order. 0 when no node is. Gaps between visible nodes count as straight."""
        return _path_length(self.path_from(start_xyz))


def _path_length(points: NDArray[np.float64]) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


#: Shortest share of the cable's known length that the measured polyline (from the held end) must cover for
#: its tip to be estimated at all; below it the tip is *not seen*. Above it, continuing the polyline straight
#: by the missing length puts the tip within millimetres; below, it can be a decimetre off (docs/results.md,
#: "Decided questions"). Continuing trusts the segmentation: with wrong masks it does harm.
MIN_SEEN_LENGTH_FRACTION = 0.5


def tip_from_polyline(measurement: Measurement, start_xyz: ArrayLike, cable_length_m: float,
                      min_fraction: float = MIN_SEEN_LENGTH_FRACTION) -> NDArray[np.float64] | None:
    """The free tip of a cable of known length, from a measured polyline that may stop short of it.

    A polyline shorter than the cable ends where the cable disappears (behind an occluder, into a region the
    segmenter drops), not at the tip. The missing length is taken to continue straight on from the last
    measured nodes. Below ``min_fraction`` of the cable nothing is reported (None: the tip is not seen);
    a polyline as long as the cable or longer gives its own last node.

    Args:
        measurement: The frame's measurement (world nodes from the held end to the far end).
        start_xyz: The held end (the gripper) in the same world frame.
        cable_length_m: The cable's length.
        min_fraction: See :data:`MIN_SEEN_LENGTH_FRACTION`.
    """
    if not cable_length_m > 0:
        raise ValueError(f"cable_length_m must be positive, got {cable_length_m!r}")
    pts = measurement.path_from(start_xyz)
    if len(pts) < 2:  # no node lifted
        return None
    length = _path_length(pts)
    if length < min_fraction * cable_length_m:
        return None
    last = pts[-1]
    missing = cable_length_m - length
    if missing <= 0:
        return last.copy()
    direction = last - pts[max(0, len(pts) - 3)]  # over the last two segments: less pixel noise
    norm = float(np.linalg.norm(direction))
    if norm < 1e-9:
        return last.copy()
    return last + direction / norm * missing


def _finite_rows(uv: NDArray[np.float64], visible: ArrayLike | None) -> NDArray[np.bool_]:
    ok = np.all(np.isfinite(uv), axis=1)
    if visible is not None:
        ok &= np.asarray(visible, dtype=bool).reshape(-1)
    return ok


def lift_with_depth(
    nodes_uv: ArrayLike,
    depth: NDArray[np.floating],
    camera: PinholeCamera,
    visible: ArrayLike | None = None,
    window: int = 1,
) -> NDArray[np.float64]:
    """Lifts pixels to 3D world points with a depth image.

    Args:
        nodes_uv: (N, 2) pixel coordinates.
        depth: (H, W) depth in metres along the camera z axis (MuJoCo's depth rendering);
            non-finite or <= 0 values are invalid.
        camera: The camera that took the depth image.
        visible: Optional (N,) mask; other rows come back NaN.
        window: Half size of the square window whose median valid depth is used (0 = the
            nearest pixel only). The median rejects isolated background pixels at the edge
            of a thin cable.

    Returns:
        (N, 3) world points, NaN where no valid depth or not visible.
    """
    uv = np.asarray(nodes_uv, dtype=np.float64).reshape(-1, 2)
    out = np.full((uv.shape[0], 3), np.nan)
    ok = _finite_rows(uv, visible)
    if not np.any(ok):
        return out
    h, w = depth.shape[:2]
    cols = np.rint(uv[ok, 0]).astype(np.int64)
    rows = np.rint(uv[ok, 1]).astype(np.int64)
    inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    z = np.full(cols.shape[0], np.nan)
    r = int(window)
    offs = np.arange(-r, r + 1)
    rr = np.clip(rows[inside, None, None] + offs[None, :, None], 0, h - 1)
    cc = np.clip(cols[inside, None, None] + offs[None, None, :], 0, w - 1)
    patch = np.asarray(depth, dtype=np.float64)[rr, cc].reshape(rr.shape[0], -1)
    patch[~(np.isfinite(patch) & (patch > 0))] = np.nan
    with np.errstate(all="ignore"):
        if patch.shape[0]:
            valid_any = np.any(np.isfinite(patch), axis=1)
            zz = np.full(patch.shape[0], np.nan)
            if np.any(valid_any):
                zz[valid_any] = np.nanmedian(patch[valid_any], axis=1)
            z[inside] = zz
    xn = camera.normalized_coords(uv[ok])
    p_cam = np.column_stack((xn * z[:, None], z))
    out[ok] = camera.camera_to_world(p_cam)
    out[~np.all(np.isfinite(out), axis=1)] = np.nan
    return out


def lift_with_plane(
    nodes_uv: ArrayLike,
    camera: PinholeCamera,
    plane: Plane | tuple[ArrayLike, float],
    visible: ArrayLike | None = None,
    floor: Plane | None = None,
) -> NDArray[np.float64]:
    """Lifts pixels to 3D by intersecting their rays with a known world plane.

    Args:
        nodes_uv: (N, 2) pixel coordinates.
        camera: The camera.
        plane: :class:`Plane` or ``(normal, d)`` for ``normal . x + d = 0``.
        visible: Optional (N,) mask; other rows come back NaN.
        floor: Optional plane the cable cannot go below (its normal pointing up; for a cable resting on the
            floor, the floor raised by the cable's radius). A ray that meets ``plane`` below it meets the
            floor first: the cable seen there lies on the floor, off ``plane``, and is taken where its ray
            meets the floor.

    Returns:
        (N, 3) world points (NaN rows where not visible).

    Raises:
        ValueError: If the plane is parallel to a ray or behind the camera
            (see :meth:`PinholeCamera.intersect_plane`).
    """
    uv = np.asarray(nodes_uv, dtype=np.float64).reshape(-1, 2)
    normal, d = (plane.normal, plane.d) if isinstance(plane, Plane) else plane
    out = np.full((uv.shape[0], 3), np.nan)
    ok = _finite_rows(uv, visible)
    if np.any(ok):
        out[ok] = camera.intersect_plane(uv[ok], normal, float(d))
        if floor is not None:
            below = ok & (out @ np.asarray(floor.normal, dtype=np.float64) + floor.d < 0)
            if np.any(below):
                out[below] = camera.intersect_plane(uv[below], floor.normal, float(floor.d))
    return out
