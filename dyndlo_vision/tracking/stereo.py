"""Two calibrated views of one cable: its centreline in 3D by epipolar matching and triangulation.

One camera and a known plane place a cable that moves in that plane (the planar tasks). A cable that leaves
the plane (vaulting's middle swings sideways as it is thrown) needs depth, or a second view. Here the second
view: both trackers give the ordered centreline from the held end in their own image. Each point sampled
along the first view's centreline has an epipolar line in the second image, which crosses the second
centreline where the same cable point is seen, and the two rays through the matched pixels meet at the cable
point.

- Of several crossings, only those where the second centreline crosses the line the way the first one does
  are candidates (a point moving along the cable sweeps through the epipolar planes the same way in both
  views), and of those the one nearest in 3D to the previous matched point is taken (the cable is
  continuous).
- Matching is not forced to move on along the second centreline: one wrong match would then reject every
  right one after it (on a cable with a loop, the far nodes end up decimetres off).
- Where the second centreline runs almost along the epipolar line (the cable lies in an epipolar plane), the
  crossing is ill-posed and the sample is skipped; the 3D polyline joins the points on either side. Place the
  cameras so that the cable rarely lies in a plane through both (tasks/vaulting.py says how).

The 3D nodes are then spaced along the cable by arc length from the held end, as the simulator's nodes are:
node k lies ``k / (N - 1)`` of the cable's length from the held end (with the length known), so an inner
node such as vaulting's middle is the same material point whatever the views' foreshortening.

Pure computation on arrays; check the geometry against projected curves (tests/tracking/test_stereo.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .camera_model import PinholeCamera
from .tracker import Measurement

__all__ = ["StereoParams", "essential_matrix", "triangulate", "match_centerlines", "nodes_by_arc_length",
           "stereo_measurement"]


@dataclass(frozen=True)
class StereoParams:
    """Tuning of :func:`match_centerlines`.

    Attributes:
        samples: Points sampled along the first view's centreline.
        min_crossing_deg: Smallest angle between the second centreline and an epipolar line for a crossing to
            be used; below it a pixel of error moves the match far along the cable. (In the vault loop, 0, 12
            and 20 degrees gave 4.6, 4.6 and 4.9 mm.)
        max_step_m: Largest 3D distance from the previous matched point (or the held end) for a crossing to be
            taken as the same cable (a wrong crossing lands on another part of it, or off it), per sample
            since that match: after unmatched samples the cable may have gone on that much farther.
        max_ray_gap_m: Largest distance between the two rays at a match (the views' calibration error).
        smooth: Width (in matched points) of the moving average taken along the matched points (1: none).
            Depth from two views is noisier than the image position, and a zig-zag lengthens the polyline:
            at 0.5 px of independent noise per path point, unsmoothed, the far end's nodes moved 13 mm towards
            the held end (test_stereo.py). The tracker's centrelines are smooth already, and in the vaulting
            loop smoothing made the middle's estimate worse (median RMSE over 10 episodes 1.5 mm unsmoothed,
            2.1 mm at 3, 4.6 mm at 5: it cuts the cable's bends), so the default is none.
    """

    samples: int = 64
    min_crossing_deg: float = 12.0
    max_step_m: float = 0.25
    max_ray_gap_m: float = 0.01
    smooth: int = 1

    def __post_init__(self) -> None:
        if not isinstance(self.samples, int) or self.samples < 2:
            raise ValueError(f"samples must be an int >= 2, got {self.samples!r}")
        if not 0.0 <= self.min_crossing_deg < 90.0:
            raise ValueError(f"min_crossing_deg must be in [0, 90), got {self.min_crossing_deg!r}")
        if not isinstance(self.smooth, int) or self.smooth < 1 or self.smooth % 2 == 0:
            raise ValueError(f"smooth must be an odd int >= 1, got {self.smooth!r}")
        for name in ("max_step_m", "max_ray_gap_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")


def _skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def essential_matrix(cam_a: PinholeCamera, cam_b: PinholeCamera) -> NDArray[np.float64]:
    """``E`` with ``x_b^T E x_a = 0`` for the normalised homogeneous coordinates of one world point."""
    r_ab = cam_b.R @ cam_a.R.T
    t_ab = cam_b.t - r_ab @ cam_a.t
    if np.linalg.norm(t_ab) < 1e-9:
        raise ValueError("the two cameras share their optical centre: no depth from two views")
    return np.asarray(_skew(t_ab) @ r_ab, dtype=np.float64)


def triangulate(cam_a: PinholeCamera, uv_a: ArrayLike, cam_b: PinholeCamera,
                uv_b: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World points seen at pixels ``uv_a`` and ``uv_b`` (N, 2): the midpoints of the rays' closest approach.

    Returns:
        ``(points (N, 3), gaps (N,))``: the gap is the rays' distance at their closest approach (0 for exact
        correspondences). NaN where the rays are parallel or the point lies behind either camera.
    """
    oa, da = cam_a.pixel_rays(uv_a)
    ob, db = cam_b.pixel_rays(uv_b)
    w0 = oa - ob
    b = np.einsum("ij,ij->i", da, db)
    d = np.einsum("ij,ij->i", da, w0)
    e = np.einsum("ij,ij->i", db, w0)
    denom = 1.0 - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        sa = (b * e - d) / denom
        sb = (e - b * d) / denom
    pa = oa + sa[:, None] * da
    pb = ob + sb[:, None] * db
    points = 0.5 * (pa + pb)
    gaps = np.linalg.norm(pa - pb, axis=1)
    bad = ~(denom > 1e-12) | ~(sa > 0) | ~(sb > 0)
    points[bad] = np.nan
    gaps[bad] = np.nan
    return points, gaps


def _segments_seen(path: NDArray[np.float64], visible: ArrayLike | None, name: str) -> NDArray[np.bool_]:
    """(M - 1,) segments of ``path`` (M, 2) that are seen: marked visible and with finite ends."""
    seen = np.ones(len(path) - 1, dtype=bool)
    if visible is not None:
        seen = np.asarray(visible, dtype=bool).reshape(-1)
        if seen.shape != (len(path) - 1,):
            raise ValueError(f"{name} has {seen.size} entries for a path of {len(path)} points; expected "
                             f"{len(path) - 1} (one per segment)")
    finite = np.all(np.isfinite(path), axis=1)
    return np.asarray(seen & finite[:-1] & finite[1:])


def _samples_on_seen(path: NDArray[np.float64], seen: NDArray[np.bool_], n: int) -> NDArray[np.float64]:
    """``n`` points evenly spaced by arc length along the seen segments of ``path`` (joined end to end)."""
    seg = np.where(seen[:, None], np.diff(np.nan_to_num(path), axis=0), 0.0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    q = np.linspace(0.0, cum[-1], n)
    # side="right": a point at a plateau (an unseen segment) goes to the seen segment after it.
    k = np.clip(np.searchsorted(cum, q, side="right") - 1, 0, len(seg) - 1)
    w = np.where(length[k] > 0, (q - cum[k]) / np.maximum(length[k], 1e-300), 0.0)
    out = np.nan_to_num(path)[k] + w[:, None] * seg[k]
    return np.asarray(out, dtype=np.float64)


def match_centerlines(
    cam_a: PinholeCamera,
    path_a_uv: ArrayLike,
    cam_b: PinholeCamera,
    path_b_uv: ArrayLike,
    held_xyz: ArrayLike,
    params: StereoParams | None = None,
    path_a_visible: ArrayLike | None = None,
    path_b_visible: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """3D points along a cable from its ordered centrelines in two views.

    Args:
        cam_a, cam_b: The two calibrated cameras.
        path_a_uv, path_b_uv: (M, 2) ordered centrelines in pixels, each starting at the held end (a
            tracker's ``Centerline.path_uv`` with the held end's pixel as anchor).
        held_xyz: (3,) the held end in the world (the gripper): where the cable starts, in 3D.
        params: Tuning.
        path_a_visible, path_b_visible: Bool per segment of each path: False where the tracker bridged a gap
            (an occluder; ``Centerline.path_visible``). A bridge is a guess, so nothing is matched on it.

    Returns:
        (K, 3) world points in order from the held end (which is not included), one per sample of the first
        centreline that was matched; empty if none was.
    """
    params = params or StereoParams()
    pa = np.asarray(path_a_uv, dtype=np.float64).reshape(-1, 2)
    pb = np.asarray(path_b_uv, dtype=np.float64).reshape(-1, 2)
    if len(pa) < 2 or len(pb) < 2:
        return np.zeros((0, 3))
    seen_a = _segments_seen(pa, path_a_visible, "path_a_visible")
    seen_b = _segments_seen(pb, path_b_visible, "path_b_visible")
    if not seen_a.any() or not seen_b.any():
        return np.zeros((0, 3))
    samples = _samples_on_seen(pa, seen_a, params.samples)
    xa = np.column_stack([cam_a.normalized_coords(samples), np.ones(len(samples))])
    xb = np.column_stack([cam_b.normalized_coords(pb), np.ones(len(pb))])
    lines = xa @ essential_matrix(cam_a, cam_b).T  # (S, 3): the epipolar line of each sample in view b
    lines /= np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    side = lines @ xb.T  # (S, M): signed distance of each b vertex to each line (normalised units)
    seg_dir = np.diff(xb[:, :2], axis=0)
    seg_len = np.linalg.norm(seg_dir, axis=1)
    # Which way each centreline moves through the pencil of epipolar planes (about the baseline): a cable
    # point moves through it the same way in both views. Where the cable turns back in that sense (a U whose
    # legs both cross the epipolar line), the leg moving the other way is the wrong one.
    pencil_a, pencil_b = _pencil_angle(cam_a, cam_b, samples), _pencil_angle(cam_a, cam_b, pb, second=True)
    sense_a = np.sign(_wrapped(np.gradient(np.unwrap(pencil_a))))
    sense_b = np.sign(_wrapped(np.diff(pencil_b)))
    min_sin = np.sin(np.radians(params.min_crossing_deg))
    # Every (sample, segment) crossing at once, then the usable ones triangulated in one call.
    f0, f1 = side[:, :-1], side[:, 1:]
    with np.errstate(invalid="ignore"):
        crosses = (f0 == 0) | (f0 * f1 < 0)
    rows, segs = np.nonzero(crosses)
    # How steeply each crossed segment cuts the line: |sin| of the angle between them.
    with np.errstate(divide="ignore", invalid="ignore"):
        steep = np.abs(f1[rows, segs] - f0[rows, segs]) / seg_len[segs]
        usable = (steep >= min_sin) & (sense_b[segs] == sense_a[rows]) & seen_b[segs]
    rows, segs = rows[usable], segs[usable]
    w = f0[rows, segs] / (f0[rows, segs] - f1[rows, segs])
    uv_b = pb[segs] + w[:, None] * (pb[segs + 1] - pb[segs])
    points, gaps = triangulate(cam_a, samples[rows], cam_b, uv_b)
    good = np.isfinite(gaps) & (gaps <= params.max_ray_gap_m)
    rows, points = rows[good], points[good]
    starts = np.searchsorted(rows, np.arange(len(samples) + 1))  # rows are sorted: candidates per sample
    out: list[NDArray[np.float64]] = []
    previous = np.asarray(held_xyz, dtype=np.float64).reshape(3)
    last = -1  # the sample of the previous match (-1: the held end)
    for i in range(len(samples)):
        candidates = points[starts[i] : starts[i + 1]]
        if len(candidates) == 0:
            continue
        step = np.linalg.norm(candidates - previous, axis=1)
        best = int(np.argmin(step))
        # After samples that could not be matched (a stretch in an epipolar plane, a gap), the cable may be
        # that much farther on: the bound grows with the samples skipped.
        if step[best] > params.max_step_m * (i - last):
            continue
        previous, last = candidates[best], i
        out.append(previous)
    return _moving_average(np.asarray(out, dtype=np.float64).reshape(-1, 3), params.smooth)


def _wrapped(angle: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(np.angle(np.exp(1j * angle)), dtype=np.float64)


def _pencil_angle(cam_a: PinholeCamera, cam_b: PinholeCamera, uv: NDArray[np.float64],
                  second: bool = False) -> NDArray[np.float64]:
    """The angle about the baseline of the epipolar plane through each pixel (of the first camera, or of the
    second with ``second``): one number per plane, the same in both views for one world point."""
    baseline = cam_b.center - cam_a.center
    axis = baseline / np.linalg.norm(baseline)
    u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    _, rays = (cam_b if second else cam_a).pixel_rays(uv)
    normal = np.cross(baseline, rays)
    return np.asarray(np.arctan2(normal @ v, normal @ u), dtype=np.float64)


def _moving_average(points: NDArray[np.float64], width: int) -> NDArray[np.float64]:
    """Centred moving average along the points, the window shrinking symmetrically at the ends (the end points
    stay where they are)."""
    half = width // 2
    if half == 0 or len(points) < 3:
        return points
    csum = np.vstack([np.zeros((1, 3)), np.cumsum(points, axis=0)])
    k = np.arange(len(points))
    h = np.minimum(np.minimum(k, len(points) - 1 - k), half)
    return np.asarray((csum[k + h + 1] - csum[k - h]) / (2 * h + 1)[:, None], dtype=np.float64)


def nodes_by_arc_length(points: ArrayLike, n_nodes: int,
                        cable_length_m: float | None = None) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """``n_nodes`` nodes spaced evenly by arc length along a 3D polyline that starts at the held end.

    With ``cable_length_m`` node k lies ``k / (n_nodes - 1) * cable_length_m`` along it, and nodes past the
    polyline's end are not seen (NaN); without it the nodes spread over the polyline's own length.

    Returns:
        ``(nodes (n_nodes, 3), visible (n_nodes,))``.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if n_nodes < 2:
        raise ValueError(f"n_nodes must be at least 2, got {n_nodes!r}")
    if cable_length_m is not None and not cable_length_m > 0:
        raise ValueError(f"cable_length_m must be positive or None, got {cable_length_m!r}")
    nodes = np.full((n_nodes, 3), np.nan)
    visible = np.zeros(n_nodes, dtype=bool)
    if len(pts) < 2:
        return nodes, visible
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    total = cable_length_m if cable_length_m is not None else s[-1]
    q = np.linspace(0.0, total, n_nodes)
    visible = q <= s[-1] + 1e-9
    for k in range(3):
        nodes[visible, k] = np.interp(q[visible], s, pts[:, k])
    return nodes, visible


def _path_visible(cl: Any) -> NDArray[np.bool_] | None:
    """A centreline's per-segment visibility, if it has one for its path."""
    vis = np.asarray(cl.path_visible, dtype=bool)
    return vis if len(vis) == max(len(cl.path_uv) - 1, 0) else None


def stereo_measurement(
    meas_a: Measurement,
    cam_a: PinholeCamera,
    meas_b: Measurement,
    cam_b: PinholeCamera,
    held_xyz: ArrayLike,
    cable_length_m: float | None = None,
    params: StereoParams | None = None,
) -> Measurement:
    """One frame's 3D measurement from the two views' 2D ones (taken at the same time).

    The nodes are the first view's count, spaced by arc length from ``held_xyz`` (see
    :func:`nodes_by_arc_length`); their pixels are their projections into the first view, and the first view's
    centreline is kept for drawing. No node is seen when either view saw no cable.
    """
    n = len(meas_a.visible)
    empty = Measurement(np.full((n, 3), np.nan), np.full((n, 2), np.nan), np.zeros(n, dtype=bool),
                        meas_a.t_capture, meas_a.centerline)
    cl_a, cl_b = meas_a.centerline, meas_b.centerline
    # The 2D centrelines decide (each tracker's own 3D lifting, onto its plane, plays no part).
    if cl_a is None or cl_b is None or not cl_a.any_visible or not cl_b.any_visible:
        return empty
    held = np.asarray(held_xyz, dtype=np.float64).reshape(3)
    points = match_centerlines(cam_a, cl_a.path_uv, cam_b, cl_b.path_uv, held, params,
                               path_a_visible=_path_visible(cl_a), path_b_visible=_path_visible(cl_b))
    if len(points) == 0:
        return empty
    nodes, visible = nodes_by_arc_length(np.vstack([held, points]), n, cable_length_m)
    uv = np.full((n, 2), np.nan)
    if visible.any():
        uv[visible] = cam_a.project(nodes[visible])
    return Measurement(nodes, uv, visible, meas_a.t_capture, cl_a)
