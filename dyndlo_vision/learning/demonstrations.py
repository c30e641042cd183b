"""Seeding an off-policy learner's replay buffer with episodes of a task's scripted baseline.

SAC learns from whatever its replay buffer holds, so episodes of a known, reasonable policy give its critic a
picture of the good region of the action space before its own exploration starts ("SAC from
demonstrations"). The demonstrations are real episodes of the training environments: they appear in the
run's monitor files, and a run reports how many it used next to its own steps.

Two tasks have a scripted baseline (:data:`DEMONSTRATORS`): task IV the geometric lift of section V-B, whose
demonstrations draw the trajectory time uniformly from ``GEOMETRIC_TIME_RANGE_S``, and task II the scripted
vault :class:`~dyndlo_vision.tasks.baselines.FlickVault`. Both add Gaussian noise of a per-episode scale drawn
from ``NOISE_SCALES`` to the normalised action, so the buffer covers the baseline family and its
neighbourhood, not one point.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from dyndlo_vision.learning.config import RunConfig

#: Trajectory times of the geometric-lift demonstrations (s); the paper's results lie at 1.35-1.47 s.
GEOMETRIC_TIME_RANGE_S = (1.0, 2.0)
#: Standard deviations of the noise added to a demonstration's normalised action, one drawn per episode.
NOISE_SCALES = (0.0, 0.05, 0.15)


def _perturbed(action: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    scale = NOISE_SCALES[rng.integers(len(NOISE_SCALES))]
    return np.clip(action + scale * rng.standard_normal(action.shape), -1.0, 1.0).astype(np.float32)


def geometric_demonstration(env: Any, obs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One perturbed geometric-lift action for a single-step task IV environment."""
    from dyndlo_vision.tasks.baselines import GeometricLift

    total_time_s = rng.uniform(*GEOMETRIC_TIME_RANGE_S)
    return _perturbed(GeometricLift(env, total_time_s)(obs), rng)


def vault_demonstration(env: Any, obs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One perturbed scripted-vault action for a single-step task II environment."""
    from dyndlo_vision.tasks.baselines import FlickVault

    return _perturbed(FlickVault(env)(obs), rng)


#: The demonstrator of each task that has one: ``(env, obs, rng) -> action``.
DEMONSTRATORS: dict[str, Callable[[Any, np.ndarray, np.random.Generator], np.ndarray]] = {
    "time-oscillation": geometric_demonstration,
    "vaulting": vault_demonstration,
}


def seed_replay_buffer(model: Any, vec: Any, config: RunConfig, episodes: int, seed: int) -> dict[str, Any]:
    """Run ``episodes`` demonstrations in the training environments and add them to the replay buffer.

    Returns the demonstrations' figures: episodes, mean reward, successes.
    """
    demonstrate = DEMONSTRATORS[config.task]
    rng = np.random.default_rng([seed, 0x44454D4F])
    # A local environment of the same task supplies the action encoding; the episodes run in ``vec``.
    planner = gym.make(config.env_id, multi_step=False, **config.env_options).unwrapped
    obs = vec.reset()
    rewards: list[float] = []
    successes = 0
    while len(rewards) < episodes:
        actions = np.stack([demonstrate(planner, o, rng) for o in obs])
        next_obs, reward, done, infos = vec.step(actions)
        final_obs = next_obs.copy()
        for i, info in enumerate(infos):
            if done[i] and "terminal_observation" in info:
                final_obs[i] = info["terminal_observation"]
        model.replay_buffer.add(obs, final_obs, actions, reward, done, infos)
        rewards.extend(float(r) for r in reward)
        successes += sum(bool(info.get("is_success")) for info in infos)
        obs = next_obs
    planner.close()
    return {"episodes": len(rewards), "mean_reward": float(np.mean(rewards)), "successes": successes}
