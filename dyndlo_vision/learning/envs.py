"""Training's environments: the task's environment (:func:`dyndlo_vision.tasks.make_env`) behind a Monitor,
one per worker, in a vectorised environment; or all of them in one batched environment
(:class:`~dyndlo_vision.learning.vec_env.BatchedVecEnv`, ``kind="batch"``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym

from dyndlo_vision.learning.config import RANDOMIZE_CABLE_EVERY, RunConfig

#: Per-episode info keys recorded by the Monitor wrapper (monitor.csv) next to reward and length.
MONITOR_KEYWORDS = ("is_success",)
#: The vectorised environments ``make_vec_env`` builds: one process per environment, all in this process, or
#: one batched environment (the physics of all in one call on C threads).
VEC_ENV_KINDS = ("subproc", "dummy", "batch")


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

    env = make_task_env(
        config.task,
        multi_step=config.multi_step,
        render_mode=render_mode,
        **_cable_options(config, randomize),
        obs_noise=Path(config.obs_noise) if config.obs_noise else None,
        robot=config.robot,
        **config.env_options,
    )
    keywords = MONITOR_KEYWORDS + (("joint_feasible",) if config.robot else ())
    return Monitor(env, str(monitor_file) if monitor_file else None, info_keywords=keywords,
                   override_existing=not append_monitor)


def _cable_options(config: RunConfig, randomize: bool | None) -> dict[str, Any]:
    """The environment's cable randomisation: the run's (``randomize`` None), none (False), or the run's
    ranges even if it trains on the nominal cable (True)."""
    from dyndlo_vision.tasks.wrappers import RandomCables

    cables = config.random_cables
    if randomize is not None and not randomize:
        cables = None
    elif randomize and cables is None:
        cables = RandomCables(config.cable_ranges, every_episodes=RANDOMIZE_CABLE_EVERY)
    return {} if cables is None else cables.env_options(config.task)


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
    """``n_envs`` environments in a DummyVecEnv, a SubprocVecEnv or one batched environment (``kind``
    ``"dummy"``, ``"subproc"``, ``"batch"``), seeded ``seed, seed + 1, ...``.

    The batched one gives the same episodes as the others on the same seeds; its monitor file is
    ``monitor_dir/batch.monitor.csv`` (one row per episode of every simulation).

    Raises:
        ValueError: An unknown kind, or ``"batch"`` with what it does not simulate (a real arm's plan checks).
    """
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if kind not in VEC_ENV_KINDS:
        raise ValueError(f"vectorised environment {kind!r}; expected one of {VEC_ENV_KINDS}")
    if kind == "batch":
        return _batched_vec_env(config, n_envs, seed, monitor_dir, randomize, append_monitor)
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


def _batched_vec_env(
    config: RunConfig, n_envs: int, seed: int, monitor_dir: Path | None, randomize: bool | None,
    append_monitor: bool,
) -> Any:
    from stable_baselines3.common.vec_env import VecMonitor

    from dyndlo_vision.learning.vec_env import BatchedVecEnv
    from dyndlo_vision.tasks.batched import BatchedEpisodes
    from dyndlo_vision.tasks.registry import make_task

    if config.robot is not None:
        raise ValueError(f"--vec-env batch does not judge plans on a real arm (--robot {config.robot}); use "
                         "--vec-env subproc or dummy")
    episodes = BatchedEpisodes(
        make_task(config.task, multi_step=config.multi_step, **config.env_options),
        n_envs,
        **_cable_options(config, randomize),
        obs_noise=Path(config.obs_noise) if config.obs_noise else None,
    )
    vec = BatchedVecEnv(episodes)
    vec.seed(seed)
    monitor = VecMonitor(vec, None, info_keywords=MONITOR_KEYWORDS)  # episode statistics, as Monitor's
    if monitor_dir is None:
        return monitor
    from stable_baselines3.common.monitor import ResultsWriter

    # The writer made here rather than by VecMonitor, which always starts its file afresh: a resumed run
    # continues its episode log.
    monitor.results_writer = ResultsWriter(
        str(monitor_dir / "batch"), header={"t_start": monitor.t_start, "env_id": config.env_id},
        extra_keys=MONITOR_KEYWORDS, override_existing=not append_monitor,
    )
    return monitor
