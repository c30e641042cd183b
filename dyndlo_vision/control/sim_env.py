"""What the control loop needs from the simulation, as a small typed protocol: :class:`SimEnv`.

The simulation adapters (:class:`~dyndlo_vision.control.sim_robot.SimRobot`, the true and noisy state
sources, the tracked camera, :func:`~dyndlo_vision.control.episode.run_loop_episode`) use a DynDLO
environment only through these members, so the loop's view of the simulator is written down in one place.
:class:`~dyndlo_vision.tasks.base.DynDLOEnv` implements it; :func:`as_sim_env` takes it out of any
Gymnasium wrappers and checks it.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim.scene import Scene
from dyndlo_vision.tasks.base import Task
from dyndlo_vision.trajectory import Replanner


@runtime_checkable
class SimEnv(Protocol):
    """A simulated task as the loop sees it."""

    @property
    def scene(self) -> Scene:
        """The MuJoCo scene: model, data, TCP state and references, the simulator's time."""
        ...

    @property
    def task(self) -> Task:
        """The task: episode length, settle time, success radius."""
        ...

    @property
    def multi_step(self) -> bool:
        """Re-plan every control period (else plan once)."""
        ...

    @property
    def goal(self) -> NDArray[np.float64]:
        """The episode's target P*."""
        ...

    @property
    def replanner(self) -> Replanner:
        """The planner that turns actions into TCP trajectories, shared with the environment."""
        ...

    @property
    def trajectory(self) -> Any:
        """The TCP trajectory being followed (None before the first plan)."""
        ...

    @property
    def model(self) -> Any:
        """The MuJoCo model (for cameras)."""
        ...

    @property
    def data(self) -> Any:
        """The MuJoCo data (for cameras)."""
        ...

    def p_dlo(self) -> NDArray[np.float64]:
        """The true P_DLO now."""
        ...

    def follow(self, times: NDArray[np.float64], positions: NDArray[np.float64],
               velocities: NDArray[np.float64]) -> None:
        """Simulate the TCPs through these references, monitoring the task as ``step`` does."""
        ...

    def outcome(self) -> tuple[float, bool, dict[str, Any]]:
        """The episode's reward, success and info, scored as ``step`` scores it."""
        ...

    def is_done_early(self) -> bool:
        """The task ends the episode now (e.g. the target was hit)."""
        ...


def as_sim_env(env: Any) -> SimEnv:
    """The :class:`SimEnv` inside ``env`` (a DynDLO environment, possibly in Gymnasium wrappers).

    Raises:
        TypeError: ``env`` is not a simulated DynDLO task.
    """
    base = getattr(env, "unwrapped", env)
    if not isinstance(base, SimEnv):
        raise TypeError(f"expected a DynDLO environment (a SimEnv), got {type(base).__name__}")
    return base
