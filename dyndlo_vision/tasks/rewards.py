"""Reward terms of the DynDLO paper (eq. 4-7, tables IV and V) as small pure functions.

r_tot = r_avoid + r_distance + r_success + r_dyn, with

* r_avoid = lambda_1 * I_avoid, I_avoid = ||P - shoulder|| > outreach  or  ||P_dot|| > v_max  or
  z(P_DLO) < 1.25 cm (cable-floor collision)  or  ||P||_xy < eps_shoulder;
* r_distance = lambda_2 * I_dist (implicit tasks) or lambda_2 * sum(dt_i) (explicit task: trajectory time);
* r_success = lambda_3 * I_success;
* r_dyn = lambda_4 * J_cost * I_dyn: implicit tasks I_dyn = (mean gripper height z_P >= M), J_cost = 1;
  task IV J_cost = ||P_eq - P_DLO||_xy (oscillation), I_dyn = arrived.

Where the paper is silent we say so next to the constant and choose the reading that keeps every term
meaningful; each choice is listed in docs/TASKS.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

# Table V, shared rows.
OUTREACH_M = 0.9
V_MAX_M_S = 1.8
SHOULDER_M = 0.25
GOAL_TOLERANCE_M = 0.01
OSCILLATION_THRESHOLD_M = 0.05
# Table IV, footnote i.
COLLISION_HEIGHT_M = 0.0125
# Not in the paper: the point the outreach is measured from. The literal ||P|| from a base on the floor
# would forbid the paper's own task IV (0.55 m lift); we measure it from the shoulder (axis 2) of the ABB
# GoFa CRB 15000, 0.265 m above the base.
SHOULDER_POSITION_M = (0.0, 0.0, 0.265)


@dataclass(frozen=True)
class RewardCoefficients:
    """One column of table V.

    Attributes:
        avoid: lambda_1 (< 0).
        distance: lambda_2 (< 0).
        success: lambda_3 (> 0).
        dyn: lambda_4 (< 0).
        height_threshold_m: M, the mean gripper height that counts as not exploiting dynamics (None: unused).
    """

    avoid: float
    distance: float
    success: float
    dyn: float
    height_threshold_m: float | None = None

    def __post_init__(self) -> None:
        if not (self.avoid < 0 and self.distance < 0 and self.success > 0 and self.dyn < 0):
            raise ValueError(f"reward signs must be lambda_1,2,4 < 0 < lambda_3, got {self}")


# Table V, one entry per column.
TABLE_V: dict[str, RewardCoefficients] = {
    "tip_control": RewardCoefficients(-5.0, -1.0, 10.0, -1.0, height_threshold_m=0.75),
    "vaulting": RewardCoefficients(-10.0, -1.0, 10.0, -2.0, height_threshold_m=0.3),
    "hooking": RewardCoefficients(-10.0, -1.0, 10.0, -2.0, height_threshold_m=0.3),
    "tip_control_multi_step": RewardCoefficients(-50.0, -1.0, 100.0, -1.0, height_threshold_m=0.75),
    "time_oscillation": RewardCoefficients(-50.0, -3.0, 1.5, -2.5),
}


@dataclass(frozen=True)
class AvoidLimits:
    """The conditions of I_avoid (table IV, first row; thresholds from table V)."""

    outreach_m: float = OUTREACH_M
    v_max_m_s: float = V_MAX_M_S
    shoulder_m: float = SHOULDER_M
    collision_height_m: float = COLLISION_HEIGHT_M
    shoulder_position_m: tuple[float, float, float] = SHOULDER_POSITION_M


def avoid_flags(
    tcp_positions: ArrayLike, tcp_velocities: ArrayLike, p_dlo: ArrayLike, limits: AvoidLimits,
    check_collision: bool = True,
) -> dict[str, bool]:
    """Return each I_avoid condition for one instant, or for any of K instants.

    Args:
        tcp_positions: (n_g, 3) gripper positions, or (K, n_g, 3) for K instants.
        tcp_velocities: Gripper velocities, same shape.
        p_dlo: (3,) position of the cable's section of interest, or (K, 3).
        limits: Thresholds.
        check_collision: Whether cable-floor contact of P_DLO counts (not for vaulting, whose cable lies on
            the floor by design).
    """
    p = np.atleast_2d(np.asarray(tcp_positions, dtype=float))
    v = np.atleast_2d(np.asarray(tcp_velocities, dtype=float))
    shoulder = np.asarray(limits.shoulder_position_m)
    return {
        "outreach": bool(np.any(np.linalg.norm(p - shoulder, axis=-1) > limits.outreach_m)),
        "velocity": bool(np.any(np.linalg.norm(v, axis=-1) > limits.v_max_m_s)),
        "collision": bool(check_collision and np.any(np.asarray(p_dlo)[..., 2] < limits.collision_height_m)),
        "shoulder": bool(np.any(np.linalg.norm(p[..., :2], axis=-1) < limits.shoulder_m)),
    }


def implicit_reward(
    coeffs: RewardCoefficients, avoid: bool, success: bool, far_from_goal: bool, max_mean_height_m: float
) -> dict[str, float]:
    """Reward terms of an implicit shape-control task, evaluated once at the end of the episode.

    Args:
        coeffs: Table V column.
        avoid: I_avoid over the episode (any condition at any time).
        success: I_success.
        far_from_goal: I_dist.
        max_mean_height_m: Highest mean gripper height reached (z_P), compared with M.
    """
    high = coeffs.height_threshold_m is not None and max_mean_height_m >= coeffs.height_threshold_m
    return {
        "r_avoid": coeffs.avoid * float(avoid),
        "r_distance": coeffs.distance * float(far_from_goal),
        "r_success": coeffs.success * float(success),
        "r_dyn": coeffs.dyn * float(high),
    }


def explicit_step_reward(
    coeffs: RewardCoefficients, avoid: bool, arrived: bool, oscillation_m: float,
    oscillation_threshold_m: float = OSCILLATION_THRESHOLD_M,
) -> dict[str, float]:
    """Per-sample reward terms of the explicit task (IV) except r_distance, which is paid once.

    Success is arrival with the oscillation under eps_oscill (table IV footnotes iii and v); the
    oscillation cost J_cost = ||P_eq - P_DLO||_xy counts only after arrival (I_dyn = arrived).
    """
    return {
        "r_avoid": coeffs.avoid * float(avoid),
        "r_success": coeffs.success * float(arrived and oscillation_m < oscillation_threshold_m),
        "r_dyn": coeffs.dyn * oscillation_m * float(arrived),
    }


def explicit_time_reward(coeffs: RewardCoefficients, trajectory_time_s: float) -> dict[str, float]:
    """r_distance of the explicit task: lambda_2 times the trajectory time (sum of the chosen dt_i)."""
    return {"r_distance": coeffs.distance * float(trajectory_time_s)}
