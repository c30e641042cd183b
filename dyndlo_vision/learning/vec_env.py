"""The batched environment behind stable-baselines3's ``VecEnv`` API.

:class:`BatchedVecEnv` steps the N episodes of a :class:`~dyndlo_vision.tasks.batched.BatchedEpisodes` as
``DummyVecEnv`` steps N environments: the same seeds (``seed(s)`` gives simulation ``i`` the seed ``s + i``
at the next reset), options, automatic resets with ``info["terminal_observation"]``,
``TimeLimit.truncated`` and ``reset_infos``; with the physics of all N in one call.
``learning.envs.make_vec_env(..., kind="batch")`` builds it for training.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from dyndlo_vision.tasks.batched import BatchedEpisodes


class BatchedVecEnv(VecEnv):  # type: ignore[misc]
    """N simulations of one task as one ``VecEnv`` (see the module docstring).

    Args:
        episodes: The batched episodes.
    """

    def __init__(self, episodes: BatchedEpisodes) -> None:
        self.episodes = episodes
        super().__init__(episodes.num_envs, episodes.observation_space, episodes.action_space)
        self._actions: NDArray[np.float32] | None = None
        self.metadata = {"render_modes": []}

    def reset(self) -> NDArray[np.float32]:
        ids = list(range(self.num_envs))
        obs, infos = self.episodes.reset(ids, list(self._seeds), list(self._options))
        self.reset_infos = infos
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: NDArray[np.float32]) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        assert self._actions is not None, "step_async first"
        actions = self._actions.reshape(self.num_envs, *self.action_space.shape)
        obs, rewards, dones, infos = self.episodes.step(actions)
        self._actions = None
        done_ids = np.flatnonzero(dones)
        for info in infos:
            info["TimeLimit.truncated"] = False  # episodes end by themselves, never by a time limit
        for i in done_ids:
            infos[i]["terminal_observation"] = obs[i].copy()
        if done_ids.size:
            new_obs, reset_infos = self.episodes.reset(done_ids.tolist(), [None] * done_ids.size,
                                                       [None] * done_ids.size)
            obs[done_ids] = new_obs
            for k, i in enumerate(done_ids):
                self.reset_infos[i] = reset_infos[k]
        return obs, rewards.astype(np.float32), dones.copy(), infos

    def close(self) -> None:
        """Nothing to release: the physics is freed with the object."""

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.episodes, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.episodes, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        raise AttributeError(f"the batched environment has no per-environment method {method_name!r}")

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[NDArray[np.uint8] | None]:
        return [None for _ in range(self.num_envs)]
