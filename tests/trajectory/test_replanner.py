"""Tests for dyndlo_vision.trajectory.replanner: plans from the commanded state, the second arm mirrored.

Written against hand-computed plans and physical invariants: before any plan the grippers rest at home; a
plan ends where the decoded action says; a re-plan keeps the commanded position and velocity (C1); every
gripper's velocity reference is the time derivative of its position reference; the second gripper mirrors
the first's lateral (y) motion about its own home, in position and in velocity.
"""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.trajectory import ActionSpec, BSplineTrajectory, Replanner

#: The hooking task's two grippers: mirror images of each other in the x-z plane (y = 0).
HOMES = np.array([[0.40, -0.12, 0.25], [0.40, 0.12, 0.25]])
MIRROR_Y = np.array([1.0, -1.0, 1.0])
SPEC = ActionSpec(num_points=2, planar=False, dx_m=(-0.2, 0.2), dy_m=(-0.1, 0.1), dz_m=(-0.2, 0.2),
                  dt_s=(0.1, 0.5))


def test_before_the_first_plan_every_gripper_rests_at_home() -> None:
    planner = Replanner(SPEC, HOMES)
    p, v = planner.references(np.array([0.0, 0.3]))
    assert p.shape == v.shape == (2, 2, 3)
    np.testing.assert_array_equal(p, np.broadcast_to(HOMES, (2, 2, 3)))
    np.testing.assert_array_equal(v, 0.0)
    p0, v0 = planner.commanded_state(1.0)
    np.testing.assert_array_equal(p0, HOMES[0])
    np.testing.assert_array_equal(v0, np.zeros(3))
    # A scalar time is one sample.
    p1, v1 = planner.references(0.5)
    assert p1.shape == v1.shape == (1, 2, 3)


def test_a_plan_from_rest_ends_where_the_action_says_for_both_grippers() -> None:
    """Hand-decoded: +1 is each range's maximum, -1 its minimum (dx, dy, dz, dx, dy, dz, dt, dt)."""
    planner = Replanner(SPEC, HOMES)
    action = np.array([1.0, -1.0, 1.0, -1.0, 0.0, 0.0, -1.0, 1.0])
    traj = planner.replan(action, 2.0)
    # Via points: home, home + (0.2, -0.1, 0.2), then + (-0.2, 0.0, 0.0); times 2.0, 2.1, 2.6.
    ends = [HOMES[0] + [0.2, -0.1, 0.2], HOMES[0] + [0.0, -0.1, 0.2]]
    np.testing.assert_allclose(traj.points, [HOMES[0], *ends], atol=1e-12)
    np.testing.assert_allclose(traj.times, [2.0, 2.1, 2.6], atol=1e-12)
    np.testing.assert_array_equal(traj.start_velocity, np.zeros(3))
    p, v = planner.references(np.array([2.0, 2.1, 2.6, 3.0]))
    np.testing.assert_allclose(p[:, 0], [HOMES[0], HOMES[0] + [0.2, -0.1, 0.2], HOMES[0] + [0.0, -0.1, 0.2],
                                         HOMES[0] + [0.0, -0.1, 0.2]], atol=1e-12)
    # The second gripper: the same x-z motion, the lateral motion mirrored (it moves +0.1 m in y).
    np.testing.assert_allclose(p[:, 1], [HOMES[1], HOMES[1] + [0.2, 0.1, 0.2], HOMES[1] + [0.0, 0.1, 0.2],
                                         HOMES[1] + [0.0, 0.1, 0.2]], atol=1e-12)
    np.testing.assert_array_equal(v[[0, 3]], 0.0)  # at rest at the start and after the end


def _moving_planner(seed: int, replans: int = 3, period: float = 0.04) -> tuple[Replanner, float]:
    rng = np.random.default_rng(seed)
    planner = Replanner(SPEC, HOMES)
    t = 0.0
    for _ in range(replans):
        planner.replan(rng.uniform(-1, 1, SPEC.size), t)
        t += period
    return planner, t


@pytest.mark.parametrize("seed", range(5))
def test_the_second_gripper_mirrors_the_first_in_position_and_velocity(seed: int) -> None:
    planner, t_now = _moving_planner(seed)
    times = t_now + np.linspace(-0.02, 0.5, 60)
    p, v = planner.references(times)
    # Position: displacement from home mirrored in y.
    np.testing.assert_allclose(p[:, 1] - HOMES[1], (p[:, 0] - HOMES[0]) * MIRROR_Y, atol=1e-12)
    # Velocity: mirrored the same way, so the grippers stay mirror images: y velocities opposite.
    np.testing.assert_allclose(v[:, 1], v[:, 0] * MIRROR_Y, atol=1e-12)
    assert np.max(np.abs(v[:, 0, 1])) > 0.05  # the plan does move sideways, or the check would be empty
    np.testing.assert_allclose(v[:, 0, 1] + v[:, 1, 1], 0.0, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_each_grippers_velocity_reference_is_the_derivative_of_its_position_reference(seed: int) -> None:
    """What a servo tracking both references needs: velocity feed-forward consistent with the positions.

    A second gripper driven with the first's y velocity but its own mirrored y position is pushed one way by
    the feed-forward and pulled the other way by the position error.
    """
    planner, t_now = _moving_planner(seed)
    h = 1e-6
    times = t_now + np.linspace(0.001, 0.4, 40)
    p_plus, _ = planner.references(times + h)
    p_minus, _ = planner.references(times - h)
    _, v = planner.references(times)
    numeric = (p_plus - p_minus) / (2 * h)
    np.testing.assert_allclose(v, numeric, atol=1e-4)


@pytest.mark.parametrize("seed", range(5))
def test_a_replan_keeps_the_commanded_position_and_velocity(seed: int) -> None:
    """C1 across re-plans: the new plan starts at the old plan's position and velocity at the re-plan time,
    for both grippers."""
    rng = np.random.default_rng(100 + seed)
    planner = Replanner(SPEC, HOMES)
    t = 0.0
    planner.replan(rng.uniform(-1, 1, SPEC.size), t)
    for _ in range(4):
        t += 0.04
        p_old, v_old = planner.references(np.array([t]))
        assert np.linalg.norm(v_old[0, 0]) > 1e-3  # moving: a re-plan from rest would prove nothing
        traj = planner.replan(rng.uniform(-1, 1, SPEC.size), t)
        assert traj.t_start == t
        np.testing.assert_allclose(traj.start_velocity, v_old[0, 0], atol=1e-12)
        p_new, v_new = planner.references(np.array([t, t + 1e-7]))
        np.testing.assert_allclose(p_new[0], p_old[0], atol=1e-12)
        np.testing.assert_allclose(v_new[0], v_old[0], atol=1e-12)
        # Just after the re-plan the motion goes on smoothly (no velocity jump).
        np.testing.assert_allclose(v_new[1], v_old[0], atol=1e-3)


def test_the_commanded_state_is_the_plans_state_at_that_time() -> None:
    planner, _ = _moving_planner(7, replans=1)
    traj = planner.trajectory
    assert isinstance(traj, BSplineTrajectory)
    for t in (0.0, 0.05, 0.17, 5.0):
        p, v = planner.commanded_state(t)
        np.testing.assert_array_equal(p, traj.position(t))
        np.testing.assert_array_equal(v, traj.velocity(t))


def test_the_final_point_ends_every_plan_and_reset_forgets_the_plan() -> None:
    spec = ActionSpec(num_points=1, planar=True, dx_m=(-0.1, 0.1), dz_m=(-0.1, 0.1), dt_s=(0.1, 0.3),
                      append_final_point=True)
    goal = np.array([0.3, 0.0, 1.1])
    planner = Replanner(spec, HOMES[:1], final_point=goal)
    traj = planner.replan(np.zeros(spec.size), 0.0)
    np.testing.assert_allclose(traj.points[-1], goal)
    np.testing.assert_allclose(traj.times, [0.0, 0.2, 0.4])
    p, _ = planner.references(np.array([0.4, 1.0]))
    np.testing.assert_allclose(p[:, 0], [goal, goal], atol=1e-12)
    other = np.array([0.5, 0.0, 0.6])
    planner.reset(other)
    assert planner.trajectory is None
    np.testing.assert_array_equal(planner.final_point, other)
    np.testing.assert_allclose(planner.replan(np.zeros(spec.size), 0.0).points[-1], other)
    planner.reset()
    assert planner.final_point is None and planner.trajectory is None
    with pytest.raises(ValueError, match="requires a final_point"):
        planner.replan(np.zeros(spec.size), 0.0)


def test_bad_homes_and_actions_are_refused_with_their_shapes() -> None:
    with pytest.raises(ValueError, match=r"gripper_home must have shape \(n_g, 3\), got \(3,\)"):
        Replanner(SPEC, HOMES[0])
    with pytest.raises(ValueError, match=r"gripper_home must have shape \(n_g, 3\), got \(2, 2\)"):
        Replanner(SPEC, HOMES[:, :2])
    planner = Replanner(SPEC, HOMES)
    with pytest.raises(ValueError, match=r"action must have shape \(8,\), got shape \(7,\)"):
        planner.replan(np.zeros(7), 0.0)
    assert planner.trajectory is None  # nothing was planned


def test_references_are_floats_for_a_home_given_in_whole_metres() -> None:
    """Setpoints go to drivers and the simulator as float arrays, before the first plan too."""
    planner = Replanner(SPEC, [[0, 0, 1], [0, 1, 1]])
    p, v = planner.references(np.array([0.0]))
    assert p.dtype == v.dtype == np.float64
    np.testing.assert_array_equal(p[0], [[0.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    p0, _ = planner.commanded_state(0.0)
    assert p0.dtype == np.float64
