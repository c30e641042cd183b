"""The noise models shipped with the package and how an option names one: a shipped name (``packaged``,
``vaulting-two-cameras``) or a file."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["PACKAGED_MODEL_NAME", "SHIPPED_NOISE_MODELS", "TASK_NOISE_MODELS", "noise_model_file",
           "packaged_noise_model_path", "portable_noise_model", "resolve_noise_model_path",
           "shipped_noise_model_path", "task_noise_model"]

#: The model fitted by ``benchmarks/tracking_accuracy.py`` on rendered tip-control episodes (package data).
PACKAGED_MODEL_NAME = "noise_model_tracking.json"
#: The models shipped with the package (``dyndlo_vision/data``), by the name an ``--obs-noise`` option or a
#: stored run gives: ``packaged`` is tip control's one-camera tracker (the name runs have always stored);
#: ``vaulting-two-cameras`` the vaulting loop's two-camera tracker, fitted by
#: ``benchmarks/loop_noise_model.py``. Each file's ``source`` names the command that made it.
SHIPPED_NOISE_MODELS = {
    "packaged": PACKAGED_MODEL_NAME,
    "vaulting-two-cameras": "noise_model_vaulting_two_cameras.json",
}
#: Each task's own loop tracker, where it is not ``packaged``'s: what ``demo --observation noisy`` uses unless
#: told (the vault's noisy row predicts its tracked row only through its own model: 99 of 100 cables agree,
#: against 92 through tip control's).
TASK_NOISE_MODELS = {"vaulting": "vaulting-two-cameras"}
PACKAGE = "dyndlo_vision"


def shipped_noise_model_path(name: str) -> Path:
    """Path of the shipped model called ``name`` (a key of :data:`SHIPPED_NOISE_MODELS`).

    Raises:
        ValueError: ``name`` is not a shipped model's.
    """
    if name not in SHIPPED_NOISE_MODELS:
        raise ValueError(f"no shipped noise model {name!r}; shipped: {', '.join(SHIPPED_NOISE_MODELS)}")
    return Path(str(resources.files(PACKAGE).joinpath("data", SHIPPED_NOISE_MODELS[name])))


def packaged_noise_model_path() -> Path:
    """Path of the noise model shipped as ``packaged`` (tip control's one-camera tracker, fitted on rendered
    episodes)."""
    return shipped_noise_model_path("packaged")


def task_noise_model(task: str) -> str:
    """The shipped model that stands for ``task``'s own loop tracker (:data:`TASK_NOISE_MODELS`; else
    ``packaged``)."""
    return TASK_NOISE_MODELS.get(task, "packaged")


def noise_model_file(value: str | Path | None) -> Path | None:
    """The file a stored noise-model option names: the shipped model for a shipped name (``"packaged"``,
    ``"vaulting-two-cameras"``), else the path given (None stays None)."""
    if value is None:
        return None
    return shipped_noise_model_path(str(value)) if str(value) in SHIPPED_NOISE_MODELS else Path(value)


def resolve_noise_model_path(value: str | None, option: str = "--obs-noise") -> str | None:
    """Absolute path of a noise-model file given on the command line, or a shipped model's name as it is.

    A shipped name (``"packaged"``, ``"vaulting-two-cameras"``) stays that word, not the file's path in this
    install: a run's stored configuration then names the shipped model of whichever install resumes it (a path
    into one copy of the package made the run unresumable from another).
    :func:`~dyndlo_vision.tasks.registry.make_env` reads the word.

    Raises:
        FileNotFoundError: If ``value`` names no file.
    """
    if value is None:
        return None
    if value in SHIPPED_NOISE_MODELS:
        return value
    if not Path(value).is_file():
        names = " or ".join(repr(n) for n in SHIPPED_NOISE_MODELS)
        raise FileNotFoundError(f"{option} {value}: no such file (expected a noise-model JSON, or {names})")
    return str(Path(value).resolve())


def portable_noise_model(value: str | None) -> str | None:
    """A shipped model's name for a path to it in any install (``.../dyndlo_vision/data/`` plus its file
    name), as runs stored before the word was kept; any other value as it is."""
    if value is None or value in SHIPPED_NOISE_MODELS:
        return value
    path = Path(value)
    if path.parent.name == "data" and path.parent.parent.name == PACKAGE:
        for name, file in SHIPPED_NOISE_MODELS.items():
            if path.name == file:
                return name
    return value
