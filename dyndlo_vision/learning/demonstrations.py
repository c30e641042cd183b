"""Seeding an off-policy learner's replay buffer with episodes of a task's scripted baseline.

SAC learns from whatever its replay buffer holds, so episodes of a known, reasonable policy give its critic a
picture of the good region of the action space before its own exploration starts ("SAC from
demonstrations"). The demonstrations are real episodes of the training environments: they appear in the
run's monitor files, and a run reports how many it used next to its own steps.

The tasks whose registry row has a ``demonstrator`` (:data:`dyndlo_vision.tasks.TASKS`) can be
demonstrated: task IV the geometric lift of section V-B and task II the scripted vault; the demonstrators
live beside the baselines in :mod:`dyndlo_vision.tasks.baselines`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dyndlo_vision.learning.config import RunConfig
from dyndlo_vision.tasks.registry import make_env, task_entry


def seed_replay_buffer(model: Any, vec: Any, config: RunConfig, episodes: int, seed: int) -> dict[str, Any]:
    """Run ``episodes`` demonstrations in the training environments and add them to the replay buffer.

    Returns the demonstrations' figures: episodes, mean reward, successes.
    """
    demonstrate = task_entry(config.task).demonstrator
    assert demonstrate is not None, f"{config.task} has no demonstrator"  # RunConfig checked it
    rng = np.random.default_rng([seed, 0x44454D4F])
    # A local environment of the same task supplies the action encoding; the episodes run in ``vec``.
    planner = make_env(config.task, multi_step=False, **config.env_options).unwrapped
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
