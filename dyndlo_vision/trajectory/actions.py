"""Mapping between a normalised agent action in [-1, 1] and trajectory via points/times.

Action layout (``k = num_points``; ``dy`` entries are absent when ``planar``)::

    [dx_1, dy_1, dz_1, dx_2, dy_2, dz_2, ..., dx_k, dy_k, dz_k,   dt_1, ..., dt_k, (dt_{k+1})]

The position increments come first, point by point, then the time intervals. ``dt_{k+1}`` exists
only with ``append_final_point``: the time to go from ``P_k`` to the fixed ``final_point``.
Each entry maps linearly from [-1, 1] onto its physical range (``-1 -> min``, ``+1 -> max``), and
``P_i = P_{i-1} + dP_i``, ``t_i = t_{i-1} + dt_i``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["ActionSpec"]

FloatArray = NDArray[np.float64]
_TOL = 1e-9  # slack for encode(): round trips through float arithmetic land just outside ranges


@dataclass(frozen=True)
class ActionSpec:
    """Normalised action <-> via points for :class:`BSplineTrajectory`.

    Attributes:
        num_points: Number ``k`` of via points chosen by the agent (after the start point).
        planar: Motion in the x-z plane only: no ``dy`` entries, ``dy = 0``.
        dx_m: Range (min, max) of each x increment in metres.
        dy_m: Range of each y increment in metres (unused when ``planar``).
        dz_m: Range of each z increment in metres.
        dt_s: Range of each time interval in seconds; the minimum must be > 0.
        append_final_point: Append a fixed target as the last point; the agent chooses one extra
            time interval for reaching it (task IV).
    """

    num_points: int = 3
    planar: bool = False
    dx_m: tuple[float, float] = (-0.3, 0.3)
    dy_m: tuple[float, float] = (-0.3, 0.3)
    dz_m: tuple[float, float] = (-0.3, 0.3)
    dt_s: tuple[float, float] = (0.1, 0.6)
    append_final_point: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.num_points, bool) or not isinstance(self.num_points, int | np.integer):
            raise ValueError(f"num_points must be an int >= 1, got {self.num_points!r}")
        if self.num_points < 1:
            raise ValueError(f"num_points must be >= 1, got {self.num_points}")
        for name in ("dx_m", "dy_m", "dz_m", "dt_s"):
            rng = getattr(self, name)
            try:
                lo, hi = (float(v) for v in rng)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a (min, max) pair of floats, got {rng!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"{name} must be finite with min < max, got {rng!r}")
            object.__setattr__(self, name, (lo, hi))  # normalise lists/ints so equality/hash behave
        if self.dt_s[0] <= 0.0:
            raise ValueError(f"dt_s minimum must be > 0 (times must increase), got {self.dt_s!r}")

    @property
    def dims(self) -> int:
        """Position increments per via point: 2 (x, z) when planar, else 3."""
        return 2 if self.planar else 3

    @property
    def num_intervals(self) -> int:
        """Number of time intervals in the action (``num_points``, +1 with ``append_final_point``)."""
        return self.num_points + int(self.append_final_point)

    @property
    def size(self) -> int:
        """Action dimension: ``dims * num_points + num_intervals``."""
        return self.dims * self.num_points + self.num_intervals

    def _ranges(self) -> tuple[FloatArray, FloatArray]:
        """Per-entry (low, high) of the physical values, in action layout."""
        pos = [self.dx_m, self.dz_m] if self.planar else [self.dx_m, self.dy_m, self.dz_m]
        rngs = pos * self.num_points + [self.dt_s] * self.num_intervals
        arr = np.array(rngs, dtype=float)
        return arr[:, 0], arr[:, 1]

    def decode(
        self,
        action: ArrayLike,
        start_position: ArrayLike,
        start_time: float,
        final_point: ArrayLike | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Turn an action into via points and times.

        Values outside [-1, 1] are clipped (policies with Gaussian noise routinely exceed the
        box; clipping keeps the physical ranges hard limits). NaN/inf are rejected instead,
        since they indicate a diverged policy rather than exploration noise.

        Args:
            action: Shape ``(size,)``.
            start_position: Current TCP position ``P_0``, shape (3,).
            start_time: Current (absolute) time ``t_0``.
            final_point: Fixed target, shape (3,); required iff ``append_final_point``.

        Returns:
            ``(points, times)`` of shapes ``(num_intervals + 1, 3)`` and ``(num_intervals + 1,)``,
            including the start point and (if enabled) the final point.

        Raises:
            ValueError: On wrong shapes, non-finite values or a missing/unexpected final_point.
        """
        a = np.asarray(action, dtype=float)
        if a.shape != (self.size,):
            raise ValueError(f"action must have shape ({self.size},), got shape {a.shape}")
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise ValueError(f"action must be finite, got {a[bad[0]]} at index {int(bad[0])}")
        p0 = _vec3(start_position, "start_position")
        t0 = float(start_time)
        if not math.isfinite(t0):
            raise ValueError(f"start_time must be finite, got {start_time!r}")
        if self.append_final_point != (final_point is not None):
            need = "requires" if self.append_final_point else "does not take"
            raise ValueError(f"ActionSpec(append_final_point={self.append_final_point}) {need} a final_point")

        lo, hi = self._ranges()
        phys = lo + 0.5 * (np.clip(a, -1.0, 1.0) + 1.0) * (hi - lo)
        npos = self.dims * self.num_points
        inc = phys[:npos].reshape(self.num_points, self.dims)
        if self.planar:
            inc = np.column_stack([inc[:, 0], np.zeros(self.num_points), inc[:, 1]])
        points = [p0, *(p0 + np.cumsum(inc, axis=0))]
        if final_point is not None:
            points.append(_vec3(final_point, "final_point"))
        times = t0 + np.concatenate([[0.0], np.cumsum(phys[npos:])])
        return np.array(points), times

    def decode_many(
        self, actions: ArrayLike, start_positions: ArrayLike, start_times: ArrayLike,
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`decode` of M actions at once (no final point), ``(M, size)``, ``(M, 3)``, ``(M,)`` ->
        points ``(M, num_points + 1, 3)`` and times ``(M, num_points + 1)``; row ``m`` equals
        ``decode(actions[m], start_positions[m], start_times[m])`` to the last bit.

        Raises:
            ValueError: As :meth:`decode`, naming the row.
        """
        a = np.asarray(actions, dtype=float)
        p0 = np.asarray(start_positions, dtype=float)
        t0 = np.asarray(start_times, dtype=float)
        if a.ndim != 2 or a.shape[1] != self.size or p0.shape != (a.shape[0], 3) or t0.shape != (a.shape[0],):
            raise ValueError(f"expected actions (M, {self.size}), start positions (M, 3) and start times "
                             f"(M,), got shapes {a.shape}, {p0.shape}, {t0.shape}")
        if self.append_final_point:
            raise ValueError("decode_many does not take final points: use decode for each action")
        bad = np.argwhere(~np.isfinite(a))
        if bad.size:
            m, i = (int(x) for x in bad[0])
            raise ValueError(f"action {m} must be finite, got {a[m, i]} at index {i}")
        if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(t0))):
            raise ValueError("start positions and times must be finite")
        lo, hi = self._ranges()
        phys = lo + 0.5 * (np.clip(a, -1.0, 1.0) + 1.0) * (hi - lo)
        npos = self.dims * self.num_points
        inc = phys[:, :npos].reshape(-1, self.num_points, self.dims)
        if self.planar:
            inc = np.stack([inc[..., 0], np.zeros(inc.shape[:2]), inc[..., 1]], axis=2)
        points = np.concatenate([p0[:, None], p0[:, None] + np.cumsum(inc, axis=1)], axis=1)
        times = t0[:, None] + np.concatenate([np.zeros((a.shape[0], 1)), np.cumsum(phys[:, npos:], axis=1)],
                                             axis=1)
        return points, times

    def encode(self, points: ArrayLike, times: ArrayLike) -> FloatArray:
        """Inverse of :meth:`decode` (for tests and scripted baselines).

        Args:
            points: Shape ``(num_intervals + 1, 3)``, starting with ``P_0`` (and ending with the
                fixed final point when ``append_final_point``; its position is not encoded).
            times: Shape ``(num_intervals + 1,)``.

        Returns:
            Action of shape ``(size,)`` in [-1, 1].

        Raises:
            ValueError: On wrong shapes, non-zero ``dy`` in planar mode, or increments/intervals
                outside their ranges.
        """
        p = np.asarray(points, dtype=float)
        t = np.asarray(times, dtype=float)
        m = self.num_intervals + 1
        if p.shape != (m, 3) or t.shape != (m,):
            raise ValueError(f"points/times must have shapes ({m}, 3)/({m},), got shapes {p.shape}/{t.shape}")
        inc = np.diff(p[: self.num_points + 1], axis=0)
        if self.planar:
            if np.any(np.abs(inc[:, 1]) > _TOL):
                raise ValueError(f"planar ActionSpec needs dy = 0, got dy = {inc[:, 1].tolist()}")
            inc = inc[:, [0, 2]]
        phys = np.concatenate([inc.ravel(), np.diff(t)])
        lo, hi = self._ranges()
        out = np.flatnonzero(~((phys >= lo - _TOL) & (phys <= hi + _TOL)))
        if out.size:
            i = int(out[0])
            raise ValueError(
                f"action entry {i} has physical value {phys[i]}, outside its range [{lo[i]}, {hi[i]}]"
            )
        return np.clip(2.0 * (phys - lo) / (hi - lo) - 1.0, -1.0, 1.0)


def _vec3(v: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    return a
