"""The noise model: the error of the tracked P_DLO the controller reads, as a few numbers stored as JSON.

What the controller reads is the filter's estimate of P_DLO, predicted to the time it reads it. Compared
with the true P_DLO at that time the estimate is, per observation (one per 40 ms control step):

* biased (``bias_m``) and lagging by ``latency_s`` (the estimate is close to the truth of a moment ago),
* noisy with a per-axis standard deviation that grows with the speed of the point,
  ``std = std_m + std_per_speed_s * speed`` (``speed`` in m/s: motion blur and prediction errors grow
  with speed),
* missing in runs ("dropouts": no measurement was accepted in the latest frame, so the filter coasts).
  Dropouts follow a two-state Markov chain with stationary probability ``dropout_prob`` and mean run
  length ``dropout_mean_run`` observations.

The gripper's (TCP) position and velocity in the observation get white noise of ``tcp_position_std_m`` and
``tcp_velocity_std_m_s`` per axis. That part is not fitted from the tracker: it stands for what a robot
reports, and it hides a simulator artefact. In the noise-free simulator the position-servoed gripper settles
by micrometres under the cable's load, differently for every cable, so the exact TCP position at t = 0
fingerprints the cable. A learner that standardises its inputs can read that, and no real arm reports it.

:mod:`.fitting` estimates a model from per-frame records; :mod:`.process` draws corrupted observations
from it.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision._atomic import write_atomic

__all__ = ["NOISE_MODEL_FORMAT", "NOISE_MODEL_VERSION", "MAX_LATENCY_S", "ObservationNoiseModel"]

NOISE_MODEL_FORMAT = "dyndlo_vision.observation_noise"
#: Version 2 added the TCP noise (``tcp_position_std_m``, ``tcp_velocity_std_m_s``); version 1 files are read
#: with both 0.
NOISE_MODEL_VERSION = 2
_READABLE_VERSIONS = (1, 2)
#: Latencies above this are not a tracking pipeline that can run at 25 Hz.
MAX_LATENCY_S = 1.0


_FIELDS = (
    "bias_m",
    "std_m",
    "std_per_speed_s",
    "latency_s",
    "dropout_prob",
    "dropout_mean_run",
    "max_coast_steps",
    "n_samples",
    "source",
    "tcp_position_std_m",
    "tcp_velocity_std_m_s",
)
_ADDED_IN_VERSION_2 = ("tcp_position_std_m", "tcp_velocity_std_m_s")


def _vector3(value: Any, name: str, nonnegative: bool = False) -> tuple[float, float, float]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be 3 numbers, got {value!r}") from exc
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    if nonnegative and np.any(arr < 0):
        raise ValueError(f"{name} must be >= 0, got {arr.tolist()}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _number(value: Any, name: str, low: float, high: float, high_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name} must be a number, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) and low <= v and (v < high if high_open else v <= high)
    if not ok:
        bracket = ")" if high_open else "]"
        raise ValueError(f"{name} must be in [{low:g}, {high:g}{bracket}, got {value!r}")
    return v



@dataclass(frozen=True)
class ObservationNoiseModel:
    """Error model of the P_DLO the controller reads; the default instance adds no error at all.

    Attributes:
        bias_m: (3,) constant offset of the estimate from the truth, world frame, metres.
        std_m: (3,) standard deviation per axis at rest, metres.
        std_per_speed_s: Growth of every axis' standard deviation per m/s of P_DLO speed (m per m/s = s).
        latency_s: The estimate equals the truth this long ago (before bias and noise).
        dropout_prob: Long-run share of observations with no fresh measurement (0 <= p < 1).
        dropout_mean_run: Mean number of consecutive observations in one dropout (>= 1).
        max_coast_steps: During a dropout the last value is extrapolated at constant velocity for at most
            this many observations, then held (the tracking filter gives up after 0.3 s, i.e. 7 steps).
        n_samples: Number of observations the model was fitted from (0: not fitted).
        source: Free text: what the model was fitted from.
        tcp_position_std_m: Standard deviation per axis of the white noise on every gripper's observed
            position (m). Not part of the P_DLO fit: what the robot reports (see the module's docstring).
        tcp_velocity_std_m_s: The same for the observed gripper velocity (m/s).
    """

    bias_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std_per_speed_s: float = 0.0
    latency_s: float = 0.0
    dropout_prob: float = 0.0
    dropout_mean_run: float = 1.0
    max_coast_steps: int = 7
    n_samples: int = 0
    source: str = field(default="", compare=False)
    tcp_position_std_m: float = 0.0
    tcp_velocity_std_m_s: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "bias_m", _vector3(self.bias_m, "bias_m"))
        object.__setattr__(self, "std_m", _vector3(self.std_m, "std_m", nonnegative=True))
        object.__setattr__(
            self, "std_per_speed_s", _number(self.std_per_speed_s, "std_per_speed_s", 0.0, 10.0)
        )
        object.__setattr__(self, "latency_s", _number(self.latency_s, "latency_s", 0.0, MAX_LATENCY_S))
        for name in _ADDED_IN_VERSION_2:
            object.__setattr__(self, name, _number(getattr(self, name), name, 0.0, 10.0))
        object.__setattr__(self, "dropout_prob", _number(self.dropout_prob, "dropout_prob", 0.0, 1.0, True))
        object.__setattr__(
            self, "dropout_mean_run", _number(self.dropout_mean_run, "dropout_mean_run", 1.0, 1e6)
        )
        for name in ("max_coast_steps", "n_samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
                raise ValueError(f"{name} must be an int >= 0, got {value!r}")
            object.__setattr__(self, name, int(value))
        if not isinstance(self.source, str):
            raise ValueError(f"source must be a string, got {self.source!r}")
        if self.dropout_enter_prob > 1.0 + 1e-12:
            raise ValueError(
                f"dropout_prob={self.dropout_prob:g} with dropout_mean_run={self.dropout_mean_run:g} is "
                f"impossible: "
                f"runs of that mean length need observed gaps between them, so dropout_prob must be <= "
                f"{self.dropout_mean_run / (self.dropout_mean_run + 1):.6g}"
            )

    @property
    def is_identity(self) -> bool:
        """Whether the model leaves observations unchanged."""
        return (
            not any(self.bias_m)
            and not any(self.std_m)
            and self.std_per_speed_s == 0.0
            and self.latency_s == 0.0
            and self.dropout_prob == 0.0
            and not self.perturbs_tcp
        )

    @property
    def perturbs_tcp(self) -> bool:
        """Whether the model puts noise on the observed gripper (TCP) state."""
        return self.tcp_position_std_m > 0.0 or self.tcp_velocity_std_m_s > 0.0

    @property
    def dropout_enter_prob(self) -> float:
        """Probability that an observed step is followed by a dropout (Markov chain, fitted mean run)."""
        p, run = self.dropout_prob, self.dropout_mean_run
        return 0.0 if p == 0.0 else p / (run * (1.0 - p))

    @property
    def dropout_leave_prob(self) -> float:
        """Probability that a dropout ends after each of its steps."""
        return 1.0 / self.dropout_mean_run

    def std_at(self, speed_m_s: ArrayLike) -> NDArray[np.float64]:
        """Per-axis standard deviation (..., 3) at the given P_DLO speed(s) (m/s)."""
        s = np.asarray(speed_m_s, dtype=np.float64)[..., None]
        return np.asarray(self.std_m) + self.std_per_speed_s * s


    @classmethod
    def fit(cls, truth: ArrayLike, estimate: ArrayLike, velocity: ArrayLike,
            **options: Any) -> ObservationNoiseModel:
        """The model fitted to per-observation records
        (:func:`~dyndlo_vision.tasks.noise.fitting.fit_noise_model`, whose arguments it takes)."""
        from dyndlo_vision.tasks.noise.fitting import fit_noise_model

        return fit_noise_model(truth, estimate, velocity, **options)

    def to_dict(self) -> dict[str, Any]:
        """The JSON object written by :meth:`save`."""
        body = asdict(self)
        body["bias_m"] = list(self.bias_m)
        body["std_m"] = list(self.std_m)
        return {"format": NOISE_MODEL_FORMAT, "version": NOISE_MODEL_VERSION, **body}

    @classmethod
    def from_dict(cls, data: Any, source: str = "noise model") -> ObservationNoiseModel:
        """Builds a model from :meth:`to_dict`'s object, checking format, version, keys and values.

        Raises:
            ValueError: Naming ``source`` and what is wrong.
        """
        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a JSON object, got {type(data).__name__}")
        if data.get("format") != NOISE_MODEL_FORMAT:
            raise ValueError(f"{source}: format is {data.get('format')!r}, expected {NOISE_MODEL_FORMAT!r}")
        version = data.get("version")
        if isinstance(version, bool) or version not in _READABLE_VERSIONS:
            raise ValueError(
                f"{source}: version {version!r} is not supported (this code reads versions "
                f"{', '.join(map(str, _READABLE_VERSIONS))})"
            )
        fields = _FIELDS if version == 2 else tuple(f for f in _FIELDS if f not in _ADDED_IN_VERSION_2)
        body = {k: v for k, v in data.items() if k not in ("format", "version")}
        unknown = sorted(set(body) - set(fields))
        missing = sorted(set(fields) - set(body))
        if unknown or missing:
            raise ValueError(
                f"{source}: unknown key(s) {unknown}, missing key(s) {missing}; version {version} expects "
                f"{list(fields)}"
            )
        try:
            return cls(**body)
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Writes the model as a small JSON file, atomically (the file appears whole or not at all)."""
        text = json.dumps(self.to_dict(), indent=2) + "\n"
        write_atomic(Path(path), lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))

    @classmethod
    def load(cls, path: str | Path) -> ObservationNoiseModel:
        """Reads a model written by :meth:`save`.

        Raises:
            FileNotFoundError: If the file does not exist.
            ValueError: If it is not valid JSON or not a valid noise model (the message names the file).
        """
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{p}: not a text (JSON) file: {exc}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{p}: not valid JSON: {exc}") from None
        return cls.from_dict(data, source=str(p))
