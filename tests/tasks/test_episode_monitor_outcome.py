"""The environment's episode monitor decides outcomes: swept goal check, mean gripper height, sticky I_avoid.

One environment reset each, then hand-made monitor samples fed through ``DynDLOEnv._record_samples`` (the
single place where the environment turns recorded states into the monitor's flags; the C rollout and the
Python stepping both end there), and the outcome read with the public ``DynDLOEnv.outcome``. No simulation
after the reset, so the states are exactly the ones written here.
"""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.tasks import make_env

GOAL = np.array([0.80, 0.0, 0.40])


def _feed(env, p_dlo: np.ndarray, tcp: np.ndarray | None = None, vel: np.ndarray | None = None) -> None:
    """Record K monitor samples 2 ms apart after the current time."""
    p_dlo = np.atleast_2d(np.asarray(p_dlo, dtype=float))
    k = len(p_dlo)
    n_g = env.scene.num_grippers
    if tcp is None:
        tcp = np.repeat(env.scene.tcp_positions()[None], k, axis=0)
    tcp = np.asarray(tcp, dtype=float).reshape(k, n_g, 3)
    vel = np.zeros_like(tcp) if vel is None else np.asarray(vel, dtype=float).reshape(k, n_g, 3)
    times = env.scene.time + 0.002 * np.arange(1, k + 1)
    env._record_samples(times, tcp, vel, p_dlo)


@pytest.mark.parametrize(("offset", "hit"), [(0.0349, True), (0.0351, False)])
@pytest.mark.parametrize("multi_step", [False, True])
def test_tip_control_hit_between_samples_counts(offset: float, hit: bool, multi_step: bool) -> None:
    env = make_env("tip-control", multi_step=multi_step).unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    tip0 = env.p_dlo()
    # The tip passes the target between two 2 ms samples, 5 cm before and 5 cm after its centre (both samples
    # outside the 3.5 cm success radius), at ``offset`` from the centre in z.
    before, after = GOAL + [-0.05, 0.0, offset], GOAL + [0.05, 0.0, offset]
    assert (
        min(np.linalg.norm(before - GOAL), np.linalg.norm(after - GOAL), np.linalg.norm(tip0 - GOAL)) > 0.06
    )
    _feed(env, [before, after])
    assert env.monitor.min_goal_distance_m == pytest.approx(offset, abs=1e-9)
    reward, success, info = env.outcome()
    assert success is hit and info["is_success"] is hit
    # Task I (multi-step) column: lambda_3 = 10 (100), lambda_2 = -1 for a miss; nothing else applies here.
    assert reward == pytest.approx((100.0 if multi_step else 10.0) if hit else -1.0)
    assert env.is_done_early() is hit


def test_tip_control_sample_points_alone_would_miss() -> None:
    # The same passage seen only at its samples (no segment between them) misses: the check is on the segment.
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    _feed(env, [GOAL + [-0.05, 0.0, 0.0]])
    assert env.monitor.min_goal_distance_m > 0.035
    assert not env.outcome()[1]


def test_tip_control_stopping_short_of_the_target_misses() -> None:
    # The tip moves straight at the target's centre and stops 5 cm short of it: the segment it swept ends
    # there (its extension through the target does not count).
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    _feed(env, [GOAL + [-0.10, 0.0, 0.0], GOAL + [-0.07, 0.0, 0.0], GOAL + [-0.05, 0.0, 0.0]])
    assert env.monitor.min_goal_distance_m == pytest.approx(0.05, abs=1e-9)
    assert not env.outcome()[1] and not env.is_done_early()


@pytest.mark.parametrize(
    ("heights", "r_dyn"),
    [
        ((0.34, 0.24), 0.0),  # mean 0.29 m < M = 0.3 m, though one gripper is above it
        ((0.32, 0.30), -2.0),  # mean 0.31 m >= M: lambda_4 = -2 (hooking column)
        ((0.29, 0.29), 0.0),
    ],
)
def test_hooking_r_dyn_uses_the_mean_gripper_height(heights: tuple[float, float], r_dyn: float) -> None:
    # Table IV footnote vi: z_P is the *mean* gripper height.
    env = make_env("hooking").unwrapped
    env.reset(seed=0)
    tcp = np.array([[[0.40, -0.12, heights[0]], [0.40, 0.12, heights[1]]]])
    _feed(env, env.p_dlo(), tcp=tcp)
    assert env.monitor.max_mean_height_m == pytest.approx(max(0.25, np.mean(heights)))
    _, success, info = env.outcome()
    assert info["r_dyn"] == r_dyn
    assert not success and info["r_avoid"] == 0.0 and info["r_distance"] == -1.0


def test_avoid_conditions_stick_for_the_rest_of_the_episode() -> None:
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    tip = env.p_dlo()
    _feed(env, [tip, tip], vel=np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.9]]))
    _feed(env, [tip, tip, tip])  # at rest again
    assert env.monitor.avoid == {"outreach": False, "velocity": True, "collision": False, "shoulder": False}
    assert env.monitor.max_tcp_speed_m_s == pytest.approx(1.9)
    _, _, info = env.outcome()
    assert info["r_avoid"] == -5.0  # lambda_1 of task I


def test_cable_on_the_floor_is_a_collision_except_in_vaulting() -> None:
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    _feed(env, [[0.6, 0.0, 0.012]])  # the tip 1.2 cm above the floor (< 1.25 cm, footnote i)
    assert env.monitor.avoid["collision"]
    assert env.outcome()[2]["r_avoid"] == -5.0

    vault = make_env("vaulting").unwrapped
    vault.reset(seed=0)
    assert vault.p_dlo()[2] < 0.0125  # the middle lies on the floor at the start, by design
    _feed(vault, [[0.5, -0.1, 0.002]])
    assert not any(vault.monitor.avoid.values())
    assert vault.outcome()[2]["r_avoid"] == 0.0


def test_tcp_near_the_base_axis_is_a_shoulder_breach_in_the_episode() -> None:
    # A TCP 0.2 m from the base axis at 0.6 m height: ||P||_xy = 0.2 < 0.25 m (the 3-D norm would be 0.63 m).
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    _feed(env, env.p_dlo(), tcp=np.array([[[0.2, 0.0, 0.6]]]))
    assert env.monitor.avoid == {"outreach": False, "velocity": False, "collision": False, "shoulder": True}
    assert env.outcome()[2]["r_avoid"] == -5.0


@pytest.mark.parametrize("task", ["tip-control", "hooking", "vaulting", "time-oscillation"])
def test_a_diverged_episode_ends_as_an_avoid_and_never_as_a_success(task: str, monkeypatch) -> None:
    # A blow-up ends the episode at that step; whatever the broken state shows, it is no success, and it
    # pays lambda_1 like any avoid condition. Each task is first set up to succeed but for the divergence,
    # and the same episode without the divergence is the control.
    def episode(diverge: bool) -> dict:
        env = make_env(task).unwrapped
        env.reset(seed=0, options={"goal": GOAL} if task == "tip-control" else None)
        if task == "tip-control":
            _feed(env, [GOAL])  # the tip on the target: a hit
        elif task == "hooking":
            monkeypatch.setattr(env.task, "hooked", lambda scene: True)
        elif task == "vaulting":
            monkeypatch.setattr(env.task, "landed_beyond", lambda scene: True)
        if diverge:
            monkeypatch.setattr(env.scene, "is_finite", lambda: False)
        action = np.zeros(env.action_space.shape, np.float32)
        _, _, terminated, truncated, info = env.step(action)
        assert terminated and not truncated
        assert env.monitor.diverged is diverge and env.outcome()[1] is info["is_success"]
        return {**info, "avoid_coefficient": env.task.coefficients().avoid}

    clean, broken = episode(False), episode(True)
    # The control loop drives the scene without env.step; its score, outcome(), sees the blow-up too.
    env = make_env(task).unwrapped
    env.reset(seed=0, options={"goal": GOAL} if task == "tip-control" else None)
    monkeypatch.setattr(env.scene, "is_finite", lambda: False)
    _, success, info = env.outcome()
    assert success is False and info["diverged"] is True and env.monitor.diverged
    assert "diverged" not in clean and broken["diverged"] is True
    lam1 = broken["avoid_coefficient"]
    if task == "time-oscillation":
        # Explicit task: lambda_1 for the step that blew up, on top of the per-step terms so far.
        assert broken["r_avoid"] == pytest.approx(clean["r_avoid"] + lam1)
    else:
        assert clean["is_success"] and clean["r_avoid"] == 0.0 and clean["r_success"] > 0
        assert broken["r_avoid"] == lam1 < 0 and broken["r_success"] == 0.0
    assert broken["is_success"] is False
