"""Many plans at once (the batched environment's planning) equal the one-by-one planning to the last bit, and
the NumPy spline fits equal scipy's splines."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline, make_interp_spline

from dyndlo_vision.trajectory import ActionSpec, BSplineTrajectory, Replanner
from dyndlo_vision.trajectory.bspline import _pp_from_bspline, sample_many
from dyndlo_vision.trajectory.replanner import replan_many

SPECS = [
    ActionSpec(num_points=3, planar=True, dx_m=(-0.25, 0.25), dz_m=(-0.25, 0.25), dt_s=(0.1, 0.5)),
    ActionSpec(num_points=2, planar=False),
    ActionSpec(num_points=1, planar=True),
]


def random_plans(spec: ActionSpec, count: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    start = rng.normal(0.0, 0.3, (count, 3))
    points, times = spec.decode_many(rng.uniform(-1.3, 1.3, (count, spec.size)), start,
                                     rng.uniform(0.0, 3.0, count))
    velocities = np.where(rng.random((count, 1)) < 0.3, 0.0, rng.normal(0.0, 0.8, (count, 3)))
    return points, times, velocities


@pytest.mark.parametrize("spec", SPECS)
def test_many_equals_one_by_one_to_the_last_bit(spec: ActionSpec) -> None:
    points, times, velocities = random_plans(spec, 200, 1)
    many = BSplineTrajectory.many(points, times, velocities)
    assert sum(p.monotone_fallback for p in many) > 0 or spec.num_points == 1  # both timing laws are covered
    for m, plan in enumerate(many):
        single = BSplineTrajectory(points[m], times[m], start_velocity=velocities[m])
        for field in ("_tb_a", "_tc_a", "_pb_a", "_pc_a"):
            np.testing.assert_array_equal(getattr(plan, field), getattr(single, field), err_msg=field)
        assert plan.monotone_fallback == single.monotone_fallback


@pytest.mark.parametrize("spec", SPECS)
def test_numpy_fits_equal_scipys_splines(spec: ActionSpec) -> None:
    points, times, velocities = random_plans(spec, 200, 2)
    for plan, p, t, v0 in zip(BSplineTrajectory.many(points, times, velocities), points, times, velocities,
                              strict=True):
        tau = t - t[0]
        n = len(tau)
        moving = bool(np.any(v0 != 0))
        c0 = 1.0 / tau[1] if moving else 0.0
        if not plan.monotone_fallback:
            timing = CubicSpline(tau, np.arange(n, dtype=float), bc_type=((1, c0), (1, 0.0)))
            np.testing.assert_allclose(plan._tc_a, timing.c.T, rtol=1e-11, atol=1e-11)
        start = [(1, v0 / c0)] if moving else [(2, np.zeros(3))]
        path = make_interp_spline(np.arange(n, dtype=float), p, k=3, bc_type=(start, [(2, np.zeros(3))]))
        np.testing.assert_allclose(plan._pc_a, _pp_from_bspline(path)[1], rtol=1e-11, atol=1e-11)


def test_sample_many_equals_each_plans_evaluation() -> None:
    points, times, velocities = random_plans(SPECS[0], 40, 3)
    plans = BSplineTrajectory.many(points, times, velocities)
    # Before, inside and after every plan, and exactly at its via-point times.
    t = np.stack([np.concatenate([p.t_start + np.linspace(-0.05, p.duration + 0.05, 300), p.times])
                  for p in plans])
    pos, vel = sample_many(plans, t)
    for m, plan in enumerate(plans):
        np.testing.assert_array_equal(pos[m], plan.position(t[m]))
        np.testing.assert_array_equal(vel[m], plan.velocity(t[m]))


def test_decode_many_and_replan_many_equal_one_by_one() -> None:
    spec = SPECS[0]
    rng = np.random.default_rng(4)
    home = np.array([[0.45, 0.0, 0.6]])
    one = [Replanner(spec, home) for _ in range(6)]
    many = [Replanner(spec, home) for _ in range(6)]
    for t in (0.0, 0.04, 0.08):  # the first plan from rest, then re-plans from a moving commanded state
        actions = rng.uniform(-1.2, 1.2, (6, spec.size))
        for r, a in zip(one, actions, strict=True):
            r.replan(a, t)
        replan_many(many, actions, np.full(6, t))
        for a, b in zip(one, many, strict=True):
            assert a.trajectory is not None and b.trajectory is not None
            for field in ("_tb_a", "_tc_a", "_pb_a", "_pc_a"):
                np.testing.assert_array_equal(getattr(a.trajectory, field), getattr(b.trajectory, field))


def test_many_names_the_bad_plan() -> None:
    points, times, velocities = random_plans(SPECS[0], 3, 5)
    times[2, 2] = times[2, 1]
    with pytest.raises(ValueError, match="trajectory 2: times must be strictly increasing"):
        BSplineTrajectory.many(points, times, velocities)
    with pytest.raises(ValueError, match=r"action 1 must be finite, got nan at index 3"):
        SPECS[0].decode_many(np.array([[0.0] * 9, [0, 0, 0, np.nan, 0, 0, 0, 0, 0]]), np.zeros((2, 3)),
                             np.zeros(2))


def _same_plans(one: list[Replanner], many: list[Replanner]) -> None:
    for a, b in zip(one, many, strict=True):
        assert a.trajectory is not None and b.trajectory is not None
        for field in ("_tb_a", "_tc_a", "_pb_a", "_pc_a"):
            np.testing.assert_array_equal(getattr(a.trajectory, field), getattr(b.trajectory, field))


def test_replan_many_fits_all_plans_in_one_computation(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    many_fits = BSplineTrajectory.many
    monkeypatch.setattr(BSplineTrajectory, "many",
                        staticmethod(lambda *args, **kw: calls.append(1) or many_fits(*args, **kw)))
    planners = [Replanner(SPECS[0], np.array([[0.45, 0.0, 0.6]])) for _ in range(4)]
    replan_many(planners, np.zeros((4, SPECS[0].size)), np.zeros(4))
    assert calls == [1] and all(p.trajectory is not None for p in planners)


@pytest.mark.parametrize("mixed", ["final point", "specs"])
def test_replan_many_with_final_points_or_mixed_specs_replans_one_by_one(mixed: str) -> None:
    """Task IV's planners (a final point) and planners of different action specs cannot share one fit: each
    re-plans on its own, to the same plans as its own ``replan``."""
    from dataclasses import replace

    home = np.array([[0.45, 0.0, 0.6]])
    rng = np.random.default_rng(7)
    with_final = replace(SPECS[0], append_final_point=True)

    def planners() -> list[Replanner]:
        if mixed == "final point":
            return [Replanner(with_final, home, final_point=[0.5, 0.0, 0.3 + 0.1 * k]) for k in range(3)]
        return [Replanner(SPECS[0], home), Replanner(SPECS[2], home), Replanner(SPECS[0], home)]

    one, many = planners(), planners()
    size = max(p.spec.size for p in one)
    for t in (0.0, 0.04):
        actions = rng.uniform(-1.0, 1.0, (3, size))
        for r, a in zip(one, actions, strict=True):
            r.replan(a[: r.spec.size], t)
        if mixed == "final point":
            replan_many(many, actions, np.full(3, t))
        else:  # one action row per planner, each its own size: rows of a list
            for r, a in zip(many, actions, strict=True):
                replan_many([r], a[None, : r.spec.size], np.array([t]))
        _same_plans(one, many)


@pytest.mark.parametrize("final_point", [None, [0.5, 0.0, 0.3]])
def test_replan_many_refuses_actions_or_times_that_do_not_match_the_planners(final_point: object) -> None:
    from dataclasses import replace

    spec = replace(SPECS[0], append_final_point=final_point is not None)
    planners = [Replanner(spec, np.array([[0.45, 0.0, 0.6]]), final_point=final_point) for _ in range(3)]
    with pytest.raises(ValueError):
        replan_many(planners, np.zeros((2, spec.size)), np.zeros(3))
    with pytest.raises(ValueError):
        replan_many(planners, np.zeros((3, spec.size)), np.zeros(2))
