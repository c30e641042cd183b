"""Many simulations of one scene's model stepped together: the physics behind the batched environment.

:class:`BatchPhysics` is the seam: what ``tasks.batched`` needs from a physics engine, and nothing else.
Rows are MuJoCo integration states (``mjSTATE_INTEGRATION``), so a row moves between engines and to a
:class:`~dyndlo_vision.sim.Scene`; a simulation's cable is given as a compiled model of the same structure.
:class:`MujocoBatch` implements it with ``mujoco.batch`` (C threads, GIL released, bit-identical to a loop of
``mj_step``). Another engine (MuJoCo Warp on a GPU) is one more class with these methods and one more row of
:data:`PHYSICS_BACKENDS`; tasks and rewards do not change.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import mujoco
import numpy as np
from numpy.typing import NDArray


class BatchPhysics(Protocol):
    """``nsim`` simulations of one model structure, each its own state row and cable parameters."""

    @property
    def nsim(self) -> int:
        """Number of simulations."""

    def set_states(self, ids: NDArray[np.int64], states: NDArray[np.float64]) -> None:
        """Set the integration states of simulations ``ids`` (n,), each a row (n, nstate)."""

    def states(self, ids: NDArray[np.int64]) -> NDArray[np.float64]:
        """Copies of the integration states of simulations ``ids``, (n, nstate)."""

    def set_model(self, sim: int, model: mujoco.MjModel) -> None:
        """Run simulation ``sim`` on the parameters of ``model``, a model of the same structure (another
        cable of the same number of segments)."""

    def rollout(
        self, ids: NDArray[np.int64], controls: NDArray[np.float64], cold_start: bool = True
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Step simulations ``ids`` (n,) once per control row, ``controls`` (n, K, nu).

        ``cold_start``: the constraint solver starts from zero (no warm start), as MuJoCo's C rollout does,
        and so :meth:`Scene.rollout <dyndlo_vision.sim.Scene.rollout>`; False goes on from the state's warm
        start (the rest of a stretch cut into several calls).

        Returns:
            time (n, K), qpos (n, K, nq) and qvel (n, K, nv) after each step. A simulation that blows up
            (MuJoCo's bad-acceleration warning) stops there: its time then no longer advances by one timestep
            per row, which is how the caller tells.
        """


class MujocoBatch:
    """:class:`BatchPhysics` on ``mujoco.batch.Batch``: every call runs its simulations on ``nthread`` C
    threads (0: one per CPU), bit-identical to stepping each in its own ``MjData``.

    A simulation's cable (:meth:`set_model`) is given through per-simulation model fields: the fields in which
    the new model differs are expanded and copied, then ``mj_setConst`` runs for that simulation, as compiling
    did (it also derives the statistics the solver scales its tolerance by), so the simulation runs
    bit-identical to the compiled model.
    """

    def __init__(self, model: mujoco.MjModel, nsim: int, nthread: int = 0) -> None:
        from mujoco import batch

        if isinstance(nsim, bool) or not isinstance(nsim, int | np.integer) or nsim < 1:
            raise ValueError(f"nsim must be a positive integer, got {nsim!r}")
        self.model = model
        self._batch = batch.Batch(model, int(nsim), nthread=int(nthread))
        self._fields = sorted(batch.MODEL_FIELDS)
        self._default = {name: self._model_value(model, name) for name in self._fields}

    @property
    def nsim(self) -> int:
        return int(self._batch.nsim)

    @property
    def nthread(self) -> int:
        """Threads the batch runs on."""
        return int(self._batch.nthread)

    def set_states(self, ids: NDArray[np.int64], states: NDArray[np.float64]) -> None:
        self._batch.state[np.asarray(ids)] = states
        self._batch.warning[np.asarray(ids)] = 0

    def states(self, ids: NDArray[np.int64]) -> NDArray[np.float64]:
        return np.array(self._batch.state[np.asarray(ids)])

    def set_model(self, sim: int, model: mujoco.MjModel) -> None:
        changed = False
        for name in self._fields:
            value = self._model_value(model, name)
            if value.shape != self._default[name].shape:
                raise ValueError(f"model field {name} has shape {value.shape}, the batch's "
                                 f"{self._default[name].shape}: not a model of the same structure")
            current = self._batch.expanded(name)
            now = self._default[name] if current is None else current[sim].reshape(value.shape)
            if np.array_equal(now, value):
                continue
            self._batch.expand(name)[sim] = value.reshape(self._batch.expand(name)[sim].shape)
            changed = True
        if changed:
            self._batch.set_const(ids=[sim])

    def rollout(
        self, ids: NDArray[np.int64], controls: NDArray[np.float64], cold_start: bool = True
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        ids = np.asarray(ids, dtype=np.int64)
        nstep = controls.shape[1]
        if cold_start:
            self._batch.bind("qacc_warmstart")[ids] = 0.0
        record = (mujoco.mjtState.mjSTATE_TIME, "qpos", "qvel")
        out = self._batch.rollout(nstep, control=controls, record=record,
                                  ids=None if len(ids) == self.nsim else ids)
        return out[mujoco.mjtState.mjSTATE_TIME][..., 0], out["qpos"], out["qvel"]

    @staticmethod
    def _model_value(model: mujoco.MjModel, name: str) -> NDArray[np.float64]:
        if name.startswith("opt."):
            return np.asarray(getattr(model.opt, name[4:]))
        return np.asarray(getattr(model, name))


#: Physics engines for the batched environment, by name: ``factory(model, nsim, nthread)``.
PHYSICS_BACKENDS: dict[str, Callable[[mujoco.MjModel, int, int], BatchPhysics]] = {
    "mujoco-batch": MujocoBatch,
}


def make_batch_physics(backend: str, model: mujoco.MjModel, nsim: int, nthread: int = 0) -> BatchPhysics:
    """The physics engine ``backend`` (a key of :data:`PHYSICS_BACKENDS`) for ``nsim`` simulations of
    ``model``.

    Raises:
        ValueError: An unknown backend, naming the known ones.
    """
    if backend not in PHYSICS_BACKENDS:
        raise ValueError(f"unknown physics backend {backend!r}; expected one of {sorted(PHYSICS_BACKENDS)}")
    return PHYSICS_BACKENDS[backend](model, nsim, nthread)

