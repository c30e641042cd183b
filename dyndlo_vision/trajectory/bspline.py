"""Smooth Cartesian TCP trajectories through via points (DynDLO paper, Sec. III-C).

The trajectory is the composition ``p(t) = path(u(t))`` of

* a *path* ``path(u)``: cubic spline interpolating the via points ``P_i`` at the uniform
  parameters ``u_i = i`` (a cubic B-spline with uniform "cardinal" interior knots), and
* a *timing law* ``u(t)``: cubic spline interpolating ``(t_i, i)``.

Both are C2, so ``p`` is C2 inside one plan, and ``p(t_i) = P_i``.

Boundary conditions (``c0 = u'(t_0)``, ``h1 = t_1 - t_0``):

* End: ``u'(t_end) = 0`` (ends at rest) and a natural path end (``path''(n-1) = 0``, the
  minimum-curvature choice). The acceleration at ``t_end`` is ``path'(n-1) u''(t_end)``, generally
  non-zero, so it jumps to zero when the final point is held after ``t_end`` (default
  ``ActionSpec``, random actions: median 10, p95 88 m/s^2).
* Start at rest (zero ``start_velocity``, no ``start_acceleration``): ``u'(t_0) = 0`` and a
  natural path start. Natural rather than a zero tangent because it is the minimum-curvature path
  of the paper and gives ~13 % lower peak accelerations over random actions; the price is a
  step from zero to ``path'(0) u''(t_0)`` in acceleration at ``t_0`` (median 11, p95 86 m/s^2).
  Pass ``start_acceleration=np.zeros(3)`` to avoid that step.
* Moving start: ``c0 = 1/h1`` (the first segment's mean rate) and ``path'(0) = v0 / c0``, so
  ``dp/dt(t_0) = v0`` exactly (up to rounding). Re-planning from the current position and
  velocity is therefore C1; the acceleration jumps (re-planning every 40 ms with random
  actions: median 22, p95 83, max 214 m/s^2; see ``test_replan_continuity``).
* ``start_acceleration`` given: ``c0 = 1/h1`` always, and the path gets one extra knot at
  ``u = 0.5`` so that both ``path'(0) = v0/c0`` and
  ``path''(0) = (a0 - path'(0) u''(t_0)) / c0**2`` can be imposed. Re-planning is then C2.
  The first path segment is then no longer a uniform (cardinal) B-spline segment, and the
  inherited acceleration raises the plans' peak accelerations (median 52 vs 30 m/s^2 above).

Monotone timing law: the plain cubic spline through ``(t_i, i)`` overshoots (``u' < 0``: the TCP
runs backwards along the path) for ~10-25 % of random actions with ``dt`` in [0.1, 0.6] s (16 %
for the default ``ActionSpec``, with ``u'`` down to -3.5 via points/s). When
that happens the timing law is replaced by the minimum-curvature (min ``int u''^2``) C2 cubic
spline with two extra knots per interval, subject to the same interpolation/boundary conditions
and non-decreasing B-spline coefficients (sufficient for ``u' >= 0``). When the plain spline is
already monotone it is used unchanged, i.e. the paper's timing law. See ``monotone_fallback``.
With the fallback ``u'`` may stay 0 over a stretch: the TCP dwells, typically at the start or the
end of the plan instead of running backwards and forwards (up to ~0.4 s seen with the default
``ActionSpec``, e.g. for ``dt = (0.6, 0.11, 0.56)``).

Outside ``[t_0, t_end]``: for ``t <= t_0`` the start state (``P0``, ``start_velocity``, start
acceleration) is returned; for ``t >= t_end`` the final point with zero velocity and acceleration.

Speed (timeit, Python 3.11, numpy 2.4, dev container CPU): scalar ``position(t)`` 1.2 us,
``velocity(t)`` 1.9 us, ``sample(t)`` 2.3 us; ``sample`` of 1000 times ~0.2 ms; construction
~0.4 ms (plain timing law) / ~2.6 ms (monotone fallback: a small LP + active-set QP).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import BSpline, CubicSpline, make_interp_spline
from scipy.optimize import linprog, nnls

__all__ = ["BSplineTrajectory"]

FloatArray = NDArray[np.float64]


def _fmt(a: FloatArray) -> str:
    return str(np.asarray(a).tolist())


def _validate(
    points: ArrayLike,
    times: ArrayLike,
    start_velocity: ArrayLike | None,
    start_acceleration: ArrayLike | None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray | None]:
    p = np.array(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2:
        raise ValueError(f"points must have shape (n, 3) with n >= 2, got shape {p.shape}")
    t = np.array(times, dtype=float)
    if t.shape != (p.shape[0],):
        raise ValueError(f"times must have shape ({p.shape[0]},) to match points, got shape {t.shape}")
    for name, arr in (("points", p), ("times", t)):
        bad = np.argwhere(~np.isfinite(arr))
        if bad.size:
            idx = tuple(int(i) for i in bad[0])
            raise ValueError(f"{name} must be finite, got {arr[idx]} at index {idx}")
    if np.any(np.diff(t) <= 0.0):
        raise ValueError(f"times must be strictly increasing, got {_fmt(t)}")

    def vec3(v: ArrayLike | None, name: str) -> FloatArray | None:
        if v is None:
            return None
        a = np.array(v, dtype=float)
        if a.shape != (3,):
            raise ValueError(f"{name} must have shape (3,), got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite, got {_fmt(a)}")
        return a

    v0 = vec3(start_velocity, "start_velocity")
    return p, t, np.zeros(3) if v0 is None else v0, vec3(start_acceleration, "start_acceleration")


def _pp_from_bspline(spl: BSpline) -> tuple[FloatArray, FloatArray]:
    """Piecewise-polynomial form of a cubic BSpline.

    Returns:
        ``(breaks (m+1,), coef (m, 4, ...))`` with coefficients of ``s**3, s**2, s, 1`` in the
        local coordinate ``s = x - breaks[j]``.
    """
    breaks = np.unique(spl.t[spl.k : -spl.k])
    x = breaks[:-1]
    # BSpline evaluates a knot with the interval on its right, i.e. the right-hand limits we need.
    derivs = [spl(x, nu) for nu in range(4)]
    coef = np.stack([derivs[3] / 6.0, derivs[2] / 2.0, derivs[1], derivs[0]], axis=1)
    return breaks, coef


def _min_rate(breaks: FloatArray, coef: FloatArray) -> float:
    """Exact minimum of ``u'`` over a scalar piecewise cubic (``u'`` is quadratic per piece)."""
    a, b, c = coef[:, 0], coef[:, 1], coef[:, 2]
    h = np.diff(breaks)
    cand = [c, (3.0 * a * h + 2.0 * b) * h + c]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(a > 0.0, -b / (3.0 * a), -1.0)
    inside = (s > 0.0) & (s < h)
    cand.append(np.where(inside, (3.0 * a * s + 2.0 * b) * s + c, np.inf))
    return float(np.min(cand))


def _start_rate(tau: FloatArray, v0: FloatArray, a0: FloatArray | None) -> float:
    """``c0 = u'(t_0)``: the first segment's mean rate for a moving start, 0 for a start at rest."""
    moving = a0 is not None or bool(np.any(v0 != 0.0))
    return 1.0 / tau[1] if moving else 0.0


def _tridiagonal(lower: FloatArray, diag: FloatArray, upper: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve tridiagonal systems along axis 1 (Thomas algorithm, no pivoting: the spline systems are
    diagonally dominant). Row ``i`` is
    ``lower[:, i] x[i-1] + diag[:, i] x[i] + upper[:, i] x[i+1] = rhs[:, i]``; every array has the systems
    along axis 0 and may have trailing axes. Elementwise, so each system's solution does not depend on the
    others."""
    n = diag.shape[1]
    c = np.empty(np.broadcast_shapes(upper.shape, diag.shape))
    d = np.empty(np.broadcast_shapes(rhs.shape, diag.shape))
    c[:, 0] = upper[:, 0] / diag[:, 0]
    d[:, 0] = rhs[:, 0] / diag[:, 0]
    for i in range(1, n):
        denom = diag[:, i] - lower[:, i] * c[:, i - 1]
        c[:, i] = upper[:, i] / denom
        d[:, i] = (rhs[:, i] - lower[:, i] * d[:, i - 1]) / denom
    x = np.empty_like(d)
    x[:, n - 1] = d[:, n - 1]
    for i in range(n - 2, -1, -1):
        x[:, i] = d[:, i] - c[:, i] * x[:, i + 1]
    return x


def _fit_plain(
    p: FloatArray, t: FloatArray, v0: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Timing laws and paths of M plans without imposed start acceleration, solved together.

    ``p`` (M, n, 3), ``t`` (M, n), ``v0`` (M, 3). The timing law is the cubic spline through
    ``(tau_i, i)`` with ``u'(tau_0) = c0`` and ``u'(tau_end) = 0``; the path the cubic spline through the
    points at ``u = 0 .. n-1`` with ``path'(0) = v0 / c0`` (moving start) or a natural start, and a natural
    end: the splines of scipy's ``CubicSpline`` and ``make_interp_spline`` (equal to rounding), from their
    tridiagonal slope equations.

    Returns:
        Timing breakpoints (M, n) and coefficients (M, n-1, 4), path breakpoints (M, n) and coefficients
        (M, n-1, 4, 3) (highest power first), and whether each plan's timing law runs backwards somewhere
        (it then needs :func:`_monotone_timing_law`).
    """
    m, n = t.shape
    tau = t - t[:, :1]
    moving = np.any(v0 != 0.0, axis=1)
    c0 = np.where(moving, 1.0 / tau[:, 1], 0.0)
    # Timing law: slopes s_j at the knots; s_0 = c0 and s_{n-1} = 0 given, the interior from
    # h_j s_{j-1} + 2 (h_{j-1} + h_j) s_j + h_{j-1} s_{j+1} = 3 (h_j d_{j-1} + h_{j-1} d_j), d_j = 1 / h_j.
    h = np.diff(tau, axis=1)
    rate = 1.0 / h
    slope = np.zeros((m, n))
    slope[:, 0] = c0
    if n > 2:
        lower, upper = h[:, 1:], h[:, :-1]
        diag = 2.0 * (h[:, :-1] + h[:, 1:])
        rhs = 3.0 * (h[:, 1:] * rate[:, :-1] + h[:, :-1] * rate[:, 1:])
        rhs[:, 0] -= lower[:, 0] * c0
        slope[:, 1:-1] = _tridiagonal(lower, diag, upper, rhs)
    excess = (slope[:, :-1] + slope[:, 1:] - 2.0 * rate) / h
    tc = np.stack([excess / h, (rate - slope[:, :-1]) / h - excess, slope[:, :-1],
                   np.broadcast_to(np.arange(n - 1, dtype=float), (m, n - 1))], axis=2)
    # Path, u-spacing 1: m_{j-1} + 4 m_j + m_{j+1} = 3 (D_{j-1} + D_j), D_j = P_{j+1} - P_j; first row
    # m_0 = v0 / c0 (moving) or 2 m_0 + m_1 = 3 D_0 (natural); last row m_{n-2} + 2 m_{n-1} = 3 D_{n-2}.
    delta = np.diff(p, axis=1)
    lower_p, upper_p, diag_p = np.ones((m, n, 1)), np.ones((m, n, 1)), np.full((m, n, 1), 4.0)
    rhs_p = np.empty((m, n, 3))
    rhs_p[:, 1:-1] = 3.0 * (delta[:, :-1] + delta[:, 1:])
    rhs_p[:, -1] = 3.0 * delta[:, -1]
    diag_p[:, -1] = 2.0
    upper_p[:, -1] = 0.0
    lower_p[:, 0] = 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        clamped = v0 / c0[:, None]
    diag_p[:, 0] = np.where(moving, 1.0, 2.0)[:, None]
    upper_p[:, 0] = np.where(moving, 0.0, 1.0)[:, None]
    rhs_p[:, 0] = np.where(moving[:, None], clamped, 3.0 * delta[:, 0])
    mp = _tridiagonal(lower_p, diag_p, upper_p, rhs_p)
    excess_p = mp[:, :-1] + mp[:, 1:] - 2.0 * delta
    pc = np.stack([excess_p, delta - mp[:, :-1] - excess_p, mp[:, :-1], p[:, :-1]], axis=2)
    pb = np.broadcast_to(np.arange(n, dtype=float), (m, n))
    return tau, tc, pb, pc, _min_rates(tau, tc) < -1e-9 * np.max(rate, axis=1)


def _min_rates(breaks: FloatArray, coef: FloatArray) -> FloatArray:
    """:func:`_min_rate` of M piecewise cubics at once, (M, k + 1) and (M, k, 4) -> (M,)."""
    a, b, c = coef[..., 0], coef[..., 1], coef[..., 2]
    h = np.diff(breaks, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(a > 0.0, -b / (3.0 * a), -1.0)
    inside = (s > 0.0) & (s < h)
    cand = np.minimum(np.minimum(c, (3.0 * a * h + 2.0 * b) * h + c),
                      np.where(inside, (3.0 * a * s + 2.0 * b) * s + c, np.inf))
    return np.min(cand, axis=1)


def _fit_with_acceleration(
    p: FloatArray, t: FloatArray, v0: FloatArray, a0: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, bool]:
    """The fit for an imposed start acceleration (C2 re-planning): scipy's splines, one extra path knot."""
    n = p.shape[0]
    tau = t - t[0]
    c0 = 1.0 / tau[1]
    timing = CubicSpline(tau, np.arange(n, dtype=float), bc_type=((1, c0), (1, 0.0)))
    tb, tc = timing.x, np.ascontiguousarray(timing.c.T)
    fallback = _min_rate(tb, tc) < -1e-9 * float(np.max(1.0 / np.diff(tau)))
    if fallback:
        tb, tc = _monotone_timing_law(tau, c0)
    u = np.arange(n, dtype=float)
    d1 = v0 / c0
    d2 = (a0 - d1 * 2.0 * tc[0, 1]) / c0**2  # u''(t_0) = 2 * (s**2 coefficient)
    knots = np.concatenate([np.zeros(4), [0.5], u[1:-1], np.full(4, n - 1.0)])
    path = make_interp_spline(u, p, k=3, t=knots, bc_type=([(1, d1), (2, d2)], [(2, np.zeros(3))]))
    pb, pc = _pp_from_bspline(path)
    return tb, tc, pb, pc, bool(fallback)


def _nonneg_qp(q: FloatArray, g: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Solve ``min x'Qx + 2g'x  s.t.  Ax = b, x >= 0`` exactly (small dense problems).

    Primal active-set method (Nocedal & Wright, Alg. 16.3) started from a feasible vertex found
    by an LP. Each iterate solves an equality-constrained QP, so the result satisfies ``Ax = b``
    to rounding, which interpolation needs.
    """
    m = q.shape[0]
    scale = float(np.max(np.abs(q)))  # rescaled objective, same minimiser, KKT entries O(1)
    q, g = q / scale, g / scale
    # A feasible start: non-negative least squares reaches Ax = b when it can, in a fraction of an LP's time.
    x, residual = nnls(a, b)
    if residual > 1e-9 * (1.0 + float(np.linalg.norm(b))):
        lp = linprog(np.zeros(m), A_eq=a, b_eq=b, bounds=(0.0, None), method="highs")
        if lp.status != 0:
            raise RuntimeError(f"no monotone timing law exists on the refined knots: {lp.message}")
        x = np.clip(lp.x, 0.0, None)
    work = np.zeros(m, dtype=bool)  # the empty working set is always a valid start
    eye = np.eye(m)
    for _ in range(20 * m + 20):
        cons = np.vstack([a, eye[work]])
        k = cons.shape[0]
        kkt = np.block([[2.0 * q, cons.T], [cons, np.zeros((k, k))]])
        rhs = np.concatenate([-2.0 * g, b, np.zeros(k - a.shape[0])])
        try:
            sol = np.linalg.solve(kkt, rhs)
        except np.linalg.LinAlgError:
            sol = np.linalg.lstsq(kkt, rhs, rcond=None)[0]
        target, mult = sol[:m], -sol[m + a.shape[0] :]  # mult >= 0 <=> bound x_i >= 0 is binding
        step = target - x
        if np.max(np.abs(step)) <= 1e-12 * (1.0 + np.max(np.abs(x))):
            if mult.size and mult.min() < -1e-12 * (1.0 + np.max(np.abs(mult))):
                work[np.flatnonzero(work)[np.argmin(mult)]] = False
                continue
            return np.clip(target, 0.0, None)
        blocking = (~work) & (step < 0.0)
        ratio = np.full(m, np.inf)
        ratio[blocking] = -x[blocking] / step[blocking]
        i = int(np.argmin(ratio))
        if ratio[i] < 1.0:
            x = x + ratio[i] * step
            x[i] = 0.0
            work[i] = True
        else:
            x = target
    raise RuntimeError("monotone timing law: active-set QP did not converge")


def _monotone_timing_law(tau: FloatArray, c0: float, sub: int = 3) -> tuple[FloatArray, FloatArray]:
    """Min-curvature C2 cubic spline through ``(tau_i, i)`` with ``u' >= 0``.

    The knots at ``tau`` are refined by ``sub - 1`` extra knots per interval; the extra degrees of
    freedom let the spline stay monotone. Non-decreasing B-spline coefficients ``c`` (sufficient
    for ``u' >= 0``) become plain bounds on the increments ``d = diff(c) >= 0``.
    """
    n = tau.size
    frac = np.arange(1, sub) / sub
    extra = (tau[:-1, None] + np.diff(tau)[:, None] * frac).ravel()
    knots = np.concatenate(
        [np.full(4, tau[0]), np.sort(np.concatenate([tau[1:-1], extra])), np.full(4, tau[-1])]
    )
    m = knots.size - 4

    # Gram matrix of int u''^2 over the coefficients: u'' is linear per knot interval, so 2-point
    # Gauss quadrature is exact.
    br = np.unique(knots)
    mid, half = 0.5 * (br[1:] + br[:-1]), 0.5 * np.diff(br)
    x = np.concatenate([mid - half / np.sqrt(3.0), mid + half / np.sqrt(3.0)])
    w = np.concatenate([half, half])
    d2 = BSpline(knots, np.eye(m), 3).derivative(2)(x)
    gram = d2.T @ (w[:, None] * d2)

    # c = cum @ d with c_0 = u(tau_0) = 0. The boundary slopes fix the first and last increment:
    # u'(tau_0) = 3 d_0 / (knots[4] - knots[1]) = c0 and u'(tau_end) = 0  <=>  d_last = 0.
    cum = np.tril(np.ones((m, m - 1)), -1)
    d_first = c0 * (knots[4] - knots[1]) / 3.0
    c_fixed, cum_free = cum[:, 0] * d_first, cum[:, 1:-1]
    interp = BSpline.design_matrix(tau[1:], knots, 3).toarray()
    free = _nonneg_qp(
        cum_free.T @ gram @ cum_free,
        cum_free.T @ gram @ c_fixed,
        interp @ cum_free,
        np.arange(1, n, dtype=float) - interp @ c_fixed,
    )
    return _pp_from_bspline(BSpline(knots, c_fixed + cum_free @ free, 3))


class BSplineTrajectory:
    """C2 Cartesian trajectory ``p(t) = path(u(t))`` through via points at given times.

    Immutable and picklable. Evaluation methods accept a scalar time (returning shape (3,)) or an
    array of times of shape (m,) (returning (m, 3)).

    Args:
        points: Via points ``P_0..P_{n-1}``, shape (n, 3), n >= 2. ``P_0`` is the current TCP position.
        times: Absolute times ``t_0 < ... < t_{n-1}``, shape (n,).
        start_velocity: TCP velocity at ``t_0``, shape (3,); zeros when None.
        start_acceleration: Optional TCP acceleration at ``t_0``, shape (3,). When given it is
            matched too, which makes re-planning C2 instead of C1.

    Raises:
        ValueError: On bad shapes, non-finite values, n < 2 or non-increasing times.
    """

    __slots__ = (
        "_args", "_t0", "_dur", "_nt", "_np", "_tb", "_tc", "_pb", "_pc",
        "_tb_a", "_tc_a", "_pb_a", "_pc_a", "_start", "_end", "_fallback",
    )  # fmt: skip
    _args: tuple[FloatArray, FloatArray, FloatArray | None, FloatArray | None]  # constructor inputs
    _t0: float
    _dur: float
    _fallback: bool
    # Timing law u(tau) and path(u) as piecewise cubics: breakpoints and (segment, power[, xyz])
    # coefficients (highest power first), as read-only arrays (vectorised evaluation) and as
    # plain Python lists/tuples (scalar evaluation); _nt/_np are the segment counts.
    _tb_a: FloatArray
    _tc_a: FloatArray
    _pb_a: FloatArray
    _pc_a: FloatArray
    _tb: list[float]
    _tc: list[tuple[float, ...]]
    _pb: list[float]
    _pc: list[tuple[float, ...]]
    _nt: int
    _np: int
    _start: tuple[FloatArray, FloatArray, FloatArray]  # state held for t <= t_0
    _end: tuple[FloatArray, FloatArray, FloatArray]  # state held for t >= t_end

    def __init__(
        self,
        points: ArrayLike,
        times: ArrayLike,
        start_velocity: ArrayLike | None = None,
        start_acceleration: ArrayLike | None = None,
    ) -> None:
        p, t, v0, a0 = _validate(points, times, start_velocity, start_acceleration)
        if a0 is None:
            tb, tc, pb, pc, fallback = _fit_plain(p[None], t[None], v0[None])
            parts = (tb[0], tc[0], pb[0], pc[0], bool(fallback[0]))
            if parts[4]:
                parts = (*_monotone_timing_law(t - t[0], _start_rate(t - t[0], v0, None)), pb[0], pc[0], True)
        else:
            parts = _fit_with_acceleration(p, t, v0, a0)
        self._finish(p, t, None if start_velocity is None else v0, v0, a0, *parts)

    @classmethod
    def many(
        cls, points: ArrayLike, times: ArrayLike, start_velocities: ArrayLike | None = None
    ) -> list[BSplineTrajectory]:
        """M trajectories at once: ``points`` (M, n, 3), ``times`` (M, n), ``start_velocities`` (M, 3) or
        None.

        Trajectory ``m`` equals ``BSplineTrajectory(points[m], times[m], start_velocities[m])`` to the last
        bit: the spline fits of all of them are solved together with the same arithmetic.

        Raises:
            ValueError: As the constructor, naming the trajectory.
        """
        pts = np.asarray(points, dtype=float)
        tms = np.asarray(times, dtype=float)
        if pts.ndim != 3 or tms.ndim != 2 or pts.shape[0] != tms.shape[0]:
            raise ValueError(f"expected points (M, n, 3) and times (M, n), got shapes {pts.shape}, "
                             f"{tms.shape}")
        vels = None if start_velocities is None else np.asarray(start_velocities, dtype=float)
        checked = []
        for m in range(pts.shape[0]):
            try:
                checked.append(_validate(pts[m], tms[m], None if vels is None else vels[m], None))
            except ValueError as err:
                raise ValueError(f"trajectory {m}: {err}") from err
        if not checked:
            return []
        p = np.stack([c[0] for c in checked])
        t = np.stack([c[1] for c in checked])
        v0 = np.stack([c[2] for c in checked])
        tb, tc, pb, pc, fallback = _fit_plain(p, t, v0)
        out = []
        for m in range(len(checked)):
            parts = (tb[m], tc[m], pb[m], pc[m], bool(fallback[m]))
            if parts[4]:
                tau = t[m] - t[m, 0]
                parts = (*_monotone_timing_law(tau, _start_rate(tau, v0[m], None)), pb[m], pc[m], True)
            traj = object.__new__(cls)
            traj._finish(p[m], t[m], None if vels is None else v0[m], v0[m], None, *parts)
            out.append(traj)
        return out

    def _finish(self, p: FloatArray, t: FloatArray, v0_arg: FloatArray | None, v0: FloatArray,
                a0: FloatArray | None, tb: FloatArray, tc: FloatArray, pb: FloatArray, pc: FloatArray,
                fallback: bool) -> None:
        """Set the fields from the fitted timing law and path (the constructor's last step)."""
        tau = t - t[0]
        s = object.__setattr__
        s(self, "_args", (p, t, v0_arg, a0))
        s(self, "_t0", float(t[0]))
        s(self, "_dur", float(tau[-1]))
        s(self, "_fallback", bool(fallback))
        for name, arr in (("_tb_a", tb), ("_tc_a", tc), ("_pb_a", pb), ("_pc_a", pc)):
            arr = np.ascontiguousarray(arr, dtype=float)
            arr.flags.writeable = False
            s(self, name, arr)
        # Plain-Python copies: scalar evaluation with floats/tuples avoids numpy call overhead.
        s(self, "_tb", tb.tolist())
        s(self, "_tc", [tuple(r) for r in tc.tolist()])
        s(self, "_pb", pb.tolist())
        s(self, "_pc", [tuple(r) for r in pc.reshape(len(pc), 12).tolist()])
        s(self, "_nt", len(tc))
        s(self, "_np", len(pc))
        # Chain rule at tau = 0, u = 0.
        a_start = a0 if a0 is not None else 2.0 * pc[0, 1] * tc[0, 2] ** 2 + pc[0, 2] * 2.0 * tc[0, 1]
        s(self, "_start", (p[0].copy(), v0.copy(), np.array(a_start, dtype=float)))
        s(self, "_end", (p[-1].copy(), np.zeros(3), np.zeros(3)))
        for arr in (*self._start, *self._end):
            arr.flags.writeable = False

    # -- immutability / pickling -------------------------------------------------------------

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __reduce__(self) -> tuple[Any, ...]:
        # Rebuilding from the inputs is deterministic and keeps the pickle small.
        return (type(self), self._args)

    def __repr__(self) -> str:
        return (
            f"BSplineTrajectory(n={len(self._args[0])}, t_start={self._t0:.4g}, "
            f"duration={self._dur:.4g}, monotone_fallback={self._fallback})"
        )

    # -- properties ---------------------------------------------------------------------------

    @property
    def t_start(self) -> float:
        """Time ``t_0`` of the first via point."""
        return self._t0

    @property
    def t_end(self) -> float:
        """Time ``t_{n-1}`` of the last via point."""
        return self._t0 + self._dur

    @property
    def duration(self) -> float:
        """``t_end - t_start``."""
        return self._dur

    @property
    def points(self) -> FloatArray:
        """Copy of the via points, shape (n, 3)."""
        return self._args[0].copy()

    @property
    def times(self) -> FloatArray:
        """Copy of the via-point times, shape (n,)."""
        return self._args[1].copy()

    @property
    def start_velocity(self) -> FloatArray:
        """Copy of the velocity at ``t_0``."""
        return self._start[1].copy()

    @property
    def start_acceleration(self) -> FloatArray:
        """Copy of the acceleration at ``t_0`` (imposed, or resulting from the boundary conditions)."""
        return self._start[2].copy()

    @property
    def monotone_fallback(self) -> bool:
        """True when the plain timing spline overshot and the monotone variant is used."""
        return self._fallback

    def shifted(self, dt: float) -> BSplineTrajectory:
        """The same trajectory ``dt`` seconds later: ``shifted(dt).sample(t + dt) == sample(t)``.

        Exact: the fits are made in local time, so only the via-point times move.
        """
        if not math.isfinite(dt):
            raise ValueError(f"dt must be finite, got {dt!r}")
        p, t, v0, a0 = self._args
        return type(self)(p, t + float(dt), start_velocity=v0, start_acceleration=a0)

    # -- evaluation ---------------------------------------------------------------------------

    def position(self, t: ArrayLike) -> FloatArray:
        """Position at time(s) ``t``: shape (3,) for scalar ``t``, else (m, 3)."""
        if isinstance(t, float | int):
            return self._scalar(float(t), 0)[0]
        return self._dispatch(t, 0)[0]

    def velocity(self, t: ArrayLike) -> FloatArray:
        """Velocity at time(s) ``t``: shape (3,) for scalar ``t``, else (m, 3)."""
        if isinstance(t, float | int):
            return self._scalar(float(t), 1)[1]
        return self._dispatch(t, 1)[1]

    def acceleration(self, t: ArrayLike) -> FloatArray:
        """Acceleration at time(s) ``t``: shape (3,) for scalar ``t``, else (m, 3)."""
        if isinstance(t, float | int):
            return self._scalar(float(t), 2)[2]
        return self._dispatch(t, 2)[2]

    def sample(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(position, velocity, acceleration)`` at time(s) ``t``."""
        if isinstance(t, float | int):
            pos, vel, acc = self._scalar(float(t), 2)
        else:
            pos, vel, acc = self._dispatch(t, 2)
        return pos, vel, acc

    def timing(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Timing law ``(u, du/dt, d2u/dt2)`` at time(s) ``t`` (clamped to ``[t_0, t_end]``)."""
        tt = np.asarray(t, dtype=float)
        tau = np.clip(tt.ravel() - self._t0, 0.0, self._dur)
        i = np.clip(np.searchsorted(self._tb_a, tau, side="right") - 1, 0, self._nt - 1)
        s, c = tau - self._tb_a[i], self._tc_a[i]
        u = ((c[:, 0] * s + c[:, 1]) * s + c[:, 2]) * s + c[:, 3]
        du = (3.0 * c[:, 0] * s + 2.0 * c[:, 1]) * s + c[:, 2]
        ddu = 6.0 * c[:, 0] * s + 2.0 * c[:, 1]
        return u.reshape(tt.shape), du.reshape(tt.shape), ddu.reshape(tt.shape)

    def max_speed(self, num: int = 2001) -> float:
        """Max ``|velocity|`` over ``num`` uniform samples of ``[t_start, t_end]``."""
        return float(
            np.max(np.linalg.norm(self.velocity(np.linspace(self.t_start, self.t_end, num)), axis=1))
        )

    def max_acceleration(self, num: int = 2001) -> float:
        """Max ``|acceleration|`` over ``num`` uniform samples of ``[t_start, t_end)``."""
        # t_end itself is excluded: there the final point is held with zero acceleration.
        t = np.linspace(self.t_start, self.t_end, num)[:-1]
        return float(np.max(np.linalg.norm(self.acceleration(t), axis=1)))

    def _dispatch(self, t: ArrayLike, order: int) -> tuple[FloatArray, ...]:
        tt = np.asarray(t, dtype=float)
        if tt.ndim == 0:
            return self._scalar(float(tt), order)
        out = self._eval(tt.ravel(), order)
        return tuple(o.reshape(*tt.shape, 3) for o in out)

    def _scalar(self, t: float, order: int) -> tuple[FloatArray, ...]:
        tau = t - self._t0
        if tau <= 0.0:
            return tuple(a.copy() for a in self._start)
        if tau >= self._dur:
            return tuple(a.copy() for a in self._end)
        tb = self._tb
        i = bisect_right(tb, tau) - 1
        if i >= self._nt:
            i = self._nt - 1
        a, b, c, d = self._tc[i]
        s = tau - tb[i]
        u = ((a * s + b) * s + c) * s + d
        pb = self._pb
        j = bisect_right(pb, u) - 1
        j = 0 if j < 0 else (self._np - 1 if j >= self._np else j)
        w = u - pb[j]
        ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz = self._pc[j]
        pos = np.array(
            (
                ((ax * w + bx) * w + cx) * w + dx,
                ((ay * w + by) * w + cy) * w + dy,
                ((az * w + bz) * w + cz) * w + dz,
            )
        )
        if order == 0:
            return (pos,)
        du = (3.0 * a * s + 2.0 * b) * s + c
        px = (3.0 * ax * w + 2.0 * bx) * w + cx
        py = (3.0 * ay * w + 2.0 * by) * w + cy
        pz = (3.0 * az * w + 2.0 * bz) * w + cz
        vel = np.array((px * du, py * du, pz * du))
        if order == 1:
            return pos, vel
        ddu = 6.0 * a * s + 2.0 * b
        du2 = du * du
        acc = np.array(
            (
                (6.0 * ax * w + 2.0 * bx) * du2 + px * ddu,
                (6.0 * ay * w + 2.0 * by) * du2 + py * ddu,
                (6.0 * az * w + 2.0 * bz) * du2 + pz * ddu,
            )
        )
        return pos, vel, acc

    def _eval(self, t: FloatArray, order: int) -> tuple[FloatArray, ...]:
        """Vectorised evaluation for a 1-D array of absolute times."""
        rel = t - self._t0
        tau = np.clip(rel, 0.0, self._dur)
        i = np.clip(np.searchsorted(self._tb_a, tau, side="right") - 1, 0, self._nt - 1)
        s, c = tau - self._tb_a[i], self._tc_a[i]
        u = ((c[:, 0] * s + c[:, 1]) * s + c[:, 2]) * s + c[:, 3]
        j = np.clip(np.searchsorted(self._pb_a, u, side="right") - 1, 0, self._np - 1)
        w, k = (u - self._pb_a[j])[:, None], self._pc_a[j]
        out = [((k[:, 0] * w + k[:, 1]) * w + k[:, 2]) * w + k[:, 3]]
        if order >= 1:
            du = ((3.0 * c[:, 0] * s + 2.0 * c[:, 1]) * s + c[:, 2])[:, None]
            dp = (3.0 * k[:, 0] * w + 2.0 * k[:, 1]) * w + k[:, 2]
            out.append(dp * du)
        if order >= 2:
            ddu = (6.0 * c[:, 0] * s + 2.0 * c[:, 1])[:, None]
            out.append((6.0 * k[:, 0] * w + 2.0 * k[:, 1]) * du * du + dp * ddu)
        before, after = rel <= 0.0, rel >= self._dur
        for o, start, end in zip(out, self._start, self._end, strict=False):
            o[before] = start
            o[after] = end
        return tuple(out)


def sample_many(
    trajectories: list[BSplineTrajectory], t: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Positions and velocities of M trajectories at their own times, ``t`` (M, K) -> (M, K, 3) each.

    Row ``m`` equals ``trajectories[m].position(t[m])`` and ``.velocity(t[m])`` to the last bit: the same
    arithmetic, with the segments of every trajectory padded to the longest (the batched environment
    evaluates all its simulations' plans in one call).
    """
    tt = np.asarray(t, dtype=float)
    m = len(trajectories)
    if tt.ndim != 2 or tt.shape[0] != m:
        raise ValueError(f"t must have shape ({m}, K) for {m} trajectories, got shape {tt.shape}")
    nt = max(tr._nt for tr in trajectories)
    n_p = max(tr._np for tr in trajectories)
    tb = np.full((m, nt + 1), np.inf)
    tc = np.zeros((m, nt, 4))
    pb = np.full((m, n_p + 1), np.inf)
    pc = np.zeros((m, n_p, 4, 3))
    t0, dur, nts, nps = np.empty(m), np.empty(m), np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    start_p, start_v, end_p = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    for k, tr in enumerate(trajectories):
        tb[k, : tr._nt + 1] = tr._tb_a
        tc[k, : tr._nt] = tr._tc_a
        pb[k, : tr._np + 1] = tr._pb_a
        pc[k, : tr._np] = tr._pc_a
        t0[k], dur[k], nts[k], nps[k] = tr._t0, tr._dur, tr._nt, tr._np
        start_p[k], start_v[k], end_p[k] = tr._start[0], tr._start[1], tr._end[0]
    rel = tt - t0[:, None]
    tau = np.clip(rel, 0.0, dur[:, None])
    # searchsorted(side="right") - 1 of each row: how many breakpoints are <= tau, less one (padding is inf)
    i = np.clip((tb[:, None, :] <= tau[:, :, None]).sum(axis=2) - 1, 0, (nts - 1)[:, None])
    rows = np.arange(m)[:, None]
    s, c = tau - tb[rows, i], tc[rows, i]
    u = ((c[..., 0] * s + c[..., 1]) * s + c[..., 2]) * s + c[..., 3]
    j = np.clip((pb[:, None, :] <= u[:, :, None]).sum(axis=2) - 1, 0, (nps - 1)[:, None])
    w, kk = (u - pb[rows, j])[..., None], pc[rows, j]
    pos = ((kk[..., 0, :] * w + kk[..., 1, :]) * w + kk[..., 2, :]) * w + kk[..., 3, :]
    du = ((3.0 * c[..., 0] * s + 2.0 * c[..., 1]) * s + c[..., 2])[..., None]
    dp = (3.0 * kk[..., 0, :] * w + 2.0 * kk[..., 1, :]) * w + kk[..., 2, :]
    vel = dp * du
    before, after = rel <= 0.0, rel >= dur[:, None]
    pos = np.where(before[..., None], start_p[:, None], np.where(after[..., None], end_p[:, None], pos))
    vel = np.where(before[..., None], start_v[:, None], np.where(after[..., None], 0.0, vel))
    return pos, vel
