"""Drawing the tracker's output on a frame: ordered polyline, tracked point, its uncertainty, a status line.

Pure functions: the input image is never modified, a new one is returned. Colours are given in RGB and are
swapped for ``channel_order="bgr"``, so the same call draws correctly on frames from either side of OpenCV.

Legend: visible nodes are filled dots joined by a solid line; invisible nodes with a position (bridged gaps,
occlusions) are hollow, joined by a thin dim line; node 0 (the held end) is a square, so a head/tail flip is
visible at a glance. The tracked point is a cross, filled when it was measured in this frame and hollow when
the filter only predicted it, inside its ``n_sigma`` uncertainty ellipse.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .camera_model import PinholeCamera

__all__ = ["annotate_frame", "project_point_covariance", "covariance_ellipse", "inset_view"]

_SHIFT = 4  # sub-pixel bits for cv2 drawing
_SCALE = 1 << _SHIFT
_LINE_RGB = (0, 230, 255)
_HIDDEN_RGB = (0, 110, 130)
_POINT_RGB = (255, 0, 220)
_TEXT_RGB = (255, 255, 255)
_TEXT_BG_RGB = (0, 0, 0)


def _fixed(p: NDArray[np.float64]) -> tuple[int, int]:
    return int(round(float(p[0]) * _SCALE)), int(round(float(p[1]) * _SCALE))


def covariance_ellipse(cov_uv: ArrayLike, n_sigma: float = 2.0) -> tuple[float, float, float]:
    """Half axes and angle of the ``n_sigma`` ellipse of a 2x2 pixel covariance.

    Args:
        cov_uv: (2, 2) covariance in px^2.
        n_sigma: Number of standard deviations along each principal axis.

    Returns:
        ``(major_px, minor_px, angle_deg)``: half axes in pixels and the major axis' angle from the u axis
        towards v (image axes, as ``cv2.ellipse`` expects).

    Raises:
        ValueError: If ``cov_uv`` is not a finite symmetric 2x2 matrix.
    """
    c = np.asarray(cov_uv, dtype=np.float64)
    if c.shape != (2, 2) or not np.all(np.isfinite(c)):
        raise ValueError(f"cov_uv must be a finite 2x2 matrix, got {c.tolist()}")
    if abs(c[0, 1] - c[1, 0]) > 1e-9 * max(1.0, float(np.max(np.abs(c)))):
        raise ValueError(f"cov_uv must be symmetric, got {c.tolist()}")
    eigval, eigvec = np.linalg.eigh(c)
    eigval = np.clip(eigval, 0.0, None)  # round-off can make a flat covariance slightly negative
    major = n_sigma * math.sqrt(eigval[1])
    minor = n_sigma * math.sqrt(eigval[0])
    angle = math.degrees(math.atan2(eigvec[1, 1], eigvec[0, 1]))
    return major, minor, angle


def project_point_covariance(
    camera: PinholeCamera, position: ArrayLike, covariance: ArrayLike, step_m: float = 1e-5
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Projects a world point and its 3x3 position covariance into the image (first order).

    ``cov_uv = J cov J^T`` with ``J`` the 2x3 Jacobian of :meth:`PinholeCamera.project` at the point, by
    central differences (so lens distortion is included).

    Args:
        camera: The camera.
        position: (3,) world point in metres.
        covariance: (3, 3) position covariance in m^2 (e.g. ``Estimate.covariance[:3, :3]``).
        step_m: Finite-difference step in metres.

    Returns:
        ``(uv, cov_uv)``: (2,) pixel and (2, 2) covariance in px^2; NaN if the point is behind the camera.
    """
    p = np.asarray(position, dtype=np.float64).reshape(3)
    cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    probes = np.vstack((p, p + step_m * np.eye(3), p - step_m * np.eye(3)))
    uv = camera.project(probes)
    jac = ((uv[1:4] - uv[4:7]) / (2.0 * step_m)).T  # (2, 3)
    return uv[0], jac @ cov @ jac.T


def annotate_frame(
    image: NDArray[np.uint8],
    nodes_uv: ArrayLike | None,
    visible: ArrayLike | None,
    *,
    point_uv: ArrayLike | None = None,
    point_cov_uv: ArrayLike | None = None,
    point_measured: bool = False,
    t: float | None = None,
    status: str = "",
    n_sigma: float = 2.0,
    channel_order: str = "rgb",
) -> NDArray[np.uint8]:
    """Draws the tracked cable and point on a copy of ``image``.

    Args:
        image: (H, W, 3) uint8 frame, RGB or BGR (see ``channel_order``).
        nodes_uv: (N, 2) node pixels from the held end (NaN rows are skipped), or None.
        visible: (N,) per-node visibility, or None (all nodes with a position count as visible).
        point_uv: (2,) pixel of the tracked point (e.g. the filter's estimate projected), or None.
        point_cov_uv: (2, 2) pixel covariance of ``point_uv``; its ``n_sigma`` ellipse is drawn.
        point_measured: The point was measured in this frame (filled marker) rather than predicted (hollow).
        t: Time in seconds for the status line, or None.
        status: Rest of the status line (tracking state).
        n_sigma: Size of the uncertainty ellipse in standard deviations.
        channel_order: ``"rgb"`` or ``"bgr"``, the order of ``image``'s channels.

    Returns:
        A new (H, W, 3) uint8 image.

    Raises:
        ValueError: On an image that is not (H, W, 3) uint8, mismatched node arrays, or an unknown
            ``channel_order``.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) uint8, got shape {img.shape} dtype {img.dtype}")
    if channel_order not in ("rgb", "bgr"):
        raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")

    def color(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
        return rgb[::-1] if channel_order == "bgr" else rgb

    out = np.ascontiguousarray(img).copy()
    h, w = out.shape[:2]
    unit = max(1, round(min(h, w) / 240))  # line width and marker size grow with the image
    if nodes_uv is not None:
        nodes = np.asarray(nodes_uv, dtype=np.float64).reshape(-1, 2)
        vis = (
            np.ones(nodes.shape[0], dtype=bool)
            if visible is None
            else np.asarray(visible, dtype=bool).reshape(-1)
        )
        if vis.shape[0] != nodes.shape[0]:
            raise ValueError(f"visible has {vis.shape[0]} entries for {nodes.shape[0]} nodes")
        finite = np.all(np.isfinite(nodes), axis=1)
        for i in range(nodes.shape[0] - 1):
            if finite[i] and finite[i + 1]:
                both = vis[i] and vis[i + 1]
                cv2.line(
                    out,
                    _fixed(nodes[i]),
                    _fixed(nodes[i + 1]),
                    color(_LINE_RGB if both else _HIDDEN_RGB),
                    unit if both else 1,
                    cv2.LINE_AA,
                    _SHIFT,
                )
        r = (unit + 1) * _SCALE
        for i in np.flatnonzero(finite).tolist():
            c = _fixed(nodes[i])
            col = color(_LINE_RGB if vis[i] else _HIDDEN_RGB)
            thick = -1 if vis[i] else 1
            if i == 0:
                cv2.rectangle(
                    out, (c[0] - r, c[1] - r), (c[0] + r, c[1] + r), col, thick, cv2.LINE_AA, _SHIFT
                )
            else:
                cv2.circle(out, c, r, col, thick, cv2.LINE_AA, _SHIFT)
    if point_uv is not None:
        p = np.asarray(point_uv, dtype=np.float64).reshape(2)
        if np.all(np.isfinite(p)):
            col = color(_POINT_RGB)
            if point_cov_uv is not None and np.all(np.isfinite(np.asarray(point_cov_uv, dtype=np.float64))):
                major, minor, angle = covariance_ellipse(point_cov_uv, n_sigma)
                limit = float(math.hypot(h, w))  # a lost filter's ellipse would swamp the frame
                axes = (int(round(min(major, limit) * _SCALE)), int(round(min(minor, limit) * _SCALE)))
                cv2.ellipse(out, _fixed(p), axes, angle, 0.0, 360.0, col, unit, cv2.LINE_AA, _SHIFT)
            arm = (3 * unit + 3) * _SCALE
            c = _fixed(p)
            cv2.line(out, (c[0] - arm, c[1]), (c[0] + arm, c[1]), col, unit, cv2.LINE_AA, _SHIFT)
            cv2.line(out, (c[0], c[1] - arm), (c[0], c[1] + arm), col, unit, cv2.LINE_AA, _SHIFT)
            cv2.circle(out, c, (unit + 2) * _SCALE, col, -1 if point_measured else unit, cv2.LINE_AA, _SHIFT)
    text = " ".join(part for part in ((f"t={t:.3f} s" if t is not None else ""), status) if part)
    if text:
        scale = 0.45 * unit
        (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, unit)
        pad = 3 * unit
        cv2.rectangle(out, (0, 0), (min(w - 1, tw + 2 * pad), th + base + 2 * pad), color(_TEXT_BG_RGB), -1)
        cv2.putText(
            out, text, (pad, pad + th), cv2.FONT_HERSHEY_SIMPLEX, scale, color(_TEXT_RGB), unit, cv2.LINE_AA
        )
    return out


def inset_view(image: NDArray[np.uint8], view: NDArray[np.uint8], fraction: float = 1 / 3,
               label: str = "second camera", corner: str = "bottom-right") -> NDArray[np.uint8]:
    """A copy of ``image`` with ``view`` shrunk to ``fraction`` of its width in a corner (``"bottom-right"``,
    clear of :func:`annotate_frame`'s status line, or ``"top-right"``), framed and labelled (both images in
    the same channel order).

    Raises:
        ValueError: On images that are not (H, W, 3) uint8, ``fraction`` outside (0, 1], or another corner.
    """
    import cv2

    for name, img in (("image", image), ("view", view)):
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"{name} must be (H, W, 3) uint8, got shape {img.shape} dtype {img.dtype}")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    if corner not in ("bottom-right", "top-right"):
        raise ValueError(f"corner must be 'bottom-right' or 'top-right', got {corner!r}")
    out = np.ascontiguousarray(image).copy()
    h, w = out.shape[:2]
    iw = max(1, int(round(w * fraction)))
    ih = min(h, max(1, int(round(iw * view.shape[0] / view.shape[1]))))
    small = np.ascontiguousarray(cv2.resize(view, (iw, ih), interpolation=cv2.INTER_AREA))
    if label:  # white on a dark box, readable on any background
        (tw, th), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        cv2.rectangle(small, (0, 0), (min(iw - 1, tw + 8), th + base + 6), (0, 0, 0), -1)
        white = (255, 255, 255)
        cv2.putText(small, label, (4, th + 3), cv2.FONT_HERSHEY_SIMPLEX, 0.45, white, 1, cv2.LINE_AA)
    top = 0 if corner == "top-right" else h - ih
    out[top:top + ih, w - iw:w] = small
    cv2.rectangle(out, (w - iw, top), (w - 1, top + ih - 1), (255, 255, 255), 1)
    return out
