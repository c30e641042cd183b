"""A small model of the error of the tracked P_DLO (fitted from measured tracker errors, stored as JSON),
and the process that draws corrupted P_DLO from it step by step (:class:`NoiseProcess`).

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
fingerprints the cable (docs/RESULTS.md, "Vaulting: the third expert round's student"). A learner that
standardises its inputs can read that, and no real arm reports it.

:meth:`ObservationNoiseModel.fit` estimates all of this from per-frame records (truth, estimate, true
velocity), as ``benchmarks/tracking_accuracy.py --fit-out`` does;
:class:`dyndlo_vision.tasks.wrappers.NoisyObservation` applies it to the observations of an environment.
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from dyndlo_vision._atomic import write_atomic

__all__ = [
    "NOISE_MODEL_FORMAT",
    "NOISE_MODEL_VERSION",
    "ObservationNoiseModel",
    "dropout_runs",
    "SHIPPED_NOISE_MODELS",
    "noise_model_file",
    "packaged_noise_model_path",
    "shipped_noise_model_path",
    "task_noise_model",
]

NOISE_MODEL_FORMAT = "dyndlo_vision.observation_noise"
#: Version 2 added the TCP noise (``tcp_position_std_m``, ``tcp_velocity_std_m_s``); version 1 files are read
#: with both 0.
NOISE_MODEL_VERSION = 2
_READABLE_VERSIONS = (1, 2)
#: TCP noise given to a fitted model unless told otherwise (our choice, not a measurement): 0.2 mm and 5 mm/s
#: per axis, far above the simulator's micrometre fingerprint of the cable and far below the task's scale.
DEFAULT_TCP_POSITION_STD_M = 2e-4
DEFAULT_TCP_VELOCITY_STD_M_S = 5e-3
#: The model fitted by ``benchmarks/tracking_accuracy.py`` on rendered tip-control episodes (package data).
PACKAGED_MODEL_NAME = "noise_model_tracking.json"
#: The models shipped with the package (``dyndlo_vision/data``), by the name an ``--obs-noise`` option or a
#: stored run gives: ``packaged`` is tip control's one-camera tracker (the name runs have always stored);
#: ``vaulting-two-cameras`` the vaulting loop's two-camera tracker, fitted by
#: ``benchmarks/loop_noise_model.py`` (docs/RESULTS.md, session 29).
SHIPPED_NOISE_MODELS = {
    "packaged": PACKAGED_MODEL_NAME,
    "vaulting-two-cameras": "noise_model_vaulting_two_cameras.json",
}
#: Each task's own loop tracker, where it is not ``packaged``'s: what ``demo --observation noisy`` uses unless
#: told (the vault's noisy row predicts its tracked row only through its own model: 99 of 100 cables agree,
#: against 92 through tip control's; session 29).
TASK_NOISE_MODELS = {"vaulting": "vaulting-two-cameras"}
PACKAGE = "dyndlo_vision"
#: Latencies above this are not a tracking pipeline that can run at 25 Hz.
MAX_LATENCY_S = 1.0

# E|r| = sigma * sqrt(2 / pi) for a zero-mean normal r: scales mean absolute residuals to standard deviations.
_ABS_TO_STD = math.sqrt(math.pi / 2.0)

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


def dropout_runs(dropped: ArrayLike, episode: ArrayLike | None = None) -> list[int]:
    """Lengths of the runs of consecutive True values, runs never spanning two episodes.

    Args:
        dropped: (K,) bool per observation, in time order within each episode.
        episode: (K,) episode id per observation (contiguous blocks); None for one episode.
    """
    d = np.asarray(dropped, dtype=bool).reshape(-1)
    ep = np.zeros(d.size, dtype=np.int64) if episode is None else np.asarray(episode).reshape(-1)
    if ep.shape != d.shape:
        raise ValueError(f"episode must have one id per observation ({d.size}), got shape {ep.shape}")
    runs: list[int] = []
    length = 0
    for i in range(d.size):
        if i > 0 and ep[i] != ep[i - 1] and length:
            runs.append(length)
            length = 0
        if d[i]:
            length += 1
        elif length:
            runs.append(length)
            length = 0
    if length:
        runs.append(length)
    return runs


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

    # ------------------------------------------------------------------ the model
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

    # ------------------------------------------------------------------ fitting
    @classmethod
    def fit(
        cls,
        truth: ArrayLike,
        estimate: ArrayLike,
        velocity: ArrayLike,
        episode: ArrayLike | None = None,
        speed: ArrayLike | None = None,
        speed_dependent: bool = True,
        max_coast_steps: int = 7,
        source: str = "",
        tcp_position_std_m: float = DEFAULT_TCP_POSITION_STD_M,
        tcp_velocity_std_m_s: float = DEFAULT_TCP_VELOCITY_STD_M_S,
    ) -> ObservationNoiseModel:
        """Fits the model to per-observation records of the estimate the controller read.

        Bias and latency come from one least-squares fit of ``estimate - truth = bias - latency * velocity``
        over all axes (a first-order expansion of ``truth(t - latency)``); a negative latency (the estimate
        leads) is clipped to 0 and the bias refitted. The standard deviations come from the residuals: with
        ``speed_dependent``, a non-negative least-squares fit of ``sqrt(pi/2) |residual|`` (whose mean is
        the standard deviation for normal errors) against ``[one-hot axis, speed]``; otherwise the per-axis
        root mean square. Dropouts are the records whose estimate is NaN.

        Args:
            truth: (K, 3) true P_DLO at each read time (m).
            estimate: (K, 3) the estimate read then; a row with any NaN is a dropout.
            velocity: (K, 3) true P_DLO velocity at the read time (m/s), for the latency.
            episode: (K,) episode id per record (records of an episode contiguous, in time order); dropout
                runs never span episodes. None: one episode.
            speed: (K,) speed the standard deviation scales with, in the definition the user of the model
                applies (the wrapper uses the mean speed over the last control step). Default ``|velocity|``.
            speed_dependent: Fit ``std_per_speed_s`` (else 0).
            max_coast_steps: Stored as is (see the attribute).
            source: Stored as is.
            tcp_position_std_m: Stored as is: the TCP noise is not in the tracker's records (default
                :data:`DEFAULT_TCP_POSITION_STD_M`).
            tcp_velocity_std_m_s: Stored as is (default :data:`DEFAULT_TCP_VELOCITY_STD_M_S`).

        Raises:
            ValueError: On shape mismatches, non-finite truth/velocity/speed, or fewer than 10 observed
                records.
        """
        tru = _records(truth, "truth")
        est = np.asarray(estimate, dtype=np.float64)
        vel = _records(velocity, "velocity")
        k = tru.shape[0]
        if est.shape != (k, 3) or vel.shape != (k, 3):
            raise ValueError(
                f"truth, estimate and velocity must all be (K, 3) with the same K, got {tru.shape}, "
                f"{est.shape}, "
                f"{vel.shape}"
            )
        spd = (
            np.linalg.norm(vel, axis=1) if speed is None else np.asarray(speed, dtype=np.float64).reshape(-1)
        )
        if spd.shape != (k,) or not np.all(np.isfinite(spd)) or np.any(spd < 0):
            raise ValueError(f"speed must be (K,) = ({k},) finite values >= 0, got shape {spd.shape}")
        dropped = ~np.all(np.isfinite(est), axis=1)
        observed = ~dropped
        n_obs = int(np.count_nonzero(observed))
        if n_obs < 10:
            raise ValueError(f"need at least 10 records with an estimate to fit a noise model, got {n_obs}")
        runs = dropout_runs(dropped, episode)
        err = est[observed] - tru[observed]
        v = vel[observed]
        bias, latency = _fit_bias_latency(err, v)
        residual = err - bias + latency * v
        s = spd[observed]
        if speed_dependent:
            std0, gain = _fit_speed_std(residual, s)
        else:
            std0, gain = np.sqrt(np.mean(residual**2, axis=0)), 0.0
        return cls(
            bias_m=tuple(bias.tolist()),  # type: ignore[arg-type]
            std_m=tuple(std0.tolist()),  # type: ignore[arg-type]
            std_per_speed_s=float(gain),
            latency_s=min(float(latency), MAX_LATENCY_S),
            dropout_prob=float(np.mean(dropped)),
            dropout_mean_run=float(np.mean(runs)) if runs else 1.0,
            max_coast_steps=max_coast_steps,
            n_samples=k,
            source=source,
            tcp_position_std_m=tcp_position_std_m,
            tcp_velocity_std_m_s=tcp_velocity_std_m_s,
        )

    # ------------------------------------------------------------------ files
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

# Mixed into the seed so that the noise stream differs from the environment's own random stream.
_NOISE_STREAM = 0x4E6F697379
# The TCP noise's own stream: a model with TCP noise gives the same P_DLO numbers as one without.
_TCP_NOISE_STREAM = 0x544350


class NoiseProcess:
    """The noise model as a process in time: one corrupted P_DLO per control step, from the true one.

    Per step:

    1. the true P_DLO is appended to a short history; the delayed value ``latency_s`` ago is interpolated
       linearly between the two neighbouring steps (the first step pads the history);
    2. a two-state Markov chain decides whether this step is a dropout (never the first one);
    3. observed: ``delayed + bias + N(0, std(speed)^2)`` per axis, with ``speed`` the true P_DLO speed over
       the last control step; dropout: the previous output moved on at the velocity of the last two
       outputs before the dropout began, for at most ``max_coast_steps`` steps, then held.

    The training wrapper (:class:`~dyndlo_vision.tasks.wrappers.NoisyObservation`) draws once per
    observation, the control loop's noisy state source once per cycle: the same numbers for the same seed.
    :meth:`corrupt_tcp` draws the TCP noise from a stream of its own, so it changes no P_DLO number.

    Args:
        model: The noise model, or the path of its JSON file.
        control_period_s: Time between steps.
        multi_step: False for single-step episodes, whose two observations are a whole trajectory apart: no
            latency is applied.
    """

    def __init__(self, model: ObservationNoiseModel | str | Path, control_period_s: float,
                 multi_step: bool = True) -> None:
        if not (math.isfinite(control_period_s) and control_period_s > 0):
            raise ValueError(
                f"control_period_s must be a positive number of seconds, got {control_period_s!r}"
            )
        self.model = model if isinstance(model, ObservationNoiseModel) else ObservationNoiseModel.load(model)
        self.control_period_s = float(control_period_s)
        self.lag_steps = self.model.latency_s / self.control_period_s if multi_step else 0.0
        self._history: deque[NDArray[np.float64]] = deque(maxlen=int(math.ceil(self.lag_steps)) + 2)
        self._outputs: deque[NDArray[np.float64]] = deque(maxlen=2)
        self._rng: np.random.Generator | None = None
        self._tcp_rng: np.random.Generator | None = None
        self._dropped = False
        self._coast_steps = 0
        self._coast_velocity = np.zeros(3)
        self.last_true = np.zeros(3)

    def reset(self, seed: int | None = None) -> None:
        """Forget the noise state (history, dropout chain); a ``seed`` also reseeds the noise."""
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), _NOISE_STREAM])
            self._tcp_rng = np.random.default_rng([int(seed), _TCP_NOISE_STREAM])
        elif self._rng is None:
            self._rng = np.random.default_rng()
            self._tcp_rng = np.random.default_rng()
        self._history.clear()
        self._outputs.clear()
        self._dropped = False
        self._coast_steps = 0

    def corrupt(self, true_p_dlo: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
        """One draw for the true P_DLO of this control step.

        Returns the corrupted P_DLO and whether it counts as measured (False during a dropout, when the
        output coasts on the last measurements).
        """
        if self._rng is None:  # used without reset()
            self._rng = np.random.default_rng()
        true_p = np.asarray(true_p_dlo, dtype=np.float64).copy()
        self.last_true = true_p
        self._history.append(true_p)
        return self._corrupt(), not self._dropped

    def corrupt_tcp(
        self, positions: ArrayLike, velocities: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The gripper positions and velocities (any shape, e.g. (n_g, 3)) with the model's white TCP noise.

        Returns copies; a model without TCP noise returns them unchanged (and draws nothing).
        """
        p = np.array(positions, dtype=np.float64)
        v = np.array(velocities, dtype=np.float64)
        m = self.model
        if not m.perturbs_tcp:
            return p, v
        if self._tcp_rng is None:  # used without reset()
            self._tcp_rng = np.random.default_rng()
        p += m.tcp_position_std_m * self._tcp_rng.standard_normal(p.shape)
        v += m.tcp_velocity_std_m_s * self._tcp_rng.standard_normal(v.shape)
        return p, v

    def _delayed(self) -> NDArray[np.float64]:
        """True P_DLO ``latency_s`` ago, interpolated in the per-step history (oldest entry if too short)."""
        h = self._history
        whole = int(math.floor(self.lag_steps))
        frac = self.lag_steps - whole
        newer = h[max(len(h) - 1 - whole, 0)]
        if frac == 0.0:
            return newer
        older = h[max(len(h) - 2 - whole, 0)]
        return (1.0 - frac) * newer + frac * older

    def _corrupt(self) -> NDArray[np.float64]:
        assert self._rng is not None
        m = self.model
        h = self._history
        speed = float(np.linalg.norm(h[-1] - h[-2])) / self.control_period_s if len(h) >= 2 else 0.0
        # Draw the same random numbers every step so that the stream does not depend on the chain's state.
        u = float(self._rng.random())
        z = self._rng.standard_normal(3)
        first = not self._outputs
        if first:
            self._dropped = False
        elif self._dropped:
            self._dropped = u >= m.dropout_leave_prob
        else:
            self._dropped = u < m.dropout_enter_prob
        if self._dropped:
            if self._coast_steps == 0:
                prev = self._outputs
                self._coast_velocity = (
                    (prev[-1] - prev[-2]) / self.control_period_s if len(prev) == 2 else np.zeros(3)
                )
            self._coast_steps += 1
            step = self._coast_velocity if self._coast_steps <= m.max_coast_steps else np.zeros(3)
            out = self._outputs[-1] + step * self.control_period_s
        else:
            self._coast_steps = 0
            out = self._delayed() + np.asarray(m.bias_m) + m.std_at(speed) * z
        self._outputs.append(out)
        return out


def _records(values: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must be (K, 3), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(
            f"{name} must be finite everywhere ({int(np.sum(~np.isfinite(arr)))} non-finite values)"
        )
    return arr


def _fit_bias_latency(
    err: NDArray[np.float64], vel: NDArray[np.float64]
) -> tuple[NDArray[np.float64], float]:
    """Least squares of ``err[i, a] = bias[a] - latency * vel[i, a]``; latency clipped to >= 0."""
    n = err.shape[0]
    if float(np.sum(vel**2)) < 1e-12:
        return err.mean(axis=0), 0.0  # the point never moved: latency is not observable
    design = np.zeros((3 * n, 4))
    for a in range(3):
        design[a::3, a] = 1.0
    design[:, 3] = -vel.reshape(-1)
    coef, *_ = np.linalg.lstsq(design, err.reshape(-1), rcond=None)
    latency = float(coef[3])
    if latency <= 0.0:
        return err.mean(axis=0), 0.0
    return coef[:3], latency


def _fit_speed_std(
    residual: NDArray[np.float64], speed: NDArray[np.float64]
) -> tuple[NDArray[np.float64], float]:
    """Non-negative fit of ``sqrt(pi/2) |residual[i, a]| = std0[a] + gain * speed[i]``."""
    n = residual.shape[0]
    design = np.zeros((3 * n, 4))
    for a in range(3):
        design[a::3, a] = 1.0
    design[:, 3] = np.repeat(speed, 3)
    coef, _ = nnls(design, _ABS_TO_STD * np.abs(residual).reshape(-1))
    return coef[:3], float(coef[3])
