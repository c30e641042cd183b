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
    IKOptions,
    JointLimitError,
    _rotation_log,
    abb_gofa_crb15000,
    check_joint_limits,
    pose_matrix,
    rotation_x,
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
    finite = r"^base_in_world translation must be finite, got \[0\.0, inf, 0\.0\]$"
    with pytest.raises(ValueError, match=finite):
        ArmKinematics(arm, base_in_world=bad_t)
    with pytest.raises(ValueError, match=r"^base_in_world rotation is not a rotation matrix"):
        ArmKinematics(arm, base_in_world=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match=r"^tool_rotation must be a finite 3x3"):
        ArmKinematics(arm, tool_rotation=np.eye(2))
    tool = pose_matrix((0.0, 0.0, 0.05))
    np.testing.assert_array_equal(ArmKinematics(arm, tcp_in_flange=tool).tcp_in_flange, tool)
    # Integer matrices are taken as floats.
    whole = ArmKinematics(arm, np.eye(4, dtype=int), np.eye(4, dtype=int), np.diag([1, -1, -1]))
    assert whole.base_in_world.dtype == whole.tcp_in_flange.dtype == whole.tool_rotation.dtype == np.float64
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


# --------------------------------------------------------------------------------- rotation log near pi
def test_rotation_log_just_below_pi_keeps_the_axis_direction() -> None:
    """Below pi the rotation vector is unique: angle times the axis it turns about, whichever sign the axis's
    largest component has (near pi the axis comes from R + I, whose columns carry no sign)."""
    for axis in ([0.0, 0.0, -1.0], [-0.48, 0.6, -0.64], [0.6, -0.8, 0.0], [0.48, -0.6, 0.64]):
        for angle in (math.pi - 1e-8, math.pi - 4e-8, math.pi - 1e-6, math.pi - 1e-3):
            rv = _rotation_log(_axis_angle(tuple(axis), angle))
            np.testing.assert_allclose(rv, angle * np.array(axis), atol=1e-7)
    # Mixed in a batch with a rotation far from pi: each keeps its own direction.
    batch = np.stack([_axis_angle((0.0, 0.0, -1.0), math.pi - 1e-8), rotation_z(0.5)])
    np.testing.assert_allclose(_rotation_log(batch), [[0, 0, -(math.pi - 1e-8)], [0, 0, 0.5]], atol=1e-7)


# ------------------------------------------------------------------------------------ arm model, ik
def test_arm_model_refuses_a_seed_below_a_lower_limit() -> None:
    gofa = abb_gofa_crb15000()
    for j in range(6):
        seed = list(gofa.seed_rad)
        seed[j] = gofa.lower_rad[j] - 0.01
        with pytest.raises(ValueError, match=r"seed_rad .* is outside the joint limits"):
            ArmModel(**{**gofa.__dict__, "seed_rad": tuple(seed)})


@pytest.mark.parametrize("make_arm", ARMS)
def test_ik_seeded_at_a_solution_returns_it_without_iterating(make_arm) -> None:
    kin = ArmKinematics(make_arm())
    for q in _well_conditioned(kin, np.random.default_rng(11), 5):
        position, rotation = kin.fk(q)
        res = kin.ik(position, q, rotation)
        assert (res.iterations, res.converged) == (0, True)
        np.testing.assert_array_equal(res.q, q)
        assert res.position_error_m <= 1e-12 and res.rotation_error_rad <= 1e-12


def test_ik_stops_as_soon_as_both_errors_are_within_their_tolerances() -> None:
    options = IKOptions(position_tolerance_m=1e-3, rotation_tolerance_rad=1e-2)
    kin = ArmKinematics(abb_gofa_crb15000(), options=options)
    q = np.array([0.1, 0.2, -0.3, 0.4, 1.2, -0.5])
    p, r = kin.fk(q)
    # Within both tolerances from the start: the seed is the answer (errors 0.5 mm, 5 mrad about world x).
    for target, rotation, e_pos, e_rot in (
        (p + [5e-4, 0.0, 0.0], r, 5e-4, 0.0),
        (p, rotation_x(5e-3) @ r, 0.0, 5e-3),
        (p + [0.0, 3e-4, -4e-4], rotation_x(-3e-3) @ rotation_y(4e-3) @ r, 5e-4, 5e-3),
    ):
        res = kin.ik(target, q, rotation)
        assert (res.iterations, res.converged) == (0, True)
        np.testing.assert_array_equal(res.q, q)
        assert res.position_error_m == pytest.approx(e_pos, rel=1e-6, abs=1e-15)
        assert res.rotation_error_rad == pytest.approx(e_rot, rel=1e-3, abs=1e-15)
    # Beyond either tolerance (2 mm; 20 mrad about x): it iterates, until within both.
    for target, rotation in ((p + [2e-3, 0.0, 0.0], r), (p, rotation_x(2e-2) @ r), (p, rotation_y(2e-2) @ r)):
        res = kin.ik(target, q, rotation)
        assert res.iterations >= 1 and res.converged
        assert res.position_error_m <= 1e-3 and res.rotation_error_rad <= 1e-2


def _pose_errors(kin: ArmKinematics, q: np.ndarray, position, rotation) -> tuple[float, float]:
    """TCP position error (m) and rotation angle (rad) of joints q from a target, by FK and the trace."""
    p, r = kin.fk(q)
    cos = (np.trace(np.asarray(rotation) @ r.T) - 1.0) / 2.0
    return float(np.linalg.norm(np.asarray(position) - p)), math.acos(min(1.0, max(-1.0, cos)))


def test_ik_reports_its_iterations_and_remaining_errors_when_it_runs_out_of_iterations() -> None:
    arm = abb_gofa_crb15000()
    target = [0.4, -0.3, 0.6]  # 5 iterations from the arm's seed
    assert ArmKinematics(arm).ik(target).iterations > 3
    kin = ArmKinematics(arm, options=IKOptions(max_iterations=3))
    res = kin.ik(target)
    assert (res.iterations, res.converged) == (3, False)
    e_pos, e_rot = _pose_errors(kin, res.q, target, TOOL_DOWN)
    assert res.position_error_m == pytest.approx(e_pos, rel=1e-9)
    assert res.rotation_error_rad == pytest.approx(e_rot, rel=1e-6)
    assert e_pos > 1e-9 and e_rot > 1e-8
    # Converged means both errors within their tolerances: a position within 1 m is not enough ...
    tilted = rotation_z(0.2) @ rotation_y(0.3) @ TOOL_DOWN
    loose = ArmKinematics(arm, options=IKOptions(position_tolerance_m=1.0, max_iterations=1))
    res = loose.ik(target, rotation=tilted)
    assert res.iterations == 1 and res.position_error_m < 1.0 and res.rotation_error_rad > 1e-8
    assert not res.converged
    # ... and neither is an orientation within 1 rad with the position off.
    still = ArmKinematics(arm, options=IKOptions(rotation_tolerance_rad=1.0, max_iterations=1))
    res = still.ik(target, rotation=tilted)
    assert res.iterations == 1 and res.rotation_error_rad < 1.0 and res.position_error_m > 1e-9
    assert not res.converged


def test_ik_out_of_reach_returns_the_best_compromise_of_the_weighted_errors() -> None:
    """An unreachable target: the configuration returned minimises |position error|^2 + (w * angle)^2,
    w = rotation_weight_m (metres worth one radian): its finite-difference gradient vanishes."""
    arm = abb_gofa_crb15000()
    for weight, target in ((0.2, [1.2, 0.9, 0.8]), (0.2, [2.0, 0.0, 0.6]), (0.5, [0.3, 1.5, 0.3])):
        kin = ArmKinematics(arm, options=IKOptions(rotation_weight_m=weight))
        res = kin.ik(target)
        assert not res.converged

        def cost(q: np.ndarray, kin=kin, target=target, weight=weight) -> float:
            e_pos, e_rot = _pose_errors(kin, q, target, TOOL_DOWN)
            return e_pos**2 + (weight * e_rot) ** 2

        h = 1e-6
        grad = [(cost(res.q + h * e) - cost(res.q - h * e)) / (2 * h) for e in np.eye(6)]
        assert np.all(res.q > kin.lower) and np.all(res.q < kin.upper)  # an interior minimum
        np.testing.assert_allclose(grad, 0.0, atol=1e-6)
        assert cost(res.q) == pytest.approx(res.position_error_m**2 + (weight * res.rotation_error_rad) ** 2)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_ik_never_leaves_the_joint_limits(sign: float) -> None:
    """Axis 6 of the GoFa turns +-180 deg. A target whose nearest solution lies past that limit: the joint
    stays at it (no solution within the limits nearby). A seed 360 deg beyond the limit, at a solution: it is
    clipped first, and the IK turns the joint back to the same pose within the limits."""
    kin = ArmKinematics(abb_gofa_crb15000())
    q = np.array([0.1, 0.2, -0.3, 0.4, 1.2, sign * math.pi])
    beyond = q + [0, 0, 0, 0, 0, sign * 0.1]
    res = kin.ik(*kin.fk(beyond)[:1], seed=q, rotation=kin.fk(beyond)[1])
    assert not res.converged
    assert np.all(res.q >= kin.lower) and np.all(res.q <= kin.upper)
    assert res.q[5] == sign * math.pi
    inside = q.copy()
    inside[5] = sign * 2.0
    position, rotation = kin.fk(inside)
    res = kin.ik(position, inside + [0, 0, 0, 0, 0, sign * 2 * math.pi], rotation)
    assert res.converged
    np.testing.assert_allclose(res.q, inside, atol=1e-9)


@pytest.mark.parametrize("make_arm", ARMS)
def test_ik_with_heavier_damping_still_converges_only_slower(make_arm) -> None:
    plain = ArmKinematics(make_arm())
    damped = ArmKinematics(make_arm(), options=IKOptions(damping_bias=1e-2))
    for target in (TCP_HOME_M, [0.5, 0.3, 0.3], [0.4, -0.3, 0.6]):
        fast, slow = plain.ik(target), damped.ik(target)
        assert fast.converged and slow.converged
        assert slow.iterations > fast.iterations
        np.testing.assert_allclose(damped.fk(slow.q)[0], target, atol=1e-9)


# ------------------------------------------------------------------------------------- joint trajectory
def test_joint_trajectory_refuses_bad_times_and_positions() -> None:
    kin = ArmKinematics(ur5e())
    home = np.array(TCP_HOME_M)
    shapes = r"^need t \(N,\) and positions \(N, 3\), got shapes "
    for t, positions, message in (
        (np.zeros((2, 1)), np.tile(home, (2, 1)), shapes + r"\(2, 1\) and \(2, 3\)$"),
        (np.zeros(0), np.zeros((0, 3)), shapes + r"\(0,\) and \(0, 3\)$"),
        (np.arange(3.0), np.tile(home, (2, 1)), shapes + r"\(3,\) and \(2, 3\)$"),
        (np.arange(2.0), np.zeros((2, 2)), shapes + r"\(2,\) and \(2, 2\)$"),
        ([0.0, np.nan], np.tile(home, (2, 1)), r"^t and positions must be finite$"),
        ([0.0, 0.1], [home, [0.4, np.inf, 0.5]], r"^t and positions must be finite$"),
        ([0.0, 0.0], np.tile(home, (2, 1)), r"^t must be strictly increasing$"),
        ([0.0, 0.1, 0.05], np.tile(home, (3, 1)), r"^t must be strictly increasing$"),
    ):
        with pytest.raises(ValueError, match=message):
            kin.joint_trajectory(t, positions)


def test_joint_trajectory_of_one_sample_and_of_integer_times() -> None:
    kin = ArmKinematics(abb_gofa_crb15000())
    one = kin.joint_trajectory([0.5], [TCP_HOME_M])
    np.testing.assert_allclose(kin.fk(one.q)[0], [TCP_HOME_M], atol=1e-9)
    slow = kin.joint_trajectory([0, 1, 2], [TCP_HOME_M, np.add(TCP_HOME_M, 0.01), np.add(TCP_HOME_M, 0.02)])
    assert slow.t.dtype == np.float64 and slow.t.tolist() == [0.0, 1.0, 2.0]


def test_joint_trajectory_keeps_the_seeds_configuration() -> None:
    """The GoFa reaches its TCP home also with the wrist flipped (axis 5 negated, axes 4 and 6 half a turn
    round): seeded there, the whole trajectory stays in that configuration."""
    kin = ArmKinematics(abb_gofa_crb15000())
    home = kin.ik(TCP_HOME_M).q
    guess = home + [0.0, 0.0, 0.0, math.pi, 0.0, math.pi]
    guess[4] = -home[4]
    guess[[3, 5]] = (guess[[3, 5]] + math.pi) % (2 * math.pi) - math.pi
    res = kin.ik(TCP_HOME_M, guess)
    assert res.converged
    flipped = res.q
    assert abs(flipped[4] + home[4]) < 0.2 and abs(abs(flipped[3] - home[3]) - math.pi) < 0.2
    t = np.linspace(0.0, 0.5, 26)
    path = np.array(TCP_HOME_M) + np.outer(t, [0.1, 0.1, -0.1])
    traj = kin.joint_trajectory(t, path, flipped)
    np.testing.assert_allclose(traj.q[0], flipped, atol=1e-6)
    assert np.max(np.abs(np.diff(traj.q, axis=0))) < 0.05
    assert np.all(np.sign(traj.q[:, 4]) == np.sign(flipped[4]))
    np.testing.assert_allclose(kin.fk(traj.q)[0], path, atol=1e-9)


def test_joint_trajectory_solves_one_sample_per_coarse_step_in_sequence(monkeypatch) -> None:
    """The samples solved one after the other are the first, the last and the first at or after each multiple
    of coarse_step_s from the start; the first starts from the seed, the second from the first's solution,
    each later one from the straight-line extrapolation of the two before it (uneven steps here)."""
    kin = ArmKinematics(abb_gofa_crb15000(), options=IKOptions(coarse_step_s=1 / 16))
    offsets = np.array([0, 1, 2, 4, 5, 7, 9, 10, 12, 15, 16, 17, 21])
    t = 1.0 + offsets / 32  # exact binary fractions: no rounding at the coarse steps
    s = t - 1.0
    path = np.array(TCP_HOME_M) + np.stack([0.2 * s, 0.1 * np.sin(3 * s), -0.3 * s**2], 1)
    seed = kin.ik(path[0]).q
    calls = []
    solve_one = kin._solve_one

    def recording(q, p_des, r_des):
        res = solve_one(q, p_des, r_des)
        calls.append((q.copy(), p_des.copy(), res.q.copy()))
        return res

    monkeypatch.setattr(kin, "_solve_one", recording)
    traj = kin.joint_trajectory(t, path, seed)
    coarse = [0, 2, 3, 5, 6, 7, 8, 9, 10, 12]  # offsets 0, 2, 4, 7, 9, 10, 12, 15, 16 and 21 (for 18 and 20)
    assert len(calls) == len(coarse)
    for (_, p_des, q_sol), i in zip(calls, coarse, strict=True):
        np.testing.assert_array_equal(p_des, path[i])
        np.testing.assert_array_equal(traj.q[i], q_sol)
    np.testing.assert_array_equal(calls[0][0], seed)
    np.testing.assert_array_equal(calls[1][0], calls[0][2])
    for k in range(2, len(coarse)):
        i, i1, i2 = coarse[k], coarse[k - 1], coarse[k - 2]
        rate = (t[i] - t[i1]) / (t[i1] - t[i2])
        np.testing.assert_allclose(calls[k][0], calls[k - 1][2] + rate * (calls[k - 1][2] - calls[k - 2][2]),
                                   rtol=0, atol=1e-15)
    np.testing.assert_allclose(kin.fk(traj.q)[0], path, atol=1e-9)


def test_joint_trajectory_when_the_coarse_grid_rounds_past_the_last_time() -> None:
    """0.48 s + 40 steps of 4 ms: np.arange's last multiple of 40 ms from the start rounds past the last
    sample time; that is the last sample, not one after it."""
    kin = ArmKinematics(abb_gofa_crb15000())
    t = 0.48 + 0.004 * np.arange(41)
    assert np.arange(t[0], t[-1], 0.04)[-1] > t[-1]
    path = np.array(TCP_HOME_M) + np.outer(t - t[0], [0.1, 0.0, 0.0])
    traj = kin.joint_trajectory(t, path, kin.ik(path[0]).q)
    np.testing.assert_allclose(kin.fk(traj.q)[0], path, atol=1e-9)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_joint_trajectory_refuses_a_path_that_takes_a_joint_past_its_limit(sign: float) -> None:
    """Axis 5 of the GoFa at constant speed through its limit (+-180 deg), axis 3 making up for it so that the
    tool keeps its orientation: the first sample past the limit has no solution within the limits, even
    though extrapolating the samples before it lands exactly on the joints past the limit."""
    arm = abb_gofa_crb15000()
    t = np.arange(8) * 0.0625
    limit = arm.upper_rad[4] if sign > 0 else arm.lower_rad[4]
    q = np.tile([0.0, 0.3, -0.2, 0.0, 0.0, 0.0], (t.size, 1))
    q[:, 4] = limit - sign * 0.3 + sign * 0.1 * np.arange(t.size)  # at the limit at 0.1875 s, past it after
    q[:, 2] -= q[:, 4] - q[0, 4]  # axes 2, 3 and 5 are parallel here: their sum sets the tool's pitch
    positions, rotations = ArmKinematics(arm).fk(q)
    np.testing.assert_allclose(rotations, np.broadcast_to(rotations[0], rotations.shape), atol=1e-12)
    options = IKOptions(position_tolerance_m=1e-6, rotation_tolerance_rad=1e-6, coarse_step_s=0.0625)
    kin = ArmKinematics(arm, tool_rotation=rotations[0], options=options)
    ok = kin.joint_trajectory(t[:4], positions[:4], q[0])
    np.testing.assert_allclose(ok.q, q[:4], atol=1e-6)
    with pytest.raises(IKError, match=r"no IK solution at t=0\.2500 s"):
        kin.joint_trajectory(t, positions, q[0])


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_joint_trajectory_from_a_seed_past_the_limits_starts_within_them(sign: float) -> None:
    """A seed with axis 6 a full turn beyond its limit is the same pose: the trajectory starts from the seed
    clipped to the limits and reaches that pose within them."""
    arm = abb_gofa_crb15000()
    inside = np.array([0.1, 0.2, -0.3, 0.4, 1.2, sign * 2.0])
    kin = ArmKinematics(arm, tool_rotation=ArmKinematics(arm).fk(inside)[1])
    t = np.linspace(0.0, 0.1, 6)
    path = kin.fk(inside)[0] + np.outer(t, [0.0, 0.0, 0.1])
    traj = kin.joint_trajectory(t, path, inside + [0, 0, 0, 0, 0, sign * 2 * math.pi])
    assert np.all(traj.q >= kin.lower) and np.all(traj.q <= kin.upper)
    np.testing.assert_allclose(traj.q[0], inside, atol=1e-9)


def test_joint_trajectory_names_a_single_unreachable_sample_between_the_coarse_ones() -> None:
    """One sample out of reach between two coarse ones at the TCP home: it is refined from the home joints
    (both neighbours' solution), and the error gives the residual of the best configuration found from there,
    the same as ik's, in millimetres and radians."""
    kin = ArmKinematics(abb_gofa_crb15000())
    home = kin.ik(TCP_HOME_M).q
    t = 0.004 * np.arange(21)
    path = np.tile(TCP_HOME_M, (21, 1))
    path[6] = [0.0, 2.00004, 0.6]  # 24 ms: not a coarse sample
    best = kin.ik(path[6], home)
    assert not best.converged and best.position_error_m > 0.5 and best.rotation_error_rad > 0.1
    residual = f"{best.position_error_m * 1e3:.3g} mm, {best.rotation_error_rad:.3g} rad"
    named = r"at t=0\.0240 s for TCP position \[0\.0, 2\.0, 0\.6\] m \(residual "
    named += residual.replace(".", r"\.")
    with pytest.raises(IKError, match=named):
        kin.joint_trajectory(t, path, home)


@pytest.mark.parametrize("make_arm", ARMS)
def test_the_batched_refinement_takes_the_same_steps_as_the_single_solver(make_arm) -> None:
    """The samples between the coarse ones are refined all at once: each problem of the batch goes through
    the same iterations as it would alone (same joints, errors and iteration count), whatever the others do:
    converged from the start, converging at different iterations, out of reach, or stopped at a limit."""
    arm = make_arm()
    kin = ArmKinematics(arm)
    rng = np.random.default_rng(12)
    q_star = np.stack(_well_conditioned(kin, rng, 6))
    p, r = kin.fk(q_star)
    seeds = np.clip(q_star + rng.uniform(-0.4, 0.4, q_star.shape), kin.lower, kin.upper)
    seeds[0] = q_star[0]  # at the solution already
    p[1] += [4e-4, 0.0, 0.0]  # within 1 mm of the seed ...
    seeds[1] = q_star[1]
    r[2] = rotation_x(4e-3) @ r[2]  # ... within 10 mrad
    seeds[2] = q_star[2]
    p[3] = [2.0, 0.5, 0.6]  # out of reach
    seeds[5, 5] = kin.upper[5]  # at a limit, and the solution a little past it
    q_star[5, 5] = kin.upper[5]
    p[5], r[5] = kin.fk(q_star[5] + [0, 0, 0, 0, 0, 0.1])
    for options in (IKOptions(), IKOptions(position_tolerance_m=1e-3, rotation_tolerance_rad=1e-2),
                    IKOptions(max_iterations=4), IKOptions(damping_bias=1e-2, rotation_weight_m=0.5)):
        kin = ArmKinematics(arm, options=options)
        for rotations in (r, TOOL_DOWN):
            q, err, used = kin._solve(seeds.copy(), p, rotations, options.max_iterations)
            assert q.shape == (6, 6) and err.shape == (6, 6)
            for i in range(6):
                one = kin._solve_one(seeds[i], p[i], rotations if rotations.ndim == 2 else rotations[i])
                assert used[i] == one.iterations, (options, i)
                # Not converged after 100 iterations in a flat valley: rounding drifts further, still small.
                close = 1e-9 if one.converged else 1e-3
                np.testing.assert_allclose(q[i], one.q, rtol=0, atol=close)
                e_pos, e_rot = np.linalg.norm(err[i, :3]), np.linalg.norm(err[i, 3:])
                assert e_pos == pytest.approx(one.position_error_m, rel=10 * close, abs=1e-15)
                assert e_rot == pytest.approx(one.rotation_error_rad, rel=10 * close, abs=1e-15)
            assert np.all(q >= kin.lower) and np.all(q <= kin.upper)
            converged = (np.linalg.norm(err[:, :3], axis=1) <= options.position_tolerance_m) & (
                np.linalg.norm(err[:, 3:], axis=1) <= options.rotation_tolerance_rad
            )
            assert not converged[3]
            if options.position_tolerance_m == 1e-3 and rotations is r:
                assert used[:3].tolist() == [0, 0, 0]  # within the tolerances from the start: untouched
                np.testing.assert_array_equal(q[:3], seeds[:3])
