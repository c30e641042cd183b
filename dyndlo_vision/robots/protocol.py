"""The robot edge of the loop: a :class:`Robot` reports its TCP state (:class:`TcpState`) and follows
Cartesian setpoints (:class:`Setpoints`). The simulated TCP and the EGM/RTDE drivers implement it, so the
same loop runs in simulation and on hardware. Times are seconds on the robot's clock.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class TcpState:
    """Measured state of the robot's tool centre point(s).

    Attributes:
        position: (n_g, 3) world positions in metres, one row per gripper.
        velocity: (n_g, 3) world velocities in m/s.
        t: Time the state was measured, seconds on the robot's clock.
    """

    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    t: float


@dataclass(frozen=True)
class Setpoints:
    """A short stretch of a Cartesian TCP trajectory, sampled at a fixed rate.

    Attributes:
        t: (K,) times in seconds on the robot's clock, strictly increasing, evenly spaced.
        position: (K, n_g, 3) commanded TCP positions.
        velocity: (K, n_g, 3) commanded TCP velocities (feed-forward).
    """

    t: NDArray[np.float64]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]

    def __post_init__(self) -> None:
        t, p, v = np.asarray(self.t), np.asarray(self.position), np.asarray(self.velocity)
        if t.ndim != 1 or t.size == 0:
            raise ValueError(f"Setpoints.t must be a non-empty 1-D array, got shape {t.shape}")
        if p.ndim != 3 or p.shape[0] != t.size or p.shape[2] != 3:
            raise ValueError(f"Setpoints.position must have shape ({t.size}, n_g, 3), got {p.shape}")
        if v.shape != p.shape:
            raise ValueError(f"Setpoints.velocity must have shape {p.shape}, got {v.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
            raise ValueError("Setpoints contain NaN or inf")
        if t.size > 1 and np.any(np.diff(t) <= 0):
            raise ValueError("Setpoints.t must be strictly increasing")

    @property
    def period(self) -> float:
        """Spacing of the samples in seconds (0 for a single sample)."""
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else 0.0


@runtime_checkable
class Robot(Protocol):
    """A robot whose TCP(s) follow Cartesian setpoints: the simulated TCP, or a driver for ABB EGM / UR RTDE.

    ``send`` hands over the setpoints for the coming control period. A simulated robot executes them at once
    (advancing the simulator's clock); a real driver streams them at its own rate in the background and
    returns.
    Drivers check every setpoint against their limits *before* anything moves and raise ``ValueError``
    (naming the limit and the value) instead of sending a setpoint outside them.
    """

    def connect(self) -> None:
        """Open the connection (no-op in simulation)."""
        ...

    def state(self) -> TcpState:
        """The latest measured TCP state."""
        ...

    def send(self, setpoints: Setpoints) -> None:
        """Follow these setpoints (replacing any not yet executed)."""
        ...

    def stop(self) -> None:
        """Bring the TCP to rest where it is and stop following setpoints. Safe to call repeatedly."""
        ...

    def close(self) -> None:
        """Stop and disconnect."""
        ...
