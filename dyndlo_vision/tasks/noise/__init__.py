"""The observation-noise model: the error of the tracked P_DLO, for training and evaluating on what a camera
would give. One module per part:

* :mod:`.model`: :class:`ObservationNoiseModel`, its numbers and its JSON file;
* :mod:`.process`: :class:`NoiseProcess`, the model drawn step by step in an episode;
* :mod:`.fitting`: :func:`fit_noise_model`, a model from a tracker's per-frame records;
* :mod:`.shipped`: the models shipped with the package and how an ``--obs-noise`` option names one.

:class:`dyndlo_vision.tasks.wrappers.NoisyObservation` applies a model to an environment's observations.
"""

from __future__ import annotations

from dyndlo_vision.tasks.noise.fitting import (
    DEFAULT_TCP_POSITION_STD_M,
    DEFAULT_TCP_VELOCITY_STD_M_S,
    dropout_runs,
    fit_noise_model,
)
from dyndlo_vision.tasks.noise.model import (
    MAX_LATENCY_S,
    NOISE_MODEL_FORMAT,
    NOISE_MODEL_VERSION,
    ObservationNoiseModel,
)
from dyndlo_vision.tasks.noise.process import NoiseProcess
from dyndlo_vision.tasks.noise.shipped import (
    PACKAGED_MODEL_NAME,
    SHIPPED_NOISE_MODELS,
    TASK_NOISE_MODELS,
    noise_model_file,
    packaged_noise_model_path,
    portable_noise_model,
    resolve_noise_model_path,
    shipped_noise_model_path,
    task_noise_model,
)

__all__ = [
    "DEFAULT_TCP_POSITION_STD_M",
    "DEFAULT_TCP_VELOCITY_STD_M_S",
    "MAX_LATENCY_S",
    "NOISE_MODEL_FORMAT",
    "NOISE_MODEL_VERSION",
    "PACKAGED_MODEL_NAME",
    "SHIPPED_NOISE_MODELS",
    "TASK_NOISE_MODELS",
    "NoiseProcess",
    "ObservationNoiseModel",
    "dropout_runs",
    "fit_noise_model",
    "noise_model_file",
    "packaged_noise_model_path",
    "portable_noise_model",
    "resolve_noise_model_path",
    "shipped_noise_model_path",
    "task_noise_model",
]
