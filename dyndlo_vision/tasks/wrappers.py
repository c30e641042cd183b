"""Gymnasium wrappers for training on the state a camera-based controller would see.

:class:`NoisyObservation` replaces the true P_DLO in a DynDLO observation (table II layout: gripper
positions ``3 n_g``, gripper velocities ``3 n_g``, P_DLO ``3``, target ``3``) by a corrupted one drawn from an
:class:`~dyndlo_vision.tasks.noise.ObservationNoiseModel`: delayed, biased, noisy, and missing in
runs, during which the last value is extrapolated at constant velocity like a coasting tracking filter.
"""

from __future__ import annotations

import math
from collections import deque
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
from dyndlo_vision.tasks.noise import ObservationNoiseModel

__all__ = ["NoisyObservation"]

# Mixed into the reset seed so that the noise stream differs from the environment's own random stream.
_NOISE_STREAM = 0x4E6F697379


class NoisyObservation(
    gym.ObservationWrapper[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]],
    gym.utils.RecordConstructorArgs,
):
    """Corrupts P_DLO in the observations of a DynDLO environment with a fitted noise model.

    Per observation (one per control step of ``control_period_s``, 40 ms in multi-step mode):

    1. the true P_DLO is appended to a short history; the delayed value ``latency_s`` ago is interpolated
       linearly between the two neighbouring steps (the observation at reset pads the history);
    2. a two-state Markov chain decides whether this observation is a dropout (never the first one);
    3. observed: ``delayed + bias + N(0, std(speed)^2)`` per axis, with ``speed`` the true P_DLO speed over
       the last control step; dropout: the previous output moved on at the velocity of the last two
       outputs before the dropout began, for at most ``max_coast_steps`` steps, then held.

    In single-step mode (``env.unwrapped.multi_step`` False) an episode has only the observations before and
    after the whole trajectory, so no latency is applied. The random stream is seeded from the seed given to
    :meth:`reset` (same seed, same noise); without one ever given it is seeded from the OS.
    ``info["p_dlo_true"]`` carries the uncorrupted P_DLO.

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
        if shape is None or len(shape) != 1 or shape[0] < 12 or (shape[0] - 6) % 6 != 0:
            raise ValueError(
                f"expected a DynDLO observation of length 6 * n_grippers + 6, got observation shape {shape}"
            )
        if not (math.isfinite(control_period_s) and control_period_s > 0):
            raise ValueError(
                f"control_period_s must be a positive number of seconds, got {control_period_s!r}"
            )
        self.model = model if isinstance(model, ObservationNoiseModel) else ObservationNoiseModel.load(model)
        n_g = (shape[0] - 6) // 6
        self._p_dlo = slice(6 * n_g, 6 * n_g + 3)
        self.control_period_s = float(control_period_s)
        multi_step = bool(getattr(env.unwrapped, "multi_step", True))
        self.lag_steps = self.model.latency_s / self.control_period_s if multi_step else 0.0
        self._history: deque[NDArray[np.float64]] = deque(maxlen=int(math.ceil(self.lag_steps)) + 2)
        self._outputs: deque[NDArray[np.float64]] = deque(maxlen=2)
        self._rng: np.random.Generator | None = None
        self._dropped = False
        self._coast_steps = 0
        self._coast_velocity = np.zeros(3)
        self._last_true = np.zeros(3)

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Resets the environment and the noise state; a ``seed`` also reseeds the noise."""
        self.reset_noise(seed)
        obs, info = super().reset(seed=seed, options=options)
        return obs, {**info, "p_dlo_true": self._last_true.copy()}

    def reset_noise(self, seed: int | None = None) -> None:
        """Forget the noise state (history, dropout chain); a ``seed`` also reseeds the noise.

        :meth:`reset` calls it; the control loop's noisy state source calls it alone, at the start of an
        episode it resets itself.
        """
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), _NOISE_STREAM])
        elif self._rng is None:
            self._rng = np.random.default_rng()
        self._history.clear()
        self._outputs.clear()
        self._dropped = False
        self._coast_steps = 0

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], SupportsFloat, bool, bool, dict[str, Any]]:
        """Steps the environment; ``info["p_dlo_true"]`` is the uncorrupted P_DLO."""
        obs, reward, terminated, truncated, info = super().step(action)
        return obs, reward, terminated, truncated, {**info, "p_dlo_true": self._last_true.copy()}

    def observation(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The observation with P_DLO replaced by its corrupted value."""
        obs = np.array(observation, dtype=np.float32, copy=True)
        p_dlo, _ = self.corrupt_p_dlo(obs[self._p_dlo].astype(np.float64))
        obs[self._p_dlo] = p_dlo.astype(np.float32)
        return obs

    def corrupt_p_dlo(self, true_p_dlo: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
        """One draw of the noise model for the true P_DLO of this control step.

        Returns the corrupted P_DLO and whether it counts as measured (False during a dropout, when the
        output coasts on the last measurements). :meth:`observation` calls it once per observation; the
        control loop's noisy state source calls it once per cycle.
        """
        if self._rng is None:  # called without reset() through this wrapper
            self._rng = np.random.default_rng()
        true_p = np.asarray(true_p_dlo, dtype=np.float64).copy()
        self._last_true = true_p
        self._history.append(true_p)
        return self._corrupt(), not self._dropped

    # ------------------------------------------------------------------ internals
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


#: Default ranges of :class:`CableRandomization`, as factors of the task's nominal cable (our choice: the
#: paper gives none). Length changes the P_DLO reach, mass and stiffness the swing, damping how fast it
#: dies out.
DEFAULT_CABLE_RANGES: dict[str, tuple[float, float]] = {
    "length_m": (0.9, 1.1),
    "mass_kg": (0.7, 1.3),
    "young_pa": (0.5, 2.0),
    "damping_s": (0.5, 2.0),
}


class CableRandomization(gym.Wrapper[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32],
                                     NDArray[np.float32]]):
    """Domain randomisation: a new cable (length, mass, Young's modulus, damping) every few episodes.

    Changing the cable means a new MuJoCo model (compile and settle, about 0.1-0.3 s), so a new one is drawn
    every ``every_episodes`` resets. Factors are drawn uniformly (log-uniformly for ``young_pa`` and
    ``damping_s``) in ``ranges`` and multiply the task's nominal cable; the seed given to :meth:`reset` seeds
    the draws. ``info["cable"]`` holds the cable of the episode.

    Args:
        env: A DynDLO environment made with ``gym.make`` (its task options are reused).
        ranges: Parameter name -> (low factor, high factor); default :data:`DEFAULT_CABLE_RANGES`.
        every_episodes: Draw a new cable every this many episodes (1: every episode).
    """

    def __init__(self, env: gym.Env[NDArray[np.float32], NDArray[np.float32]],
                 ranges: dict[str, tuple[float, float]] | None = None, every_episodes: int = 10) -> None:
        super().__init__(env)
        from dyndlo_vision.sim.cable import CableParams

        self.ranges = dict(DEFAULT_CABLE_RANGES if ranges is None else ranges)
        fields = set(CableParams.__dataclass_fields__)
        for name, (lo, hi) in self.ranges.items():
            if name not in fields or name in ("num_segments",):
                expected = sorted(DEFAULT_CABLE_RANGES)
                raise ValueError(f"cannot randomise {name!r}; expected some of {expected}")
            if not (0 < lo <= hi and math.isfinite(hi)):
                raise ValueError(f"range of {name} must be 0 < low <= high factors, got ({lo}, {hi})")
        if every_episodes < 1:
            raise ValueError(f"every_episodes must be >= 1, got {every_episodes}")
        self.every_episodes = int(every_episodes)
        base = env.unwrapped
        self.nominal = base.task.cable  # type: ignore[attr-defined]
        self._episodes = 0
        self._rng: np.random.Generator | None = None
        self.cable = self.nominal

    def _draw(self) -> Any:
        from dataclasses import replace

        assert self._rng is not None
        changes = {}
        for name, (lo, hi) in self.ranges.items():
            if name in ("young_pa", "damping_s"):
                factor = math.exp(self._rng.uniform(math.log(lo), math.log(hi)))
            else:
                factor = self._rng.uniform(lo, hi)
            changes[name] = getattr(self.nominal, name) * factor
        return replace(self.nominal, **changes)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Draw a new cable when due (rebuilding the environment's scene), then reset."""
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), _NOISE_STREAM + 1])
        elif self._rng is None:
            self._rng = np.random.default_rng()
        if self._episodes % self.every_episodes == 0:
            self.cable = self._draw()
            base = self.env.unwrapped
            task = base.task  # type: ignore[attr-defined]
            task.cable = self.cable
            base.__init__(task, base.render_mode, base.render_camera)  # type: ignore[misc]  (rebuilds the scene)
        self._episodes += 1
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, {**info, "cable": self.cable}
