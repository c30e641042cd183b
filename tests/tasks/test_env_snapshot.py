"""Snapshots of an episode: a restored branch is the episode a fresh run with the same actions would be."""

from __future__ import annotations

import numpy as np
import pytest

import dyndlo_vision  # noqa: F401
from dyndlo_vision.tasks.registry import make_env

#: Decisions before the branch point; the two branches then take different actions.
PREFIX = 4


def _actions(seed: int, n: int, size: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.4, 0.4, (n, size)).astype(np.float32)


def _run(env, actions, coast: bool = True):
    """Step each action, then coast to the end of the episode; the last observation and info."""
    for a in actions:
        obs, _, done, _, info = env.step(a)
        if done:
            return obs, info
    while coast and not done:
        obs, _, done, _, info = env.coast()
    return obs, info


@pytest.mark.parametrize("task", ["tip-control", "vaulting"])
def test_a_restored_branch_is_a_fresh_episode_with_the_same_actions(task: str) -> None:
    """Plan, monitor (closest approach, limits), decision count and physics all come back: after a branch that
    took other actions, the restored one ends exactly as an episode run from the reset with its actions."""
    env = make_env(task, multi_step=True)
    u = env.unwrapped
    size = u.action_space.shape[0]
    prefix, second = _actions(1, PREFIX, size), _actions(3, 2, size)
    first = np.ones((2, size), np.float32)  # a violent branch: it breaks a limit, the restored one must not
    env.reset(seed=5)
    _run(u, prefix, coast=False)
    snapshot = u.snapshot()
    before = u.observation()
    violent = _run(u, first)[1]  # to the end of the episode along one branch
    u.restore(snapshot)
    assert np.array_equal(u.observation(), before)
    got = _run(u, second)
    env.reset(seed=5)
    want = _run(u, np.vstack([prefix, second]))
    assert np.array_equal(got[0], want[0])
    assert got[1] == want[1]
    assert any(violent["avoid"].values()) and not any(got[1]["avoid"].values())
    u.restore(snapshot)  # a snapshot restores any number of times
    assert np.array_equal(_run(u, second)[0], want[0])
    env.close()


def test_coast_keeps_the_plan_and_needs_one() -> None:
    env = make_env("tip-control", multi_step=True)
    u = env.unwrapped
    env.reset(seed=2)
    with pytest.raises(RuntimeError, match="step"):
        u.coast()
    u.step(_actions(4, 1, u.action_space.shape[0])[0])
    plan = u.trajectory
    for _ in range(3):
        u.coast()
    assert u.trajectory is plan  # no re-plan
    p, _ = u.replanner.commanded_state(u.scene.time)
    assert np.linalg.norm(u.scene.tcp_positions()[0] - p) < 0.02  # the TCP tracks the same plan
    env.close()
    single = make_env("tip-control", multi_step=False)
    single.reset(seed=2)
    with pytest.raises(RuntimeError, match="multi-step"):
        single.unwrapped.coast()
    single.close()


def test_restore_refuses_a_snapshot_of_another_model() -> None:
    tip, vault = make_env("tip-control", multi_step=True), make_env("vaulting", multi_step=True)
    tip.reset(seed=0)
    vault.reset(seed=0)
    with pytest.raises(ValueError, match="another cable or task"):
        vault.unwrapped.restore(tip.unwrapped.snapshot())
    tip.unwrapped.set_robot("ur5e")
    with pytest.raises(RuntimeError, match="set_robot"):
        tip.unwrapped.snapshot()
    tip.close()
    vault.close()
