"""Training's environments: the task's environment (:func:`dyndlo_vision.tasks.make_env`) behind a Monitor,
one per worker, in a vectorised environment."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym

from dyndlo_vision.learning.config import RunConfig

#: Per-episode info keys recorded by the Monitor wrapper (monitor.csv) next to reward and length.
MONITOR_KEYWORDS = ("is_success",)
#: A randomised training cable is redrawn every this many episodes (a new cable is a new MuJoCo model).
RANDOMIZE_CABLE_EVERY = 10


def make_training_env(
    config: RunConfig,
    monitor_file: Path | None = None,
    render_mode: str | None = None,
    randomize: bool | None = None,
    append_monitor: bool = False,
) -> gym.Env[Any, Any]:
    """One environment of the run: the task, optional cable randomisation and observation noise, a Monitor.

    ``append_monitor`` continues an existing monitor file (a resumed run) instead of starting it afresh.
    """
    from stable_baselines3.common.monitor import Monitor

    from dyndlo_vision.tasks.registry import make_env as make_task_env

    randomize = config.randomize_cable if randomize is None else randomize
    env = make_task_env(
        config.task,
        multi_step=config.multi_step,
        render_mode=render_mode,
        randomize_cable_every=RANDOMIZE_CABLE_EVERY if randomize else None,
        obs_noise=Path(config.obs_noise) if config.obs_noise else None,
        robot=config.robot,
        **config.env_options,
    )
    keywords = MONITOR_KEYWORDS + (("joint_feasible",) if config.robot else ())
    return Monitor(env, str(monitor_file) if monitor_file else None, info_keywords=keywords,
                   override_existing=not append_monitor)


def env_factory(
    config: RunConfig, monitor_file: Path | None, randomize: bool | None = None, append_monitor: bool = False
) -> Callable[[], gym.Env[Any, Any]]:
    """A picklable thunk for SubprocVecEnv."""

    def thunk() -> gym.Env[Any, Any]:
        return make_training_env(config, monitor_file, randomize=randomize, append_monitor=append_monitor)

    return thunk


def make_vec_env(
    config: RunConfig,
    n_envs: int,
    seed: int,
    monitor_dir: Path | None,
    kind: str,
    randomize: bool | None = None,
    append_monitor: bool = False,
) -> Any:
    """``n_envs`` environments in a DummyVecEnv or SubprocVecEnv, seeded ``seed, seed + 1, ...``."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    thunks = [
        env_factory(
            config, monitor_dir / f"env{rank}" if monitor_dir is not None else None, randomize, append_monitor
        )
        for rank in range(n_envs)
    ]
    vec = (
        SubprocVecEnv(thunks, start_method="forkserver")
        if kind == "subproc" and n_envs > 1
        else DummyVecEnv(thunks)
    )
    vec.seed(seed)
    return vec
