"""Tests for dyndlo_vision.robots.kinematics: DH tables, FK/IK, Jacobian, joint trajectories, limit check."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dyndlo_vision.robots.kinematics import (
    TOOL_DOWN,
    TOOL_FORWARD,
    ArmKinematics,
    ArmModel,
    DHLink,
    IKError,
    JointLimitError,
    _rotation_log,
    abb_gofa_crb15000,
    check_joint_limits,
    pose_matrix,
    rotation_y,
    rotation_z,
    ur5e,
)
from dyndlo_vision.tasks.rewards import OUTREACH_M, SHOULDER_M, SHOULDER_POSITION_M, V_MAX_M_S
from dyndlo_vision.tasks.tip_control import TCP_HOME_M

ARMS = [abb_gofa_crb15000, ur5e]


def _axis_angle(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    k = np.array(axis, dtype=float)
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew


def _ros_industrial_gofa_tool0(q: np.ndarray) -> np.ndarray:
    """tool0 of ABB's ROS-Industrial crb15000_5_95 description: joint origins and axes, not DH."""
    joints = [
        ((0, 0, 0.265), (0, 0, 1)),
        ((0, 0, 0), (0, 1, 0)),
        ((0, 0, 0.444), (0, 1, 0)),
        ((0, 0, 0.110), (1, 0, 0)),
        ((0.470, 0, 0), (0, 1, 0)),
        ((0.101, 0, 0.080), (1, 0, 0)),
    ]
    t = np.eye(4)
    for (origin, axis), angle in zip(joints, q, strict=True):
        t = t @ pose_matrix(origin) @ pose_matrix(rotation=_axis_angle(axis, angle))
    return t @ pose_matrix(rotation=rotation_y(math.pi / 2))  # flange -> tool0


def _well_conditioned(kin: ArmKinematics, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    lo, hi = np.maximum(kin.lower, -math.pi), np.minimum(kin.upper, math.pi)
    out = []
    while len(out) < n:
        q = rng.uniform(lo, hi)
        if np.linalg.cond(kin.jacobian(q)) < 100.0:  # away from singularities
            out.append(q)
    return out


def test_gofa_dh_matches_ros_industrial_description() -> None:
    kin = ArmKinematics(abb_gofa_crb15000())
    rng = np.random.default_rng(0)
    for q in rng.uniform(-math.pi, math.pi, size=(50, 6)):
        np.testing.assert_allclose(kin.fk_matrix(q), _ros_industrial_gofa_tool0(q), atol=1e-12)
    # Shoulder (axis 2) at the height our simulated outreach check uses.
    axes_origins = kin._frames(np.zeros(6))[1]
    np.testing.assert_allclose(axes_origins[1], SHOULDER_POSITION_M, atol=1e-12)


def test_ur5e_zero_pose() -> None:
    position, rotation = ArmKinematics(ur5e()).fk(np.zeros(6))
    # All links stretched along -x: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    np.testing.assert_allclose(position, [-0.425 - 0.3922, -(0.1333 + 0.0996), 0.1625 - 0.0997], atol=1e-12)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("make_arm", ARMS)
def test_seed_reaches_task_home_with_tool_down(make_arm) -> None:
    kin = ArmKinematics(make_arm())
    res = kin.ik(TCP_HOME_M)
    assert res.converged
    position, rotation = kin.fk(res.q)
    np.testing.assert_allclose(position, TCP_HOME_M, atol=1e-9)
    np.testing.assert_allclose(rotation, TOOL_DOWN, atol=1e-8)
    assert np.all(res.q >= kin.lower) and np.all(res.q <= kin.upper)


@pytest.mark.parametrize("make_arm", ARMS)
def test_fk_ik_round_trip_on_random_reachable_poses(make_arm) -> None:
    kin = ArmKinematics(make_arm())
    rng = np.random.default_rng(1)
    for q in _well_conditioned(kin, rng, 150):
        position, rotation = kin.fk(q)
        seed = np.clip(q + rng.uniform(-0.2, 0.2, 6), kin.lower, kin.upper)
        res = kin.ik(position, seed, rotation)
        assert res.converged, (q, res)
        p_back, r_back = kin.fk(res.q)
        assert np.linalg.norm(p_back - position) < 1e-6
        assert np.linalg.norm(_rotation_log(r_back @ rotation.T)) < 1e-6


def test_base_placement_and_tool_offset() -> None:
    arm = abb_gofa_crb15000()
    base = pose_matrix([0.3, -0.2, 0.05], rotation_z(0.7))
    tool = pose_matrix([0.0, 0.0, 0.12])
    placed = ArmKinematics(arm, base_in_world=base, tcp_in_flange=tool)
    plain = ArmKinematics(arm)
    q = np.array([0.2, -0.3, 0.4, 0.1, 1.2, -0.5])
    np.testing.assert_allclose(placed.fk_matrix(q), base @ plain.fk_matrix(q) @ tool, atol=1e-12)
    # The tool holds its world orientation whatever the base yaw.
    res = placed.ik([0.7, 0.1, 0.5], seed=arm.seed_rad)
    assert res.converged
    np.testing.assert_allclose(placed.fk(res.q)[1], TOOL_DOWN, atol=1e-8)


def test_forward_facing_tool_orientation() -> None:
    kin = ArmKinematics(abb_gofa_crb15000(), tool_rotation=TOOL_FORWARD)
    res = kin.ik(TCP_HOME_M, seed=np.zeros(6))
    assert res.converged
    np.testing.assert_allclose(kin.fk(res.q)[1][:, 2], [1.0, 0.0, 0.0], atol=1e-8)  # tool z along +x


@pytest.mark.parametrize("make_arm", ARMS)
def test_jacobian_matches_finite_differences(make_arm) -> None:
    kin = ArmKinematics(make_arm(), base_in_world=pose_matrix([0.1, 0.2, 0.3], rotation_z(0.4)))
    rng = np.random.default_rng(2)
    h = 1e-6
    for q in rng.uniform(-2.0, 2.0, size=(20, 6)):
        jac = kin.jacobian(q)
        _, r0 = kin.fk(q)
        for i in range(6):
            dq = np.zeros(6)
            dq[i] = h
            (p_plus, r_plus), (p_minus, r_minus) = kin.fk(q + dq), kin.fk(q - dq)
            np.testing.assert_allclose(jac[:3, i], (p_plus - p_minus) / (2 * h), atol=1e-8)
            omega = (_rotation_log(r_plus @ r0.T) - _rotation_log(r_minus @ r0.T)) / (2 * h)
            np.testing.assert_allclose(jac[3:, i], omega, atol=1e-8)
    # Batched evaluation gives the same Jacobians.
    qs = rng.uniform(-2.0, 2.0, size=(4, 6))
    np.testing.assert_allclose(kin.jacobian(qs), np.stack([kin.jacobian(q) for q in qs]), atol=1e-14)


def test_rotation_log_near_pi() -> None:
    for axis in ([1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.48, -0.6, 0.64]):
        for angle in (math.pi, math.pi - 1e-6, math.pi - 1e-8, 1e-9, 0.3):
            r = _axis_angle(tuple(axis), angle)
            rv = _rotation_log(r)
            np.testing.assert_allclose(
                _axis_angle(tuple(rv / np.linalg.norm(rv)), np.linalg.norm(rv)), r, atol=1e-7
            )


def test_joint_trajectory_follows_the_path_and_keeps_the_configuration() -> None:
    kin = ArmKinematics(abb_gofa_crb15000())
    t = np.linspace(0.0, 1.0, 251)
    home = np.array(TCP_HOME_M)
    path = home + np.stack(
        [0.15 * np.sin(2 * np.pi * t), np.zeros_like(t), 0.1 * (1 - np.cos(2 * np.pi * t))], 1
    )
    seed = kin.ik(home).q
    traj = kin.joint_trajectory(t, path, seed)
    p, r = kin.fk(traj.q)
    assert np.max(np.linalg.norm(p - path, axis=1)) < 1e-8
    assert np.max(np.abs(r - TOOL_DOWN)) < 1e-8
    # Seeded sample to sample: no configuration change, so joint steps stay small.
    assert np.max(np.abs(np.diff(traj.q, axis=0))) < 0.05


def test_joint_trajectory_names_the_unreachable_sample() -> None:
    kin = ArmKinematics(abb_gofa_crb15000())
    t = np.array([0.0, 0.1, 0.2])
    path = np.array([TCP_HOME_M, [0.6, 0.0, 0.6], [2.0, 0.0, 0.6]])
    with pytest.raises(IKError, match=r"t=0\.2000 s .*\[2\.0, 0\.0, 0\.6\]"):
        kin.joint_trajectory(t, path, kin.ik(TCP_HOME_M).q)


def test_limit_check_catches_joint_speed_when_the_tcp_limits_are_met() -> None:
    """The paper's vaulting failure: within the simulator's TCP limits, beyond the GoFa's joint limits."""
    arm = abb_gofa_crb15000()
    kin = ArmKinematics(arm)
    t = np.arange(0.0, 0.4 + 1e-9, 0.004)
    speed = 1.5  # m/s, below v_max = 1.8
    path = np.stack([np.full_like(t, 0.30), speed * (t - 0.2), np.full_like(t, 0.45)], 1)
    # Every TCP constraint of the simulated tasks holds along this path ...
    assert np.all(np.linalg.norm(path - np.array(SHOULDER_POSITION_M), axis=1) <= OUTREACH_M)
    assert np.all(np.linalg.norm(path[:, :2], axis=1) >= SHOULDER_M)
    traj = kin.joint_trajectory(t, path, kin.ik(path[0]).q)
    tcp_speed = np.linalg.norm(np.diff(kin.fk(traj.q)[0], axis=0), axis=1) / np.diff(t)
    assert np.max(tcp_speed) <= V_MAX_M_S
    # ... but axis 1 has to turn at speed / radius = 5 rad/s near y = 0, over its 125 deg/s.
    report = check_joint_limits(arm, traj.t, traj.q)
    assert not report.ok
    v = next(v for v in report.violations if v.joint == "axis_1" and v.quantity == "velocity")
    assert v.limit == pytest.approx(math.radians(125.0))
    assert abs(v.value) == pytest.approx(speed / 0.30, rel=0.02)
    assert v.t_s == pytest.approx(0.2, abs=0.01)
    with pytest.raises(
        JointLimitError, match=r"joint axis_1 velocity [+-]\d\.\d+ rad/s at t=0\.\d+ s .* 2\.182 rad/s"
    ):
        report.raise_if_violated()


def test_limit_check_accepts_a_slow_motion() -> None:
    arm = abb_gofa_crb15000()
    kin = ArmKinematics(arm)
    t = np.linspace(0.0, 2.0, 501)
    path = np.array(TCP_HOME_M) + np.outer(0.5 - 0.5 * np.cos(np.pi * t / 2.0), [0.1, 0.05, -0.1])
    traj = kin.joint_trajectory(t, path, kin.ik(TCP_HOME_M).q)
    report = check_joint_limits(arm, traj.t, traj.q)
    assert report.ok, str(report)
    report.raise_if_violated()


def test_limit_check_finite_differences_on_uneven_times() -> None:
    arm = ur5e()
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.001, 0.004, 60))  # the speed stays below its limit
    limit = arm.max_acceleration_rad_s2[2]
    for accel, broken in ((0.99 * limit, False), (1.01 * limit, True)):
        q = np.zeros((t.size, 6))
        q[:, 2] = 0.5 * accel * (t - t[0]) ** 2  # exact constant acceleration for the formula used
        report = check_joint_limits(arm, t, q)
        assert [(v.joint, v.quantity) for v in report.violations] == (
            [("elbow", "acceleration")] if broken else []
        )
        if broken:
            assert report.violations[0].value == pytest.approx(accel, rel=1e-9)
            assert report.violations[0].samples == t.size - 2


def test_limit_check_positions() -> None:
    arm = abb_gofa_crb15000()
    t = np.arange(5) * 1.0
    q = np.zeros((5, 6))
    q[:, 2] = [0.0, 0.5, 1.0, 1.6, 1.0]  # axis 3 upper limit 85 deg = 1.4835 rad
    report = check_joint_limits(arm, t, q)
    assert [(v.joint, v.quantity, v.t_s, v.value) for v in report.violations] == [
        ("axis_3", "position", 3.0, 1.6)
    ]
    assert report.violations[0].limit == pytest.approx(math.radians(85.0))


def test_limit_check_rejects_bad_input() -> None:
    arm = ur5e()
    with pytest.raises(ValueError, match="strictly increasing"):
        check_joint_limits(arm, [0.0, 0.0], np.zeros((2, 6)))
    with pytest.raises(ValueError, match=r"q \(N, 6\)"):
        check_joint_limits(arm, [0.0, 1.0], np.zeros((2, 5)))


def test_arm_model_validation_and_scaling() -> None:
    gofa = abb_gofa_crb15000()
    with pytest.raises(ValueError, match="6 DH rows"):
        ArmModel(**{**gofa.__dict__, "dh": gofa.dh[:5]})
    with pytest.raises(ValueError, match="lower_rad must be < upper_rad"):
        ArmModel(**{**gofa.__dict__, "lower_rad": gofa.upper_rad})
    with pytest.raises(ValueError, match="seed_rad"):
        ArmModel(**{**gofa.__dict__, "seed_rad": (4.0, 0, 0, 0, 0, 0)})
    slow = gofa.scaled_limits(velocity=0.5, acceleration=0.25)
    assert slow.max_velocity_rad_s[0] == pytest.approx(0.5 * gofa.max_velocity_rad_s[0])
    assert slow.max_acceleration_rad_s2[3] == pytest.approx(0.25 * gofa.max_acceleration_rad_s2[3])
    assert DHLink(0.1, 0.0, 0.2).theta_offset_rad == 0.0
    with pytest.raises(ValueError, match="rotation"):
        ArmKinematics(gofa, tool_rotation=np.ones((3, 3)))


@pytest.mark.parametrize("make_arm", ARMS)
def test_tcp_velocity_is_the_derivative_of_the_tcp_position(make_arm) -> None:
    kin = ArmKinematics(make_arm())
    rng = np.random.default_rng(5)
    for q in _well_conditioned(kin, rng, 5):
        qd = rng.normal(size=6)
        h = 1e-6
        numeric = (kin.fk(q + h * qd)[0] - kin.fk(q - h * qd)[0]) / (2 * h)
        np.testing.assert_allclose(kin.tcp_velocity(q, qd), numeric, atol=1e-7)
    qs = np.stack(_well_conditioned(kin, rng, 3))
    assert kin.tcp_velocity(qs, np.ones((3, 6))).shape == (3, 3)


def test_limit_reports_read_as_sentences_with_units() -> None:
    from dyndlo_vision.robots.kinematics import LimitReport, LimitViolation

    position = LimitViolation("axis_3", "position", 3.0, 1.6, 1.4835, 2.5, 2)
    velocity = LimitViolation("wrist_3", "velocity", 0.02, -4.7124, 3.1416, 0.004, 5)
    acceleration = LimitViolation("elbow", "acceleration", 0.1, 30.0, 15.0, 0.05, 12)
    assert str(position) == ("joint axis_3 position +1.6 rad at t=3.0000 s breaks the limit 1.484 rad "
                             "(first at t=2.5000 s, 2 samples over)")
    assert str(velocity).startswith("joint wrist_3 velocity -4.712 rad/s at t=0.0200 s breaks the limit")
    assert "limit 3.142 rad/s (first" in str(velocity)
    assert "+30 rad/s^2" in str(acceleration) and "limit 15 rad/s^2" in str(acceleration)
    assert str(LimitReport()) == "joint trajectory within all position, velocity and acceleration limits"
    report = LimitReport((position, velocity))
    assert str(report) == f"joint limits broken:\n  {position}\n  {velocity}"
    error = JointLimitError(report)
    assert str(error) == str(report) and error.report is report and error.at_join is False
    joined = JointLimitError(report, "\n  (a hint)", at_join=1)  # type: ignore[arg-type]
    assert str(joined).endswith("(a hint)") and joined.at_join is True


def test_scaled_limits_scale_only_what_is_asked() -> None:
    gofa = abb_gofa_crb15000()
    assert gofa.scaled_limits() == gofa
    slower = gofa.scaled_limits(velocity=0.5)
    assert slower.max_velocity_rad_s == tuple(0.5 * v for v in gofa.max_velocity_rad_s)
    assert slower.max_acceleration_rad_s2 == gofa.max_acceleration_rad_s2
    gentler = gofa.scaled_limits(acceleration=0.5)
    assert gentler.max_velocity_rad_s == gofa.max_velocity_rad_s
    for kwargs in ({"velocity": 0.0}, {"acceleration": 0.0}, {"velocity": -1.0, "acceleration": 1.0}):
        with pytest.raises(ValueError, match=r"^limit scale factors must be > 0, got velocity="):
            gofa.scaled_limits(**kwargs)


def test_an_unreachable_sample_between_the_coarse_ones_is_named() -> None:
    """Samples between the coarse ones (every 40 ms) are solved together afterwards: the first of them that
    has no solution is named in the error, with its time and position."""
    arm = abb_gofa_crb15000()
    kin = ArmKinematics(arm)
    t = 0.004 * np.arange(21)
    path = np.tile(TCP_HOME_M, (21, 1))
    path[[5, 7]] = [[2.0, 0.0, 0.6], [2.5, 0.0, 0.6]]  # 20 ms and 28 ms: neither is a coarse sample
    named = r"no IK solution at t=0\.0200 s for TCP position \[2\.0, 0\.0, 0\.6\] m \(residual [0-9.e+]+ mm, "
    with pytest.raises(IKError, match=named):
        kin.joint_trajectory(t, path, kin.ik(TCP_HOME_M).q)


def test_ik_refuses_a_non_finite_target_and_names_a_bad_orientation() -> None:
    kin = ArmKinematics(ur5e())
    with pytest.raises(ValueError, match=r"^position must be 3 finite numbers, got \[0\.4, nan, 0\.5\]$"):
        kin.ik([0.4, np.nan, 0.5])
    with pytest.raises(ValueError, match=r"^rotation must be a finite 3x3 rotation matrix"):
        kin.ik(TCP_HOME_M, rotation=np.eye(2))
    with pytest.raises(ValueError, match=r"^rotation is not a rotation matrix"):
        kin.ik(TCP_HOME_M, rotation=np.diag([1.0, 1.0, -1.0]))


def test_elementary_rotations_turn_the_axes_the_right_way() -> None:
    from dyndlo_vision.robots.kinematics import rotation_x

    quarter = math.pi / 2
    np.testing.assert_allclose(rotation_x(quarter) @ [0, 1, 0], [0, 0, 1], atol=1e-15)  # y -> z
    np.testing.assert_allclose(rotation_y(quarter) @ [0, 0, 1], [1, 0, 0], atol=1e-15)  # z -> x
    np.testing.assert_allclose(rotation_z(quarter) @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # x -> y
    np.testing.assert_allclose(rotation_x(0.3), [[1, 0, 0], [0, math.cos(0.3), -math.sin(0.3)],
                                                 [0, math.sin(0.3), math.cos(0.3)]])


def test_rotation_log_small_angles_and_batches() -> None:
    from dyndlo_vision.robots.kinematics import rotation_x

    axis = np.array([0.0, 0.6, 0.8])
    small = _axis_angle(tuple(axis), 4e-7)  # under the 1e-6 rad series branch
    np.testing.assert_allclose(_rotation_log(small), 4e-7 * axis, rtol=1e-6, atol=1e-15)
    batch = np.stack([np.stack([rotation_x(0.1), rotation_z(-0.2)]), np.stack([small, np.eye(3)])])
    out = _rotation_log(batch)
    assert out.shape == (2, 2, 3)
    np.testing.assert_allclose(out, [[[0.1, 0, 0], [0, 0, -0.2]], [4e-7 * axis, [0, 0, 0]]], atol=1e-12)
    # Both halves of a batch near pi: each gets its own axis.
    near = np.stack([rotation_x(math.pi), rotation_z(math.pi)])
    np.testing.assert_allclose(np.abs(_rotation_log(near)), [[math.pi, 0, 0], [0, 0, math.pi]], atol=1e-7)


def test_poses_and_rotations_are_checked_with_their_names() -> None:
    with pytest.raises(ValueError, match=r"^position must be 3 finite numbers, got \[0\.0, nan, 0\.0\]$"):
        pose_matrix([0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match=r"^rotation must be a finite 3x3 rotation matrix, got shape"):
        pose_matrix(rotation=np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match=r"^rotation is not a rotation matrix"):
        pose_matrix(rotation=np.eye(3) + 1e-3)
    arm = ur5e()
    bad_row = np.eye(4)
    bad_row[3, 0] = 0.5
    with pytest.raises(ValueError, match=r"^tcp_in_flange must be a 4x4 homogeneous transform"):
        ArmKinematics(arm, tcp_in_flange=bad_row)
    bad_t = np.eye(4)
    bad_t[1, 3] = np.inf
    with pytest.raises(ValueError, match=r"^base_in_world translation must be finite, got \[0\.0, inf"):
        ArmKinematics(arm, base_in_world=bad_t)
    with pytest.raises(ValueError, match=r"^base_in_world rotation is not a rotation matrix"):
        ArmKinematics(arm, base_in_world=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match=r"^tool_rotation must be a finite 3x3"):
        ArmKinematics(arm, tool_rotation=np.eye(2))
    tool = pose_matrix((0.0, 0.0, 0.05))
    np.testing.assert_array_equal(ArmKinematics(arm, tcp_in_flange=tool).tcp_in_flange, tool)
    with pytest.raises(ValueError, match=r"^joint positions must be finite with last dimension 6, got shape"):
        ArmKinematics(arm).fk([0.0, 0.0, np.nan, 0.0, 0.0, 0.0])


def test_arm_models_and_ik_options_are_checked() -> None:
    from dyndlo_vision.robots.kinematics import IKOptions

    gofa = abb_gofa_crb15000()
    for name in ("max_velocity_rad_s", "max_acceleration_rad_s2"):
        for bad in (0.0, np.inf):
            values = (bad,) + getattr(gofa, name)[1:]
            with pytest.raises(ValueError, match=rf"^ArmModel '.*': {name} must be positive and finite, got"):
                ArmModel(**{**gofa.__dict__, name: values})
    slow = (0.5,) + gofa.max_velocity_rad_s[1:]  # a joint under 1 rad/s is a valid limit
    assert ArmModel(**{**gofa.__dict__, "max_velocity_rad_s": slow}).max_velocity_rad_s[0] == 0.5
    with pytest.raises(ValueError, match=r"^ArmModel '.*': joint_names needs 6 entries, got \('a',\)$"):
        ArmModel(**{**gofa.__dict__, "joint_names": ("a",)})
    at_bounds = (gofa.lower_rad[0], 0.0, 0.0, 0.0, gofa.upper_rad[4], 0.0)
    assert ArmModel(**{**gofa.__dict__, "seed_rad": at_bounds}).seed_rad == at_bounds  # on a bound is within
    with pytest.raises(ValueError, match=r"^flange_rotation is not a rotation matrix"):
        ArmModel(**{**gofa.__dict__, "flange_rotation": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0))})
    for field in ("position_tolerance_m", "rotation_tolerance_rad", "rotation_weight_m", "coarse_step_s"):
        with pytest.raises(ValueError, match=rf"^IKOptions\.{field} must be > 0, got 0\.0$"):
            IKOptions(**{field: 0.0})
    assert IKOptions(damping_bias=0.0, max_iterations=1).max_iterations == 1
    with pytest.raises(ValueError, match=r"^IKOptions\.damping_bias must be >= 0, got -1e-09$"):
        IKOptions(damping_bias=-1e-9)
    with pytest.raises(ValueError, match=r"^IKOptions\.max_iterations must be >= 1, got 0$"):
        IKOptions(max_iterations=0)
