"""N episodes of one task in one object: the physics of all of them in one batched call, the rest in NumPy.

:class:`BatchedEpisodes` runs what :class:`~dyndlo_vision.tasks.base.DynDLOEnv` runs, for ``num_envs``
simulations at once, and gives the same results on the same seeds and actions (rewards, outcomes, infos and
observations, to the last bit; ``tests/tasks/test_batched.py``):

* plan: each action becomes its simulation's B-spline through the same :class:`~dyndlo_vision.trajectory.
  Replanner`; the references of every simulation's physics steps are evaluated in one call
  (:func:`~dyndlo_vision.trajectory.bspline.sample_many`);
* simulate: every simulation's steps go through one :class:`~dyndlo_vision.sim.batch.BatchPhysics` call
  (``mujoco.batch`` on C threads by default); a single-step episode's steps run in as few calls as the
  episodes' lengths allow;
* monitor: the avoid conditions, the closest approach to the goal (swept, for tip control), the TCP speed and
  height of every recorded sample of every simulation, computed on all samples at once;
* reward, success, observation: the task's own functions on each simulation's state, loaded into a
  :class:`~dyndlo_vision.sim.Scene` of its cable.

Cable randomisation is per simulation: a drawn cable's compiled model sets that simulation's model fields
(:meth:`~dyndlo_vision.sim.batch.BatchPhysics.set_model`), its settled state its row; the batch is not
rebuilt.
Observation noise is a :class:`~dyndlo_vision.tasks.noise.NoiseProcess` per simulation.

Not here (use :class:`DynDLOEnv`): a real arm's plan checks (``robot``), cable pushes, frame hooks, rendering.
The state after a blow-up differs: the batch stops a simulation that blows up, where MuJoCo's rollout resets
and goes on; the episode's reward, outcome and ``info["diverged"]`` are the same, its last observation is not.

The SB3 ``VecEnv`` around it is :class:`dyndlo_vision.learning.vec_env.BatchedVecEnv`.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from numpy.typing import NDArray

from dyndlo_vision.sim.batch import BatchPhysics, make_batch_physics
from dyndlo_vision.sim.cable import CableParams
from dyndlo_vision.sim.chain import ChainKinematics
from dyndlo_vision.sim.scene import Scene
from dyndlo_vision.tasks.base import (
    CONTROL_PERIOD_S,
    MONITOR_PERIOD_S,
    EpisodeMonitor,
    Task,
    _segment_point_distances,
    observation_vector,
    record_samples,
)
from dyndlo_vision.trajectory import Replanner
from dyndlo_vision.trajectory.bspline import sample_many
from dyndlo_vision.trajectory.replanner import MIRROR, replan_many

#: Compiled and settled scenes kept per cable (a randomised cable is redrawn every few episodes).
SCENE_CACHE_SIZE = 64


class BatchedEpisodes:
    """``num_envs`` episodes of ``task``, simulated together (see the module docstring).

    Args:
        task: The task (its cable is the nominal one); each simulation gets its own copy.
        num_envs: Number of simulations.
        backend: Physics engine, a key of :data:`dyndlo_vision.sim.batch.PHYSICS_BACKENDS`.
        nthread: Threads of the physics engine (0: one per CPU).
        randomize_cable_every: Draw a new cable for a simulation every this many of its episodes, as
            :class:`~dyndlo_vision.tasks.wrappers.CableRandomization` does (None: the nominal cable).
        cable_ranges: The randomisation's ranges (default: ``wrappers.DEFAULT_CABLE_RANGES``).
        obs_noise: Observation-noise model (a file, a loaded model, or a shipped model's name), as
            :class:`~dyndlo_vision.tasks.wrappers.NoisyObservation`; None: true P_DLO.

    Raises:
        ValueError: ``num_envs`` below 1, an unknown backend, bad cable ranges.
    """

    def __init__(
        self,
        task: Task,
        num_envs: int,
        *,
        backend: str = "mujoco-batch",
        nthread: int = 0,
        randomize_cable_every: int | None = None,
        cable_ranges: dict[str, tuple[float, float]] | None = None,
        obs_noise: str | Path | Any | None = None,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        n = int(num_envs)
        self.num_envs = n
        self.render_mode: str | None = None  # nothing is rendered
        self.task = task
        self.multi_step = task.multi_step
        self.tasks = [copy.deepcopy(task) for _ in range(n)]
        nominal_cable = getattr(task, "cable", None)
        self._scenes: dict[Any, Scene] = {}
        self._reset_rows: dict[Any, NDArray[np.float64]] = {}
        scene = self._scene_for(nominal_cable)
        self.nominal_scene = scene
        self.spec_actions = task.action_spec()
        n_g = scene.num_grippers
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(self.spec_actions.size,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(6 * n_g + 6,), dtype=np.float32)
        self.physics: BatchPhysics = make_batch_physics(backend, scene.model, n, nthread)
        self.backend = backend
        self._dt = scene.timestep
        self._steps_per_monitor = max(1, int(round(MONITOR_PERIOD_S / self._dt)))
        self._steps_per_control = int(round(CONTROL_PERIOD_S / self._dt))
        self._home = scene.gripper_home
        self._kp = scene.config.gains.kp_per_s
        self._tcp_qpos, self._tcp_dof, self._tcp_act = scene.tcp_indices
        self._base_ctrl = scene.data.ctrl.copy()
        # Per simulation.
        self._cables: list[Any] = [nominal_cable] * n
        self._sim_scenes: list[Scene] = [scene] * n
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._goals = np.zeros((n, 3))
        self._time = np.zeros(n)
        self._ended = np.zeros(n, dtype=bool)
        self._replanners = [Replanner(self.spec_actions, scene.gripper_home) for _ in range(n)]
        self._monitors = [EpisodeMonitor() for _ in range(n)]
        self._decisions = np.zeros(n, dtype=np.int64)
        self.physics.set_states(np.arange(n), np.tile(self._reset_rows[self._key(nominal_cable)], (n, 1)))
        # Cable randomisation, as CableRandomization does it, per simulation.
        self.randomize_cable_every = randomize_cable_every
        self._cable_ranges: dict[str, tuple[float, float]] | None = None
        self._cable_rngs: list[np.random.Generator | None] = [None] * n
        self._episodes = np.zeros(n, dtype=np.int64)
        if randomize_cable_every is not None:
            from dyndlo_vision.tasks.wrappers import DEFAULT_CABLE_RANGES, check_cable_ranges

            if int(randomize_cable_every) != randomize_cable_every or randomize_cable_every < 1:
                raise ValueError(f"randomize_cable_every must be >= 1, got {randomize_cable_every!r}")
            if nominal_cable is None:
                raise ValueError(f"{type(task).__name__} has no cable option to randomise")
            ranges = DEFAULT_CABLE_RANGES if cable_ranges is None else cable_ranges
            self._cable_ranges = check_cable_ranges(ranges)
        self._noise: list[Any] | None = None
        if obs_noise is not None:
            from dyndlo_vision.tasks.noise import NoiseProcess, ObservationNoiseModel, noise_model_file

            if isinstance(obs_noise, str | Path):
                obs_noise = ObservationNoiseModel.load(noise_model_file(obs_noise))
            self._noise = [NoiseProcess(obs_noise, CONTROL_PERIOD_S, self.multi_step) for _ in range(n)]

    # ------------------------------------------------------------------ scenes per cable
    @staticmethod
    def _key(cable: Any) -> Any:
        return repr(cable)

    def _scene_for(self, cable: Any) -> Scene:
        """The compiled, settled scene of ``cable`` (cached), and its reset row."""
        key = self._key(cable)
        scene = self._scenes.get(key)
        if scene is None:
            task = self.task
            if cable is not None and cable != getattr(task, "cable", None):
                task = copy.copy(task)
                task.cable = cable  # type: ignore[attr-defined]
            scene = Scene(task.scene_config())
            self._scenes[key] = scene
            self._reset_rows[key] = scene.reset_state()
            if len(self._scenes) > SCENE_CACHE_SIZE:
                in_use = {self._key(c) for c in getattr(self, "_cables", [])} | {key}
                unused = [k for k in self._scenes if k not in in_use]
                for old in unused[: len(self._scenes) - SCENE_CACHE_SIZE]:
                    del self._scenes[old], self._reset_rows[old]
        return scene

    # ------------------------------------------------------------------ reset
    def reset(
        self, ids: list[int], seeds: list[int | None], options: list[dict[str, Any] | None]
    ) -> tuple[NDArray[np.float32], list[dict[str, Any]]]:
        """Start a new episode in simulations ``ids``, each with its seed and options (as ``DynDLOEnv.reset``:
        ``{"goal": (x, y, z)}``, ``{"cable": CableParams(...)}``).

        Returns:
            Their observations (len(ids), obs_dim) and reset infos.
        """
        obs = np.empty((len(ids), self.observation_space.shape[0]), dtype=np.float32)
        infos = []
        for row, (i, seed, opts) in enumerate(zip(ids, seeds, options, strict=True)):
            obs[row], info = self._reset_one(int(i), seed, dict(opts or {}))
            infos.append(info)
        return obs, infos

    def _reset_one(self, i: int, seed: int | None, options: dict[str, Any]) -> tuple[NDArray[np.float32],
                                                                                 dict[str, Any]]:
        extra: dict[str, Any] = {}
        if self._noise is not None:
            self._noise[i].reset(seed)
        if self._cable_ranges is not None:
            from dyndlo_vision.tasks.wrappers import _cable_rng, draw_cable

            if seed is not None:
                self._cable_rngs[i] = _cable_rng(seed)
            elif self._cable_rngs[i] is None:
                self._cable_rngs[i] = np.random.default_rng()
            assert self.randomize_cable_every is not None
            cable = self._cables[i]
            if self._episodes[i] % self.randomize_cable_every == 0:
                cable = draw_cable(self.task.cable, self._cable_ranges,  # type: ignore[attr-defined]
                                   self._cable_rngs[i])  # type: ignore[arg-type]
            self._episodes[i] += 1
            options = {**options, "cable": cable}
            extra["cable"] = cable
        if seed is not None or self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random(seed)
        if "cable" in options:
            cable = options["cable"]
            if not isinstance(cable, CableParams):
                raise ValueError(f"options['cable'] must be a CableParams, got {type(cable).__name__}")
            if not hasattr(self.task, "cable"):
                raise ValueError(f"{type(self.task).__name__} has no cable option to swap")
            self._set_cable(i, cable)
        scene = self._sim_scenes[i]
        task = self.tasks[i]
        task.begin_episode()
        if "goal" in options:
            goal = np.asarray(options["goal"], dtype=float)
            if goal.shape != (3,) or not np.all(np.isfinite(goal)):
                raise ValueError(f"options['goal'] must be 3 finite numbers, got {options['goal']!r}")
            self._goals[i] = goal
        else:
            self._goals[i] = task.sample_goal(self._rngs[i])  # type: ignore[arg-type]
        self._replanners[i].reset(task.final_point(self._goals[i]))
        self._monitors[i] = EpisodeMonitor()
        self._decisions[i] = 0
        self._time[i] = 0.0
        self._ended[i] = False
        scene.load_state(self._reset_rows[self._key(self._cables[i])])
        if scene.config.target_radius_m > 0:
            # The marker is part of the state (not of the physics: it collides with nothing); set as the
            # single environment sets it, a simulation's state row is the single environment's.
            scene.set_target(self._goals[i])
        self.physics.set_states(np.array([i]), scene.state()[None])
        # The first monitor sample, of the state at reset (DynDLOEnv._sample_monitor).
        p_dlo = scene.cable_nodes()[task.p_dlo_node(scene)]
        self._record(i, np.array([scene.time]), scene.tcp_positions()[None], scene.tcp_velocities()[None],
                     p_dlo[None])
        obs = observation_vector(scene.tcp_positions(), scene.tcp_velocities(), p_dlo, self._goals[i])
        info = {"goal": self._goals[i].copy(), **extra}
        return self._corrupt(i, obs, info), info

    def _set_cable(self, i: int, cable: CableParams) -> None:
        if self._key(cable) == self._key(self._cables[i]):
            return
        scene = self._scene_for(cable)
        if scene.model.nq != self.nominal_scene.model.nq:
            raise ValueError(f"a cable of {cable.num_segments} segments cannot join a batch of "
                             f"{self.task.cable.num_segments}: the batch needs one model structure")  # type: ignore[attr-defined]
        self.physics.set_model(i, scene.model)
        self._cables[i] = cable
        self._sim_scenes[i] = scene
        self.tasks[i].cable = cable  # type: ignore[attr-defined]

    # ------------------------------------------------------------------ step
    def step(
        self, actions: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_], list[dict[str, Any]]]:
        """One decision of every simulation: plan, simulate, monitor, reward, observe (no reset).

        Returns:
            observations (N, obs_dim), rewards (N,), terminated (N,), infos.

        Raises:
            ValueError: Actions of the wrong shape or not finite (naming the simulation).
            RuntimeError: A simulation whose single-step episode has ended and was not reset.
        """
        a = np.asarray(actions)
        n = self.num_envs
        if a.shape != (n, *self.action_space.shape):
            raise ValueError(f"actions must have shape {(n, *self.action_space.shape)}, got shape {a.shape}")
        if self._ended.any():
            raise RuntimeError(f"episodes of simulations {np.flatnonzero(self._ended).tolist()} have ended: "
                               "reset them first")
        bad = np.argwhere(~np.isfinite(a))
        if bad.size:  # checked before any plan changes, so a refused call leaves every episode as it was
            i, j = (int(x) for x in bad[0])
            raise ValueError(f"simulation {i}: action must be finite, got {a[i, j]} at index {j}")
        replan_many(self._replanners, a.astype(np.float64), self._time)
        all_ids = np.arange(n)
        diverged = np.zeros(n, dtype=bool)
        if self.multi_step:
            self._simulate(all_ids, np.full(n, self._steps_per_control), diverged)
            self._decisions += 1
            early = np.array([self._task_call(i, "is_done_early") for i in range(n)], dtype=bool)
            final = early | (self._time >= np.array([t.episode_s for t in self.tasks]) - 1e-9)
            settle = np.flatnonzero(final & ~early & ~diverged)
            if settle.size:
                steps = np.array([int(round(self.tasks[i].settle_s / self._dt)) for i in settle])
                self._simulate(settle, steps, diverged)
        else:
            steps = np.array([int(np.ceil((self._replanners[i].trajectory.t_end  # type: ignore[union-attr]
                                           - float(self._time[i]) + self.tasks[i].settle_s) / self._dt))
                              for i in range(n)])
            self._simulate(all_ids, steps, diverged)
            final = np.ones(n, dtype=bool)
        obs = np.empty((n, self.observation_space.shape[0]), dtype=np.float32)
        rewards = np.empty(n)
        infos: list[dict[str, Any]] = []
        done = final | diverged
        for i in range(n):
            mon = self._monitors[i]
            mon.diverged = mon.diverged or bool(diverged[i])
            scene = self._load(i)
            terms, success, extra = self.tasks[i].evaluate(scene, self._goals[i], mon, bool(done[i]))
            rewards[i] = float(sum(terms.values()))
            info: dict[str, Any] = {**terms, **extra, "is_success": bool(success), "avoid": dict(mon.avoid),
                                    "sim_time_s": float(self._time[i])}
            if diverged[i]:
                info["diverged"] = True
            p_dlo = scene.cable_nodes()[self.tasks[i].p_dlo_node(scene)]
            true = observation_vector(scene.tcp_positions(), scene.tcp_velocities(), p_dlo, self._goals[i])
            obs[i] = self._corrupt(i, true, info)
            infos.append(info)
        self._ended = done.copy()
        return obs, rewards, done, infos

    def _task_call(self, i: int, name: str) -> Any:
        scene = self._load(i)
        return getattr(self.tasks[i], name)(scene, self._goals[i], self._monitors[i])

    def _load(self, i: int) -> Scene:
        """Simulation ``i``'s scene in the simulation's current state."""
        scene = self._sim_scenes[i]
        scene.load_state(self.physics.states(np.array([i]))[0])
        return scene

    def _corrupt(self, i: int, obs: NDArray[np.float32], info: dict[str, Any]) -> NDArray[np.float32]:
        if self._noise is None:
            return obs
        from dyndlo_vision.tasks.wrappers import corrupt_observation

        out = corrupt_observation(self._noise[i], obs)
        info["p_dlo_true"] = self._noise[i].last_true.copy()
        return out

    # ------------------------------------------------------------------ simulate
    def _simulate(
        self, ids: NDArray[np.int64], nsteps: NDArray[np.int64], diverged: NDArray[np.bool_]
    ) -> None:
        """Follow each simulation's plan for its number of physics steps, then monitor the recorded states.

        As ``DynDLOEnv._simulate_span`` with the C rollout: references at the step times, the physics, then
        a monitor sample every ``MONITOR_PERIOD_S`` of the steps that stayed finite.
        """
        keep = nsteps > 0
        ids, nsteps = ids[keep], nsteps[keep]
        if not ids.size:
            return
        kmax = int(nsteps.max())
        t0 = self._time[ids].copy()
        times = t0[:, None] + self._dt * np.arange(kmax)[None, :]
        ref_p, ref_v = self._references(ids, times)
        ctrl = np.tile(self._base_ctrl, (len(ids), kmax, 1))
        tcp = (ref_v + self._kp * (ref_p - self._home)).reshape(len(ids), kmax, -1)
        ctrl[:, :, self._tcp_act.ravel()] = tcp
        nq, nv = self.nominal_scene.model.nq, self.nominal_scene.model.nv
        rec_t = np.empty((len(ids), kmax))
        rec_q = np.empty((len(ids), kmax, nq))
        rec_v = np.empty((len(ids), kmax, nv))
        # Runs of equal length go together; the others stop when their episode's steps are done.
        done = np.zeros(len(ids), dtype=np.int64)
        while True:
            active = np.flatnonzero(done < nsteps)
            if not active.size:
                break
            start = int(done[active].min())
            k = int(nsteps[active].min()) - start
            # The stretch starts with the solver cold, as the single environment's C rollout does; the calls
            # that continue it keep the warm start.
            cold = done[active] == 0
            if cold.any() and not cold.all():
                raise AssertionError("a call mixes the starts and continuations of stretches")
            part = np.ascontiguousarray(ctrl[active, start:start + k])
            tt, qq, vv = self.physics.rollout(ids[active], part, cold_start=bool(cold[0]))
            rec_t[active, start:start + k], rec_q[active, start:start + k] = tt, qq
            rec_v[active, start:start + k] = vv
            done[active] += k
        samples_t, samples_q, samples_v, owners = [], [], [], []
        for row, i in enumerate(ids):
            k = int(nsteps[row])
            expected = t0[row] + self._dt * np.arange(1, k + 1)
            good = np.abs(rec_t[row, :k] - expected) < 0.5 * self._dt
            good &= np.all(np.isfinite(rec_q[row, :k]), axis=1) & np.all(np.isfinite(rec_v[row, :k]), axis=1)
            good &= self._sim_scenes[i].in_bounds(rec_q[row, :k])
            finite = k if good.all() else int(np.argmin(good))
            if finite < k:
                diverged[i] = True
            self._time[i] = rec_t[row, k - 1]
            samples = np.arange(self._steps_per_monitor - 1, finite, self._steps_per_monitor)
            if samples.size:
                samples_t.append(t0[row] + self._dt * (samples + 1))
                samples_q.append(rec_q[row, samples])
                samples_v.append(rec_v[row, samples])
                owners.append(int(i))
        if owners:
            self._record_many(owners, samples_t, samples_q, samples_v)

    def _references(self, ids: NDArray[np.int64], times: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Every gripper's reference position and velocity at ``times`` (n, K), each (n, K, n_g, 3)."""
        pos, vel = sample_many([self._replanners[i].trajectory for i in ids], times)  # type: ignore[misc]
        home = self._home
        p, v = [pos], [vel]
        for g in range(1, len(home)):
            p.append(home[g] + (pos - home[0]) * MIRROR)
            v.append(vel * MIRROR)
        return np.stack(p, axis=2), np.stack(v, axis=2)

    # ------------------------------------------------------------------ monitor
    def _nodes(self, owners: list[int], qpos: list[NDArray[np.float64]]) -> list[NDArray[np.float64]]:
        """P_DLO of each simulation's recorded configurations, computed as its own scene computes them."""
        out: list[NDArray[np.float64] | None] = [None] * len(owners)
        vector_rows, vector_seg, vector_at = [], [], []
        for k, (i, q) in enumerate(zip(owners, qpos, strict=True)):
            scene = self._sim_scenes[i]
            chain = scene.chain
            if chain is not None and q.shape[0] > ChainKinematics.SMALL_BATCH:
                vector_rows.append(q)
                vector_seg.append(np.full(q.shape[0], chain.segment_m()))
                vector_at.append(k)
            else:
                out[k] = scene.nodes_from_qpos(q)[:, self.tasks[i].p_dlo_node(scene)]
        if vector_rows:
            chain = self.nominal_scene.chain
            assert chain is not None
            nodes = chain.nodes_vectorized(np.concatenate(vector_rows), np.concatenate(vector_seg))
            start = 0
            for k, q in zip(vector_at, vector_rows, strict=True):
                i = owners[k]
                out[k] = nodes[start:start + q.shape[0], self.tasks[i].p_dlo_node(self._sim_scenes[i])]
                start += q.shape[0]
        return out  # type: ignore[return-value]

    def _record_many(self, owners: list[int], times: list[NDArray[np.float64]],
                     qpos: list[NDArray[np.float64]], qvel: list[NDArray[np.float64]]) -> None:
        """``DynDLOEnv._record_samples`` for the recorded samples of several simulations, on all at once."""
        p = [self._home + q[:, self._tcp_qpos] for q in qpos]
        v = [qv[:, self._tcp_dof] for qv in qvel]
        record_samples_many([self.tasks[i] for i in owners], [self._monitors[i] for i in owners],
                            self._goals[owners], times, p, v, self._nodes(owners, qpos))

    def _record(self, i: int, times: NDArray[np.float64], p: NDArray[np.float64], v: NDArray[np.float64],
                p_dlo: NDArray[np.float64]) -> None:
        """One simulation's samples (the reset sample), as the single environment records them."""
        record_samples(self.tasks[i], self._monitors[i], self._goals[i], times, p, v, p_dlo)


def record_samples_many(
    tasks: list[Task], monitors: list[EpisodeMonitor], goals: NDArray[np.float64],
    times: list[NDArray[np.float64]], p: list[NDArray[np.float64]], v: list[NDArray[np.float64]],
    p_dlo: list[NDArray[np.float64]],
) -> None:
    """:func:`~dyndlo_vision.tasks.base.record_samples` for M simulations at once, each with its task,
    monitor, goal (M, 3) and K_m samples: times (K_m,), TCP positions and velocities (K_m, n_g, 3), P_DLO
    (K_m, 3). Every monitor ends as ``record_samples`` leaves it, to the last bit; the avoid conditions,
    speeds, heights and goal distances of all samples are computed together. The tasks are of one class (one
    batch)."""
    task = tasks[0]
    counts = np.array([len(t) for t in times])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    p_all, v_all, dlo = np.concatenate(p), np.concatenate(v), np.concatenate(p_dlo)
    rows_goal = np.repeat(np.asarray(goals, dtype=float), counts, axis=0)
    limits = task.limits
    shoulder = np.asarray(limits.shoulder_position_m)
    speed = np.linalg.norm(v_all, axis=-1)
    flags = {
        "outreach": np.any(np.linalg.norm(p_all - shoulder, axis=-1) > limits.outreach_m, axis=1),
        "velocity": np.any(speed > limits.v_max_m_s, axis=1),
        "collision": (dlo[..., 2] < limits.collision_height_m) & task.check_collision,
        "shoulder": np.any(np.linalg.norm(p_all[..., :2], axis=-1) < limits.shoulder_m, axis=1),
    }
    flags_any = {key: np.logical_or.reduceat(value, starts) for key, value in flags.items()}
    max_speed = np.maximum.reduceat(speed.max(axis=1), starts)
    max_height = np.maximum.reduceat(p_all[:, :, 2].mean(axis=1), starts)
    if type(task).goal_distances is not Task.goal_distances:
        dist = np.concatenate([t.goal_distances(pp, dd, g) for t, pp, dd, g in zip(tasks, p, p_dlo, goals,
                                                                                     strict=True)])
    else:
        dist = np.linalg.norm(dlo - rows_goal, axis=-1)
    if task.swept_goal_check:
        # Each simulation's first segment starts where its P_DLO was at its previous sample.
        previous = np.empty_like(dlo)
        previous[1:] = dlo[:-1]
        for mon, s in zip(monitors, starts, strict=True):
            previous[s] = dlo[s] if mon.last_p_dlo is None else mon.last_p_dlo
        dist = np.minimum(dist, _segment_point_distances(previous, dlo, rows_goal))
    min_dist = np.minimum.reduceat(dist, starts)
    custom_samples = type(task).on_samples is not Task.on_samples
    for k, (t, mon) in enumerate(zip(tasks, monitors, strict=True)):
        for key in flags_any:
            mon.avoid[key] = mon.avoid[key] or bool(flags_any[key][k])
        mon.max_tcp_speed_m_s = max(mon.max_tcp_speed_m_s, float(max_speed[k]))
        mon.max_mean_height_m = max(mon.max_mean_height_m, float(max_height[k]))
        s, c = int(starts[k]), int(counts[k])
        if custom_samples:
            running = np.minimum.accumulate(np.minimum(dist[s:s + c], mon.min_goal_distance_m))
        mon.min_goal_distance_m = float(min(mon.min_goal_distance_m, float(min_dist[k])))
        mon.last_p_dlo = dlo[s + c - 1].copy()
        mon.samples += c
        if custom_samples:
            t.on_samples(times[k], p[k], v[k], p_dlo[k], running, mon)
