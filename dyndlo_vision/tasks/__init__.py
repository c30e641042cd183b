"""The four DynDLO tasks as Gymnasium environments, their registry and the training wrappers.

    from dyndlo_vision.tasks import make_env
    env = make_env("tip-control", multi_step=True, render_mode="rgb_array")
    # or, once dyndlo_vision is imported: gym.make("DynDLO/TipControl-v0", multi_step=True)

* :mod:`~.base`: the environment (:class:`DynDLOEnv`) and what a task defines (:class:`Task`);
* one module per task family, and :mod:`~.rewards` with the paper's reward terms as pure functions;
* :mod:`~.registry`: one row per task (:data:`TASKS`) and the one environment factory (:func:`make_env`);
* :mod:`~.baselines`: scripted policies and demonstrators;
* :mod:`~.noise` and :mod:`~.wrappers`: the fitted observation-noise model and cable randomisation that
  training uses instead of rendering.
"""

from __future__ import annotations

from dyndlo_vision.tasks.base import CONTROL_PERIOD_S, DynDLOEnv, EpisodeMonitor, Task
from dyndlo_vision.tasks.hooking import Hooking
from dyndlo_vision.tasks.registry import ENV_IDS, TASKS, TaskEntry, make_env, register_envs, task_entry
from dyndlo_vision.tasks.time_oscillation import TimeOscillation
from dyndlo_vision.tasks.tip_control import TipControl
from dyndlo_vision.tasks.vaulting import Vaulting

__all__ = [
    "CONTROL_PERIOD_S",
    "ENV_IDS",
    "TASKS",
    "DynDLOEnv",
    "EpisodeMonitor",
    "Hooking",
    "Task",
    "TaskEntry",
    "TimeOscillation",
    "TipControl",
    "Vaulting",
    "make_env",
    "register_envs",
    "task_entry",
]
