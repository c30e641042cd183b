"""Hand-computed cases for every reward term of dyndlo_vision.tasks.rewards (paper eq. 4-7, tables IV and V).

Expected values are written out from the paper's formulas and table V numbers in each test, not computed by
the functions under test, so a changed threshold, comparison or coefficient fails here. Boundaries are tested
on both sides (and exactly on the threshold where the paper's strict or non-strict comparison decides).
"""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.tasks.rewards import (
    TABLE_V,
    AvoidLimits,
    RewardCoefficients,
    avoid_flags,
    explicit_step_reward,
    explicit_time_reward,
    implicit_reward,
)

LIMITS = AvoidLimits()
# docs/TASKS.md: outreach is measured from the GoFa's shoulder (axis 2), 0.265 m above the base.
SHOULDER = np.array([0.0, 0.0, 0.265])
SAFE_P = np.array([0.45, 0.0, 0.60])  # tip control's TCP home: every condition false
REST = np.zeros(3)
HIGH_DLO = np.array([0.8, 0.0, 0.40])  # P_DLO well above the floor


def _flags(p, v=REST, p_dlo=HIGH_DLO, check_collision: bool = True) -> dict[str, bool]:
    return avoid_flags(np.atleast_2d(p), np.atleast_2d(v), p_dlo, LIMITS, check_collision)


def _only(name: str | None) -> dict[str, bool]:
    flags = {"outreach": False, "velocity": False, "collision": False, "shoulder": False}
    if name is not None:
        flags[name] = True
    return flags


# ------------------------------------------------------------------------------------------------ table V
def test_table_v_coefficients_are_the_papers() -> None:
    # Table V, columns Task I, II, III, Task I multi-step, Task IV: lambda_1..lambda_4 and M.
    expected = {
        "tip_control": (-5.0, -1.0, 10.0, -1.0, 0.75),
        "vaulting": (-10.0, -1.0, 10.0, -2.0, 0.3),
        "hooking": (-10.0, -1.0, 10.0, -2.0, 0.3),
        "tip_control_multi_step": (-50.0, -1.0, 100.0, -1.0, 0.75),
        "time_oscillation": (-50.0, -3.0, 1.5, -2.5, None),
    }
    assert set(TABLE_V) == set(expected)
    for name, (l1, l2, l3, l4, m) in expected.items():
        c = TABLE_V[name]
        assert (c.avoid, c.distance, c.success, c.dyn, c.height_threshold_m) == (l1, l2, l3, l4, m), name


def test_table_v_shared_thresholds() -> None:
    # Table V shared rows: eps_outreach 0.9 m, v_max 1.8 m/s, eps_shoulder 0.25 m; footnote i: 1.25 cm.
    assert (LIMITS.outreach_m, LIMITS.v_max_m_s, LIMITS.shoulder_m) == (0.9, 1.8, 0.25)
    assert LIMITS.collision_height_m == 0.0125
    assert LIMITS.shoulder_position_m == (0.0, 0.0, 0.265)


@pytest.mark.parametrize(
    "coeffs",
    [
        (1.0, -1.0, 10.0, -1.0), (-1.0, 1.0, 10.0, -1.0), (-1.0, -1.0, -10.0, -1.0), (-1.0, -1.0, 10.0, 1.0),
        # Zero is no sign, and the signs are about 0, not 1.
        (0.0, -1.0, 10.0, -1.0), (-1.0, 0.0, 10.0, -1.0), (-1.0, -1.0, 0.0, -1.0), (-1.0, -1.0, 10.0, 0.0),
        (0.5, -1.0, 10.0, -1.0), (-1.0, 0.5, 10.0, -1.0), (-1.0, -1.0, 10.0, 0.5),
    ],
)
def test_coefficient_signs_are_enforced(coeffs: tuple[float, float, float, float]) -> None:
    # Eq. 5-7: lambda_1, lambda_2, lambda_4 < 0 < lambda_3.
    with pytest.raises(ValueError, match="reward signs"):
        RewardCoefficients(*coeffs)


# ------------------------------------------------------------------------------------------------ I_avoid
def test_a_safe_pose_breaks_no_condition() -> None:
    assert _flags(SAFE_P) == _only(None)


def test_outreach_is_measured_from_the_shoulder_with_a_strict_threshold() -> None:
    # Table IV: ||P|| > outreach, P from the shoulder (0, 0, 0.265) m (docs/TASKS.md), outreach 0.9 m.
    direction = np.array([0.6, 0.0, 0.8])  # unit vector, xy norm 0.6 * r >> eps_shoulder
    assert _flags(SHOULDER + 0.8999 * direction) == _only(None)
    assert _flags(SHOULDER + 0.9001 * direction) == _only("outreach")
    # Exactly at 0.9 m is not beyond it (strict >): (0.9, 0, 0.265) is 0.9 m from the shoulder.
    assert _flags([0.9, 0.0, 0.265]) == _only(None)
    assert _flags([0.9001, 0.0, 0.265]) == _only("outreach")


def test_outreach_allows_task_iv_targets_that_are_out_of_reach_from_the_base() -> None:
    # Task IV "up" target (0.30, 0, 1.10): from the shoulder sqrt(0.30^2 + 0.835^2) = 0.887 m < 0.9 m; from
    # the base on the floor it would be sqrt(0.30^2 + 1.10^2) = 1.140 m > 0.9 m (docs/TASKS.md).
    assert np.hypot(0.30, 1.10 - 0.265) == pytest.approx(0.8873, abs=1e-4)
    assert _flags([0.30, 0.0, 1.10]) == _only(None)
    # ... and (0.3, 0, 1.165), 0.9 m above the shoulder and 0.3 m in front of it (0.949 m), is beyond.
    assert _flags([0.3, 0.0, 0.265 + 0.9])["outreach"]


def test_velocity_is_the_3d_speed_with_a_strict_threshold() -> None:
    # Table IV: ||P_dot|| > v_max = 1.8 m/s, the Euclidean norm of the TCP velocity.
    assert _flags(SAFE_P, [1.7999, 0.0, 0.0]) == _only(None)
    assert _flags(SAFE_P, [0.0, 0.0, -1.8001]) == _only("velocity")
    assert _flags(SAFE_P, [1.8, 0.0, 0.0]) == _only(None)  # exactly v_max is allowed
    # 1.2 and 1.4 m/s per axis, each below 1.8, make sqrt(1.44 + 1.96) = 1.844 m/s: too fast.
    assert _flags(SAFE_P, [1.2, 0.0, 1.4]) == _only("velocity")
    # 1.0, 1.0, 1.0 m/s: sqrt(3) = 1.732 m/s, allowed.
    assert _flags(SAFE_P, [1.0, -1.0, 1.0]) == _only(None)


def test_cable_floor_collision_below_one_and_a_quarter_centimetres() -> None:
    # Footnote i: collision = z(P_DLO) < 1.25 cm.
    assert _flags(SAFE_P, p_dlo=[0.8, 0.0, 0.0126]) == _only(None)
    assert _flags(SAFE_P, p_dlo=[0.8, 0.0, 0.0124]) == _only("collision")
    assert _flags(SAFE_P, p_dlo=[0.8, 0.0, 0.013]) == _only(None)  # 1.3 cm: clear (not 12.5 cm)
    assert _flags(SAFE_P, p_dlo=[0.8, 0.0, 0.0125]) == _only(None)  # exactly 1.25 cm: not below
    # Vaulting's cable lies on the floor by design: the condition can be switched off (docs/TASKS.md).
    assert _flags(SAFE_P, p_dlo=[0.8, 0.0, 0.0], check_collision=False) == _only(None)
    # Only P_DLO's height counts: a TCP low over the floor is not a cable-floor contact.
    assert _flags([0.45, 0.0, 0.005], p_dlo=HIGH_DLO) == _only(None)


def test_shoulder_condition_is_the_horizontal_distance_from_the_base_axis() -> None:
    # Table IV: ||P||_xy < eps_shoulder = 0.25 m, whatever the height (a TCP above the base is near the
    # shoulder singularity). The 3-D norm of the first point is sqrt(0.2^2 + 0.1^2 + 0.6^2) = 0.66 m, far
    # above 0.25 m, so a 3-D norm would never fire at working heights.
    assert _flags([0.2, 0.1, 0.6]) == _only("shoulder")  # xy: sqrt(0.04 + 0.01) = 0.2236 m
    assert _flags([0.0, 0.0, 0.9]) == _only("shoulder")  # straight above the base
    assert _flags([0.2499, 0.0, 0.6]) == _only("shoulder")
    assert _flags([0.2501, 0.0, 0.6]) == _only(None)
    assert _flags([0.0, -0.2501, 0.3]) == _only(None)
    assert _flags([0.25, 0.0, 0.6]) == _only(None)  # exactly eps_shoulder: not closer
    # 0.18 m in x and y each: 0.2546 m from the axis, allowed.
    assert _flags([0.18, 0.18, 0.5]) == _only(None)


def test_avoid_flags_over_instants_and_grippers() -> None:
    # K = 4 instants, n_g = 2 grippers: one breach anywhere sets its flag; the others stay clear.
    p = np.tile([[0.40, -0.12, 0.35], [0.40, 0.12, 0.35]], (4, 1, 1))
    v = np.zeros_like(p)
    p_dlo = np.tile([0.6, 0.0, 0.2], (4, 1))
    assert avoid_flags(p, v, p_dlo, LIMITS) == _only(None)
    v_fast = v.copy()
    v_fast[2, 1] = [0.0, 0.0, 2.0]  # the second gripper, third instant
    assert avoid_flags(p, v_fast, p_dlo, LIMITS) == _only("velocity")
    p_near = p.copy()
    p_near[3, 0] = [0.1, -0.1, 0.35]  # the first gripper, last instant: 0.141 m from the axis
    assert avoid_flags(p_near, v, p_dlo, LIMITS) == _only("shoulder")
    low = p_dlo.copy()
    low[0, 2] = 0.01
    assert avoid_flags(p, v, low, LIMITS) == _only("collision")


def test_outreach_and_speed_are_3d_norms_over_instants_too() -> None:
    """(K, n_g, 3) samples: the 3-D distance and speed decide, not a single coordinate."""
    p = np.tile([[0.45, 0.0, 0.60]], (3, 1, 1))
    p[1, 0] = [0.5, 0.5, 0.9]  # 0.95 m from the shoulder, every coordinate of the offset under 0.9 m
    v = np.zeros_like(p)
    p_dlo = np.tile(HIGH_DLO, (3, 1))
    assert avoid_flags(p, v, p_dlo, LIMITS) == _only("outreach")
    p[1, 0] = [0.45, 0.0, 0.60]
    v[2, 0] = [1.3, 1.3, 0.0]  # 1.84 m/s, each component under 1.8 m/s
    assert avoid_flags(p, v, p_dlo, LIMITS) == _only("velocity")


# ------------------------------------------------------------------------------------------------ implicit
@pytest.mark.parametrize(
    ("column", "avoid", "success", "far", "height", "expected"),
    [
        # Eq. 4-7, implicit: r_avoid = l1 I_avoid, r_distance = l2 I_dist, r_success = l3 I_success,
        # r_dyn = l4 * 1 * [z_P >= M]; table V columns.
        ("tip_control", False, True, False, 0.60, (0.0, 0.0, 10.0, 0.0)),
        ("tip_control", False, False, True, 0.60, (0.0, -1.0, 0.0, 0.0)),
        ("tip_control", True, False, True, 0.80, (-5.0, -1.0, 0.0, -1.0)),
        ("tip_control", True, True, False, 0.75, (-5.0, 0.0, 10.0, -1.0)),  # z_P = M: I_dyn = 1 (>=)
        ("tip_control", False, True, False, 0.7499, (0.0, 0.0, 10.0, 0.0)),
        ("tip_control_multi_step", True, True, False, 0.76, (-50.0, 0.0, 100.0, -1.0)),
        ("tip_control_multi_step", False, False, True, 0.10, (0.0, -1.0, 0.0, 0.0)),
        ("vaulting", True, False, True, 0.30, (-10.0, -1.0, 0.0, -2.0)),
        ("vaulting", False, True, False, 0.2999, (0.0, 0.0, 10.0, 0.0)),
        ("hooking", False, True, False, 0.31, (0.0, 0.0, 10.0, -2.0)),
        ("hooking", True, False, True, 0.25, (-10.0, -1.0, 0.0, 0.0)),
    ],
)
def test_implicit_reward_terms(
    column: str, avoid: bool, success: bool, far: bool, height: float, expected: tuple[float, ...]
) -> None:
    terms = implicit_reward(TABLE_V[column], avoid, success, far, height)
    assert set(terms) == {"r_avoid", "r_distance", "r_success", "r_dyn"}
    got = (terms["r_avoid"], terms["r_distance"], terms["r_success"], terms["r_dyn"])
    assert got == pytest.approx(expected, abs=1e-12)


def test_implicit_total_follows_eq_4() -> None:
    # r_tot of task I with every indicator on: -5 - 1 + 10 - 1 = 3 (eq. 4).
    terms = implicit_reward(TABLE_V["tip_control"], True, True, True, 0.9)
    assert sum(terms.values()) == pytest.approx(3.0)


def test_no_height_threshold_means_no_r_dyn() -> None:
    c = RewardCoefficients(-1.0, -1.0, 1.0, -1.0, height_threshold_m=None)
    assert implicit_reward(c, False, False, False, 5.0)["r_dyn"] == 0.0


# ------------------------------------------------------------------------------------------------ explicit
@pytest.mark.parametrize(
    ("avoid", "arrived", "osc", "expected"),
    [
        # Task IV, per 25 Hz sample (docs/TASKS.md): r_avoid = -50 I_avoid,
        # r_success = 1.5 [arrived and osc < 0.05], r_dyn = -2.5 * osc * arrived.
        (False, False, 0.30, (0.0, 0.0, 0.0)),  # before arrival nothing of the oscillation is charged
        (True, False, 0.30, (-50.0, 0.0, 0.0)),
        (False, True, 0.04, (0.0, 1.5, -0.1)),
        (False, True, 0.0499, (0.0, 1.5, -0.12475)),
        (False, True, 0.05, (0.0, 0.0, -0.125)),  # exactly eps_oscill: not under it
        (False, True, 0.0501, (0.0, 0.0, -0.12525)),
        (True, True, 0.20, (-50.0, 0.0, -0.5)),
        (False, True, 0.0, (0.0, 1.5, 0.0)),
    ],
)
def test_explicit_step_reward_terms(
    avoid: bool, arrived: bool, osc: float, expected: tuple[float, ...]
) -> None:
    terms = explicit_step_reward(TABLE_V["time_oscillation"], avoid, arrived, osc)
    assert set(terms) == {"r_avoid", "r_success", "r_dyn"}
    assert (terms["r_avoid"], terms["r_success"], terms["r_dyn"]) == pytest.approx(expected, abs=1e-12)


def test_explicit_step_reward_uses_the_given_threshold() -> None:
    c = TABLE_V["time_oscillation"]
    assert explicit_step_reward(c, False, True, 0.08, oscillation_threshold_m=0.1)["r_success"] == 1.5
    assert explicit_step_reward(c, False, True, 0.08, oscillation_threshold_m=0.05)["r_success"] == 0.0


@pytest.mark.parametrize(("t_traj", "expected"), [(1.35, -4.05), (1.468, -4.404), (0.0, 0.0)])
def test_explicit_time_reward(t_traj: float, expected: float) -> None:
    # Eq. r_distance, explicit: lambda_2 * sum(dt_i) with lambda_2 = -3 (table V, task IV); the paper's
    # learned times 1.35 s (up) and 1.468 s (down).
    assert explicit_time_reward(TABLE_V["time_oscillation"], t_traj) == {
        "r_distance": pytest.approx(expected)
    }


def test_vault_progress_climbs_towards_a_vault() -> None:
    """vault_progress: 0 for a cable whose middle lies below the TCP's home and never crosses the box's
    mid-plane, growing as the middle nears the far face and as the crossing rises to the box's top, below 1
    always."""
    from dyndlo_vision.tasks.vaulting import OBSTACLE_CENTRE_M, OBSTACLE_SIZE_M, TCP_HOME_M, vault_progress

    top = OBSTACLE_CENTRE_M[2] + OBSTACLE_SIZE_M[2] / 2
    far = OBSTACLE_CENTRE_M[0] + OBSTACLE_SIZE_M[0] / 2
    home = TCP_HOME_M[0]

    def cable(middle_x: float, crossing_z: float | None) -> np.ndarray:
        # held end, middle, far end; the far end beyond the box when the cable crosses it
        end_x = 1.0 if crossing_z is not None else OBSTACLE_CENTRE_M[0] - 0.05
        return np.array([[home, 0, 0.2], [middle_x, 0, crossing_z if crossing_z is not None else 0.01],
                         [end_x, 0, crossing_z if crossing_z is not None else 0.01]])

    start = vault_progress(cable(home, None), 1)
    halfway_x = 0.5 * (home + far)
    halfway = vault_progress(cable(halfway_x, None), 1)
    low_crossing = vault_progress(cable(far, 0.05), 1)
    over_the_top = vault_progress(cable(far, top), 1)
    assert start == 0.0
    assert 0 < halfway < low_crossing < over_the_top < 1.0
    assert halfway == pytest.approx(0.25)


@pytest.mark.slow
def test_shaped_vaulting_reward_slopes_only_for_failures() -> None:
    """distance_reward='shaped': a failed episode's r_distance is lambda_2 x 5 x (1 - progress) (the indicator
    gives lambda_2); a vault is scored exactly as table V scores it."""
    from dyndlo_vision.tasks.baselines import FlickVault
    from dyndlo_vision.tasks.registry import make_env
    from dyndlo_vision.tasks.vaulting import SHAPED_DISTANCE_SCALE

    shaped, plain = make_env("vaulting", distance_reward="shaped"), make_env("vaulting")
    lam = TABLE_V["vaulting"].distance
    still = np.zeros(shaped.action_space.shape, dtype=np.float32)
    shaped.reset(seed=0)
    info = shaped.step(still)[4]
    # The TCP rises 0.3 m and pulls the cable up against the box's side: no vault, and no progress over it
    # (the middle lies beside the box from the start, so the reach half is full).
    assert not info["is_success"] and info["vault_progress"] == pytest.approx(0.5)
    assert info["r_distance"] == pytest.approx(lam * SHAPED_DISTANCE_SCALE * (1.0 - info["vault_progress"]))
    plain.reset(seed=0)
    assert plain.step(still)[4]["r_distance"] == lam
    obs, _ = shaped.reset(seed=0)
    vault = FlickVault(shaped)(obs)
    _, reward, _, _, info = shaped.step(vault)
    plain.reset(seed=0)
    _, reward_plain, _, _, info_plain = plain.step(vault)
    assert info["is_success"] and info_plain["is_success"] and reward == reward_plain
    with pytest.raises(ValueError, match="distance_reward='linear'"):
        make_env("vaulting", distance_reward="linear")
