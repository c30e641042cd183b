"""Trained policies shipped with the package, loaded by name, and a checked loader for policy files.

    from dyndlo_vision import policies
    model = policies.load("tip-control-single-step")      # a stable-baselines3 model
    action, _ = model.predict(obs, deterministic=True)

Each shipped policy is ``<name>.zip`` (stable-baselines3) with ``<name>.json`` beside it: the task, mode,
algorithm, training budget and the success rate it was measured at. stable-baselines3 zip files contain
pickled Python objects: load only files you trust.

A policy whose metadata has ``p_dlo_history`` H reads, besides the table-II observation, how P_DLO moved over
the last H decisions (:class:`~dyndlo_vision.tasks.wrappers.PDloHistory`). :func:`load` returns such a policy
as a :class:`HistoryPolicy`, which takes table-II observations like any other and keeps that history itself:
call its ``reset()`` at the start of every episode.
"""

from __future__ import annotations

import json
import zipfile
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: The learning algorithms: name -> stable-baselines3 class name.
ALGORITHMS: dict[str, str] = {"ppo": "PPO", "sac": "SAC"}


def algorithm_class(name: str) -> Any:
    """The stable-baselines3 class of an algorithm name (a key of :data:`ALGORITHMS`).

    Raises:
        ValueError: For an unknown name, listing the known ones.
    """
    if name not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}; expected one of {sorted(ALGORITHMS)}")
    import stable_baselines3

    return getattr(stable_baselines3, ALGORITHMS[name])


def available() -> list[str]:
    """Names of the shipped policies."""
    folder = resources.files(__name__)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".json"))


def default_for(task: str) -> str:
    """The first installed of the task's shipped policies, in its registry row's order of preference.

    Raises:
        ValueError: For an unknown task, or when none of its policies is installed.
    """
    from dyndlo_vision.tasks.registry import task_entry

    shipped = available()
    for name in task_entry(task).shipped_policies:
        if name in shipped:
            return name
    raise ValueError(f"no shipped {task} policy found (have {shipped}); pass --policy PATH.zip")


def metadata(name: str) -> dict[str, Any]:
    """The metadata of a shipped policy (task, multi_step, algo, timesteps, measured success)."""
    if name not in available():
        raise ValueError(f"no shipped policy named {name!r}; available: {available()}")
    return dict(json.loads(resources.files(__name__).joinpath(f"{name}.json").read_text()))


def resolve(name_or_path: str | Path) -> tuple[Path, dict[str, Any]]:
    """The zip file and metadata of a shipped name or a path (metadata from a JSON beside it, if any)."""
    text = str(name_or_path)
    if text in available():
        with resources.as_file(resources.files(__name__).joinpath(f"{text}.zip")) as path:
            return Path(path), metadata(text)
    path = Path(text)
    if not path.exists():
        raise FileNotFoundError(f"policy {text!r} is neither a file nor a shipped policy ({available()})")
    meta_file = path.with_suffix(".json")
    meta: dict[str, Any] = {}
    if meta_file.is_file():
        meta = json.loads(meta_file.read_text())
    elif (path.parent / "config.json").is_file():  # a model.zip inside a training run folder
        config = json.loads((path.parent / "config.json").read_text())
        meta = {
            k: config[k]
            for k in ("task", "multi_step", "algo", "timesteps", "env_options", "p_dlo_history")
            if k in config
        }
        if "first_round_episodes" in config:  # a distill run's student (from before model_round<r>.json)
            meta.setdefault("multi_step", True)
    return path, meta


def load(name_or_path: str | Path, env: Any = None, algo: str | None = None) -> Any:
    """Load a shipped policy by name, or a stable-baselines3 zip file by path.

    Args:
        name_or_path: A name from :func:`available` or a path to a ``.zip``.
        env: Optional environment whose observation and action spaces the policy must match.
        algo: A key of :data:`ALGORITHMS` when the file has no metadata (else each is tried in turn).

    Raises:
        FileNotFoundError: The file does not exist.
        ValueError: The file is not a stable-baselines3 policy, or its spaces do not match ``env``.
    """
    path, meta = resolve(name_or_path)
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path} is not a stable-baselines3 policy file (not a zip archive)")
    wanted = algo or meta.get("algo")
    if wanted is not None and wanted not in ALGORITHMS:
        raise ValueError(f"algo={wanted!r}; expected one of {sorted(ALGORITHMS)}")
    order = [algorithm_class(wanted)] if wanted else [algorithm_class(name) for name in ALGORITHMS]
    errors = []
    for cls in order:
        try:
            model = cls.load(path, device="cpu")
            break
        except Exception as err:  # noqa: BLE001  (SB3 raises many kinds for foreign or corrupt files)
            errors.append(f"{cls.__name__}: {type(err).__name__}: {err}")
    else:
        raise ValueError(f"{path} could not be loaded as a stable-baselines3 policy: " + "; ".join(errors))
    for removed in ("decision_clock", "correction_gate"):  # experimental students' features, since removed
        if meta.get(removed):
            raise ValueError(f"{path}: its metadata asks for {removed}, which this version does not support")
    history = int(meta.get("p_dlo_history") or 0)
    if history:
        model = HistoryPolicy(model, history)
    if env is not None:
        for space in ("observation_space", "action_space"):
            theirs, ours = getattr(model, space), getattr(env, space)
            if theirs.shape != ours.shape:
                raise ValueError(
                    f"{path}: the policy's {space} has shape {theirs.shape}, the environment's {ours.shape}"
                )
    return model


class HistoryPolicy:
    """A stable-baselines3 model trained on observations with student features, fed table-II observations.

    ``predict`` appends :class:`~dyndlo_vision.tasks.wrappers.StudentFeatures` (the P_DLO history) to the
    observation it is given and remembers what they need; ``reset`` starts a new episode (without it, the
    first decision of the next episode would see the jump from the last one's P_DLO as motion). Its
    ``observation_space`` is the table-II one.

    Args:
        model: The stable-baselines3 model, whose observation has the features' values more than table II.
        length: H, the history's number of periods.
    """

    def __init__(self, model: Any, length: int) -> None:
        import gymnasium as gym

        from dyndlo_vision.tasks.wrappers import StudentFeatures

        space = model.observation_space
        self.sb3_model = model
        self.features = StudentFeatures.for_input_size(int(space.shape[0]), length)
        size = self.features.observation_size
        self.observation_space = gym.spaces.Box(space.low[:size], space.high[:size], dtype=space.dtype)
        self.action_space = model.action_space

    def reset(self, *_: Any) -> None:
        """Forget the episode's history (extra arguments, e.g. an env, are ignored)."""
        self.features.reset()

    def student_input(self, observation: Any) -> NDArray[np.float32]:
        """The model's input for one table-II observation (it with the features appended); the features
        remember it, so call this once per decision."""
        obs = np.asarray(observation, dtype=np.float32)
        if obs.shape != self.observation_space.shape:
            raise ValueError(
                f"expected one observation of shape {self.observation_space.shape}, got {obs.shape}"
            )
        return self.features(obs)

    def predict(self, observation: Any, deterministic: bool = True, **kwargs: Any) -> tuple[Any, Any]:
        """The action for one table-II observation (not a batch), as ``model.predict`` gives it."""
        return self.sb3_model.predict(self.student_input(observation), deterministic=deterministic, **kwargs)
