"""What a training run is: task, mode, algorithm, budget and hyperparameters, stored with the run.

Hyperparameters live in versioned YAML files beside this module (``hyperparams/ppo.yml``, ``sac.yml``),
one entry per task and mode in the style of rl-baselines3-zoo; a run folder keeps the resolved
:class:`RunConfig` in ``config.json`` so that it can be resumed and reproduced.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from dyndlo_vision.policies import ALGORITHMS
from dyndlo_vision.tasks.registry import TASKS, check_robot, task_entry

if TYPE_CHECKING:
    from dyndlo_vision.tasks.wrappers import RandomCables

HYPERPARAMS_VERSION = 1
#: A randomised training cable is redrawn every this many episodes (a new cable is a new MuJoCo model).
RANDOMIZE_CABLE_EVERY = 10
#: Tasks with a scripted baseline whose episodes can seed SAC's replay buffer (``learning.demonstrations``).
DEMONSTRABLE_TASKS = tuple(name for name, entry in TASKS.items() if entry.demonstrator is not None)


def load_hyperparams(algo: str, task: str, multi_step: bool) -> dict[str, Any]:
    """The YAML entry of ``algo`` for a task and mode: n_envs, n_timesteps, policy, hyperparams.

    Raises:
        ValueError: For an unknown algorithm, a task and mode without an entry, or a file of another version.
    """
    if algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algo!r}; expected one of {list(ALGORITHMS)}")
    text = resources.files("dyndlo_vision.learning").joinpath(f"hyperparams/{algo}.yml").read_text()
    table = yaml.safe_load(text)
    if table.get("version") != HYPERPARAMS_VERSION:
        raise ValueError(
            f"hyperparams/{algo}.yml has version {table.get('version')}, expected {HYPERPARAMS_VERSION}"
        )
    key = task_entry(task).hyperparams_key(multi_step)
    if key not in table:
        entries = sorted(k for k in table if k != "version")
        raise ValueError(f"no {algo} hyperparameters for {key!r}; available: {entries}")
    entry = dict(table[key])
    entry.setdefault("hyperparams", {})
    return entry


@dataclass(frozen=True)
class RunConfig:
    """Everything that defines a training run.

    Attributes:
        task: Task name (a key of :data:`dyndlo_vision.tasks.TASKS`).
        multi_step: Re-plan every 0.04 s instead of planning once.
        algo: A key of :data:`dyndlo_vision.policies.ALGORITHMS`.
        timesteps: Total environment steps (decisions) to train for.
        seed: Seed of the algorithm and of the training environments (evaluation uses seed + 10_000).
        n_envs: Environments stepped in parallel.
        vec_env: "subproc" (one process per environment), "dummy" (all in this process) or "batch" (one
            batched environment: the physics of all of them in one call on C threads, the same episodes).
        policy: stable-baselines3 policy name.
        hyperparams: Keyword arguments of the algorithm (from the YAML file, then ``--hp`` overrides).
        env_options: Task options passed to ``gym.make`` (e.g. ``{"target": "down"}``).
        obs_noise: Path of an observation-noise model file (``dyndlo_vision.tasks.noise``), ``"packaged"`` for
            the shipped one, or None.
        randomize_cable: Draw a new cable (length, mass, E, damping) every 10 training episodes
            (``dyndlo_vision.tasks.wrappers.CableRandomization``; evaluation keeps the nominal cable).
        cable_ranges: With ``randomize_cable``, the named ranges the cables are drawn from
            (``dyndlo_vision.tasks.wrappers.CABLE_RANGES``: ``"training"``, the default, or ``"beyond"``).
        eval_freq: Evaluate every this many environment steps.
        eval_episodes: Episodes per evaluation.
        checkpoint_freq: Save a resumable checkpoint every this many environment steps.
        demonstrations: Episodes of the task's scripted baseline (perturbed) put into SAC's replay buffer
            before learning (``dyndlo_vision.learning.demonstrations``); 0: none, as in the paper.
        robot: Judge every plan on this arm's joint limits, an avoid condition (``"gofa"``, ``"ur5e"``;
            ``DynDLOEnv.set_robot``); None: the paper's TCP-only conditions.
    """

    task: str
    multi_step: bool
    algo: str
    timesteps: int
    seed: int = 0
    n_envs: int = 2
    vec_env: str = "subproc"
    policy: str = "MlpPolicy"
    hyperparams: dict[str, Any] = field(default_factory=dict)
    env_options: dict[str, Any] = field(default_factory=dict)
    obs_noise: str | None = None
    randomize_cable: bool = False
    cable_ranges: str = "training"
    eval_freq: int = 2000
    eval_episodes: int = 20
    checkpoint_freq: int = 2000
    demonstrations: int = 0
    robot: str | None = None

    def __post_init__(self) -> None:
        task_entry(self.task)
        if self.robot is not None:
            check_robot(self.robot)
        if self.algo not in ALGORITHMS:
            raise ValueError(f"algo={self.algo!r}; expected one of {list(ALGORITHMS)}")
        for name in ("timesteps", "n_envs", "eval_freq", "eval_episodes", "checkpoint_freq"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}={value!r}; expected a positive integer")
        if self.vec_env not in ("subproc", "dummy", "batch"):
            raise ValueError(f"vec_env={self.vec_env!r}; expected 'subproc', 'dummy' or 'batch'")
        if self.vec_env == "batch" and self.robot is not None:
            raise ValueError(f"vec_env='batch' does not judge plans on a real arm (robot={self.robot!r}); "
                             "use 'subproc' or 'dummy'")
        from dyndlo_vision.tasks.wrappers import CABLE_RANGES

        if self.cable_ranges not in CABLE_RANGES:
            raise ValueError(f"cable_ranges={self.cable_ranges!r}; expected one of {list(CABLE_RANGES)}")
        if self.cable_ranges != "training" and not self.randomize_cable:
            raise ValueError(f"cable_ranges={self.cable_ranges!r} draws random cables: it needs "
                             "randomize_cable=True")
        if not isinstance(self.demonstrations, int) or self.demonstrations < 0:
            raise ValueError(f"demonstrations={self.demonstrations!r}; expected a non-negative integer")
        if self.demonstrations and self.algo != "sac":
            raise ValueError(f"demonstrations={self.demonstrations} need an off-policy algorithm (sac), "
                             f"got algo={self.algo!r}")
        if self.demonstrations and (self.task not in DEMONSTRABLE_TASKS or self.multi_step):
            raise ValueError(
                f"demonstrations are available for single-step {list(DEMONSTRABLE_TASKS)} only (a scripted "
                f"baseline plans the whole episode), got task={self.task!r}, multi_step={self.multi_step}"
            )

    @property
    def random_cables(self) -> RandomCables | None:
        """The training environments' cable randomisation (None: the nominal cable)."""
        from dyndlo_vision.tasks.wrappers import RandomCables

        ranges = RandomCables(self.cable_ranges, every_episodes=RANDOMIZE_CABLE_EVERY)
        return ranges if self.randomize_cable else None

    @property
    def env_id(self) -> str:
        """Gymnasium id of the task."""
        return task_entry(self.task).env_id

    @property
    def key(self) -> str:
        """Task and mode, e.g. ``tip-control-multi-step``."""
        return task_entry(self.task).hyperparams_key(self.multi_step)

    def to_json(self) -> str:
        """JSON text of the configuration."""
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, path: Path) -> RunConfig:
        """Read ``config.json`` of a run folder, with a clear error for a missing or malformed file."""
        if not path.is_file():
            raise FileNotFoundError(f"{path} not found: not a run folder made by `dyndlo-vision train`")
        from dyndlo_vision.tasks.noise import portable_noise_model

        try:
            data = json.loads(path.read_text())
            if isinstance(data, dict) and isinstance(data.get("obs_noise"), str):
                # Stored before "packaged" was kept as the word: the shipped model's path in that install.
                data["obs_noise"] = portable_noise_model(data["obs_noise"])
            return cls(**data)
        except (json.JSONDecodeError, TypeError) as err:
            raise ValueError(f"{path} is not a valid run configuration: {err}") from err
