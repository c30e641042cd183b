"""P_DLO history: finite-difference velocities appended to the table-II observation, online and offline."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import dyndlo_vision  # noqa: F401  (registers the environment ids)
from dyndlo_vision.tasks.noise import packaged_noise_model_path
from dyndlo_vision.tasks.wrappers import NoisyObservation, PDloHistory, PDloHistoryWrapper

T = 0.04
P_DLO = slice(6, 9)  # one gripper: position 0:3, velocity 3:6, P_DLO 6:9, target 9:12


def observations(points: np.ndarray) -> np.ndarray:
    """Table-II observations (one gripper) whose P_DLO runs through ``points``; the rest is arbitrary."""
    obs = np.tile(np.arange(12, dtype=np.float32), (len(points), 1))
    obs[:, P_DLO] = points
    return obs


def test_history_is_the_velocity_over_the_last_periods() -> None:
    """Closed form: P_DLO on p0 + v t + a t^2 / 2 gives (p(t) - p(t - kT)) / kT = v + a (t - kT / 2)."""
    v, a = np.array([1.0, -0.5, 0.2]), np.array([0.0, 3.0, -9.81])
    t = T * np.arange(6)
    points = np.array([0.4, 0.0, 0.3]) + t[:, None] * v + 0.5 * t[:, None] ** 2 * a
    history = PDloHistory(3, P_DLO, T)
    out = np.array([history(o) for o in observations(points)])
    assert out.shape == (6, 12 + 9)
    assert np.array_equal(out[:, :12], observations(points))  # the observation itself is unchanged
    for i in range(6):
        for k in (1, 2, 3):
            expected = v + a * (t[i] - k * T / 2) if i >= k else (points[i] - points[0]) / (k * T)
            assert np.allclose(out[i, 12 + 3 * (k - 1) : 15 + 3 * (k - 1)], expected, atol=1e-4), (i, k)
    assert np.all(out[0, 12:] == 0)  # at reset the cable is taken to be at rest


def test_stack_is_the_online_history_with_a_reset_per_episode() -> None:
    rng = np.random.default_rng(0)
    obs = observations(rng.normal(size=(9, 3)))
    ids = np.array([5, 5, 5, 5, 8, 8, 8, 8, 8])
    stacked = PDloHistory(2, P_DLO).stack(obs, ids)
    online = PDloHistory(2, P_DLO)
    expected = []
    for i, row in enumerate(obs):
        if i in (0, 4):
            online.reset()
        expected.append(online(row))
    assert np.allclose(stacked, np.array(expected))
    assert np.all(stacked[4, 12:] == 0)  # the second episode does not see the jump from the first one


def test_without_a_reset_the_next_episode_sees_the_last_one() -> None:
    """What a missing reset costs: an episode's first decision takes the jump between episodes for motion."""
    history = PDloHistory(1, P_DLO)
    obs = observations(np.array([[0.0, 0.0, 0.3], [0.1, 0.0, 0.3], [0.5, 0.0, 0.6]]))
    history(obs[0]), history(obs[1])
    assert not np.all(history(obs[2])[12:] == 0)
    history.reset()
    assert np.all(history(obs[2])[12:] == 0)


def test_wrapper_appends_the_history_of_the_p_dlo_the_policy_sees() -> None:
    """Outside the noise wrapper, the history is of the corrupted P_DLO; reset starts it afresh."""
    noisy = NoisyObservation(gym.make("DynDLO/TipControl-v0", multi_step=True), packaged_noise_model_path())
    env = PDloHistoryWrapper(noisy, 2)
    assert env.observation_space.shape == (18,)
    assert env.observation_space.contains(np.zeros(18, dtype=np.float32))
    base = NoisyObservation(gym.make("DynDLO/TipControl-v0", multi_step=True), packaged_noise_model_path())
    action = np.full(env.action_space.shape, 0.3, dtype=np.float32)
    for seed in (3, 4):  # two episodes: the second starts afresh
        seen, plain = [env.reset(seed=seed)[0]], [base.reset(seed=seed)[0]]
        for _ in range(4):
            seen.append(env.step(action)[0])
            plain.append(base.step(action)[0])
        seen_arr, plain_arr = np.array(seen), np.array(plain)
        assert np.array_equal(seen_arr[:, :12], plain_arr)
        assert np.allclose(seen_arr, PDloHistory(2, P_DLO).stack(plain_arr, np.zeros(len(plain_arr))))
        assert np.all(seen_arr[0, 12:] == 0) and np.any(seen_arr[-1, 12:] != 0)
    env.close()
    base.close()


@pytest.mark.parametrize("length, period, size", [(0, T, 12), (1.5, T, 12), (2, 0.0, 12), (2, T, 13)])
def test_bad_history_settings_are_refused(length, period, size) -> None:
    with pytest.raises(ValueError, match="history length|control period|observation of length"):
        PDloHistory.for_observation_size(length, size, period)
