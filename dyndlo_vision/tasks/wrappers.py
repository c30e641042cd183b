"""Gymnasium wrappers for training on the state a camera-based controller would see, and on cables that
differ from the nominal one.

:class:`NoisyObservation` replaces the true P_DLO in a DynDLO observation (table II layout: gripper
positions ``3 n_g``, gripper velocities ``3 n_g``, P_DLO ``3``, target ``3``) by a corrupted one drawn from an
:class:`~dyndlo_vision.tasks.noise.ObservationNoiseModel`: delayed, biased, noisy, and missing in
runs, during which the last value is extrapolated at constant velocity like a coasting tracking filter.

:class:`CableRandomization` hands a cable drawn by the pure function :func:`draw_cable` to the environment's
reset every few episodes.

:class:`PDloHistory` appends P_DLO's finite-difference velocities over the last few decisions to an
observation (a pure function of the observations so far), for a student that must tell the cable from how it
moves. :class:`StudentFeatures` appends what a student's metadata asks for; :class:`StudentFeaturesWrapper`
(and :class:`PDloHistoryWrapper`) put it on an environment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim.cable import CableParams
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
from dyndlo_vision.tasks.noise import NoiseProcess, ObservationNoiseModel

__all__ = [
    "CableRandomization",
    "NoisyObservation",
    "PDloHistory",
    "PDloHistoryWrapper",
    "RandomCables",
    "StudentFeatures",
    "StudentFeaturesWrapper",
    "draw_cable",
    "cable_for_seed",
    "corrupt_observation",
    "describe_cable_ranges",
    "observation_layout",
]

# Mixed into the reset seed so that the cable draws differ from the environment's own random stream.
_CABLE_STREAM = 0x4E6F697379 + 1


def observation_layout(size: int) -> tuple[slice, slice, slice]:
    """The gripper positions, gripper velocities and P_DLO in a table-II observation of ``size`` values
    (``6 n_g + 6``: then the goal)."""
    if size < 12 or (size - 6) % 6 != 0:
        raise ValueError(f"expected a DynDLO observation of length 6 * n_grippers + 6, got width {size}")
    n_g = (size - 6) // 6
    return slice(0, 3 * n_g), slice(3 * n_g, 6 * n_g), slice(6 * n_g, 6 * n_g + 3)


def corrupt_observation(process: NoiseProcess, observation: NDArray[np.floating[Any]]) -> NDArray[np.float32]:
    """One draw of ``process`` for a table-II observation: a float32 copy with P_DLO corrupted, and the
    gripper state too where the model has TCP noise."""
    obs = np.array(observation, dtype=np.float32, copy=True)
    tcp_position, tcp_velocity, p_dlo = observation_layout(obs.shape[-1])
    p, _ = process.corrupt(obs[p_dlo].astype(np.float64))
    obs[p_dlo] = p.astype(np.float32)
    if process.model.perturbs_tcp:
        q, v = process.corrupt_tcp(obs[tcp_position], obs[tcp_velocity])
        obs[tcp_position], obs[tcp_velocity] = q.astype(np.float32), v.astype(np.float32)
    return obs


class NoisyObservation(
    gym.ObservationWrapper[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]],
    gym.utils.RecordConstructorArgs,
):
    """Corrupts P_DLO (and the TCP state) in the observations of a DynDLO environment with a noise model.

    One draw of a :class:`~dyndlo_vision.tasks.noise.NoiseProcess` per observation (one per control step of
    ``control_period_s``, 40 ms in multi-step mode). In single-step mode (``env.unwrapped.multi_step`` False)
    an episode has only the observations before and after the whole trajectory, so no latency is applied.
    The random stream is seeded from the seed given to :meth:`reset` (same seed, same noise); without one
    ever given it is seeded from the OS. ``info["p_dlo_true"]`` carries the uncorrupted P_DLO. The gripper
    positions and velocities get the model's white TCP noise (``tcp_position_std_m``,
    ``tcp_velocity_std_m_s``), from a stream of its own.

    Args:
        env: A DynDLO environment (observation of length ``6 n_g + 6``).
        model: The noise model, or the path of a JSON file written by
            :meth:`ObservationNoiseModel.save`.
        control_period_s: Time between observations in multi-step mode.
    """

    def __init__(
        self,
        env: gym.Env[NDArray[np.float32], NDArray[np.float32]],
        model: ObservationNoiseModel | str | Path,
        control_period_s: float = CONTROL_PERIOD_S,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, model=model, control_period_s=control_period_s)
        gym.ObservationWrapper.__init__(self, env)
        shape = env.observation_space.shape
        if shape is None or len(shape) != 1:
            raise ValueError(
                f"expected a DynDLO observation of length 6 * n_grippers + 6, got observation shape {shape}"
            )
        observation_layout(shape[0])  # refuses any other length
        multi_step = bool(getattr(env.unwrapped, "multi_step", True))
        self.process = NoiseProcess(model, control_period_s, multi_step)
        self.model = self.process.model

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Resets the environment and the noise state; a ``seed`` also reseeds the noise."""
        self.process.reset(seed)
        obs, info = super().reset(seed=seed, options=options)
        return obs, {**info, "p_dlo_true": self.process.last_true.copy()}

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], SupportsFloat, bool, bool, dict[str, Any]]:
        """Steps the environment; ``info["p_dlo_true"]`` is the uncorrupted P_DLO."""
        obs, reward, terminated, truncated, info = super().step(action)
        return obs, reward, terminated, truncated, {**info, "p_dlo_true": self.process.last_true.copy()}

    def observation(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The observation with P_DLO and the TCP state replaced by their corrupted values."""
        return corrupt_observation(self.process, observation)


#: Default ranges of :class:`CableRandomization`, as factors of the task's nominal cable (our choice: the
#: paper gives none). Length changes the P_DLO reach, mass and stiffness the swing, damping how fast it
#: dies out.
DEFAULT_CABLE_RANGES: dict[str, tuple[float, float]] = {
    "length_m": (0.9, 1.1),
    "mass_kg": (0.7, 1.3),
    "young_pa": (0.5, 2.0),
    "damping_s": (0.5, 2.0),
}

#: The evaluation ranges beyond the training ones (``--cable-ranges beyond``): length 0.8-1.2x, mass 0.5-2x,
#: Young's modulus 0.25-4x (0.5-8 MPa for the paper's 2 MPa cable) and damping 0.25-4x. For testing whether
#: a policy copes with a cable it was not trained on; training uses :data:`DEFAULT_CABLE_RANGES`.
BEYOND_TRAINING_CABLE_RANGES: dict[str, tuple[float, float]] = {
    "length_m": (0.8, 1.2),
    "mass_kg": (0.5, 2.0),
    "young_pa": (0.25, 4.0),
    "damping_s": (0.25, 4.0),
}
#: Named ranges, for the command line.
CABLE_RANGES = {"training": DEFAULT_CABLE_RANGES, "beyond": BEYOND_TRAINING_CABLE_RANGES}
#: Where a task's scene cannot take a named range whole: vaulting's cable must pass the box's side on the
#: floor on its way to the support, which takes at least 0.807 m (0.897x the paper's 0.9 m), so its "beyond"
#: lengths start at 0.9x, the training ranges' low end; the other parameters are the beyond ranges'.
TASK_CABLE_RANGES: dict[tuple[str, str], dict[str, tuple[float, float]]] = {
    ("vaulting", "beyond"): {**BEYOND_TRAINING_CABLE_RANGES, "length_m": (0.9, 1.2)},
}


def cable_ranges_for(task: str, name: str) -> dict[str, tuple[float, float]]:
    """The named cable ranges (:data:`CABLE_RANGES`) as drawn for ``task`` (:data:`TASK_CABLE_RANGES`).

    Raises:
        ValueError: An unknown name.
    """
    if name not in CABLE_RANGES:
        raise ValueError(f"cable ranges {name!r}; expected one of {sorted(CABLE_RANGES)}")
    return dict(TASK_CABLE_RANGES.get((task, name), CABLE_RANGES[name]))


def describe_cable_ranges(ranges: dict[str, tuple[float, float]]) -> str:
    """``ranges`` in words, e.g. ``length 0.9-1.1x, mass 0.7-1.3x, Young's modulus and damping 0.5-2x``."""
    words = {"length_m": "length", "mass_kg": "mass", "radius_m": "radius", "young_pa": "Young's modulus",
             "poisson": "Poisson's ratio", "damping_s": "damping"}
    groups: dict[tuple[float, float], list[str]] = {}
    for name, span in ranges.items():
        groups.setdefault(tuple(span), []).append(words.get(name, name))  # type: ignore[arg-type]
    return ", ".join(f"{' and '.join(names)} {lo:g}-{hi:g}x" for (lo, hi), names in groups.items())


@dataclass(frozen=True)
class RandomCables:
    """Cable randomisation as a run asks for it, checked when made: a new cable every ``every_episodes``
    episodes, drawn from the episode's seed (:class:`CableRandomization`) within the named ranges
    (:data:`CABLE_RANGES`, as :func:`cable_ranges_for` gives them for a task). A run on the nominal cable
    has none (None).

    Attributes:
        ranges: ``"training"`` (:data:`DEFAULT_CABLE_RANGES`) or ``"beyond"``
            (:data:`BEYOND_TRAINING_CABLE_RANGES`).
        every_episodes: Draw a new cable every this many episodes (1: every episode; training: 10).
    """

    ranges: str = "training"
    every_episodes: int = 1

    def __post_init__(self) -> None:
        if self.ranges not in CABLE_RANGES:
            raise ValueError(f"cable ranges {self.ranges!r}; expected one of {sorted(CABLE_RANGES)}")
        if isinstance(self.every_episodes, bool) or not isinstance(self.every_episodes, int) \
                or self.every_episodes < 1:
            raise ValueError(f"a new cable every {self.every_episodes!r} episodes; expected an integer >= 1")

    def factors(self, task: str) -> dict[str, tuple[float, float]]:
        """The ranges as drawn for ``task``.

        Raises:
            ValueError: The task's scene cannot take the shortest cable of the ranges (vaulting).
        """
        ranges = cable_ranges_for(task, self.ranges)
        if task == "vaulting":
            from dyndlo_vision.tasks.vaulting import check_cable_lengths

            check_cable_lengths(ranges["length_m"][0], f"cable ranges {self.ranges!r}")
        return ranges

    def env_options(self, task: str) -> dict[str, Any]:
        """The keyword arguments of :func:`~dyndlo_vision.tasks.registry.make_env` (and of
        :class:`~dyndlo_vision.tasks.batched.BatchedEpisodes`) that draw these cables for ``task``."""
        return {"randomize_cable_every": self.every_episodes, "cable_ranges": self.factors(task)}


#: The cable parameters a factor can scale: the continuous physical ones (not the discretisation or model).
RANDOMIZABLE = ("length_m", "mass_kg", "radius_m", "young_pa", "poisson", "damping_s")


def check_cable_ranges(ranges: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    """The ranges, checked: continuous cable parameters (:data:`RANDOMIZABLE`), ``0 < low <= high`` factors.

    Raises:
        ValueError: Naming the parameter or range that is wrong and what was expected.
    """
    for name, (lo, hi) in ranges.items():
        if name not in RANDOMIZABLE:
            raise ValueError(f"cannot randomise {name!r}; expected some of {list(RANDOMIZABLE)}")
        if not (0 < lo <= hi and math.isfinite(hi)):
            raise ValueError(f"range of {name} must be 0 < low <= high factors, got ({lo}, {hi})")
    return dict(ranges)


def draw_cable(nominal: CableParams, ranges: dict[str, tuple[float, float]],
               rng: np.random.Generator) -> CableParams:
    """A random cable: each ranged parameter of ``nominal`` times a factor drawn in its range.

    Factors are uniform, log-uniform for ``young_pa`` and ``damping_s`` (they span a factor of 4 or more). A
    pure function of its arguments: the same generator state gives the same cable.
    """
    changes = {}
    for name, (lo, hi) in ranges.items():
        if name in ("young_pa", "damping_s"):
            factor = math.exp(rng.uniform(math.log(lo), math.log(hi)))
        else:
            factor = rng.uniform(lo, hi)
        changes[name] = getattr(nominal, name) * factor
    return replace(nominal, **changes)


def cable_for_seed(nominal: CableParams, ranges: dict[str, tuple[float, float]], seed: int) -> CableParams:
    """The cable :class:`CableRandomization` draws at a reset with ``seed`` when a cable is due (every reset
    with ``every_episodes=1``, as in ``demo``, ``evaluate`` and ``distill`` with random cables), without
    building or resetting an environment."""
    return draw_cable(nominal, ranges, _cable_rng(seed))


def _cable_rng(seed: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), _CABLE_STREAM])


class CableRandomization(gym.Wrapper[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32],
                                     NDArray[np.float32]]):
    """Domain randomisation: a new cable (length, mass, Young's modulus, damping) every few episodes.

    Every ``every_episodes`` resets a cable is drawn (:func:`draw_cable`, seeded by the seed given to
    :meth:`reset`) and handed to the environment's reset (``options={"cable": ...}``), which compiles the
    new model (about 0.1-0.3 s) and keeps everything else. ``info["cable"]`` holds the episode's cable.

    Args:
        env: A DynDLO environment.
        ranges: Parameter name -> (low factor, high factor); default :data:`DEFAULT_CABLE_RANGES`.
        every_episodes: Draw a new cable every this many episodes (1: every episode).
    """

    def __init__(self, env: gym.Env[NDArray[np.float32], NDArray[np.float32]],
                 ranges: dict[str, tuple[float, float]] | None = None, every_episodes: int = 10) -> None:
        super().__init__(env)
        self.ranges = check_cable_ranges(DEFAULT_CABLE_RANGES if ranges is None else ranges)
        if every_episodes < 1:
            raise ValueError(f"every_episodes must be >= 1, got {every_episodes}")
        self.every_episodes = int(every_episodes)
        self.nominal: CableParams = env.unwrapped.task.cable  # type: ignore[attr-defined]
        self._episodes = 0
        self._rng: np.random.Generator | None = None
        self.cable = self.nominal

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Draw a new cable when due, then reset the environment with it."""
        if seed is not None:
            self._rng = _cable_rng(seed)
        elif self._rng is None:
            self._rng = np.random.default_rng()
        if self._episodes % self.every_episodes == 0:
            self.cable = draw_cable(self.nominal, self.ranges, self._rng)
        self._episodes += 1
        obs, info = self.env.reset(seed=seed, options={**(options or {}), "cable": self.cable})
        return obs, {**info, "cable": self.cable}


# ---------------------------------------------------------------------------------------- student features
class _EpisodeFeature:
    """A feature appended to observations that depends on the episode so far: ``reset`` and ``__call__``."""

    def reset(self) -> None:  # pragma: no cover - every feature defines it
        raise NotImplementedError

    def __call__(self, observation: NDArray[np.floating[Any]]) -> NDArray[np.float32]:  # pragma: no cover
        raise NotImplementedError

    #: How many values it appends.
    size: int = 0

    def stack(
        self, observations: NDArray[np.floating[Any]], episode_ids: NDArray[Any]
    ) -> NDArray[np.float32]:
        """Each row of ``observations`` (N, n) with the feature, episodes told apart by ``episode_ids`` (N,).

        The rows of an episode must be consecutive and in time order, as :func:`~dyndlo_vision.learning.
        distill.collect` stores them. The same result as calling this object on them one by one, with a
        :meth:`reset` at the start of every episode.
        """
        observations = np.asarray(observations)
        ids = np.asarray(episode_ids)
        if observations.ndim != 2 or len(ids) != len(observations):
            raise ValueError(f"expected (N, n) observations and N episode ids, got {observations.shape}, "
                             f"{ids.shape}")
        out = []
        for i, row in enumerate(observations):
            if i == 0 or ids[i] != ids[i - 1]:
                self.reset()
            out.append(self(row))
        self.reset()
        return np.array(out, dtype=np.float32).reshape(len(observations), -1)


class PDloHistory(_EpisodeFeature):
    """Appends how P_DLO moved to a table-II observation: a history for a policy that must infer the cable.

    For ``length`` H it appends the finite-difference velocities of P_DLO over the last ``k`` control periods,
    ``(p(t) - p(t - k T)) / (k T)`` for ``k = 1 .. H`` (3 values each, m/s), from the P_DLO of the
    observations it was given, one per decision. Velocities, not past positions: they are on the scale of the
    observation's gripper velocities, and a cable's stiffness and mass show in how P_DLO swings, not where
    it hangs. Before ``k`` periods have passed, ``p(t - k T)`` is the episode's first P_DLO (the cable is at
    rest at reset). Pure: the same observations give the same output, whether they come from a simulator
    (:class:`PDloHistoryWrapper`) or from the control loop's estimate
    (:class:`~dyndlo_vision.policies.HistoryPolicy`).

    Call :meth:`reset` at the start of every episode.

    Args:
        length: H, the number of past periods (at least 1).
        p_dlo: Where P_DLO sits in the observation.
        control_period_s: T, the time between two observations.
    """

    def __init__(self, length: int, p_dlo: slice, control_period_s: float = CONTROL_PERIOD_S) -> None:
        if int(length) != length or length < 1:
            raise ValueError(f"P_DLO history length {length!r}; expected an integer of at least 1")
        if not control_period_s > 0:
            raise ValueError(f"control period {control_period_s!r} s; expected a positive number")
        self.length = int(length)
        self.size = 3 * self.length
        self.p_dlo = p_dlo
        self.period_s = float(control_period_s)
        self._past: list[NDArray[np.float64]] = []

    @staticmethod
    def for_observation_size(
        length: int, size: int, control_period_s: float = CONTROL_PERIOD_S
    ) -> PDloHistory:
        """The history of a table-II observation of ``size`` values (``6 n_g + 6``)."""
        return PDloHistory(length, observation_layout(size)[2], control_period_s)

    def reset(self) -> None:
        """Forget the episode: the next observation is its first."""
        self._past = []

    def features(self, p_dlo: NDArray[np.floating[Any]]) -> NDArray[np.float64]:
        """The 3 H velocities for the P_DLO observed now, which is remembered."""
        p = np.asarray(p_dlo, dtype=np.float64).reshape(3)
        if not self._past:
            self._past = [p] * self.length
        out = np.concatenate([(p - self._past[-k]) / (k * self.period_s) for k in range(1, self.length + 1)])
        self._past = [*self._past[1 - self.length:], p] if self.length > 1 else [p]
        return out

    def __call__(self, observation: NDArray[np.floating[Any]]) -> NDArray[np.float32]:
        """``observation`` with the history appended (length ``len(observation) + 3 H``)."""
        obs = np.asarray(observation, dtype=np.float32)
        return np.concatenate([obs, self.features(obs[self.p_dlo]).astype(np.float32)])


class StudentFeatures(_EpisodeFeature):
    """What a student reads besides table II: :class:`PDloHistory`.

    Args:
        observation_size: Values in the table-II observation (``6 n_g + 6``).
        p_dlo_history: H of :class:`PDloHistory` (at least 1).
        control_period_s: T, the time between two decisions.

    Raises:
        ValueError: No feature asked for, or a bad H, period or observation size.
    """

    def __init__(self, observation_size: int, p_dlo_history: int = 0,
                 control_period_s: float = CONTROL_PERIOD_S) -> None:
        if isinstance(p_dlo_history, bool) or int(p_dlo_history) != p_dlo_history or p_dlo_history < 0:
            raise ValueError(f"P_DLO history length {p_dlo_history!r}; expected an integer >= 0 (0: none)")
        self.parts: list[_EpisodeFeature] = []
        if p_dlo_history:
            self.parts.append(PDloHistory.for_observation_size(int(p_dlo_history), observation_size,
                                                               control_period_s))
        if not self.parts:
            raise ValueError("no student feature asked for: give p_dlo_history >= 1")
        self.observation_size = int(observation_size)
        self.size = sum(part.size for part in self.parts)

    @classmethod
    def for_input_size(cls, input_size: int, p_dlo_history: int = 0,
                       control_period_s: float = CONTROL_PERIOD_S) -> StudentFeatures:
        """The features of a student whose input (table II, then the features) has ``input_size`` values."""
        added = cls(12, p_dlo_history, control_period_s).size  # the same for any table-II size
        return cls(int(input_size) - added, p_dlo_history, control_period_s)

    def reset(self) -> None:
        """Every feature starts a new episode."""
        for part in self.parts:
            part.reset()

    def __call__(self, observation: NDArray[np.floating[Any]]) -> NDArray[np.float32]:
        """``observation`` with every feature appended, in order."""
        out = np.asarray(observation, dtype=np.float32)
        if out.shape != (self.observation_size,):
            raise ValueError(
                f"expected one observation of {self.observation_size} values, got shape {out.shape}"
            )
        for part in self.parts:
            out = part(out)
        return out


class StudentFeaturesWrapper(
    gym.ObservationWrapper[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]],
    gym.utils.RecordConstructorArgs,
):
    """A DynDLO environment whose observations carry :class:`StudentFeatures` (unbounded values appended).

    Put it outside :class:`NoisyObservation`, so that the history is of the P_DLO the policy sees.
    """

    def __init__(self, env: gym.Env[NDArray[np.float32], NDArray[np.float32]], p_dlo_history: int = 0,
                 control_period_s: float = CONTROL_PERIOD_S) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, p_dlo_history=p_dlo_history, control_period_s=control_period_s
        )
        gym.ObservationWrapper.__init__(self, env)
        shape = env.observation_space.shape
        if shape is None or len(shape) != 1:
            raise ValueError(f"expected a DynDLO observation vector, got observation shape {shape}")
        self.features = StudentFeatures(shape[0], p_dlo_history, control_period_s)
        base = env.observation_space
        assert isinstance(base, gym.spaces.Box)
        extra = np.full(self.features.size, np.inf, dtype=np.float32)
        self.observation_space = gym.spaces.Box(
            np.concatenate([base.low, -extra]), np.concatenate([base.high, extra]), dtype=np.float32
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Resets the environment and the features."""
        self.features.reset()
        return super().reset(seed=seed, options=options)

    def observation(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The observation with the features appended."""
        return self.features(observation)


class PDloHistoryWrapper(StudentFeaturesWrapper):
    """A DynDLO environment whose observations carry :class:`PDloHistory` (3 H more values, unbounded)."""

    def __init__(self, env: gym.Env[NDArray[np.float32], NDArray[np.float32]], length: int,
                 control_period_s: float = CONTROL_PERIOD_S) -> None:
        if int(length) != length or length < 1:
            raise ValueError(f"P_DLO history length {length!r}; expected an integer of at least 1")
        super().__init__(env, p_dlo_history=length, control_period_s=control_period_s)
