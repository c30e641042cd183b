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


def test_a_hit_between_two_batches_of_samples_counts() -> None:
    """The swept segment joins the last sample of one batch to the first of the next (the C rollout hands
    the monitor one batch per stretch of simulation)."""
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    _feed(env, [GOAL + [-0.10, 0.0, 0.0], GOAL + [-0.05, 0.0, 0.001]])
    _feed(env, [GOAL + [0.05, 0.0, 0.001], GOAL + [0.10, 0.0, 0.0]])
    assert env.monitor.min_goal_distance_m == pytest.approx(0.001, abs=1e-9)
    assert env.outcome()[1] and env.is_done_early()


def test_the_monitor_keeps_the_highest_mean_height_and_counts_its_samples() -> None:
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    assert env.monitor.samples == 1  # the reset's own sample
    tip = env.p_dlo()
    _feed(env, [tip, tip, tip], tcp=np.array([[[0.45, 0.0, 0.2]], [[0.45, 0.0, 0.8]], [[0.45, 0.0, 0.3]]]))
    assert env.monitor.samples == 4
    assert env.monitor.max_mean_height_m == pytest.approx(0.8)  # the highest sample, not the batch's mean
    reward, success, info = env.outcome()
    assert info["r_dyn"] == -1.0  # M = 0.75 m reached (task I)
    assert info["avoid"] == env.monitor.avoid and info["sim_time_s"] == env.scene.time
    assert reward == pytest.approx(sum(info[k] for k in ("r_avoid", "r_distance", "r_success", "r_dyn")))


def test_the_observation_is_table_ii_as_float32() -> None:
    from dyndlo_vision.tasks.base import observation_vector

    obs = observation_vector(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), np.array([[7.0, 8.0, 9.0]] * 2),
                             np.array([0.1, 0.2, 0.3]), np.array([0.4, 0.5, 0.6]))
    assert obs.dtype == np.float32
    np.testing.assert_array_equal(
        obs, np.array([1, 2, 3, 4, 5, 6, 7, 8, 9, 7, 8, 9, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6], np.float32)
    )


def test_segment_point_distances_hand_computed() -> None:
    from dyndlo_vision.tasks.base import _segment_point_distances

    a = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    b = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 1.0]])  # the last: a point
    c = np.array([0.5, 0.3, 0.4])
    got = _segment_point_distances(a, b, c)
    np.testing.assert_allclose(got[:1], [0.5])  # beside the segment
    c2 = np.array([-0.3, 0.4, 0.0])
    np.testing.assert_allclose(_segment_point_distances(a[:1], b[:1], c2), [0.5])  # before its start
    np.testing.assert_allclose(_segment_point_distances(a[3:], b[3:], c), [np.linalg.norm(c - 1.0)])


def test_the_default_goal_distance_is_p_dlos() -> None:
    from dyndlo_vision.tasks import TipControl

    p_dlo = np.array([[0.8, 0.0, 0.43], [0.8, 0.04, 0.4]])
    np.testing.assert_allclose(TipControl().goal_distances(np.zeros((2, 1, 3)), p_dlo, GOAL), [0.03, 0.04])


class _Spy:
    """Wraps a task's method, recording the scene and goal it is called with."""

    def __init__(self, method, answer=None) -> None:
        self.method, self.answer, self.calls = method, answer, []

    def __call__(self, scene, goal, *args):
        self.calls.append((scene, np.array(goal)))
        result = self.method(scene, goal, *args)
        return result if self.answer is None else self.answer(result)


def test_a_multi_step_episode_ends_at_its_length_after_settling() -> None:
    env = make_env("tip-control", multi_step=True).unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    spy = _Spy(env.task.is_done_early)
    env.task.is_done_early = spy
    evaluate = _Spy(env.task.evaluate)
    env.task.evaluate = evaluate
    action = np.zeros(env.action_space.shape, np.float32)
    for decisions in range(1, 61):  # bounded: an episode that never ends fails here, it does not hang
        _, reward, terminated, truncated, info = env.step(action)
        assert not truncated
        assert reward == pytest.approx(sum(info[k] for k in ("r_avoid", "r_distance", "r_success", "r_dyn")))
        if terminated:
            break
        assert info["sim_time_s"] == pytest.approx(0.04 * decisions)  # no settling before the end
    assert decisions == 40  # 1.6 s of 40 ms decisions
    assert info["sim_time_s"] == pytest.approx(1.6 + 0.5)  # then the cable settles for settle_s
    calls = spy.calls + evaluate.calls
    assert all(scene is env.scene and np.array_equal(goal, GOAL) for scene, goal in calls)


def test_an_early_end_is_final_without_settling() -> None:
    env = make_env("tip-control", multi_step=True).unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    env.task.is_done_early = _Spy(env.task.is_done_early, answer=lambda _: env.scene.time > 0.1)
    action = np.zeros(env.action_space.shape, np.float32)
    ends = [env.step(action)[2] for _ in range(3)]
    assert ends == [False, False, True] and env.scene.time == pytest.approx(0.12)


def test_a_single_step_episode_runs_its_plan_then_settles() -> None:
    env = make_env("tip-control").unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    _, _, terminated, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
    t_end = env.trajectory.t_end
    # The plan's end plus settle_s, rounded up to whole physics steps (the clock sums steps: rounding).
    assert terminated and t_end + 0.5 - 1e-9 <= info["sim_time_s"] < t_end + 0.5 + env.scene.timestep


def test_the_outcome_and_the_early_end_ask_the_task_about_this_scene_and_goal() -> None:
    env = make_env("tip-control", multi_step=True).unwrapped
    env.reset(seed=0, options={"goal": GOAL})
    evaluate, early = _Spy(env.task.evaluate), _Spy(env.task.is_done_early)
    env.task.evaluate, env.task.is_done_early = evaluate, early
    env.outcome()
    env.is_done_early()
    for scene, goal in evaluate.calls + early.calls:
        assert scene is env.scene and np.array_equal(goal, GOAL)
    assert len(evaluate.calls) == 1 and len(early.calls) == 1
