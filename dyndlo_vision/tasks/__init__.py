"""The four DynDLO tasks as Gymnasium environments, and their registration.

    import gymnasium as gym, dyndlo_vision
    env = gym.make("DynDLO/TipControl-v0", multi_step=True, render_mode="rgb_array")
"""

from __future__ import annotations

import inspect
from typing import Any

import gymnasium as gym

from dyndlo_vision.tasks.base import CONTROL_PERIOD_S, DynDLOEnv, EpisodeMonitor, Task
from dyndlo_vision.tasks.hooking import Hooking
from dyndlo_vision.tasks.time_oscillation import TimeOscillation
from dyndlo_vision.tasks.tip_control import TipControl
from dyndlo_vision.tasks.vaulting import Vaulting

TASKS: dict[str, type[Task]] = {
    "TipControl": TipControl,
    "Vaulting": Vaulting,
    "Hooking": Hooking,
    "TimeOscillation": TimeOscillation,
}
ENV_IDS = tuple(f"DynDLO/{name}-v0" for name in TASKS)


def make_env(
    task: str, render_mode: str | None = None, render_camera: str = "front", **options: Any
) -> DynDLOEnv:
    """Build the environment of ``task`` (a key of ``TASKS``) with task ``options``.

    The ``cable`` option takes a :class:`~dyndlo_vision.sim.CableParams`, or, so that it can be given on the
    command line (``--env-option cable=chain``), a cable model name (``"rod"``, ``"chain"``) or a mapping of
    ``CableParams`` fields: either changes the task's own nominal cable (its length and segments kept; the
    damping becomes the new model's default unless given).

    Raises:
        ValueError: For an unknown task or option, naming the valid ones.
    """
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; expected one of {sorted(TASKS)}")
    cls = TASKS[task]
    valid = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for {task}; valid options: {valid + ['render_mode']}")
    cable = options.get("cable")
    if isinstance(cable, str | dict):
        options = {**options, "cable": _task_cable(cls, options, cable)}
    return DynDLOEnv(cls(**options), render_mode=render_mode, render_camera=render_camera)


def _task_cable(cls: type[Task], options: dict[str, Any], change: str | dict[str, Any]) -> Any:
    """The task's nominal cable with a new model (a name) or new fields (a mapping)."""
    from dataclasses import replace

    changes = {"model": change} if isinstance(change, str) else dict(change)
    nominal = cls(**{k: v for k, v in options.items() if k != "cable"}).cable  # type: ignore[attr-defined]
    if "model" in changes and changes["model"] != nominal.model:
        # the model's own damping defaults, unless given
        changes.setdefault("damping_s", None)
        changes.setdefault("damping_quadratic_s2", None)
    try:
        return replace(nominal, **changes)
    except TypeError as exc:
        raise ValueError(f"cable option {change!r}: {exc}") from exc


def register_envs() -> None:
    """Register every task under ``DynDLO/<Task>-v0`` (idempotent)."""
    for name in TASKS:
        env_id = f"DynDLO/{name}-v0"
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point="dyndlo_vision.tasks:make_env", kwargs={"task": name},
                         disable_env_checker=False)


__all__ = [
    "CONTROL_PERIOD_S",
    "ENV_IDS",
    "TASKS",
    "DynDLOEnv",
    "EpisodeMonitor",
    "Hooking",
    "Task",
    "TimeOscillation",
    "TipControl",
    "Vaulting",
    "make_env",
    "register_envs",
]
