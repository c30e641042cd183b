"""The noise model as a process in time: one corrupted P_DLO (and gripper state) per control step."""

from __future__ import annotations

import math
from collections import deque
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision.tasks.noise.model import ObservationNoiseModel

__all__ = ["NoiseProcess"]

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
