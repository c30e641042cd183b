"""The batched environment gives what the single environment gives: same seeds and actions, the same rewards,
outcomes, infos and observations, to the last bit (``tasks/batched.py``, ``learning/vec_env.py``)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from dyndlo_vision.learning.vec_env import BatchedVecEnv
from dyndlo_vision.sim.batch import MujocoBatch, make_batch_physics
from dyndlo_vision.tasks import TipControl, make_env, task_entry
from dyndlo_vision.tasks.batched import BatchedEpisodes


def _same_info(a: dict[str, Any], b: dict[str, Any], where: str) -> None:
    assert set(a) == set(b), f"{where}: info keys differ: {set(a) ^ set(b)}"
    for key, value in a.items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(value, b[key], err_msg=f"{where}: info[{key!r}]")
        else:
            assert value == b[key], f"{where}: info[{key!r}] {value!r} != {b[key]!r}"


def run_both(task: str, multi_step: bool, n: int, steps: int, seed: int = 7, **kwargs: Any) -> dict[str, int]:
    """Step a DummyVecEnv of single environments and the batched VecEnv with the same seeds and random
    actions; assert every return is equal; count episodes and successes."""
    options = {k: v for k, v in kwargs.items() if k not in ("randomize_cable_every", "obs_noise")}
    wrappers = {k: v for k, v in kwargs.items() if k in ("randomize_cable_every", "obs_noise")}
    single = DummyVecEnv([lambda: make_env(task, multi_step=multi_step, **kwargs) for _ in range(n)])
    batched = BatchedVecEnv(BatchedEpisodes(task_entry(task).task_class(multi_step=multi_step, **options), n,
                                            nthread=2, **wrappers))
    single.seed(seed)
    batched.seed(seed)
    np.testing.assert_array_equal(single.reset(), batched.reset())
    for a, b in zip(single.reset_infos, batched.reset_infos, strict=True):
        _same_info(a, b, "reset")
    rng = np.random.default_rng(seed)
    counts = {"episodes": 0, "successes": 0}
    for k in range(steps):
        actions = rng.uniform(-1, 1, (n, *single.action_space.shape)).astype(np.float32)
        obs_a, rew_a, done_a, info_a = single.step(actions)
        obs_b, rew_b, done_b, info_b = batched.step(actions)
        np.testing.assert_array_equal(rew_a, rew_b, err_msg=f"step {k}: rewards")
        np.testing.assert_array_equal(done_a, done_b, err_msg=f"step {k}: dones")
        for i, (a, b) in enumerate(zip(info_a, info_b, strict=True)):
            _same_info(a, b, f"step {k}, simulation {i}")
        np.testing.assert_array_equal(obs_a, obs_b, err_msg=f"step {k}: observations")
        # The whole simulation state too: time, positions, velocities, solver warm start, controls, marker.
        states = batched.episodes.physics.states(np.arange(n))
        for i, env in enumerate(single.envs):
            np.testing.assert_array_equal(env.unwrapped.scene.state(), states[i],
                                          err_msg=f"step {k}: state of simulation {i}")
        counts["episodes"] += int(done_a.sum())
        ended = [info for info, d in zip(info_a, done_a, strict=True) if d]
        counts["successes"] += sum(bool(info["is_success"]) for info in ended)
    return counts


def test_single_step_tip_control_is_identical() -> None:
    counts = run_both("tip-control", False, 3, 4)
    assert counts["episodes"] == 12


def test_multi_step_tip_control_is_identical_through_resets_and_hits() -> None:
    # 40 decisions of 3 simulations: episodes end by hits and by time, and restart with their own goals.
    counts = run_both("tip-control", True, 3, 45, seed=7)
    assert counts["episodes"] >= 3 and counts["successes"] >= 1


@pytest.mark.slow
def test_random_cables_and_observation_noise_are_identical() -> None:
    # A new cable every episode (per-simulation model fields), the shipped tracker-noise model on P_DLO.
    run_both("tip-control", False, 2, 3, randomize_cable_every=1, obs_noise="packaged")
    counts = run_both("tip-control", True, 3, 45, randomize_cable_every=2, obs_noise="packaged")
    assert counts["episodes"] >= 3


@pytest.mark.slow
@pytest.mark.parametrize("task", ["hooking", "time-oscillation"])
def test_other_tasks_are_identical(task: str) -> None:
    # Their rewards read the scene (the hook, the tip's oscillation) and task IV's monitor hook keeps state.
    run_both(task, False, 2, 2)


def test_per_simulation_cable_runs_as_its_own_compiled_model() -> None:
    from dataclasses import replace

    from dyndlo_vision.sim import CableParams, Scene

    nominal = make_env("tip-control").unwrapped.scene
    other = Scene(replace(nominal.config, cable=CableParams(length_m=0.55, mass_kg=0.013, young_pa=4e6,
                                                            damping_s=0.01)))
    physics = MujocoBatch(nominal.model, 2, nthread=1)
    physics.set_model(1, other.model)
    physics.set_states(np.arange(2), np.stack([nominal.reset_state(), other.reset_state()]))
    home = other.gripper_home
    t = 0.001 * np.arange(300)
    ref = home + np.stack([0.2 * np.sin(8 * t), 0 * t, 0.1 * np.sin(5 * t)], axis=1)[:, None]
    ctrl = other.tcp_controls(ref, np.zeros_like(ref))
    _, qpos, _ = physics.rollout(np.arange(2), np.stack([ctrl, ctrl]))
    other.reset()
    own, _, _ = other.rollout(ctrl)
    nominal.reset()
    base, _, _ = nominal.rollout(ctrl)
    np.testing.assert_array_equal(qpos[1], own)
    np.testing.assert_array_equal(qpos[0], base)
    assert np.abs(own - base).max() > 1e-3  # the cables do move differently


def test_bad_input_is_refused_with_what_was_expected() -> None:
    with pytest.raises(ValueError, match="num_envs must be a positive integer, got 0"):
        BatchedEpisodes(TipControl(), 0)
    with pytest.raises(ValueError, match="unknown physics backend 'nope'"):
        BatchedEpisodes(TipControl(), 1, backend="nope")
    with pytest.raises(ValueError, match="unknown physics backend 'nope'.*mujoco-batch"):
        make_batch_physics("nope", make_env("tip-control").unwrapped.model, 1)
    episodes = BatchedEpisodes(TipControl(), 2, nthread=1)
    episodes.reset([0, 1], [0, 1], [None, None])
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 9\), got shape \(9,\)"):
        episodes.step(np.zeros(9, dtype=np.float32))
    with pytest.raises(ValueError, match="simulation 1: action must be finite, got nan at index 0"):
        episodes.step(np.array([[0.0] * 9, [np.nan] + [0.0] * 8], dtype=np.float32))
    _, _, done, _ = episodes.step(np.zeros((2, 9), dtype=np.float32))  # the refused call changed nothing
    assert done.all()
    with pytest.raises(RuntimeError, match=r"episodes of simulations \[0, 1\] have ended: reset them first"):
        episodes.step(np.zeros((2, 9), dtype=np.float32))


def _monitor_fields(mon: Any) -> tuple[Any, ...]:
    last = None if mon.last_p_dlo is None else tuple(mon.last_p_dlo)
    return (dict(mon.avoid), mon.max_tcp_speed_m_s, mon.max_mean_height_m, mon.min_goal_distance_m, last,
            mon.samples)


@pytest.mark.parametrize("task_name", ["tip-control", "time-oscillation", "hooking"])
def test_monitor_of_many_equals_the_single_monitor_across_calls(task_name: str) -> None:
    from dyndlo_vision.tasks.base import EpisodeMonitor, record_samples
    from dyndlo_vision.tasks.batched import record_samples_many
    from dyndlo_vision.tasks.registry import make_task

    rng = np.random.default_rng(3)
    m = 4
    goals = np.array([[0.8, 0.0, 0.4]] * m) + rng.normal(0, 0.05, (m, 3))
    tasks_a = [make_task(task_name) for _ in range(m)]
    tasks_b = [make_task(task_name) for _ in range(m)]
    for t in tasks_a + tasks_b:
        t.begin_episode()
    one, many = [EpisodeMonitor() for _ in range(m)], [EpisodeMonitor() for _ in range(m)]
    for call in range(3):
        counts = [int(c) for c in rng.integers(2, 30, m)]
        times = [0.1 * call + 0.002 * np.arange(1, c + 1) for c in counts]
        n_g = tasks_a[0].scene_config().num_grippers  # hooking: two grippers
        p = [np.array([0.45, 0.0, 0.6]) + rng.normal(0, 0.3, (c, n_g, 3)) for c in counts]
        v = [rng.normal(0, 1.2, (c, n_g, 3)) for c in counts]
        p_dlo = [goals[k] + rng.normal(0, 0.1, (c, 3)) for k, c in enumerate(counts)]
        # Simulation 0's tip sweeps straight through its target between this call's last sample and the
        # next call's first: only the segment across the calls comes within the target.
        side = 1.0 if call % 2 == 0 else -1.0
        p_dlo[0][-1] = goals[0] + side * np.array([0.2, 0.0, 0.0])
        if call > 0:
            p_dlo[0][0] = goals[0] + side * np.array([0.2, 0.0, 0.0])  # across from the last call's last
        for k in range(m):
            record_samples(tasks_a[k], one[k], goals[k], times[k], p[k], v[k], p_dlo[k])
        record_samples_many(tasks_b, many, goals, times, p, v, p_dlo)
        for k in range(m):
            assert _monitor_fields(one[k]) == _monitor_fields(many[k]), f"call {call}, simulation {k}"
            assert vars(tasks_a[k]).keys() == vars(tasks_b[k]).keys()
    if task_name == "tip-control":
        assert one[0].min_goal_distance_m < 1e-9  # the swept segment through the target was seen
