"""Accuracy metrics of a cable tracker against ground truth, after TrackDLO's evaluation protocol.

TrackDLO (Xiang et al., 2023) scores a tracked cable per frame by the symmetric point-to-polyline distance
between the estimated and the true centreline, and summarises a sequence by the mean error, the share of
frames below fixed thresholds, the frames where the track was lost, and head/tail flips. These are the
pure functions behind ``benchmarks/tracking_accuracy.py``; they work in any dimension (pixels or metres).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision.tracking.centerline import polyline_distance

__all__ = [
    "SPEED_BAND_EDGES_M_S",
    "count_onsets",
    "error_summary",
    "is_flipped",
    "polyline_prefix",
    "speed_band_index",
    "speed_band_labels",
    "symmetric_polyline_error",
]

#: Speed bands of the cable point, m/s: <0.5 (at rest, swinging out), 0.5-2, 2-5, >5 (whip).
SPEED_BAND_EDGES_M_S = (0.5, 2.0, 5.0)


def _finite_rows(points: ArrayLike, name: str) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2:
        raise ValueError(f"{name} must be an (N, D) array of points, got shape {p.shape}")
    return p[np.all(np.isfinite(p), axis=1)]


def symmetric_polyline_error(estimate: ArrayLike, truth: ArrayLike, n_samples: int = 200) -> float:
    """Symmetric mean point-to-polyline distance between an estimated and a true centreline.

    Both polylines are resampled to ``n_samples`` points equally spaced in arc length; the error is the
    mean of (mean distance of the estimate's samples to the true polyline) and (mean distance of the true
    samples to the estimated polyline). Rows with NaN (invisible nodes) are dropped first, so an estimate
    with a hidden middle is joined across the gap.

    Args:
        estimate: (N, D) estimated nodes, NaN rows allowed.
        truth: (M, D) true nodes.
        n_samples: Samples per polyline (>= 2).

    Returns:
        The error in the units of the inputs; NaN when either polyline has fewer than two finite points.
    """
    if n_samples < 2:
        raise ValueError(f"n_samples must be >= 2, got {n_samples}")
    est = _finite_rows(estimate, "estimate")
    tru = _finite_rows(truth, "truth")
    if est.shape[0] < 2 or tru.shape[0] < 2:
        return float("nan")
    if est.shape[1] != tru.shape[1]:
        raise ValueError(f"estimate and truth differ in dimension: {est.shape[1]} vs {tru.shape[1]}")
    return float(polyline_distance(est, tru, n_samples=n_samples))


def polyline_prefix(polyline: ArrayLike, fraction: float) -> NDArray[np.float64]:
    """The part of a polyline from its start up to ``fraction`` of its arc length (end point interpolated).

    Used to compare a tracker that reports the unoccluded part of a cable with the matching part of the
    truth when the last ``1 - fraction`` of the cable is hidden.
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    p = np.asarray(polyline, dtype=np.float64)
    if p.ndim != 2 or p.shape[0] < 2:
        raise ValueError(f"polyline must be an (N >= 2, D) array, got shape {p.shape}")
    s = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))))
    s_end = fraction * s[-1]
    keep = s < s_end
    end = np.array([np.interp(s_end, s, p[:, j]) for j in range(p.shape[1])])
    return np.vstack((p[keep], end))


def is_flipped(estimate: ArrayLike, truth: ArrayLike) -> bool:
    """Whether an estimate's node order is reversed with respect to the truth (head/tail flip).

    Nodes correspond by index (node i of the estimate and of the truth sit at the same arc-length
    fraction). Only the first and the last visible node are judged, so that a wrong turn inside a loop
    is not called a flip: the estimate is flipped when pairing those two nodes with the truth reversed
    (node i with node N-1-i) fits better than pairing them in order.

    Args:
        estimate: (N, D) estimated nodes, NaN where invisible.
        truth: (N, D) true nodes, same N.

    Returns:
        False when fewer than two nodes are visible (no orientation to judge).
    """
    est = np.asarray(estimate, dtype=np.float64)
    tru = np.asarray(truth, dtype=np.float64)
    if est.shape != tru.shape or est.ndim != 2:
        raise ValueError(
            f"estimate and truth must both be (N, D) with the same shape, got {est.shape}, {tru.shape}"
        )
    visible = np.flatnonzero(np.all(np.isfinite(est), axis=1))
    if visible.size < 2:
        return False
    ends = visible[[0, -1]]
    direct = float(np.sum(np.linalg.norm(est[ends] - tru[ends], axis=1)))
    reverse = float(np.sum(np.linalg.norm(est[ends] - tru[::-1][ends], axis=1)))
    return reverse < direct


def count_onsets(flags: ArrayLike) -> int:
    """Number of runs of True in a per-frame flag sequence (a True first frame starts a run)."""
    f = np.asarray(flags, dtype=bool).reshape(-1)
    if f.size == 0:
        return 0
    return int(f[0]) + int(np.count_nonzero(f[1:] & ~f[:-1]))


def speed_band_labels(edges: Sequence[float] = SPEED_BAND_EDGES_M_S) -> list[str]:
    """Labels of the bands cut by increasing ``edges``, e.g. ``['<0.5', '0.5-2', '2-5', '>5']``."""
    e = [float(x) for x in edges]
    if not e or any(b <= a for a, b in zip(e, e[1:], strict=False)):
        raise ValueError(f"edges must be a non-empty increasing sequence, got {list(edges)}")
    fmt = [f"{x:g}" for x in e]
    return [f"<{fmt[0]}"] + [f"{a}-{b}" for a, b in zip(fmt, fmt[1:], strict=False)] + [f">{fmt[-1]}"]


def speed_band_index(speed: ArrayLike, edges: Sequence[float] = SPEED_BAND_EDGES_M_S) -> NDArray[np.int64]:
    """Band of each speed: 0 below ``edges[0]``, ..., ``len(edges)`` at or above the last edge."""
    speed_band_labels(edges)  # validates the edges
    return np.searchsorted(
        np.asarray(edges, dtype=np.float64), np.asarray(speed, dtype=np.float64), side="right"
    )


def error_summary(errors: ArrayLike, thresholds: Sequence[float] = (0.010, 0.020)) -> dict[str, Any]:
    """Mean, median and 95th percentile of per-frame errors, and the share of frames under each threshold.

    A NaN error is a frame without an estimate: it counts in ``n`` and as *not* under any threshold
    (``available`` is the share of frames with an estimate), so a tracker cannot score by giving up.

    Returns:
        ``{"n", "available", "mean", "median", "p95", "under": {threshold: share}}``; the statistics are
        NaN when no frame has an estimate.
    """
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    ok = np.isfinite(e)
    n = int(e.size)
    good = e[ok]
    stats = {
        "mean": float(np.mean(good)) if good.size else float("nan"),
        "median": float(np.median(good)) if good.size else float("nan"),
        "p95": float(np.percentile(good, 95)) if good.size else float("nan"),
    }
    under = {float(t): (float(np.count_nonzero(good < t)) / n if n else float("nan")) for t in thresholds}
    return {
        "n": n,
        "available": float(np.count_nonzero(ok)) / n if n else float("nan"),
        **stats,
        "under": under,
    }
