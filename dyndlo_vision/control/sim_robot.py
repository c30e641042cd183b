"""The simulated robot: the TCP(s) of a DynDLO environment behind the :class:`Robot` protocol."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from dyndlo_vision.control.sim_env import SimEnv, as_sim_env
from dyndlo_vision.robots.protocol import Setpoints, TcpState

log = logging.getLogger(__name__)


class SimRobot:
    """Drives the grippers of a :class:`~dyndlo_vision.tasks.DynDLOEnv` from setpoints.

    ``send`` executes the setpoints at once, stepping the physics until the last one has been held for a
    setpoint period: in simulation the robot's clock *is* the simulator's time. The environment keeps
    monitoring the task (constraints, goal distance), so :meth:`DynDLOEnv.outcome` scores a loop-driven
    episode exactly as an episode driven through ``env.step``.
    """

    def __init__(self, env: Any) -> None:
        self.env: SimEnv = as_sim_env(env)
        self.connected = False
        self.stopped = False

    def connect(self) -> None:
        """Nothing to open in simulation."""
        self.connected = True
        self.stopped = False

    def state(self) -> TcpState:
        """Positions and velocities of the TCPs now, at the simulator's time."""
        scene = self.env.scene
        return TcpState(scene.tcp_positions(), scene.tcp_velocities(), scene.time)

    def send(self, setpoints: Setpoints) -> None:
        """Simulate until the setpoints have been followed.

        Raises:
            RuntimeError: After :meth:`stop`, until :meth:`connect` is called again.
            ValueError: Setpoints for another number of grippers, or starting in the simulator's past.
        """
        if self.stopped:
            raise RuntimeError("SimRobot is stopped; call connect() to resume")
        n_g = self.env.scene.num_grippers
        if setpoints.position.shape[1] != n_g:
            raise ValueError(f"setpoints for {setpoints.position.shape[1]} grippers; this robot has {n_g}")
        now = self.env.scene.time
        if setpoints.t[0] < now - 0.5 * self.env.scene.timestep:
            raise ValueError(
                f"setpoints start at t={setpoints.t[0]:.4f} s, before the robot's time {now:.4f} s"
            )
        self.env.follow(setpoints.t, setpoints.position, setpoints.velocity)

    def hold(self, duration_s: float) -> None:
        """Keep the TCPs where they are commanded to be now, at rest, for ``duration_s`` of simulated time."""
        scene = self.env.scene
        dt = scene.timestep
        n = int(round(duration_s / dt))
        if n <= 0:
            return
        p, _ = self.env.replanner.references(np.array([scene.time]))
        t = scene.time + dt * np.arange(n)
        self.env.follow(t, np.repeat(p, n, axis=0), np.zeros((n, *p.shape[1:])))

    def stop(self) -> None:
        """Hold the measured position at rest from now on (references only; nothing is simulated)."""
        scene = self.env.scene
        scene.set_tcp_reference(scene.tcp_positions(), np.zeros((scene.num_grippers, 3)))
        if not self.stopped:
            log.info("SimRobot stopped at t=%.3f s", scene.time)
        self.stopped = True

    def close(self) -> None:
        """Stop."""
        self.stop()
        self.connected = False


class DelayedRobot:
    """A simulated robot that executes every setpoint ``latency_s`` after its time stamp: actuation latency.

    ``send`` executes, over the span the new setpoints cover, the setpoints sent so far shifted by the
    latency (sample and hold): the motion commanded for time ``t`` happens at ``t + latency_s``, while the
    planner goes on from the state it commanded, as with a real arm whose driver delays the commands. Before
    the first setpoint is due, the first position is held at rest. An optional disturbance
    (``demo --actuation-latency-ms``); for a robot whose clock is the simulator's (:class:`SimRobot`).

    Raises:
        ValueError: A latency that is not a finite time in [0, 1] s.
    """

    def __init__(self, robot: SimRobot, latency_s: float) -> None:
        if not (np.isfinite(latency_s) and 0.0 <= latency_s <= 1.0):
            raise ValueError(f"actuation latency must be in [0, 1] s, got {latency_s!r}")
        self.robot = robot
        self.latency_s = float(latency_s)
        self._t: list[np.ndarray] = []
        self._p: list[np.ndarray] = []
        self._v: list[np.ndarray] = []

    def __getattr__(self, name: str) -> Any:  # connect, state, hold, stop, close, env, ...
        return getattr(self.robot, name)

    def send(self, setpoints: Setpoints) -> None:
        """Execute what was commanded ``latency_s`` before each of these setpoints' times."""
        if self.latency_s == 0.0:
            self.robot.send(setpoints)
            return
        self._t.append(np.asarray(setpoints.t, dtype=float))
        self._p.append(np.asarray(setpoints.position, dtype=float))
        self._v.append(np.asarray(setpoints.velocity, dtype=float))
        t_all, p_all, v_all = (np.concatenate(x) for x in (self._t, self._p, self._v))
        due = setpoints.t - self.latency_s
        index = np.searchsorted(t_all, due + 1e-9, side="right") - 1
        early = index < 0
        index = np.maximum(index, 0)
        velocity = v_all[index].copy()
        velocity[early] = 0.0
        self.robot.send(Setpoints(setpoints.t, p_all[index], velocity))
