"""Tests for dyndlo_vision.trajectory.bspline."""

from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest
from scipy.interpolate import CubicSpline, PPoly

from dyndlo_vision.trajectory import ActionSpec, BSplineTrajectory
from dyndlo_vision.trajectory.bspline import _min_rate, _monotone_timing_law, _nonneg_qp


def _random_plan(
    rng: np.random.Generator, k: int = 3, moving: bool = True, accel: bool = False, t0: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    spec = ActionSpec(num_points=k)
    t0 = float(rng.uniform(-5.0, 50.0)) if t0 is None else t0
    points, times = spec.decode(rng.uniform(-1, 1, spec.size), rng.normal(size=3), t0)
    v0 = rng.normal(scale=1.0, size=3) if moving else None
    a0 = rng.normal(scale=10.0, size=3) if accel else None
    return points, times, v0, a0


PLAN_CASES = [(k, moving, accel) for k in (1, 2, 3, 5) for moving in (False, True) for accel in (False, True)]


@pytest.mark.parametrize(("k", "moving", "accel"), PLAN_CASES)
def test_interpolates_points_and_boundary_velocities(k: int, moving: bool, accel: bool) -> None:
    rng = np.random.default_rng(k + 10 * moving + 100 * accel)
    for _ in range(20):
        points, times, v0, a0 = _random_plan(rng, k, moving, accel)
        traj = BSplineTrajectory(points, times, v0, a0)
        np.testing.assert_allclose(traj.position(times), points, rtol=0, atol=1e-9)
        for t, p in zip(times, points, strict=True):
            np.testing.assert_allclose(traj.position(float(t)), p, rtol=0, atol=1e-9)

        amax = traj.max_acceleration()
        v_start = np.zeros(3) if v0 is None else v0
        np.testing.assert_array_equal(traj.velocity(traj.t_start), v_start)
        # Right limit of the spline itself, not just the stored start state.
        eps = 1e-9
        np.testing.assert_allclose(traj.velocity(traj.t_start + eps), v_start, atol=2 * eps * amax + 1e-12)
        np.testing.assert_allclose(traj.velocity(traj.t_end - eps), 0.0, atol=2 * eps * amax + 1e-12)
        np.testing.assert_array_equal(traj.velocity(traj.t_end), np.zeros(3))
        u, du, _ = traj.timing(np.array([traj.t_start, traj.t_end]))
        np.testing.assert_allclose(u, [0.0, k], atol=1e-12)
        assert du[1] == pytest.approx(0.0, abs=1e-9)
        expected_c0 = 1.0 / (times[1] - times[0]) if (moving or accel) else 0.0
        assert du[0] == pytest.approx(expected_c0, rel=1e-9, abs=1e-9)
        if a0 is not None:
            np.testing.assert_allclose(traj.acceleration(traj.t_start + eps), a0, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(("k", "moving", "accel"), PLAN_CASES)
def test_c2_inside_plan(k: int, moving: bool, accel: bool) -> None:
    rng = np.random.default_rng(1000 + k + 10 * moving + 100 * accel)
    for _ in range(10):
        points, times, v0, a0 = _random_plan(rng, k, moving, accel)
        traj = BSplineTrajectory(points, times, v0, a0)
        amax, vmax = traj.max_acceleration(), traj.max_speed()
        # Left/right limits at every interior knot (path knots sit at t_i, timing knots may be refined).
        eps = 1e-9
        knots = times[1:-1]
        for f, scale in ((traj.position, 1.0), (traj.velocity, vmax), (traj.acceleration, amax)):
            jump = np.abs(f(knots + eps) - f(knots - eps)).max(initial=0.0)
            assert jump <= 1e-5 * (1.0 + scale), (f.__name__, jump)
        # Analytic derivatives against central differences at interior times.
        t = np.linspace(times[0], times[-1], 203)[1:-1]
        h = 1e-6
        fd_vel = (traj.position(t + h) - traj.position(t - h)) / (2 * h)
        fd_acc = (traj.velocity(t + h) - traj.velocity(t - h)) / (2 * h)
        np.testing.assert_allclose(fd_vel, traj.velocity(t), rtol=0, atol=1e-5 * (1.0 + vmax))
        np.testing.assert_allclose(fd_acc, traj.acceleration(t), rtol=0, atol=1e-5 * (1.0 + amax))


@pytest.mark.parametrize("match_acceleration", [False, True])
def test_replan_continuity(match_acceleration: bool) -> None:
    """Re-plan every 40 ms from the old plan's state with new random via points."""
    rng = np.random.default_rng(7)
    spec = ActionSpec()
    jumps = []
    for _ in range(12):
        points, times = spec.decode(rng.uniform(-1, 1, spec.size), np.zeros(3), 0.0)
        traj = BSplineTrajectory(points, times)
        for step in range(1, 11):
            t = 0.04 * step
            p, v, a = traj.sample(t)
            points, times = spec.decode(rng.uniform(-1, 1, spec.size), p, t)
            new = BSplineTrajectory(points, times, v, a if match_acceleration else None)
            eps = 1e-9
            amax = new.max_acceleration(num=501)
            np.testing.assert_allclose(new.position(t), p, rtol=0, atol=1e-9)
            np.testing.assert_allclose(new.velocity(t), v, rtol=0, atol=1e-9)
            np.testing.assert_allclose(new.position(t + eps), traj.position(t + eps), rtol=0, atol=1e-9)
            np.testing.assert_allclose(new.velocity(t + eps), v, rtol=0, atol=2 * eps * amax + 1e-9)
            jumps.append(np.linalg.norm(new.acceleration(t + 1e-11) - a))  # right limit of the spline
            traj = new
    jumps_arr = np.array(jumps)
    print(
        f"\nacceleration jump at re-plan (match_acceleration={match_acceleration}): "
        f"median {np.median(jumps_arr):.3g}, p95 {np.percentile(jumps_arr, 95):.3g}, "
        f"max {jumps_arr.max():.3g} m/s^2"
    )
    if match_acceleration:
        assert jumps_arr.max() < 1e-5
    else:
        # Only C1 across plans: the jump is real (documented), typically tens of m/s^2.
        assert np.median(jumps_arr) > 1.0


def test_two_points_from_rest_closed_form() -> None:
    p0, p1 = np.array([0.1, -0.2, 0.3]), np.array([0.4, 0.2, 0.1])
    traj = BSplineTrajectory([p0, p1], [2.0, 2.5])
    t = np.linspace(2.0, 2.5, 101)
    s = (t - 2.0) / 0.5
    blend = 3 * s**2 - 2 * s**3  # rest-to-rest cubic timing law, natural path = straight line
    np.testing.assert_allclose(traj.position(t), p0 + blend[:, None] * (p1 - p0), atol=1e-12)
    dblend = (6 * s - 6 * s**2) / 0.5
    np.testing.assert_allclose(traj.velocity(t[:-1]), dblend[:-1, None] * (p1 - p0), atol=1e-11)


@pytest.mark.parametrize("start_speed", [0.0, 1.0])
def test_collinear_equally_spaced_points_give_straight_line(start_speed: float) -> None:
    direction = np.array([1.0, 2.0, -2.0]) / 3.0
    step = 0.1 * direction
    points = np.array([0.5, 0.0, 1.0]) + np.arange(5)[:, None] * step
    times = 0.2 * np.arange(5)
    # A start velocity along the line, consistent with uniform motion along the path.
    v0 = start_speed * direction
    traj = BSplineTrajectory(points, times, v0)
    t = np.linspace(times[0], times[-1], 1001)
    pos = traj.position(t)
    rel = pos - points[0]
    lateral = rel - (rel @ direction)[:, None] * direction
    assert np.abs(lateral).max() < 1e-12
    if start_speed == 0.0:
        # Natural end conditions on equally spaced collinear points: path(u) = P0 + u * step exactly.
        u = traj.timing(t)[0]
        np.testing.assert_allclose(pos, points[0] + u[:, None] * step, atol=1e-12)


def test_collinear_unequal_points_stay_on_line() -> None:
    rng = np.random.default_rng(3)
    direction = np.array([0.0, 0.6, 0.8])
    for _ in range(20):
        s = np.concatenate([[0.0], rng.uniform(-0.3, 0.3, 4)])  # may even reverse along the line
        points = np.array([1.0, 2.0, 3.0]) + np.cumsum(s)[:, None] * direction
        times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.1, 0.6, 4))])
        traj = BSplineTrajectory(points, times, rng.normal() * direction, rng.normal() * direction)
        rel = traj.position(np.linspace(times[0], times[-1], 500)) - points[0]
        lateral = rel - (rel @ direction)[:, None] * direction
        assert np.abs(lateral).max() < 1e-12


def test_plain_timing_spline_overshoots_and_fallback_is_monotone() -> None:
    # Long-short-long intervals: the plain clamped spline through (t_i, i) runs backwards.
    times = np.array([0.0, 0.6, 0.7, 1.3])
    plain = CubicSpline(times, np.arange(4.0), bc_type=((1, 0.0), (1, 0.0)))
    assert plain(np.linspace(0, 1.3, 2001), 1).min() < -0.1
    traj = BSplineTrajectory(np.random.default_rng(0).normal(size=(4, 3)), times)
    assert traj.monotone_fallback
    u, du, _ = traj.timing(np.linspace(0, 1.3, 20001))
    assert du.min() >= -1e-9
    assert np.all(np.diff(u) >= -1e-12)


@pytest.mark.parametrize("moving", [False, True])
def test_timing_law_monotone_for_random_actions(moving: bool) -> None:
    rng = np.random.default_rng(11 + moving)
    fallbacks = 0
    for k in (1, 2, 3, 4, 6):
        for _ in range(30):
            points, times, v0, _ = _random_plan(rng, k, moving)
            traj = BSplineTrajectory(points, times, v0)
            fallbacks += traj.monotone_fallback
            du = traj.timing(np.linspace(traj.t_start, traj.t_end, 4001))[1]
            assert du.min() >= -1e-9 * (1.0 + du.max())
            np.testing.assert_allclose(traj.position(times), points, atol=1e-9)
    assert fallbacks > 0  # the fallback path is actually exercised


def test_monotone_fallback_reduces_to_plain_spline_when_unconstrained() -> None:
    """The fallback is min-curvature; without active constraints it must equal the plain spline."""
    rng = np.random.default_rng(5)
    checked = 0
    for _ in range(40):
        n = int(rng.integers(2, 7))
        tau = np.concatenate([[0.0], np.cumsum(rng.uniform(0.25, 0.3, n - 1))])
        c0 = float(rng.choice([0.0, 1.0 / tau[1]]))
        plain = CubicSpline(tau, np.arange(n, dtype=float), bc_type=((1, c0), (1, 0.0)))
        if _min_rate(plain.x, plain.c.T) < 0:
            continue
        breaks, coef = _monotone_timing_law(tau, c0)
        x = np.linspace(0.0, tau[-1], 501)
        np.testing.assert_allclose(PPoly(coef.T, breaks)(x), plain(x), atol=1e-8)
        checked += 1
    assert checked > 10


def test_outside_time_range() -> None:
    rng = np.random.default_rng(2)
    points, times, v0, a0 = _random_plan(rng, 3, moving=True, accel=True)
    traj = BSplineTrajectory(points, times, v0, a0)
    pos, vel, acc = traj.sample(np.array([times[0] - 1.0, times[-1] + 1.0]))
    np.testing.assert_array_equal(pos, [points[0], points[-1]])
    np.testing.assert_array_equal(vel, [v0, np.zeros(3)])
    np.testing.assert_array_equal(acc, [a0, np.zeros(3)])
    pos, vel, acc = traj.sample(times[0] - 1.0)
    np.testing.assert_array_equal(vel, v0)
    np.testing.assert_array_equal(traj.acceleration(times[-1] + 1e-3), np.zeros(3))


def test_scalar_and_vector_evaluation_agree() -> None:
    rng = np.random.default_rng(4)
    points, times, v0, _ = _random_plan(rng, 4, moving=True)
    traj = BSplineTrajectory(points, times, v0)
    t = np.linspace(times[0] - 0.1, times[-1] + 0.1, 97)
    vec = traj.sample(t)
    for i, ti in enumerate(t):
        for got, want in zip(traj.sample(float(ti)), vec, strict=True):
            np.testing.assert_allclose(got, want[i], rtol=1e-12, atol=1e-12)
    assert traj.position(np.float64(t[5])).shape == (3,)
    assert traj.velocity(np.array(t[5])).shape == (3,)
    assert traj.acceleration(int(times[0])).shape == (3,)
    assert traj.position(t.reshape(97, 1)).shape == (97, 1, 3)
    assert traj.position(list(t[:4])).shape == (4, 3)


def test_max_speed_and_acceleration() -> None:
    rng = np.random.default_rng(8)
    points, times, v0, _ = _random_plan(rng, 3, moving=True)
    traj = BSplineTrajectory(points, times, v0)
    t = np.linspace(times[0], times[-1], 20001)[:-1]
    assert traj.max_speed(num=5001) == pytest.approx(np.linalg.norm(traj.velocity(t), axis=1).max(), rel=1e-3)
    assert traj.max_acceleration(num=5001) == pytest.approx(
        np.linalg.norm(traj.acceleration(t), axis=1).max(), rel=1e-2
    )


def test_properties_and_immutability() -> None:
    points = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.1], [0.2, 0.1, 0.0]])
    times = np.array([10.0, 10.3, 10.5])
    traj = BSplineTrajectory(points, times)
    assert (traj.t_start, traj.t_end) == (10.0, 10.5)
    assert traj.duration == pytest.approx(0.5)
    got = traj.points
    got[0, 0] = 99.0
    np.testing.assert_array_equal(traj.points, points)
    traj.times[0] = -1.0
    assert traj.t_start == 10.0
    with pytest.raises(AttributeError, match="immutable"):
        traj.foo = 1  # type: ignore[attr-defined]
    with pytest.raises(AttributeError, match="immutable"):
        traj._t0 = 0.0  # type: ignore[misc]
    # Returned arrays are copies: mutating them must not corrupt the start/end state.
    traj.position(0.0)[0] = 5.0
    np.testing.assert_array_equal(traj.position(0.0), points[0])
    points[0, 0] = 7.0  # input arrays are copied too
    np.testing.assert_array_equal(traj.position(0.0), [0.0, 0.0, 0.0])


@pytest.mark.parametrize("accel", [False, True])
def test_pickle_round_trip(accel: bool) -> None:
    rng = np.random.default_rng(9)
    points, times, v0, a0 = _random_plan(rng, 3, moving=True, accel=accel)
    traj = BSplineTrajectory(points, times, v0, a0)
    clone = pickle.loads(pickle.dumps(traj))
    t = np.linspace(times[0] - 0.1, times[-1] + 0.1, 300)
    for got, want in zip(clone.sample(t), traj.sample(t), strict=True):
        np.testing.assert_array_equal(got, want)
    assert clone.monotone_fallback == traj.monotone_fallback


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (
            {"points": np.zeros((1, 3)), "times": [0.0]},
            r"points must have shape \(n, 3\) with n >= 2, got shape \(1, 3\)",
        ),
        ({"points": np.zeros((3, 2)), "times": [0.0, 1, 2]}, r"got shape \(3, 2\)"),
        (
            {"points": np.zeros((3, 3)), "times": [0.0, 1.0]},
            r"times must have shape \(3,\) to match points, got shape \(2,\)",
        ),
        (
            {"points": np.zeros((3, 3)), "times": [0.0, 0.3, 0.2]},
            r"strictly increasing, got \[0.0, 0.3, 0.2\]",
        ),
        ({"points": np.zeros((3, 3)), "times": [0.0, 0.3, 0.3]}, r"^times must be strictly increasing, got"),
        (
            {"points": np.zeros((2, 3)), "times": [0.0, 1.0, 2.0]},
            r"times must have shape \(2,\) to match points, got shape \(3,\)",
        ),
        (
            {"points": np.zeros((2, 3)), "times": [0.0, 1.0], "start_velocity": [0, np.inf, 0]},
            r"start_velocity must be finite, got \[0\.0, inf, 0\.0\]",
        ),
        (
            {"points": [[0, 0, 0], [0, np.nan, 0]], "times": [0.0, 1.0]},
            r"points must be finite, got nan at index \(1, 1\)",
        ),
        (
            {"points": np.zeros((2, 3)), "times": [0.0, np.inf]},
            r"times must be finite, got inf at index \(1,\)",
        ),
        (
            {"points": np.zeros((2, 3)), "times": [0.0, 1.0], "start_velocity": [1.0, 2.0]},
            r"start_velocity must have shape \(3,\)",
        ),
        (
            {"points": np.zeros((2, 3)), "times": [0.0, 1.0], "start_acceleration": [0, np.nan, 0]},
            r"start_acceleration must be finite",
        ),
    ],
)
def test_invalid_inputs(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        BSplineTrajectory(**kwargs)


def test_shifted_is_the_same_trajectory_later() -> None:
    points = np.array([[0.0, 0.0, 0.0], [0.1, 0.05, -0.02], [0.3, 0.0, 0.1], [0.35, 0.02, 0.1]])
    traj = BSplineTrajectory(points, [1.0, 1.2, 1.5, 1.9], start_velocity=[0.2, 0.0, 0.1])
    later = traj.shifted(0.37)
    t = np.linspace(0.9, 2.0, 57)
    for a, b in zip(later.sample(t + 0.37), traj.sample(t), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert later.t_start == pytest.approx(1.37) and later.duration == pytest.approx(traj.duration)
    with pytest.raises(ValueError, match="dt must be finite"):
        traj.shifted(float("nan"))


def test_whole_number_inputs_give_float_outputs() -> None:
    traj = BSplineTrajectory([[0, 0, 1], [1, 0, 1], [2, 1, 1]], [0, 1, 2], start_velocity=[1, 0, 0],
                             start_acceleration=[0, 1, 0])
    assert traj.points.dtype == traj.times.dtype == np.float64
    for state in traj.sample(-1.0):  # the start state, held before t_0
        assert state.dtype == np.float64
    np.testing.assert_array_equal(traj.start_velocity, [1.0, 0.0, 0.0])


@pytest.mark.parametrize("moving", [False, True])
def test_start_acceleration_is_the_plans_own_when_not_imposed(moving: bool) -> None:
    """Without ``start_acceleration`` the start state's acceleration is what the boundary conditions give:
    the right limit of the spline's acceleration at t_0 (held for t <= t_0, so continuous there)."""
    rng = np.random.default_rng(21 + moving)
    for k in (1, 2, 3):
        for _ in range(5):
            points, times, v0, _ = _random_plan(rng, k, moving)
            traj = BSplineTrajectory(points, times, v0)
            right = traj.acceleration(traj.t_start + 1e-9)
            scale = 1.0 + traj.max_acceleration(num=201)
            np.testing.assert_allclose(traj.start_acceleration, right, atol=1e-6 * scale)
            np.testing.assert_allclose(traj.acceleration(traj.t_start), right, atol=1e-6 * scale)


def test_timing_law_derivatives_clamping_and_shapes() -> None:
    rng = np.random.default_rng(31)
    for moving in (False, True):
        points, times, v0, _ = _random_plan(rng, 3, moving)
        traj = BSplineTrajectory(points, times, v0)
        t = np.linspace(traj.t_start, traj.t_end, 301)[1:-1]
        h = 1e-6
        u, du, ddu = traj.timing(t)
        u_p, du_p, _ = traj.timing(t + h)
        u_m, du_m, _ = traj.timing(t - h)
        np.testing.assert_allclose(du, (u_p - u_m) / (2 * h), atol=1e-6 * (1 + np.abs(du).max()))
        np.testing.assert_allclose(ddu, (du_p - du_m) / (2 * h), atol=1e-4 * (1 + np.abs(ddu).max()))
        # Clamped to [t_0, t_end]: before the start it is the start's, after the end the end's.
        for outside, edge in ((traj.t_start - 0.5, traj.t_start), (traj.t_end + 0.5, traj.t_end)):
            for a, b in zip(traj.timing(outside), traj.timing(edge), strict=True):
                assert a == b
        u_end, du_end, _ = traj.timing(traj.t_end + 0.5)
        assert (u_end, du_end) == (pytest.approx(3.0), pytest.approx(0.0, abs=1e-9))
        # The output has the input's shape.
        assert [x.shape for x in traj.timing(traj.t_start + 0.1)] == [()] * 3
        assert [x.shape for x in traj.timing(t[:6].reshape(3, 2))] == [(3, 2)] * 3


@pytest.mark.parametrize("moving", [False, True])
def test_path_and_timing_law_are_the_natural_and_clamped_cubic_splines(moving: bool) -> None:
    """Where the plain timing law is monotone: ``u(t)`` is the cubic spline through ``(t_i - t_0, i)`` with
    ``u'(t_0) = c0`` (0 from rest, the first interval's mean rate when moving) and ``u'(t_end) = 0``; the path
    is the cubic spline through ``(i, P_i)``, natural at the end, natural at the start from rest and with
    ``path'(0) = v0 / c0`` when moving. Checked against scipy's ``CubicSpline``, an independent solver."""
    rng = np.random.default_rng(41 + moving)
    checked = 0
    for k in (1, 2, 3, 4):
        for _ in range(10):
            points, times, v0, _ = _random_plan(rng, k, moving)
            traj = BSplineTrajectory(points, times, v0)
            if traj.monotone_fallback:
                continue
            tau = times - times[0]
            c0 = 1.0 / tau[1] if moving else 0.0
            timing = CubicSpline(tau, np.arange(k + 1.0), bc_type=((1, c0), (1, 0.0)))
            start = (1, v0 / c0) if moving else (2, np.zeros(3))
            path = CubicSpline(np.arange(k + 1.0), points, bc_type=(start, (2, np.zeros(3))))
            t = np.linspace(times[0], times[-1], 157)
            u = timing(t - times[0])
            np.testing.assert_allclose(traj.timing(t)[0], u, atol=1e-9)
            np.testing.assert_allclose(traj.position(t), path(u), atol=1e-9)
            inner = t[1:-1]
            ui, dui = timing(inner - times[0]), timing(inner - times[0], 1)
            np.testing.assert_allclose(traj.velocity(inner), path(ui, 1) * dui[:, None], atol=1e-7)
            checked += 1
    assert checked >= 20


def _curvature(traj: BSplineTrajectory, t: np.ndarray) -> np.ndarray:
    v, a = traj.velocity(t), traj.acceleration(t)
    return np.linalg.norm(np.cross(v, a), axis=1) / np.linalg.norm(v, axis=1) ** 3


@pytest.mark.parametrize("accel", [False, True])
def test_the_path_ends_straight(accel: bool) -> None:
    """The path's end is natural (``path'' = 0``): the trajectory's curvature |v x a| / |v|^3, which does not
    depend on the timing law, goes to zero at the last via point, whatever the start conditions."""
    rng = np.random.default_rng(51 + accel)
    for _ in range(10):
        points, times, v0, a0 = _random_plan(rng, 3, True, accel)
        traj = BSplineTrajectory(points, times, v0, a0)
        d = traj.duration
        near_end = _curvature(traj, traj.t_end - d * np.array([1e-3, 1e-4]))
        inside = np.median(_curvature(traj, np.linspace(traj.t_start, traj.t_end, 101)[1:-1]))
        assert near_end[1] < 1e-3 * inside, (near_end, inside)
        assert near_end[1] < 0.2 * near_end[0]  # and keeps shrinking towards the end


def test_shifted_keeps_an_imposed_start_acceleration() -> None:
    rng = np.random.default_rng(61)
    points, times, v0, a0 = _random_plan(rng, 3, True, True)
    traj = BSplineTrajectory(points, times, v0, a0)
    later = traj.shifted(0.25)
    np.testing.assert_array_equal(later.start_acceleration, a0)
    t = np.linspace(times[0] - 0.1, times[-1] + 0.1, 41)
    for a, b in zip(later.sample(t + 0.25), traj.sample(t), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_a_monotone_plan_keeps_the_papers_timing_law() -> None:
    """The fallback replaces the timing law only where the plain spline runs backwards: from rest with even
    intervals (u' = 0 at both ends, positive between) it is not used."""
    points = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.1], [0.2, 0.1, 0.1], [0.3, 0.0, 0.0]])
    for times in ([0.0, 0.3, 0.6, 0.9], [5.0, 5.2, 5.45, 5.7]):
        traj = BSplineTrajectory(points, times)
        assert not traj.monotone_fallback
        assert traj.timing(np.linspace(times[0], times[-1], 1001))[1].min() >= -1e-12


def test_monotone_timing_law_has_two_extra_knots_per_interval() -> None:
    tau = np.array([0.0, 0.6, 0.7, 1.3])
    breaks, coef = _monotone_timing_law(tau, 0.0)
    np.testing.assert_allclose(breaks, np.linspace(0.0, 0.6, 4).tolist() + [0.6 + 0.1 / 3, 0.6 + 0.2 / 3]
                               + np.linspace(0.7, 1.3, 4).tolist(), atol=1e-12)
    assert coef.shape == (9, 4)


# The monotone timing law's solver: min x'Qx + 2g'x subject to Ax = b, x >= 0.
@pytest.mark.parametrize(
    ("q", "g", "a", "b", "x"),
    [
        # On the line x1 + x2 = 1 the unconstrained minimum (2, -1) is infeasible: the bound x2 >= 0 holds it.
        (np.eye(2), [-1.0, 2.0], [[1.0, 1.0]], [1.0], [1.0, 0.0]),
        (np.eye(2), [0.0, 0.0], [[1.0, 1.0]], [1.0], [0.5, 0.5]),  # no bound active
        (np.eye(2), [-1.0, 2.0], [[1.0, 1.0], [2.0, 2.0]], [1.0, 2.0], [1.0, 0.0]),  # dependent rows
        ([[2.0]], [-1.0], [[1.0]], [3.0], [3.0]),  # one variable
        (np.diag([1.0, 2.0, 3.0]), [1.0, 1.0, -6.0], [[1.0, 1.0, 1.0]], [2.0], [0.0, 0.0, 2.0]),
    ],
)
def test_nonneg_qp_hand_computed(q, g, a, b, x) -> None:
    got = _nonneg_qp(np.array(q), np.array(g), np.array(a), np.array(b))
    np.testing.assert_allclose(got, x, atol=1e-9)
    assert np.all(got >= 0.0)


def _qp_by_enumeration(q, g, a, b):
    """The same QP solved by trying every set of zero bounds (independent of the active-set solver)."""
    m = q.shape[0]
    best, best_x = np.inf, None
    for mask in range(2**m):
        free = np.array([(mask >> i) & 1 == 0 for i in range(m)])
        if not free.any():
            continue
        qf, af = q[np.ix_(free, free)], a[:, free]
        k = af.shape[0]
        kkt = np.block([[2 * qf, af.T], [af, np.zeros((k, k))]])
        try:
            sol = np.linalg.solve(kkt, np.concatenate([-2 * g[free], b]))
        except np.linalg.LinAlgError:
            continue
        x = np.zeros(m)
        x[free] = sol[: free.sum()]
        if np.all(x >= -1e-12) and np.allclose(a @ x, b, atol=1e-9):
            f = x @ q @ x + 2 * g @ x
            if f < best - 1e-12:
                best, best_x = f, x
    return best_x


def _random_qp(seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    m = int(rng.integers(2, 8))
    n_eq = int(rng.integers(1, m))
    half = rng.normal(size=(m, m))
    q = half @ half.T + 0.1 * np.eye(m)
    g = rng.normal(scale=3.0, size=m)
    a = rng.normal(size=(n_eq, m))
    return q, g, a, a @ rng.uniform(0.0, 1.0, m)  # feasible


# Seeds 44, 62 and 78: problems on which a solver that steps past a bound, or starts from an infeasible point,
# ends at a wrong optimum (found by trying such solvers on seeds 0-999).
@pytest.mark.parametrize("seed", [*range(40), 44, 62, 78])
def test_nonneg_qp_agrees_with_enumerating_the_active_sets(seed: int) -> None:
    q, g, a, b = _random_qp(seed)
    got = _nonneg_qp(q, g, a, b)
    want = _qp_by_enumeration(q, g, a, b)
    np.testing.assert_allclose(got, want, atol=1e-7)
    np.testing.assert_allclose(a @ got, b, atol=1e-9)


def test_the_random_qps_have_binding_bounds() -> None:
    bound = sum(int(np.sum(_qp_by_enumeration(*_random_qp(seed)) < 1e-12)) for seed in range(40))
    assert bound > 20  # the bounds bind in many of these problems: the active set is exercised


@pytest.mark.parametrize(
    ("breaks", "coef", "minimum"),
    [
        # u' = 3 a s^2 + 2 b s + c per piece (coefficients of s^3, s^2, s, 1).
        ([0.0, 2.0], [[2.0, -6.0, 2.0, 0.0]], -4.0),  # u' = 6s^2 - 12s + 2: vertex inside, at s = 1
        ([0.0, 0.9], [[2.0, -6.0, 2.0, 0.0]], 6 * 0.81 - 12 * 0.9 + 2),  # vertex beyond: the end is lowest
        ([0.0, 2.0], [[-1.0, 0.0, 1.0, 0.0]], -11.0),  # concave: an end is lowest
        ([0.0, 1.0, 3.0], [[0.0, 0.0, 1.0, 0.0], [1.0, -3.0, 2.0, 1.0]], -1.0),  # linear piece, then a dip
        ([0.0, 1.0], [[0.0, 1.0, -0.5, 0.0]], -0.5),  # a = 0: no vertex, the start is lowest
    ],
)
def test_min_rate_hand_computed(breaks, coef, minimum) -> None:
    """The exact minimum of u' over a piecewise cubic, silently (no division warning where a = 0)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _min_rate(np.array(breaks), np.array(coef)) == pytest.approx(minimum, abs=1e-12)


def test_deleting_an_attribute_is_refused() -> None:
    traj = BSplineTrajectory(np.zeros((2, 3)), [0.0, 1.0])
    with pytest.raises(AttributeError, match="^BSplineTrajectory is immutable$"):
        del traj._t0


def test_max_speed_and_acceleration_are_over_the_documented_samples() -> None:
    rng = np.random.default_rng(81)
    points, times, v0, _ = _random_plan(rng, 3, moving=True)
    traj = BSplineTrajectory(points, times, v0)
    for num in (7, 2001):
        t = np.linspace(traj.t_start, traj.t_end, num)
        assert traj.max_speed(num) == np.linalg.norm(traj.velocity(t), axis=1).max()
        assert traj.max_acceleration(num) == np.linalg.norm(traj.acceleration(t[:-1]), axis=1).max()
    t = np.linspace(traj.t_start, traj.t_end, 2001)
    assert traj.max_speed() == np.linalg.norm(traj.velocity(t), axis=1).max()
    assert traj.max_acceleration() == np.linalg.norm(traj.acceleration(t[:-1]), axis=1).max()


def test_at_t_end_the_plan_is_at_rest_for_arrays_of_times_too() -> None:
    rng = np.random.default_rng(91)
    points, times, v0, a0 = _random_plan(rng, 3, True, True)
    traj = BSplineTrajectory(points, times, v0, a0)
    pos, vel, acc = traj.sample(np.array([traj.t_start, traj.t_end]))
    np.testing.assert_array_equal(pos, [points[0], points[-1]])
    np.testing.assert_array_equal(vel, [v0, np.zeros(3)])
    np.testing.assert_array_equal(acc, [a0, np.zeros(3)])
