"""The task registry: one row per task, from which every table of tasks is derived, and the one factory that
builds a task's environment for training, evaluation, distillation and the demo.

A row names the task on the command line (``tip-control``), gives its :class:`~dyndlo_vision.tasks.base.Task`
class, its Gymnasium id (``DynDLO/TipControl-v0``), its scripted baseline and demonstrator if it has them,
the shipped policies that solve it, and its key in the hyperparameter files. Adding a task is adding a row.

    from dyndlo_vision.tasks import make_env
    env = make_env("tip-control", multi_step=True, randomize_cable_every=1, obs_noise="packaged")
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.tasks.base import DynDLOEnv, Task
from dyndlo_vision.tasks.baselines import (
    FlickVault,
    GeometricLift,
    geometric_demonstration,
    vault_demonstration,
)
from dyndlo_vision.tasks.hooking import Hooking
from dyndlo_vision.tasks.time_oscillation import TimeOscillation
from dyndlo_vision.tasks.tip_control import TipControl
from dyndlo_vision.tasks.vaulting import Vaulting

#: ``(env, obs, rng) -> action``: one perturbed action of a task's scripted baseline (demonstrations).
Demonstrator = Callable[[Any, NDArray[np.float32], np.random.Generator], NDArray[np.float32]]


@dataclass(frozen=True)
class TaskEntry:
    """One task and everything the package knows it by.

    Attributes:
        name: The task's name on the command line and in run and policy metadata, e.g. ``"tip-control"``.
        task_class: The :class:`Task` subclass; its class name is the Gymnasium id's stem.
        baseline: Name of the task's scripted baseline in ``dyndlo-vision evaluate`` (None: it has none).
        baseline_class: The scripted baseline, ``cls(env, ...)`` is a policy ``obs -> action``.
        demonstrator: Perturbed baseline actions that seed SAC's replay buffer (None: no demonstrations).
        shipped_policies: Shipped policies of the task, preferred first (the demo's default is the first one
            that is installed).
        algo: The learning algorithm ``dyndlo-vision train`` uses by default (the paper's choice).
    """

    name: str
    task_class: type[Task]
    baseline: str | None = None
    baseline_class: Callable[..., Callable[[NDArray[np.float32]], NDArray[np.float32]]] | None = None
    demonstrator: Demonstrator | None = None
    shipped_policies: tuple[str, ...] = ()
    algo: str = "ppo"

    @property
    def env_id(self) -> str:
        """The Gymnasium id, e.g. ``DynDLO/TipControl-v0``."""
        return f"DynDLO/{self.task_class.__name__}-v0"

    def hyperparams_key(self, multi_step: bool) -> str:
        """Key of the task and mode in the hyperparameter files, e.g. ``tip-control-multi-step``."""
        return f"{self.name}-multi-step" if multi_step else self.name

    def options(self) -> list[str]:
        """Names of the options the task's constructor takes (``multi_step``, ``cable``, ``target``, ...)."""
        return [p for p in inspect.signature(self.task_class.__init__).parameters if p != "self"]


TASKS: Mapping[str, TaskEntry] = {
    entry.name: entry
    for entry in (
        TaskEntry(
            "tip-control",
            TipControl,
            shipped_policies=(
                "tip-control-multi-step",
                "tip-control-single-step",
                "tip-control-single-step-gofa",
                "tip-control-single-step-ur5e",
            ),
        ),
        TaskEntry(
            "vaulting",
            Vaulting,
            baseline="flick-vault",
            baseline_class=FlickVault,
            demonstrator=vault_demonstration,
            shipped_policies=("vaulting", "vaulting-multi-step"),
        ),
        TaskEntry("hooking", Hooking, shipped_policies=("hooking",)),
        TaskEntry(
            "time-oscillation",
            TimeOscillation,
            baseline="geometric",
            baseline_class=GeometricLift,
            demonstrator=geometric_demonstration,
            shipped_policies=("time-oscillation-up", "time-oscillation-down"),
            algo="sac",
        ),
    )
}
#: Every task's Gymnasium id, in registry order.
ENV_IDS = tuple(entry.env_id for entry in TASKS.values())


def check_robot(name: str) -> str:
    """``name`` if it is an arm ``make_env(robot=...)`` can judge plans on (``"gofa"``, ``"ur5e"``).

    Raises:
        ValueError: An unknown arm, listing the known ones.
    """
    from dyndlo_vision.robots.feasibility import robot_arm

    return robot_arm(name).name


def task_entry(name: str) -> TaskEntry:
    """The registry row of a task name.

    Raises:
        ValueError: For a name that is not a task, listing the valid ones.
    """
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; expected one of {sorted(TASKS)}")
    return TASKS[name]


def build_task_env(
    task: str, render_mode: str | None = None, render_camera: str = "front", **options: Any
) -> DynDLOEnv:
    """The bare environment of ``task`` with task ``options`` (Gymnasium's entry point for the ids).

    The ``cable`` option takes a :class:`~dyndlo_vision.sim.CableParams`, or, so that it can be given on the
    command line (``--env-option cable=rod``), a cable model name (``"rod"``, ``"chain"``) or a mapping of
    ``CableParams`` fields: either changes the task's own nominal cable (its length and segments kept; the
    damping becomes the new model's default unless given).

    Raises:
        ValueError: For an unknown task or option, naming the valid ones.
    """
    return DynDLOEnv(make_task(task, **options), render_mode=render_mode, render_camera=render_camera)


def make_task(task: str, **options: Any) -> Task:
    """The :class:`Task` of ``task`` with task ``options`` (what :func:`build_task_env` and the batched
    environment simulate); options as :func:`build_task_env` takes them.

    Raises:
        ValueError: For an unknown task or option, naming the valid ones.
    """
    entry = task_entry(task)
    valid = entry.options()
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for {task}; valid options: {valid + ['render_mode']}")
    cable = options.get("cable")
    if isinstance(cable, str | dict):
        options = {**options, "cable": _task_cable(entry.task_class, options, cable)}
    return entry.task_class(**options)


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


def make_env(
    task: str,
    *,
    render_mode: str | None = None,
    render_camera: str = "front",
    randomize_cable_every: int | None = None,
    cable_ranges: dict[str, tuple[float, float]] | None = None,
    obs_noise: str | Path | Any | None = None,
    robot: str | None = None,
    **options: Any,
) -> gym.Env[Any, Any]:
    """The environment of ``task`` as training, evaluation, distillation and the demo use it.

    ``gym.make`` of the task's id (Gymnasium's checks and order enforcing), then optionally
    :class:`~dyndlo_vision.tasks.wrappers.CableRandomization` (a new cable every ``randomize_cable_every``
    episodes, drawn from the reset seed) and :class:`~dyndlo_vision.tasks.wrappers.NoisyObservation`
    (P_DLO through an observation-noise model: a file, a loaded model, or a shipped model's name,
    ``"packaged"`` or ``"vaulting-two-cameras"``; see ``tasks.noise.SHIPPED_NOISE_MODELS``), in that order.

    Args:
        task: A task name (a key of :data:`TASKS`).
        render_mode: None or ``"rgb_array"``.
        render_camera: The scene camera :meth:`render` draws.
        randomize_cable_every: Draw a new cable every this many episodes (None: the nominal cable).
        cable_ranges: The randomisation's ranges (default: ``wrappers.DEFAULT_CABLE_RANGES``).
        obs_noise: Observation-noise model (None: true P_DLO).
        robot: Judge every plan on this arm's joint limits (``"gofa"``, ``"ur5e"``; the avoid condition
            ``joints``, see :meth:`~dyndlo_vision.tasks.base.DynDLOEnv.set_robot`). None: no arm.
        **options: Task options (``multi_step``, ``cable``, ``target``, ...).

    Raises:
        ValueError: For an unknown task, option or robot.
    """
    register_envs()
    entry = task_entry(task)
    env: gym.Env[Any, Any] = gym.make(entry.env_id, render_mode=render_mode, render_camera=render_camera,
                                      **options)
    if robot is not None:
        env.unwrapped.set_robot(robot)  # type: ignore[attr-defined]
    if randomize_cable_every is not None:
        from dyndlo_vision.tasks.wrappers import CableRandomization

        env = CableRandomization(env, ranges=cable_ranges, every_episodes=randomize_cable_every)
    if obs_noise is not None:
        from dyndlo_vision.tasks.noise import ObservationNoiseModel, noise_model_file
        from dyndlo_vision.tasks.wrappers import NoisyObservation

        if isinstance(obs_noise, str | Path):
            obs_noise = ObservationNoiseModel.load(noise_model_file(obs_noise))
        env = NoisyObservation(env, obs_noise)
    return env


def register_envs() -> None:
    """Register every task under its Gymnasium id (idempotent)."""
    for entry in TASKS.values():
        if entry.env_id not in gym.registry:
            gym.register(id=entry.env_id, entry_point="dyndlo_vision.tasks.registry:build_task_env",
                         kwargs={"task": entry.name}, disable_env_checker=False)
