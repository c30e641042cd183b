"""Tests for dyndlo_vision.trajectory.actions."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dyndlo_vision.trajectory import ActionSpec, BSplineTrajectory


def test_sizes() -> None:
    assert ActionSpec().size == 12
    assert ActionSpec(num_points=3, planar=True).size == 9  # 3 * k
    assert ActionSpec(num_points=2, planar=True).size == 6
    assert ActionSpec(num_points=3, append_final_point=True).size == 13
    assert ActionSpec(num_points=1, planar=True, append_final_point=True).size == 4


def test_decode_layout_and_accumulation() -> None:
    spec = ActionSpec(num_points=2, dx_m=(-0.2, 0.4), dy_m=(0.0, 1.0), dz_m=(-1.0, -0.5), dt_s=(0.1, 0.5))
    # [dx1, dy1, dz1, dx2, dy2, dz2, dt1, dt2]
    action = np.array([-1.0, 1.0, 0.0, 1.0, 0.0, -1.0, -1.0, 0.5])
    p0 = np.array([1.0, 2.0, 3.0])
    points, times = spec.decode(action, p0, 5.0)
    d1, d2 = np.array([-0.2, 1.0, -0.75]), np.array([0.4, 0.5, -1.0])
    np.testing.assert_allclose(points, [p0, p0 + d1, p0 + d1 + d2])
    np.testing.assert_allclose(times, [5.0, 5.1, 5.1 + 0.4])


def test_decode_clips_out_of_box_actions() -> None:
    spec = ActionSpec()
    rng = np.random.default_rng(0)
    action = rng.normal(scale=3.0, size=spec.size)
    assert np.abs(action).max() > 1.0
    got = spec.decode(action, np.zeros(3), 0.0)
    want = spec.decode(np.clip(action, -1.0, 1.0), np.zeros(3), 0.0)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)
    _, times = spec.decode(np.full(spec.size, -10.0), np.zeros(3), 0.0)
    np.testing.assert_allclose(np.diff(times), spec.dt_s[0])


@pytest.mark.parametrize(
    "spec",
    [
        ActionSpec(),
        ActionSpec(num_points=1),
        ActionSpec(num_points=4, planar=True),
        ActionSpec(num_points=2, append_final_point=True),
        ActionSpec(num_points=3, planar=True, append_final_point=True, dt_s=(0.05, 1.0)),
    ],
)
def test_round_trip(spec: ActionSpec) -> None:
    rng = np.random.default_rng(spec.size)
    final = np.array([0.5, 0.0, 1.2]) if spec.append_final_point else None
    for _ in range(50):
        action = rng.uniform(-1.0, 1.0, spec.size)
        points, times = spec.decode(action, rng.normal(size=3), rng.uniform(0, 100), final)
        assert points.shape == (spec.num_intervals + 1, 3)
        assert times.shape == (spec.num_intervals + 1,)
        np.testing.assert_allclose(spec.encode(points, times), action, atol=1e-9)
    # The extremes of the box map to the ends of the ranges and back.
    for value in (-1.0, 1.0):
        action = np.full(spec.size, value)
        np.testing.assert_allclose(spec.encode(*spec.decode(action, np.zeros(3), 0.0, final)), action)


def test_planar_has_no_dy() -> None:
    spec = ActionSpec(num_points=3, planar=True)
    rng = np.random.default_rng(1)
    points, _ = spec.decode(rng.uniform(-1, 1, spec.size), np.array([0.0, 0.7, 0.0]), 0.0)
    np.testing.assert_array_equal(points[:, 1], 0.7)
    # x and z of the first point come from entries 0 and 1.
    points, _ = spec.decode(np.array([1.0, -1.0, 0, 0, 0, 0, 0, 0, 0]), np.zeros(3), 0.0)
    np.testing.assert_allclose(points[1], [0.3, 0.0, -0.3])
    with pytest.raises(ValueError, match=r"planar ActionSpec needs dy = 0"):
        spec.encode(points + np.array([[0.0, 0.0, 0.0]] * 3 + [[0.0, 0.1, 0.0]]), np.arange(4) * 0.2)


def test_append_final_point() -> None:
    spec = ActionSpec(num_points=2, append_final_point=True)
    final = np.array([0.3, -0.1, 0.9])
    action = np.zeros(spec.size)
    action[-1] = 1.0  # the extra interval: time from P_2 to the fixed target
    points, times = spec.decode(action, np.zeros(3), 1.0, final_point=final)
    assert points.shape == (4, 3)
    np.testing.assert_array_equal(points[-1], final)
    np.testing.assert_allclose(np.diff(times), [0.35, 0.35, 0.6])
    with pytest.raises(ValueError, match="requires a final_point"):
        spec.decode(action, np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="does not take a final_point"):
        ActionSpec().decode(np.zeros(12), np.zeros(3), 0.0, final_point=final)
    with pytest.raises(ValueError, match=r"final_point must have shape \(3,\)"):
        spec.decode(action, np.zeros(3), 1.0, final_point=[1.0, 2.0])


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (np.zeros(11), r"action must have shape \(12,\), got shape \(11,\)"),
        (np.zeros((1, 12)), r"action must have shape \(12,\), got shape \(1, 12\)"),
        (np.where(np.arange(12) == 4, np.nan, 0.0), r"action must be finite, got nan at index 4"),
        (np.where(np.arange(12) == 11, -np.inf, 0.0), r"action must be finite, got -inf at index 11"),
    ],
)
def test_decode_rejects_bad_actions(action: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ActionSpec().decode(action, np.zeros(3), 0.0)


def test_decode_rejects_bad_start() -> None:
    with pytest.raises(ValueError, match=r"start_position must have shape \(3,\)"):
        ActionSpec().decode(np.zeros(12), np.zeros(2), 0.0)
    with pytest.raises(ValueError, match=r"^start_position must be finite, got \[0\.0, nan, 1\.0\]$"):
        ActionSpec().decode(np.zeros(12), [0.0, np.nan, 1.0], 0.0)
    with pytest.raises(ValueError, match=r"start_time must be finite"):
        ActionSpec().decode(np.zeros(12), np.zeros(3), float("nan"))


def test_encode_rejects_out_of_range() -> None:
    spec = ActionSpec(num_points=1)
    with pytest.raises(
        ValueError, match=r"action entry 0 has physical value 0.5, outside its range \[-0.3, 0.3\]"
    ):
        spec.encode([[0, 0, 0], [0.5, 0, 0]], [0.0, 0.2])
    with pytest.raises(ValueError, match=r"action entry 3 has physical value 0.05"):
        spec.encode([[0, 0, 0], [0.1, 0, 0]], [0.0, 0.05])
    with pytest.raises(ValueError, match=r"points/times must have shapes \(2, 3\)/\(2,\)"):
        spec.encode(np.zeros((3, 3)), np.zeros(3))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"num_points": 0}, "num_points must be >= 1, got 0"),
        ({"num_points": 2.0}, "num_points must be an int"),
        ({"dx_m": (0.3, -0.3)}, r"dx_m must be finite with min < max, got \(0.3, -0.3\)"),
        ({"dz_m": (0.1, 0.1)}, "dz_m must be finite with min < max"),
        ({"dy_m": (0.0,)}, "dy_m must be a \\(min, max\\) pair"),
        ({"dt_s": (0.0, 0.5)}, r"dt_s minimum must be > 0"),
        ({"dt_s": (-0.1, 0.5)}, r"dt_s minimum must be > 0"),
    ],
)
def test_spec_validation(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ActionSpec(**kwargs)


def test_spec_is_frozen_and_normalised() -> None:
    spec = ActionSpec(dx_m=[-1, 1])  # type: ignore[arg-type]
    assert spec.dx_m == (-1.0, 1.0)
    assert spec == ActionSpec(dx_m=(-1.0, 1.0))
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.num_points = 5  # type: ignore[misc]


def test_decoded_actions_build_valid_trajectories() -> None:
    spec = ActionSpec(num_points=3, planar=True)
    rng = np.random.default_rng(2)
    for _ in range(20):
        points, times = spec.decode(rng.uniform(-1.5, 1.5, spec.size), np.array([0.0, 0.0, 1.0]), 3.0)
        traj = BSplineTrajectory(points, times)
        t = np.linspace(traj.t_start, traj.t_end, 200)
        np.testing.assert_allclose(traj.position(t)[:, 1], 0.0, atol=1e-12)  # planar stays planar


def test_encode_checks_points_and_times_shapes_each() -> None:
    spec = ActionSpec(num_points=1)
    with pytest.raises(ValueError, match=r"got shapes \(3, 3\)/\(2,\)$"):
        spec.encode(np.zeros((3, 3)), [0.0, 0.2])
    with pytest.raises(ValueError, match=r"got shapes \(2, 3\)/\(3,\)$"):
        spec.encode(np.zeros((2, 3)), [0.0, 0.2, 0.4])


def test_encode_accepts_rounding_up_to_its_tolerance_and_clips_into_the_box() -> None:
    """Round trips through floats land a hair outside the ranges: up to 1e-9 (the tolerance) is accepted and
    clipped to exactly -1 or 1; more is refused. The same for a planar spec's dy."""
    tol = 1e-9
    spec = ActionSpec(num_points=1, dx_m=(-0.3, 0.3), dt_s=(0.1, 0.6))
    lo_dt, hi_dx = 0.1 - tol, 0.3 + tol  # the comparison's own bounds, computed as the code does
    a = spec.encode([[0.0, 0.0, 0.0], [hi_dx, 0.0, 0.0]], [0.0, lo_dt])
    assert a[0] == 1.0 and a[3] == -1.0  # exactly: clipped, not 1 + 3e-9
    assert np.all(np.abs(a) <= 1.0)
    a = spec.encode([[0.0, 0.0, 0.0], [-0.3 - 0.5 * tol, 0.0, 0.0]], [0.0, 0.6 + 0.5 * tol])
    assert a[0] == -1.0 and a[3] == 1.0
    with pytest.raises(ValueError, match="action entry 0"):
        spec.encode([[0.0, 0.0, 0.0], [0.3 + 3 * tol, 0.0, 0.0]], [0.0, 0.2])
    with pytest.raises(ValueError, match="action entry 3"):
        spec.encode([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], [0.0, 0.1 - 3 * tol])
    planar = ActionSpec(num_points=2, planar=True)
    ok = planar.encode([[0.0, 0.0, 0.0], [0.1, tol, 0.0], [0.2, tol, 0.0]], [0.0, 0.2, 0.4])
    flat = planar.encode([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]], [0.0, 0.2, 0.4])
    np.testing.assert_allclose(ok, flat)
    with pytest.raises(ValueError, match=r"planar ActionSpec needs dy = 0, got dy = \[0\.0, 0\.05\]"):
        planar.encode([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.05, 0.1]], [0.0, 0.2, 0.4])
