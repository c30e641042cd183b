"""The loop's NumPy forward pass gives the actions stable-baselines3's ``predict`` gives."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision import policies
from dyndlo_vision.policies.actor import NumpyActor, deterministic_policy


def _observations(space, n: int, seed: int) -> np.ndarray:
    """Observations inside the space and far outside it (so that clipped and saturated actions occur)."""
    rng = np.random.default_rng(seed)
    scale = rng.choice([0.3, 1.0, 5.0, 30.0], size=(n, 1))
    return (scale * rng.standard_normal((n, *space.shape))).astype(np.float32)


@pytest.mark.parametrize("name", policies.available())
def test_every_shipped_policy_acts_as_predict(name: str) -> None:
    reference, fast_model = policies.load(name), policies.load(name)
    act = deterministic_policy(fast_model)
    if not hasattr(fast_model, "sb3_model"):
        assert isinstance(act, NumpyActor)  # the loop gets the fast path for every shipped policy
    obs = _observations(reference.observation_space, 120, seed=len(name))
    low, high = reference.action_space.low, reference.action_space.high
    at_bound = 0
    for k, o in enumerate(obs):
        if k % 40 == 0 and hasattr(reference, "reset"):  # a history policy: episodes start afresh in both
            reference.reset()
            fast_model.reset()
        expected = reference.predict(o, deterministic=True)[0]
        got = act(o)
        assert got.shape == expected.shape
        np.testing.assert_allclose(got, expected, atol=2e-5, rtol=1e-5)
        at_bound += int(np.any(np.isclose(expected, low, atol=1e-4) | np.isclose(expected, high, atol=1e-4)))
    assert at_bound > 0, "no action reached the space's bounds: the clip and the rescale went untested"


def test_a_policy_it_cannot_reproduce_keeps_predict() -> None:
    import gymnasium as gym
    from stable_baselines3 import PPO

    env = gym.make("Pendulum-v1")
    model = PPO("MlpPolicy", env, use_sde=True, n_steps=64, seed=0, device="cpu")
    with pytest.raises(ValueError, match="use_sde"):
        NumpyActor.from_sb3(model)
    act = deterministic_policy(model)
    assert not isinstance(act, NumpyActor)
    o = env.observation_space.sample()
    np.testing.assert_allclose(act(o), model.predict(o, deterministic=True)[0])


def test_a_wrong_observation_size_is_named() -> None:
    act = NumpyActor.from_sb3(policies.load("tip-control-single-step"))
    with pytest.raises(ValueError, match=r"12 numbers, got shape \(13,\)"):
        act(np.zeros(13))
