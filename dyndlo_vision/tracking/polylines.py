"""Ordered polylines of every cable in a mask (photos with several cables), each end marked free or cut.

:func:`extract_polylines` takes the longest ordered walk of :func:`extract_centerline` (which goes straight
through crossings), removes the pixels that walk covers from the mask, and repeats, so crossing cables come
out as separate polylines. An end is *free* when it lies inside the image; an end at the image border is cut
off by the frame and is not a free end of the cable.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision.tracking.centerline import CenterlineParams, extract_centerline

__all__ = ["Polyline", "extract_polylines"]


@dataclass(frozen=True)
class Polyline:
    """One ordered cable polyline in pixels.

    Attributes:
        points_uv: (K, 2) ordered points (u, v), about ``spacing_px`` apart.
        visible: (K - 1,) bool per segment; False where the walk bridged a gap (an occlusion).
        length_px: Arc length.
        width_px: Estimated cable width.
        start_free, end_free: The first / last point is a free end of the cable (not cut by the image border).
    """

    points_uv: NDArray[np.float64]
    visible: NDArray[np.bool_]
    length_px: float
    width_px: float
    start_free: bool
    end_free: bool

    def to_json(self) -> dict[str, object]:
        """A JSON-ready dict."""
        return {
            "points_uv": [[round(float(u), 2), round(float(v), 2)] for u, v in self.points_uv],
            "segment_visible": [bool(x) for x in self.visible],
            "length_px": round(self.length_px, 2),
            "width_px": round(self.width_px, 2),
            "ends": {"start": {"free": self.start_free}, "end": {"free": self.end_free}},
        }


def _subsample(
    path: NDArray[np.float64], vis: NDArray[np.bool_], spacing: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    seg = np.hypot(*np.diff(path, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(2, int(np.ceil(s[-1] / spacing)) + 1)
    t = np.linspace(0.0, s[-1], n)
    pts = np.column_stack([np.interp(t, s, path[:, 0]), np.interp(t, s, path[:, 1])])
    mid = 0.5 * (t[:-1] + t[1:])
    idx = np.clip(np.searchsorted(s, mid, side="right") - 1, 0, vis.size - 1)
    return pts, vis[idx]


def extract_polylines(
    mask: ArrayLike,
    max_cables: int = 8,
    min_length_px: float = 15.0,
    spacing_px: float = 4.0,
    params: CenterlineParams | None = None,
) -> list[Polyline]:
    """The ordered polylines of up to ``max_cables`` cables in a binary mask, longest first.

    Args:
        mask: (H, W) bool/uint8 mask.
        max_cables: Most polylines returned (each costs one centreline extraction).
        min_length_px: Walks shorter than this are noise and end the search.
        spacing_px: Distance between output points.
        params: Tuning of :func:`extract_centerline`.

    Raises:
        ValueError: A mask that is not 2-D, or bad settings.
    """
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {m.shape}")
    if max_cables < 1 or min_length_px <= 0 or spacing_px <= 0:
        raise ValueError(
            f"need max_cables >= 1, min_length_px > 0, spacing_px > 0; got {max_cables}, {min_length_px}, "
            f"{spacing_px}"
        )
    work = (m > 0).astype(np.uint8)
    out: list[Polyline] = []
    for _ in range(max_cables):
        c = extract_centerline(work, n_nodes=2, params=params)
        if c.path_uv.shape[0] < 2 or c.length_px < min_length_px:
            break
        pts, vis = _subsample(c.path_uv, c.path_visible, spacing_px)
        out.append(
            Polyline(
                pts, vis, float(c.length_px), float(c.width_px), not c.start_at_border, not c.end_at_border
            )
        )
        # Remove what this walk covers (the strand, a little wider than the cable) and look again.
        thick = max(3, int(np.ceil(c.width_px * 1.6)) + 2)
        pts_i = np.round(c.path_uv * 16).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(work, [pts_i], False, 0, thick, cv2.LINE_8, 4)
    return out
