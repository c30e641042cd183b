"""Kinematics of a 6-axis arm for the real-robot drivers: FK, Jacobian, seeded IK, and the joint-limit check.

The paper's vaulting failure (Sec. V-B, task II) came from limits checked only at the TCP: a Cartesian plan
within the TCP speed limit asked the GoFa's joints for more than they can give. Here every Cartesian plan is
turned into a joint trajectory by inverse kinematics seeded with the previous sample (the paper uses TRAC-IK
seeded the same way) and its joint positions, velocities and accelerations are checked *before* anything is
sent to a robot.

Conventions:

* Arms are described by **standard (distal) Denavit-Hartenberg** parameters:
  ``T_{i-1,i} = Rz(q_i + theta_offset_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``. A fixed rotation then maps DH frame 6
  onto the maker's flange frame (ABB/ROS ``tool0``); an optional tool transform maps the flange onto the TCP.
* Joint angles in radians, lengths in metres, times in seconds. Rotations are 3x3 matrices, poses 4x4.
* The TCP keeps a fixed orientation in our tasks (the paper's TCP only translates); IK solves for the TCP
  position with the orientation held at ``tool_rotation`` (default :data:`TOOL_DOWN`, gripper pointing down,
  the cable hanging along the tool axis).

IK is damped least squares on the analytic geometric Jacobian (Levenberg-Marquardt with Sugihara's damping,
``lambda = E + lambda_bias``), joint positions projected onto their limits after every step. A whole Cartesian
trajectory is solved coarse-to-fine: samples every ``coarse_step_s`` are solved in sequence, each seeded with
the previous solution; the samples in between are seeded by interpolating those and refined all at once
(vectorised Newton steps). See ``ArmKinematics.joint_trajectory``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "TOOL_DOWN",
    "TOOL_FORWARD",
    "ArmKinematics",
    "ArmModel",
    "DHLink",
    "IKError",
    "IKOptions",
    "IKResult",
    "JointLimitError",
    "JointTrajectory",
    "LimitReport",
    "LimitViolation",
    "abb_gofa_crb15000",
    "check_joint_limits",
    "pose_matrix",
    "rotation_x",
    "rotation_y",
    "rotation_z",
    "ur5e",
]

FloatArray = NDArray[np.float64]


def rotation_x(angle_rad: float) -> FloatArray:
    """Rotation matrix about x."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(angle_rad: float) -> FloatArray:
    """Rotation matrix about y."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(angle_rad: float) -> FloatArray:
    """Rotation matrix about z."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# Tool orientations in the task's world frame (z up, x towards the cable's workspace).
TOOL_DOWN = rotation_y(math.pi)  # tool z points down, tool x backwards: ABB's usual [0, 0, 1, 0] quaternion
TOOL_FORWARD = rotation_y(math.pi / 2) @ rotation_z(math.pi)  # tool z along world +x, tool x down


def pose_matrix(position: ArrayLike = (0.0, 0.0, 0.0), rotation: ArrayLike | None = None) -> FloatArray:
    """4x4 homogeneous transform from a position (3,) and a rotation matrix (3, 3) (identity when None)."""
    p = np.asarray(position, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"position must be 3 finite numbers, got {np.asarray(position).tolist()}")
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    _check_rotation(r, "rotation")
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r, p
    return out


def _check_rotation(r: FloatArray, name: str) -> None:
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise ValueError(f"{name} must be a finite 3x3 rotation matrix, got shape {r.shape}")
    err = float(np.max(np.abs(r @ r.T - np.eye(3))))
    if err > 1e-6 or np.linalg.det(r) < 0.0:
        raise ValueError(
            f"{name} is not a rotation matrix (|R R^T - I| = {err:.2e}, det = {np.linalg.det(r):.3f})"
        )


def _check_pose(t: ArrayLike, name: str) -> FloatArray:
    t = np.asarray(t, dtype=float)
    if t.shape != (4, 4) or not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{name} must be a 4x4 homogeneous transform, got {t.tolist()}")
    _check_rotation(t[:3, :3], f"{name} rotation")
    if not np.all(np.isfinite(t[:3, 3])):
        raise ValueError(f"{name} translation must be finite, got {t[:3, 3].tolist()}")
    return t.copy()


@dataclass(frozen=True)
class DHLink:
    """One row of a standard DH table: ``Rz(q + theta_offset_rad) Tz(d_m) Tx(a_m) Rx(alpha_rad)``."""

    a_m: float
    alpha_rad: float
    d_m: float
    theta_offset_rad: float = 0.0


@dataclass(frozen=True)
class ArmModel:
    """A 6-axis arm: standard DH table, flange frame and joint limits (one entry per joint, base to wrist).

    Attributes:
        name: Maker and model.
        dh: Six standard DH rows.
        joint_names: Names used in limit reports.
        lower_rad, upper_rad: Joint position limits.
        max_velocity_rad_s: Joint speed limits (absolute value).
        max_acceleration_rad_s2: Joint acceleration limits (absolute value).
        flange_rotation: Rotation from DH frame 6 to the maker's flange (tool0) frame, row-major 3x3.
        seed_rad: A configuration with the tool pointing down in front of the robot, the usual IK seed.
        sources: Where the numbers come from (datasheet, manual) and which are assumptions.
    """

    name: str
    dh: tuple[DHLink, ...]
    joint_names: tuple[str, ...]
    lower_rad: tuple[float, ...]
    upper_rad: tuple[float, ...]
    max_velocity_rad_s: tuple[float, ...]
    max_acceleration_rad_s2: tuple[float, ...]
    flange_rotation: tuple[tuple[float, float, float], ...] = (
        (1.0, 0.0, 0.0),
        (0.0, 1.0, 0.0),
        (0.0, 0.0, 1.0),
    )
    seed_rad: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    sources: str = ""

    def __post_init__(self) -> None:
        if len(self.dh) != 6:
            raise ValueError(f"ArmModel {self.name!r}: expected 6 DH rows, got {len(self.dh)}")
        for name in (
            "joint_names",
            "lower_rad",
            "upper_rad",
            "max_velocity_rad_s",
            "max_acceleration_rad_s2",
            "seed_rad",
        ):
            if len(getattr(self, name)) != 6:
                raise ValueError(
                    f"ArmModel {self.name!r}: {name} needs 6 entries, got {getattr(self, name)!r}"
                )
        lo, hi = np.array(self.lower_rad), np.array(self.upper_rad)
        if not np.all(lo < hi):
            raise ValueError(f"ArmModel {self.name!r}: lower_rad must be < upper_rad, got {lo} and {hi}")
        for name in ("max_velocity_rad_s", "max_acceleration_rad_s2"):
            v = np.array(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(v) & (v > 0.0)):
                raise ValueError(
                    f"ArmModel {self.name!r}: {name} must be positive and finite, got {v.tolist()}"
                )
        seed = np.array(self.seed_rad)
        if np.any(seed < lo) or np.any(seed > hi):
            raise ValueError(f"ArmModel {self.name!r}: seed_rad {seed.tolist()} is outside the joint limits")
        _check_rotation(np.array(self.flange_rotation, dtype=float), "flange_rotation")

    def scaled_limits(self, velocity: float = 1.0, acceleration: float = 1.0) -> ArmModel:
        """A copy with the velocity and acceleration limits multiplied by these factors (a safety margin)."""
        if not (0.0 < velocity and 0.0 < acceleration):
            raise ValueError(
                f"limit scale factors must be > 0, got velocity={velocity}, acceleration={acceleration}"
            )
        return replace(
            self,
            max_velocity_rad_s=tuple(velocity * v for v in self.max_velocity_rad_s),
            max_acceleration_rad_s2=tuple(acceleration * a for a in self.max_acceleration_rad_s2),
        )


def abb_gofa_crb15000() -> ArmModel:
    """ABB GoFa CRB 15000-5/0.95, the paper's robot (Sec. V-B).

    DH rows derived from the joint origins of ABB's ROS-Industrial description (``abb_crb15000_support``,
    ``crb15000_5_95_macro.xacro``: shoulder 0.265 m above the base, upper arm 0.444 m, elbow offset 0.110 m,
    forearm 0.470 m, wrist offset 0.080 m, flange 0.101 m beyond axis 5); tests check the DH chain against
    that description. The wrist is not spherical (axes 4 and 6 are 0.080 m apart), hence the numerical IK.
    Joint ranges and speeds: the same file (axis 6 +-180 deg there; ABB's product specification
    3HAC077389-001, not consulted here, is the primary source). ABB does not publish axis accelerations: the
    values here are assumptions to be identified on the robot.
    """
    half_pi = math.pi / 2
    deg = math.pi / 180.0
    return ArmModel(
        name="ABB GoFa CRB 15000-5/0.95",
        dh=(
            DHLink(a_m=0.0, alpha_rad=-half_pi, d_m=0.265),
            DHLink(a_m=0.444, alpha_rad=0.0, d_m=0.0, theta_offset_rad=-half_pi),
            DHLink(a_m=0.110, alpha_rad=-half_pi, d_m=0.0),
            DHLink(a_m=0.0, alpha_rad=half_pi, d_m=0.470),
            DHLink(a_m=0.080, alpha_rad=-half_pi, d_m=0.0),
            DHLink(a_m=0.0, alpha_rad=0.0, d_m=0.101),
        ),
        joint_names=("axis_1", "axis_2", "axis_3", "axis_4", "axis_5", "axis_6"),
        lower_rad=tuple(d * deg for d in (-180.0, -180.0, -225.0, -180.0, -180.0, -180.0)),
        upper_rad=tuple(d * deg for d in (180.0, 180.0, 85.0, 180.0, 180.0, 180.0)),
        max_velocity_rad_s=tuple(d * deg for d in (125.0, 125.0, 140.0, 200.0, 200.0, 200.0)),
        max_acceleration_rad_s2=(10.0, 10.0, 15.0, 25.0, 25.0, 25.0),  # assumption, not published
        # DH frame 6 has z along the flange normal and x along world +z at zero; ABB's tool0 has x along -z.
        flange_rotation=((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
        seed_rad=(0.0, 0.0, 0.0, 0.0, half_pi, 0.0),
        sources="geometry, ranges, speeds: ROS-Industrial abb_crb15000_support crb15000_5_95_macro.xacro; "
        "accelerations: assumed",
    )


def ur5e() -> ArmModel:
    """Universal Robots UR5e.

    DH rows: Universal Robots, "DH parameters for calculations of kinematics and dynamics" (standard DH, UR5e:
    d1 0.1625, a2 -0.425, a3 -0.3922, d4 0.1333, d5 0.0997, d6 0.0996 m). Ranges and speeds: UR5e user manual
    (+-360 deg, 180 deg/s every joint) as in Universal_Robots_ROS2_Description config/ur5e/joint_limits.yaml,
    which restricts the elbow to +-180 deg (beyond it the shoulder is in the way). UR does not publish joint
    accelerations (that file's 180 deg/s^2 is a placeholder for MoveIt): the values here are assumptions.
    """
    half_pi = math.pi / 2
    two_pi = 2.0 * math.pi
    return ArmModel(
        name="Universal Robots UR5e",
        dh=(
            DHLink(a_m=0.0, alpha_rad=half_pi, d_m=0.1625),
            DHLink(a_m=-0.425, alpha_rad=0.0, d_m=0.0),
            DHLink(a_m=-0.3922, alpha_rad=0.0, d_m=0.0),
            DHLink(a_m=0.0, alpha_rad=half_pi, d_m=0.1333),
            DHLink(a_m=0.0, alpha_rad=-half_pi, d_m=0.0997),
            DHLink(a_m=0.0, alpha_rad=0.0, d_m=0.0996),
        ),
        joint_names=("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"),
        lower_rad=(-two_pi, -two_pi, -math.pi, -two_pi, -two_pi, -two_pi),
        upper_rad=(two_pi, two_pi, math.pi, two_pi, two_pi, two_pi),
        max_velocity_rad_s=(math.pi,) * 6,
        max_acceleration_rad_s2=(15.0, 15.0, 15.0, 25.0, 25.0, 25.0),  # assumption, not published
        # Arm reaching towards base +x (the UR's DH x axis points the other way), tool pointing down.
        seed_rad=(math.pi, -2.0, 2.0, -half_pi, -half_pi, half_pi),
        sources="DH: universal-robots.com DH parameter article (UR5e); ranges, speeds: UR5e user manual via "
        "Universal_Robots_ROS2_Description joint_limits.yaml; accelerations: assumed",
    )


@dataclass(frozen=True)
class IKOptions:
    """Settings of the damped least-squares IK.

    Attributes:
        position_tolerance_m: Converged when the TCP is this close to the target ...
        rotation_tolerance_rad: ... and its orientation this close (angle of the rotation error).
        max_iterations: Per solve (coarse samples) or per refinement (the vectorised pass).
        rotation_weight_m: Metres of position error worth one radian of orientation error.
        damping_bias: lambda_bias in Sugihara's damping ``lambda = E + lambda_bias`` (m^2).
        coarse_step_s: Spacing of the sequentially solved samples in ``joint_trajectory``. 40 ms gives the
            same joints as 20 ms, faster (docs/results.md, "Decided questions").
    """

    position_tolerance_m: float = 1e-9
    rotation_tolerance_rad: float = 1e-8
    max_iterations: int = 100
    rotation_weight_m: float = 0.2
    damping_bias: float = 1e-9
    coarse_step_s: float = 0.04

    def __post_init__(self) -> None:
        for name in ("position_tolerance_m", "rotation_tolerance_rad", "rotation_weight_m", "coarse_step_s"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"IKOptions.{name} must be > 0, got {getattr(self, name)}")
        if self.damping_bias < 0.0:
            raise ValueError(f"IKOptions.damping_bias must be >= 0, got {self.damping_bias}")
        if self.max_iterations < 1:
            raise ValueError(f"IKOptions.max_iterations must be >= 1, got {self.max_iterations}")


@dataclass(frozen=True)
class IKResult:
    """One IK solution: joints, remaining TCP position/orientation error, iterations, whether it converged."""

    q: FloatArray
    position_error_m: float
    rotation_error_rad: float
    iterations: int
    converged: bool


class IKError(ValueError):
    """Inverse kinematics found no solution within tolerance (out of reach, at a singularity or a limit)."""


@dataclass(frozen=True)
class JointTrajectory:
    """Joint positions at sample times. Attributes: ``t`` (N,) seconds, ``q`` (N, 6) radians."""

    t: FloatArray
    q: FloatArray


def _rotation_log(r: FloatArray) -> FloatArray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3), valid up to and including pi."""
    cos = 0.5 * (r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2] - 1.0)
    skew = r[..., _SKEW_ROW, _SKEW_COL] - r[..., _SKEW_COL, _SKEW_ROW]  # 2 sin(angle) * axis
    two_sin = np.sqrt(np.sum(skew * skew, axis=-1))
    angle = np.arctan2(0.5 * two_sin, cos)  # accurate near 0 and near pi, unlike arccos(cos)
    # angle / (2 sin angle), its series for small angles (np.maximum only keeps the unused branch finite).
    scale = np.where(angle > 1e-6, angle / np.maximum(two_sin, 1e-300), 0.5 + angle * angle / 12.0)
    out = skew * scale[..., None]
    near_pi = (two_sin < 1e-7) & (cos < 0.0)
    if np.any(near_pi):
        # The skew part vanishes at pi; the axis is then the dominant column of (R + I) / 2 = n n^T.
        flat_r, flat_out = r.reshape(-1, 3, 3), out.reshape(-1, 3).copy()
        flat_angle, flat_skew = angle.reshape(-1), skew.reshape(-1, 3)
        for i in np.flatnonzero(near_pi.reshape(-1)):
            m = 0.5 * (flat_r[i] + np.eye(3))
            k = int(np.argmax(np.diag(m)))
            axis = m[:, k] / math.sqrt(max(m[k, k], 1e-300))
            if axis @ flat_skew[i] < 0.0:
                axis = -axis
            flat_out[i] = axis * flat_angle[i]
        out = flat_out.reshape(out.shape)
    return out


_SKEW_ROW = np.array([2, 0, 1])
_SKEW_COL = np.array([1, 2, 0])


class ArmKinematics:
    """An arm placed in the task's world frame, holding its TCP at one orientation.

    Args:
        arm: The arm model.
        base_in_world: 4x4 pose of the robot base (DH frame 0) in the task's world frame; identity when None
            (our simulated tasks measure the outreach from a shoulder at (0, 0, 0.265), i.e. the GoFa's base
            at the world origin).
        tcp_in_flange: 4x4 pose of the TCP in the flange frame (the gripper); identity when None.
        tool_rotation: 3x3 orientation the TCP holds in the world frame during IK (:data:`TOOL_DOWN` if None).
        options: IK settings.
    """

    def __init__(
        self,
        arm: ArmModel,
        base_in_world: ArrayLike | None = None,
        tcp_in_flange: ArrayLike | None = None,
        tool_rotation: ArrayLike | None = None,
        options: IKOptions | None = None,
    ) -> None:
        self.arm = arm
        self.options = options or IKOptions()
        self.base_in_world = _check_pose(
            np.eye(4) if base_in_world is None else base_in_world, "base_in_world"
        )
        flange = pose_matrix(rotation=np.array(arm.flange_rotation, dtype=float))
        tcp = _check_pose(np.eye(4) if tcp_in_flange is None else tcp_in_flange, "tcp_in_flange")
        self.tcp_in_flange = tcp
        self._tip = flange @ tcp  # DH frame 6 -> TCP
        rot = TOOL_DOWN if tool_rotation is None else np.asarray(tool_rotation, dtype=float)
        _check_rotation(rot, "tool_rotation")
        self.tool_rotation = rot.copy()
        a = np.array([link.a_m for link in arm.dh])
        d = np.array([link.d_m for link in arm.dh])
        ca = np.array([math.cos(link.alpha_rad) for link in arm.dh])
        sa = np.array([math.sin(link.alpha_rad) for link in arm.dh])
        zero, one = np.zeros(6), np.ones(6)
        self._row_u = np.stack([one, zero, zero, a], -1)
        self._row_v = np.stack([zero, -ca, sa, zero], -1)
        self._rows_23 = np.stack([np.stack([zero, sa, ca, d], -1), np.stack([zero, zero, zero, one], -1)], -2)
        self._offset = np.array([link.theta_offset_rad for link in arm.dh])
        self.lower = np.array(arm.lower_rad)
        self.upper = np.array(arm.upper_rad)
        self._weight = np.array([1.0, 1.0, 1.0] + [self.options.rotation_weight_m**2] * 3)

    # ----------------------------------------------------------------------------------------------- FK
    def _frames(self, q: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """World-frame joint axes z_{i-1}, origins o_{i-1} (..., 6, 3), and the TCP pose (..., 4, 4)."""
        th = q + self._offset
        ct, st = np.cos(th)[..., None], np.sin(th)[..., None]
        links = np.empty((*q.shape, 4, 4))
        # Rows 0, 1 of Rz(th) Tz(d) Tx(a) Rx(alpha) are ct*U + st*V and st*U - ct*V; rows 2, 3 are constant.
        links[..., 0, :] = ct * self._row_u + st * self._row_v
        links[..., 1, :] = st * self._row_u - ct * self._row_v
        links[..., 2:, :] = self._rows_23
        batch = q.shape[:-1]
        axes = np.empty((*batch, 6, 3))
        origins = np.empty((*batch, 6, 3))
        t = np.broadcast_to(self.base_in_world, (*batch, 4, 4))
        for i in range(6):
            axes[..., i, :] = t[..., :3, 2]
            origins[..., i, :] = t[..., :3, 3]
            t = t @ links[..., i, :, :]
        return axes, origins, t @ self._tip

    def fk_matrix(self, q: ArrayLike) -> FloatArray:
        """TCP pose(s) in the world frame: (4, 4) for q of shape (6,), (N, 4, 4) for (N, 6)."""
        return self._frames(self._joints(q))[2]

    def fk(self, q: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """TCP position(s) (..., 3) and orientation(s) (..., 3, 3) in the world frame for joints (..., 6)."""
        t = self.fk_matrix(q)
        return t[..., :3, 3], t[..., :3, :3]

    def jacobian(self, q: ArrayLike) -> FloatArray:
        """Geometric Jacobian(s) (..., 6, 6) of the TCP, world frame, rows (v_x, v_y, v_z, w_x, w_y, w_z)."""
        axes, origins, tcp = self._frames(self._joints(q))
        return self._jacobian(axes, origins, tcp)

    @staticmethod
    def _jacobian(axes: FloatArray, origins: FloatArray, tcp: FloatArray) -> FloatArray:
        r = tcp[..., None, :3, 3] - origins
        z0, z1, z2 = axes[..., 0], axes[..., 1], axes[..., 2]
        r0, r1, r2 = r[..., 0], r[..., 1], r[..., 2]
        jac = np.empty((*axes.shape[:-2], 6, 6))
        jac[..., 0, :] = z1 * r2 - z2 * r1  # linear part: z_{i-1} x (p - o_{i-1})
        jac[..., 1, :] = z2 * r0 - z0 * r2
        jac[..., 2, :] = z0 * r1 - z1 * r0
        jac[..., 3:, :] = np.swapaxes(axes, -1, -2)
        return jac

    def tcp_velocity(self, q: ArrayLike, qd: ArrayLike) -> FloatArray:
        """Linear TCP velocity (..., 3) for joint positions and velocities (..., 6)."""
        j = self.jacobian(q)
        return np.einsum("...ij,...j->...i", j[..., :3, :], np.asarray(qd, dtype=float))

    def _joints(self, q: ArrayLike) -> FloatArray:
        a = np.asarray(q, dtype=float)
        if a.shape[-1:] != (6,) or not np.all(np.isfinite(a)):
            raise ValueError(f"joint positions must be finite with last dimension 6, got shape {a.shape}")
        return a

    # ----------------------------------------------------------------------------------------------- IK
    def _errors(self, q: FloatArray, p_des: FloatArray, r_des: FloatArray) -> tuple[FloatArray, ...]:
        axes, origins, tcp = self._frames(q)
        e_pos = p_des - tcp[..., :3, 3]
        e_rot = _rotation_log(r_des @ np.swapaxes(tcp[..., :3, :3], -1, -2))
        return np.concatenate([e_pos, e_rot], -1), self._jacobian(axes, origins, tcp)

    def _converged(self, err: FloatArray) -> NDArray[np.bool_]:
        o = self.options
        sq = err * err
        return (sq[..., :3].sum(-1) <= o.position_tolerance_m**2) & (
            sq[..., 3:].sum(-1) <= o.rotation_tolerance_rad**2
        )

    def _solve(
        self, q: FloatArray, p_des: FloatArray, r_des: FloatArray, iterations: int
    ) -> tuple[FloatArray, ...]:
        """Vectorised LM over N independent problems (q (N, 6), p_des (N, 3), r_des (3, 3) or (N, 3, 3)).

        Returns q, final errors (N, 6), iterations used (N,).
        """
        w = self._weight
        eye = np.eye(6)
        err, jac = self._errors(q, p_des, r_des)
        cost = np.einsum("ni,i,ni->n", err, w, err)
        bias = np.full(q.shape[0], self.options.damping_bias)
        used = np.zeros(q.shape[0], dtype=int)
        active = ~self._converged(err)
        for _ in range(iterations):
            if not np.any(active):
                break
            idx = np.flatnonzero(active)
            j, e = jac[idx], err[idx]
            jtw = np.swapaxes(j, -1, -2) * w[None, None, :]
            h = jtw @ j + (0.5 * cost[idx] + bias[idx])[:, None, None] * eye
            step = np.linalg.solve(h, np.einsum("nij,nj->ni", jtw, e)[..., None])[..., 0]
            q_new = np.clip(q[idx] + step, self.lower, self.upper)
            r_sel = r_des if r_des.ndim == 2 else r_des[idx]
            err_new, jac_new = self._errors(q_new, p_des[idx], r_sel)
            cost_new = np.einsum("ni,i,ni->n", err_new, w, err_new)
            better = cost_new < cost[idx]
            acc = idx[better]
            q[acc], err[acc], jac[acc], cost[acc] = (
                q_new[better],
                err_new[better],
                jac_new[better],
                cost_new[better],
            )
            bias[idx[~better]] = np.maximum(bias[idx[~better]], 1e-6) * 10.0  # reject: damp harder
            bias[acc] = self.options.damping_bias
            used[idx] += 1
            active = ~self._converged(err) & (bias < 1e3)
        return q, err, used

    def ik(
        self, position: ArrayLike, seed: ArrayLike | None = None, rotation: ArrayLike | None = None
    ) -> IKResult:
        """Joints that put the TCP at ``position`` with orientation ``rotation`` (``tool_rotation`` if None).

        Args:
            position: Target TCP position (3,) in the world frame.
            seed: Start configuration (6,), normally the previous solution; the arm's ``seed_rad`` when None.
            rotation: Target TCP orientation (3, 3) in the world frame.

        Returns:
            The solution; check ``converged`` (it is the best configuration found when False).
        """
        p = np.asarray(position, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"position must be 3 finite numbers, got {np.asarray(position).tolist()}")
        if rotation is None:
            r = self.tool_rotation
        else:
            r = np.asarray(rotation, dtype=float)
            _check_rotation(r, "rotation")
        q0 = np.array(self.arm.seed_rad if seed is None else seed, dtype=float)
        self._joints(q0)
        return self._solve_one(np.clip(q0, self.lower, self.upper), p, r)

    def _solve_one(self, q: FloatArray, p_des: FloatArray, r_des: FloatArray) -> IKResult:
        """The LM iteration of ``_solve`` for one problem, without the batch bookkeeping (3x faster)."""
        o, w = self.options, self._weight
        tol_p2, tol_r2 = o.position_tolerance_m**2, o.rotation_tolerance_rad**2
        err, jac = self._errors(q, p_des, r_des)
        sq = err * err
        cost = float(sq @ w)
        bias = o.damping_bias
        used = 0
        diag = np.diag_indices(6)
        while used < o.max_iterations and bias < 1e3:
            if sq[:3].sum() <= tol_p2 and sq[3:].sum() <= tol_r2:
                break
            jtw = jac.T * w
            h = jtw @ jac
            h[diag] += 0.5 * cost + bias
            q_new = np.clip(q + np.linalg.solve(h, jtw @ err), self.lower, self.upper)
            err_new, jac_new = self._errors(q_new, p_des, r_des)
            sq_new = err_new * err_new
            cost_new = float(sq_new @ w)
            used += 1
            if cost_new < cost:
                q, err, jac, sq, cost, bias = q_new, err_new, jac_new, sq_new, cost_new, o.damping_bias
            else:
                bias = max(bias, 1e-6) * 10.0  # rejected step: damp harder
        e_pos, e_rot = math.sqrt(sq[:3].sum()), math.sqrt(sq[3:].sum())
        return IKResult(
            q=q,
            position_error_m=e_pos,
            rotation_error_rad=e_rot,
            iterations=used,
            converged=e_pos <= o.position_tolerance_m and e_rot <= o.rotation_tolerance_rad,
        )

    def joint_trajectory(
        self, t: ArrayLike, positions: ArrayLike, seed: ArrayLike | None = None
    ) -> JointTrajectory:
        """Joint trajectory moving the TCP through ``positions`` at times ``t``, the orientation held fixed.

        Samples ``coarse_step_s`` apart are solved one after the other, each seeded with the previous solution
        (the first with ``seed``), so the arm keeps its configuration along the path; the samples in between
        start from the interpolated coarse solutions and are refined together.

        Args:
            t: Sample times (N,), strictly increasing.
            positions: TCP positions (N, 3) in the world frame.
            seed: Joints (6,) near the first sample, normally the robot's current joints.

        Raises:
            IKError: When a sample has no solution within tolerance (message names its time and position).
            ValueError: On bad shapes or non-finite values.
        """
        ts = np.asarray(t, dtype=float)
        p = np.asarray(positions, dtype=float)
        if ts.ndim != 1 or ts.size == 0 or p.shape != (ts.size, 3):
            raise ValueError(f"need t (N,) and positions (N, 3), got shapes {ts.shape} and {p.shape}")
        if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(p))):
            raise ValueError("t and positions must be finite")
        if ts.size > 1 and np.any(np.diff(ts) <= 0.0):
            raise ValueError("t must be strictly increasing")
        q_prev = np.array(self.arm.seed_rad if seed is None else seed, dtype=float)
        self._joints(q_prev)
        n = ts.size
        # Coarse samples: the first, the last, and one every coarse_step_s. (np.arange's last value can round
        # past ts[-1], where searchsorted answers n: clipped to the last sample.)
        steps = np.searchsorted(ts, np.arange(ts[0], ts[-1], self.options.coarse_step_s))
        coarse = np.unique(np.concatenate([[0, n - 1], np.minimum(steps, n - 1)]))
        q_coarse = np.empty((coarse.size, 6))
        for k, i in enumerate(coarse):
            res = None
            if k >= 2:
                # Seed extrapolated from the last two solutions: one or two LM steps fewer than q_prev alone.
                rate = (ts[i] - ts[coarse[k - 1]]) / (ts[coarse[k - 1]] - ts[coarse[k - 2]])
                guess = np.clip(q_prev + rate * (q_prev - q_coarse[k - 2]), self.lower, self.upper)
                res = self._solve_one(guess, p[i], self.tool_rotation)
            if res is None or not res.converged:
                res = self._solve_one(np.clip(q_prev, self.lower, self.upper), p[i], self.tool_rotation)
            if not res.converged:
                raise self._ik_error(ts[i], p[i], res.position_error_m, res.rotation_error_rad)
            q_coarse[k] = q_prev = res.q
        q = np.empty((n, 6))
        for j in range(6):
            q[:, j] = np.interp(ts, ts[coarse], q_coarse[:, j])
        fine = np.setdiff1d(np.arange(n), coarse)
        if fine.size:
            q_fine, err, _ = self._solve(q[fine], p[fine], self.tool_rotation, self.options.max_iterations)
            q[fine] = q_fine
            bad = np.flatnonzero(~self._converged(err))
            if bad.size:
                i = int(fine[bad[0]])
                raise self._ik_error(
                    ts[i],
                    p[i],
                    float(np.linalg.norm(err[bad[0], :3])),
                    float(np.linalg.norm(err[bad[0], 3:])),
                )
        return JointTrajectory(t=ts.copy(), q=q)

    def _ik_error(self, t: float, p: FloatArray, e_pos: float, e_rot: float) -> IKError:
        return IKError(
            f"{self.arm.name}: no IK solution at t={t:.4f} s for TCP position {np.round(p, 4).tolist()} m "
            f"(residual {e_pos * 1e3:.3g} mm, {e_rot:.3g} rad): out of reach, at a singularity or a limit"
        )


# --------------------------------------------------------------------------------------------- limit check
@dataclass(frozen=True)
class LimitViolation:
    """The worst breach of one limit of one joint over a trajectory.

    Attributes:
        joint: Joint name.
        quantity: "position", "velocity" or "acceleration".
        t_s: Time of the worst sample (velocities: the end of the interval).
        value: Its value (rad, rad/s or rad/s^2; signed).
        limit: The limit it breaks (the bound on that side for positions, the magnitude otherwise).
        first_t_s: Time the limit is first broken.
        samples: Number of samples over the limit.
    """

    joint: str
    quantity: str
    t_s: float
    value: float
    limit: float
    first_t_s: float
    samples: int

    def __str__(self) -> str:
        unit = {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2"}[self.quantity]
        return (
            f"joint {self.joint} {self.quantity} {self.value:+.4g} {unit} at t={self.t_s:.4f} s breaks the "
            f"limit {self.limit:.4g} {unit} (first at t={self.first_t_s:.4f} s, {self.samples} samples over)"
        )


@dataclass(frozen=True)
class LimitReport:
    """Result of :func:`check_joint_limits`; no ``violations`` means the trajectory is within every limit."""

    violations: tuple[LimitViolation, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        """True when no limit is broken."""
        return not self.violations

    def __str__(self) -> str:
        if self.ok:
            return "joint trajectory within all position, velocity and acceleration limits"
        return "joint limits broken:\n  " + "\n  ".join(str(v) for v in self.violations)

    def raise_if_violated(self) -> None:
        """Raise :class:`JointLimitError` when a limit is broken."""
        if not self.ok:
            raise JointLimitError(self)


class JointLimitError(ValueError):
    """A joint trajectory breaks a position, velocity or acceleration limit; ``report`` says where."""

    def __init__(self, report: LimitReport, hint: str = "", at_join: bool = False) -> None:
        super().__init__(str(report) + hint)
        self.report = report
        #: The setpoints alone keep the limits; only their join to the targets already sent breaks them.
        self.at_join = bool(at_join)


def check_joint_limits(arm: ArmModel, t: ArrayLike, q: ArrayLike, tolerance: float = 1e-9) -> LimitReport:
    """Check joint positions, and finite-difference velocities and accelerations, against the arm's limits.

    Velocities are ``(q[k+1] - q[k]) / (t[k+1] - t[k])`` per interval; accelerations are the differences of
    successive interval velocities over half the sum of the two intervals (exact for a constant acceleration,
    also on uneven time steps, such as a trajectory joined to the last samples already sent).

    Args:
        arm: Limits to check against.
        t: Sample times (N,), strictly increasing.
        q: Joint positions (N, 6).
        tolerance: Relative slack on every limit (rounding).

    Returns:
        A report with the worst breach per joint and quantity (empty when within limits).
    """
    ts = np.asarray(t, dtype=float)
    qs = np.asarray(q, dtype=float)
    if ts.ndim != 1 or qs.shape != (ts.size, 6):
        raise ValueError(f"need t (N,) and q (N, 6), got shapes {ts.shape} and {qs.shape}")
    if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(qs))):
        raise ValueError("t and q must be finite")
    dt = np.diff(ts)
    if np.any(dt <= 0.0):
        raise ValueError("t must be strictly increasing")
    lo, hi = np.array(arm.lower_rad), np.array(arm.upper_rad)
    vmax, amax = np.array(arm.max_velocity_rad_s), np.array(arm.max_acceleration_rad_s2)
    found: list[LimitViolation] = []

    def collect(
        quantity: str, times: FloatArray, values: FloatArray, excess: FloatArray, limit: FloatArray
    ) -> None:
        # excess > 0 where the limit is broken; limit (M, 6) is the bound each value is compared with.
        for j in range(6):
            over = np.flatnonzero(excess[:, j] > 0.0)
            if over.size:
                k = int(over[np.argmax(excess[over, j])])
                found.append(
                    LimitViolation(
                        arm.joint_names[j],
                        quantity,
                        float(times[k]),
                        float(values[k, j]),
                        float(limit[k, j]),
                        float(times[over[0]]),
                        int(over.size),
                    )
                )

    slack = 1.0 + tolerance
    below, above = qs < lo - tolerance * np.abs(lo), qs > hi + tolerance * np.abs(hi)
    bound = np.where(qs < lo, lo, hi) * np.ones_like(qs)
    collect("position", ts, qs, np.where(below, lo - qs, 0.0) + np.where(above, qs - hi, 0.0), bound)
    if ts.size >= 2:
        vel = np.diff(qs, axis=0) / dt[:, None]
        collect("velocity", ts[1:], vel, np.abs(vel) - vmax * slack, np.broadcast_to(vmax, vel.shape))
    if ts.size >= 3:
        acc = np.diff(vel, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None]
        collect("acceleration", ts[1:-1], acc, np.abs(acc) - amax * slack, np.broadcast_to(amax, acc.shape))
    return LimitReport(tuple(found))
