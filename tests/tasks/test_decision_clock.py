"""The decision clock: the time since the episode began, appended to the student's observation, online (the
loop's policy wrapper, an environment wrapper) and offline (fitted data) alike."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

import dyndlo_vision  # noqa: F401  (registers the environment ids)
from dyndlo_vision import policies
from dyndlo_vision.tasks.wrappers import DecisionClock, PDloHistory, StudentFeatures, StudentFeaturesWrapper

T = 0.04


def test_the_clock_counts_decisions_since_the_reset() -> None:
    clock = DecisionClock(T)
    obs = np.arange(12, dtype=np.float32)
    out = np.array([clock(obs) for _ in range(5)])
    assert out.shape == (5, 13)
    assert np.array_equal(out[:, :12], np.tile(obs, (5, 1)))
    assert np.allclose(out[:, 12], T * np.arange(5))
    clock.reset()
    assert clock(obs)[12] == 0.0


def test_stack_restarts_the_clock_at_every_episode() -> None:
    obs = np.zeros((7, 12), dtype=np.float32)
    ids = np.array([3, 3, 3, 9, 9, 9, 9])
    out = DecisionClock(T).stack(obs, ids)
    assert np.allclose(out[:, 12], T * np.array([0, 1, 2, 0, 1, 2, 3]))


def test_student_features_put_the_history_first_then_the_clock() -> None:
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(6, 12)).astype(np.float32)
    ids = np.zeros(6)
    both = StudentFeatures(12, p_dlo_history=2, clock=True).stack(obs, ids)
    history = PDloHistory.for_observation_size(2, 12).stack(obs, ids)
    assert both.shape == (6, 12 + 6 + 1)
    assert np.array_equal(both[:, :18], history)
    assert np.allclose(both[:, 18], T * np.arange(6))
    assert StudentFeatures(12, clock=True).size == 1 and StudentFeatures(12, 3, True).size == 10


@pytest.mark.parametrize("table_ii, history, clock", [(12, 2, True), (12, 0, True), (18, 3, False)])
def test_the_features_of_a_students_input_size(table_ii, history, clock) -> None:
    """A loaded student knows only its input size: table II is what is left after the features."""
    features = StudentFeatures.for_input_size(table_ii + 3 * history + int(clock), history, clock)
    assert features.observation_size == table_ii and features.size == 3 * history + int(clock)
    if history:  # P_DLO's slice follows the number of grippers
        assert features.parts[0].p_dlo == slice(table_ii - 6, table_ii - 3)


@pytest.mark.parametrize("history, clock, match", [(0, False, "no student feature"), (-1, True, "history"),
                                                    (1.5, True, "history"), (True, True, "history")])
def test_bad_feature_settings_are_refused(history, clock, match) -> None:
    with pytest.raises(ValueError, match=match):
        StudentFeatures(12, history, clock)


def test_the_wrapper_and_the_loaded_policy_see_the_same_clock(tmp_path) -> None:
    """A student saved with ``decision_clock`` loads as a policy that keeps the clock itself: fed table-II
    observations, it acts as its network does on the observations the wrapper gave during training; without
    a reset, its clock runs on into the next episode."""
    from dyndlo_vision.learning.distill import new_student

    env = StudentFeaturesWrapper(gym.make("DynDLO/TipControl-v0", multi_step=True), clock=True)
    assert env.observation_space.shape == (13,)
    network = new_student(env, (16,), seed=3)
    with torch.no_grad():  # make the network's output depend strongly on the clock
        network.policy.mlp_extractor.policy_net[0].weight[:, 12] = 50.0
    network.save(tmp_path / "model.zip")
    meta = {"algo": "ppo", "multi_step": True, "decision_clock": True}
    (tmp_path / "model.json").write_text(json.dumps(meta))
    model = policies.load(tmp_path / "model.zip", env=gym.make("DynDLO/TipControl-v0", multi_step=True))
    assert isinstance(model, policies.HistoryPolicy)
    assert model.observation_space.shape == (12,)

    seen = [env.reset(seed=5)[0]]
    action = np.full(env.action_space.shape, 0.2, dtype=np.float32)
    for _ in range(3):
        seen.append(env.step(action)[0])
    seen_arr = np.array(seen)
    assert np.allclose(seen_arr[:, 12], T * np.arange(4))
    offline = np.array([network.predict(o, deterministic=True)[0] for o in seen_arr])
    model.reset()
    online = np.array([model.predict(o[:12])[0] for o in seen_arr])
    assert np.allclose(online, offline, atol=1e-6)
    stale = model.predict(seen_arr[0, :12])[0]  # no reset: decision 4's clock on decision 0's observation
    assert not np.allclose(stale, offline[0], atol=1e-3)
    model.reset()
    assert np.allclose(model.predict(seen_arr[0, :12])[0], offline[0], atol=1e-6)
    env.close()
