"""One Gymnasium environment for every DynDLO task: a :class:`Task` supplies the scene and the reward.

An episode is a B-spline TCP trajectory (``dyndlo_vision.trajectory``) followed in MuJoCo:

* single-step (``multi_step=False``): one action plans the whole trajectory; the environment runs it, lets
  the cable move on for ``Task.settle_s``, and returns the episode's reward (``terminated=True``);
* multi-step (``multi_step=True``): every ``control_period_s`` (0.04 s, 25 Hz) the agent re-plans from the
  current reference position *and velocity* of the TCP, so the commanded motion stays C1 across re-plans.

Observations (table II): gripper positions (3 n_g), gripper velocities (3 n_g), P_DLO (3), P* (3).
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import mujoco
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim.scene import Scene, SceneConfig
from dyndlo_vision.tasks.rewards import AvoidLimits, RewardCoefficients, avoid_flags
from dyndlo_vision.trajectory import ActionSpec, BSplineTrajectory, Replanner

if TYPE_CHECKING:
    from dyndlo_vision.robots.feasibility import PlanFeasibility

CONTROL_PERIOD_S = 0.04  # section IV-B: re-plan every 0.04 s
MONITOR_PERIOD_S = 0.002  # how often constraints and the goal are checked while simulating
#: A plan an arm refuses (``DynDLOEnv.set_robot``) costs lambda_1 times (1 + its excess over the joint limits,
#: the larger of peak speed and peak acceleration as a fraction of the limit, minus 1), the excess capped here
#: (and at the cap for a plan without IK solution): lambda_1 for a plan just over, 4 lambda_1 at most.
JOINT_EXCESS_CAP = 3.0


@dataclass
class EpisodeMonitor:
    """What happened during an episode, accumulated at ``MONITOR_PERIOD_S``."""

    avoid: dict[str, bool] = field(
        default_factory=lambda: {"outreach": False, "velocity": False, "collision": False, "shoulder": False}
    )
    max_tcp_speed_m_s: float = 0.0
    max_mean_height_m: float = -np.inf
    min_goal_distance_m: float = np.inf
    last_p_dlo: NDArray[np.float64] | None = None
    samples: int = 0
    #: The simulation blew up (MuJoCo's bad-acceleration reset, a non-finite or runaway state). The episode
    #: ends there; it counts as an avoid condition and never as a success, so a plan that breaks the
    #: simulator is not rewarded for what the broken state shows.
    diverged: bool = False

    @property
    def any_avoid(self) -> bool:
        """I_avoid over the episode so far (a divergence counts)."""
        return self.diverged or any(self.avoid.values())


class Task(ABC):
    """What differs between DynDLO tasks: scene, goal, action ranges, reward.

    Subclasses are small; the environment does the simulation, trajectory and bookkeeping.
    """

    #: "implicit" (evaluate once at the end) or "explicit" (accumulate per step).
    kind: str = "implicit"
    #: Time the cable moves on after a single-step trajectory ends (and after the last re-plan).
    settle_s: float = 0.6
    #: Episode length in multi-step mode.
    episode_s: float = 2.0
    #: Whether cable-floor contact of P_DLO counts as a collision.
    check_collision: bool = True
    #: Whether the goal distance is the distance of P_DLO's path between monitor samples to P* (tip control).
    swept_goal_check: bool = False

    def __init__(self, planar: bool = True, multi_step: bool = False) -> None:
        self.planar = planar
        self.multi_step = multi_step
        self.limits = AvoidLimits()

    @abstractmethod
    def scene_config(self) -> SceneConfig:
        """Return the scene of this task."""

    @abstractmethod
    def action_spec(self) -> ActionSpec:
        """Return the action ranges of this task."""

    @abstractmethod
    def coefficients(self) -> RewardCoefficients:
        """Return the table V column of this task (and mode)."""

    @abstractmethod
    def p_dlo_node(self, scene: Scene) -> int:
        """Index of the cable node whose position is P_DLO."""

    @abstractmethod
    def sample_goal(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Return P* (target, obstacle or hook position) for a new episode."""

    def begin_episode(self) -> None:  # noqa: B027  (optional hook)
        """Clear per-episode state (called by the environment's reset)."""

    def on_samples(  # noqa: B027  (optional hook)
        self, times: NDArray[np.float64], tcp_positions: NDArray[np.float64],
        tcp_velocities: NDArray[np.float64], p_dlo: NDArray[np.float64],
        min_goal_distances: NDArray[np.float64], monitor: EpisodeMonitor,
    ) -> None:
        """Called after the monitor took K samples (one every ``MONITOR_PERIOD_S``), with their states.

        Args:
            times: (K,) simulated times of the samples.
            tcp_positions: (K, n_g, 3) gripper positions.
            tcp_velocities: (K, n_g, 3) gripper velocities.
            p_dlo: (K, 3) positions of the cable's section of interest.
            min_goal_distances: (K,) the episode's smallest goal distance up to and including each sample.
            monitor: The episode monitor, already updated with all K samples.
        """

    def goal_distances(
        self, tcp_positions: NDArray[np.float64], p_dlo: NDArray[np.float64], goal: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Distances used for the goal condition at K samples, (K, n_g, 3) and (K, 3) -> (K,) (min kept)."""
        return np.linalg.norm(p_dlo - goal, axis=-1)

    def final_point(self, goal: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The point appended to every plan (task IV), else None."""
        return None

    @abstractmethod
    def evaluate(
        self, scene: Scene, goal: NDArray[np.float64], monitor: EpisodeMonitor, final: bool
    ) -> tuple[dict[str, float], bool, dict[str, Any]]:
        """Return (reward terms, success, extra info) for the step that just ended.

        ``final`` is True at the end of the episode. Implicit tasks return zero terms until then.
        """

    def is_done_early(self, scene: Scene, goal: NDArray[np.float64], monitor: EpisodeMonitor) -> bool:
        """Whether a multi-step episode may end before ``episode_s`` (e.g. the target was hit)."""
        return False


@dataclass(frozen=True)
class CablePush:
    """A disturbance in every episode: an impulse on one cable node at one instant (``demo --push``).

    Attributes:
        time_s: When, in episode time; rounded up to the next monitor instant (2 ms).
        impulse_n_s: The impulse (N s, world frame). The nominal cable of task I weighs 10 g, so 0.01 N s
            is the momentum of the whole cable moving at 1 m/s.
        node: The cable node pushed; None: the middle node.
    """

    time_s: float
    impulse_n_s: tuple[float, float, float]
    node: int | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.time_s) and self.time_s >= 0.0):
            raise ValueError(f"push time must be a finite time >= 0 s, got {self.time_s!r}")
        impulse = np.asarray(self.impulse_n_s, dtype=float)
        if impulse.shape != (3,) or not np.all(np.isfinite(impulse)):
            raise ValueError(f"push impulse must be 3 finite numbers (N s), got {self.impulse_n_s!r}")
        object.__setattr__(self, "impulse_n_s", tuple(float(x) for x in impulse))


@dataclass(frozen=True)
class EnvSnapshot:
    """An episode's state, from :meth:`DynDLOEnv.snapshot`: MuJoCo's integration state
    (``mjSTATE_INTEGRATION``: time, positions, velocities, controls, mocap bodies), the count of blow-up
    warnings, and copies of the Python side (plan, monitor, the task's attributes, decision count, goal)."""

    physics: NDArray[np.float64]
    bad_acceleration_warnings: int
    python: dict[str, Any]


class DynDLOEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """A DynDLO task as a Gymnasium environment.

    Args:
        task: The task definition.
        render_mode: None or "rgb_array".
        render_camera: Name of the MuJoCo camera used by ``render``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(self, task: Task, render_mode: str | None = None, render_camera: str = "front") -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r}; expected None or 'rgb_array'")
        self.task = task
        self.multi_step = task.multi_step
        self.render_mode = render_mode
        self.render_camera = render_camera
        self._renderer: Any = None
        self._build_scene()
        if render_camera not in [self.scene.model.camera(i).name for i in range(self.scene.model.ncam)]:
            raise ValueError(f"render_camera={render_camera!r} is not a camera of the scene")
        #: Called with the environment every 40 ms of simulated time while it simulates (None: never).
        self.frame_hook: Callable[[DynDLOEnv], None] | None = None
        #: The open-loop stretches of an episode run in MuJoCo's C rollout (no Python per step) and the
        #: monitor and task hooks see the recorded states afterwards; False steps in Python (the reference,
        #: for tests and benchmarks).
        self.batch_monitor = True
        #: Judges every plan on a real arm's joint limits (``set_robot``); None: no arm.
        self.arm_check: PlanFeasibility | None = None
        #: A push on the cable in every episode (a disturbance); None: none.
        self.cable_push: CablePush | None = None
        self._pushed = False

    def set_robot(self, robot: str | None) -> None:
        """Judge every plan as a real arm's driver would (``"gofa"``, ``"ur5e"``; None: no arm).

        A plan the arm cannot follow (no IK with the tool down, or a joint position, velocity or acceleration
        limit broken, the plan joined to the arm's motion so far and ended by the driver's braking tail; see
        :mod:`dyndlo_vision.robots.feasibility`) is refused, as the driver refuses it: nothing of it runs,
        the episode ends there with the avoid condition ``joints``, scored on the state reached (a
        single-step episode: the cable never moved, so no success), and with an avoid term that grows with
        how far the plan breaks the limits (:data:`JOINT_EXCESS_CAP`; not in the paper, whose avoid term is
        flat: with it, SAC learned plans the GoFa can follow more slowly).
        ``info["joint_feasible"]`` says whether every plan passed, ``info["joint_usage"]`` how close the last
        judged one came to the limits, and ``info["joint_limit_reason"]`` why a plan was refused.

        Raises:
            ValueError: An unknown arm, or a task with two grippers (the arms drive one TCP).
        """
        if robot is None:
            self.arm_check = None
            return
        from dyndlo_vision.robots.feasibility import PlanFeasibility

        if self.scene.num_grippers != 1:
            raise ValueError(f"robot={robot!r}: the arm drives one TCP; {type(self.task).__name__} has "
                             f"{self.scene.num_grippers} grippers")
        self.arm_check = PlanFeasibility(robot)

    def _build_scene(self) -> None:
        """Compile the task's scene and all that depends on it (at construction, and for a new cable)."""
        task = self.task
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.scene = Scene(task.scene_config())
        self.spec_actions = task.action_spec()
        self.coeffs = task.coefficients()
        n_g = self.scene.num_grippers
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(self.spec_actions.size,), dtype=np.float32)
        obs_dim = 6 * n_g + 6
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)
        self._dt = self.scene.timestep
        self._steps_per_monitor = max(1, int(round(MONITOR_PERIOD_S / self._dt)))
        self._steps_per_control = int(round(CONTROL_PERIOD_S / self._dt))
        self._goal = np.zeros(3)
        self._replanner = Replanner(self.spec_actions, self.scene.gripper_home)
        self._monitor = EpisodeMonitor()
        self._decisions = 0

    # ------------------------------------------------------------------ gym API
    @property
    def monitor(self) -> EpisodeMonitor:
        """What the episode has recorded so far: avoid conditions, closest approach, TCP speed."""
        return self._monitor

    @property
    def model(self) -> Any:
        """The ``mujoco.MjModel``."""
        return self.scene.model

    @property
    def data(self) -> Any:
        """The ``mujoco.MjData``."""
        return self.scene.data

    def cable_nodes(self) -> NDArray[np.float64]:
        """World positions of the cable nodes, held end first, (N, 3)."""
        return self.scene.cable_nodes()

    @property
    def goal(self) -> NDArray[np.float64]:
        """P* of the current episode."""
        return self._goal.copy()

    @property
    def trajectory(self) -> BSplineTrajectory | None:
        """The TCP trajectory being followed (of the first gripper), None before the first action."""
        return self._replanner.trajectory

    @property
    def replanner(self) -> Replanner:
        """The planner that turns actions into gripper trajectories (shared with the control loop)."""
        return self._replanner

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Start an episode; ``options={"goal": (x, y, z)}`` fixes P*, ``{"cable": CableParams(...)}`` swaps
        the cable (a new MuJoCo model, compiled and settled, when it differs from the current one; hooks and
        settings such as :attr:`frame_hook` stay)."""
        super().reset(seed=seed)
        if options and "cable" in options:
            self._swap_cable(options["cable"])
        self.scene.reset()
        self.task.begin_episode()
        if options and "goal" in options:
            goal = np.asarray(options["goal"], dtype=float)
            if goal.shape != (3,) or not np.all(np.isfinite(goal)):
                raise ValueError(f"options['goal'] must be 3 finite numbers, got {options['goal']!r}")
            self._goal = goal
        else:
            self._goal = self.task.sample_goal(self.np_random)
        if self.scene.config.target_radius_m > 0:
            self.scene.set_target(self._goal)
        self._replanner.reset(self.task.final_point(self._goal))
        self._monitor = EpisodeMonitor()
        self._decisions = 0
        self._pushed = False
        self._arm_verdict: Any = None
        if self.arm_check is not None:
            self._monitor.avoid["joints"] = False
            self.arm_check.start(self.scene.time, self.scene.tcp_positions()[0])
        self._sample_monitor()
        return self.observation(), {"goal": self._goal.copy()}

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Plan from the action, simulate, observe and reward."""
        self._plan(action)
        if self.arm_check is not None and not self._check_arm():
            return self._refused()
        return self._advance()

    def coast(self) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """One decision of a multi-step episode without a new plan: the current plan goes on for 40 ms.

        What a policy whose re-plan reproduced the plan exactly would get; a search (``learning.distill``)
        scores a re-plan by coasting on it to the end of the episode. Returns what :meth:`step` returns.

        Raises:
            RuntimeError: A single-step episode, or no plan yet.
        """
        if not self.multi_step or self._replanner.trajectory is None:
            raise RuntimeError("coast() continues the plan of a multi-step episode: call step() first")
        return self._advance()

    def snapshot(self) -> EnvSnapshot:
        """The episode's whole state now (physics, plan, monitor, task): :meth:`restore` goes back to it.

        Raises:
            RuntimeError: A real arm's plan checks are on (:meth:`set_robot`): their record of the arm's
                motion so far is not part of a snapshot.
        """
        if self.arm_check is not None:
            raise RuntimeError("snapshot() does not cover the arm's plan checks: call set_robot(None) first")
        m, d = self.scene.model, self.scene.data
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        physics = np.empty(mujoco.mj_stateSize(m, spec))
        mujoco.mj_getState(m, d, physics, spec)
        python = {"replanner": self._replanner, "monitor": self._monitor, "task": vars(self.task),
                  "decisions": self._decisions, "pushed": self._pushed, "goal": self._goal}
        return EnvSnapshot(physics, int(d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number),
                           copy.deepcopy(python))

    def restore(self, snapshot: EnvSnapshot) -> None:
        """Go back to a state of this environment taken by :meth:`snapshot` (any number of times).

        Raises:
            ValueError: A snapshot of another model (another cable or task).
        """
        m, d = self.scene.model, self.scene.data
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        if snapshot.physics.shape != (mujoco.mj_stateSize(m, spec),):
            raise ValueError(f"a snapshot of {snapshot.physics.size} physics values cannot restore this "
                             f"model's {mujoco.mj_stateSize(m, spec)}: taken with another cable or task")
        mujoco.mj_setState(m, d, snapshot.physics, spec)
        d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number = snapshot.bad_acceleration_warnings
        mujoco.mj_forward(m, d)
        python = copy.deepcopy(snapshot.python)
        vars(self._replanner).update(vars(python["replanner"]))  # the loop may hold this planner: same object
        self._monitor = python["monitor"]
        self.task.__dict__.update(python["task"])
        self._decisions, self._pushed, self._goal = python["decisions"], python["pushed"], python["goal"]

    def _advance(self) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Simulate the plan in force for one decision (multi-step) or to its end (single-step); reward."""
        if self.multi_step:
            self._simulate(self._steps_per_control)
            self._decisions += 1
            elapsed = self.scene.time
            early = self.task.is_done_early(self.scene, self._goal, self._monitor)
            final = early or elapsed >= self.task.episode_s - 1e-9
            if final and not early:
                self._simulate(int(round(self.task.settle_s / self._dt)))
        else:
            assert self._replanner.trajectory is not None
            remaining = self._replanner.trajectory.t_end - self.scene.time + self.task.settle_s
            self._simulate(int(np.ceil(remaining / self._dt)))
            final = True
        diverged = not self.scene.is_finite()
        self._monitor.diverged = self._monitor.diverged or diverged
        terms, success, extra = self.task.evaluate(self.scene, self._goal, self._monitor, final or diverged)
        reward = float(sum(terms.values()))
        info: dict[str, Any] = {**terms, **extra, "is_success": bool(success),
                                "avoid": dict(self._monitor.avoid), "sim_time_s": self.scene.time}
        if diverged:
            info["diverged"] = True
        self._arm_info(info)
        return self.observation(), reward, bool(final or diverged), False, info

    def render(self) -> NDArray[np.uint8] | None:
        """Return an RGB image from ``render_camera`` (rgb_array mode), else None."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            from dyndlo_vision.sim.rendering import make_renderer

            self._renderer = make_renderer(self.scene.model, *self.scene.config.image_size[::-1])
        # Bring what is drawn up to the state: after a C rollout the positions MuJoCo last computed are one
        # step old and place the target marker where the rollout's scratch state had it (the body's default).
        mujoco.mj_forward(self.scene.model, self.scene.data)
        self._renderer.update_scene(self.scene.data, camera=self.render_camera)
        return np.asarray(self._renderer.render(), dtype=np.uint8)

    def close(self) -> None:
        """Release the renderer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict[str, Any]:
        # MuJoCo objects pickle, but renderers and the settled state are cheaper to rebuild.
        return {"task": self.task, "render_mode": self.render_mode, "render_camera": self.render_camera,
                "robot": None if self.arm_check is None else self.arm_check.arm.name}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["task"], state["render_mode"], state["render_camera"])  # type: ignore[misc]
        self.set_robot(state.get("robot"))

    # ------------------------------------------------------------------ internals
    def _swap_cable(self, cable: Any) -> None:
        from dyndlo_vision.sim.cable import CableParams

        if not isinstance(cable, CableParams):
            raise ValueError(f"options['cable'] must be a CableParams, got {type(cable).__name__}")
        if cable == getattr(self.task, "cable", None):
            return
        if not hasattr(self.task, "cable"):
            raise ValueError(f"{type(self.task).__name__} has no cable option to swap")
        self.task.cable = cable  # type: ignore[attr-defined]
        obs_space, act_space = self.observation_space, self.action_space
        self._build_scene()
        # Wrappers keep the spaces they saw; the spaces depend on the grippers and the actions, not the cable.
        if (self.observation_space, self.action_space) != (obs_space, act_space):
            raise RuntimeError("a new cable changed the observation or action space")

    def _plan(self, action: NDArray[np.float32]) -> None:
        a = np.asarray(action)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got shape {a.shape}")
        if not self.multi_step and self._replanner.trajectory is not None:
            raise RuntimeError("single-step episode already ended: call reset()")
        self._replanner.replan(a.astype(np.float64), self.scene.time)

    def _check_arm(self) -> bool:
        """Judge the plan just made, from now to its end, on the arm's cycle (see :meth:`set_robot`)."""
        assert self.arm_check is not None and self._replanner.trajectory is not None
        period = self.arm_check.period_s
        t0 = self.scene.time
        t_end = max(self._replanner.trajectory.t_end, t0 + period)
        times = t0 + period * np.arange(int(np.ceil((t_end - t0) / period - 1e-9)) + 1)
        positions, _ = self._replanner.references(times)
        self._arm_verdict = self.arm_check.check(times, positions[:, 0])
        return bool(self._arm_verdict.ok)

    def _refused(self) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """End the episode at a plan the arm refuses: nothing more is simulated; scored on the state now.

        The avoid term grows with how far the plan breaks the limits (see :data:`JOINT_EXCESS_CAP`): a flat
        penalty gives a learner no direction towards plans the arm can follow, other than the few it finds by
        chance.
        """
        self._monitor.avoid["joints"] = True
        terms, success, extra = self.task.evaluate(self.scene, self._goal, self._monitor, True)
        verdict = self._arm_verdict
        usage = verdict.usage if verdict is not None else {}
        excess = max(usage.get("velocity_fraction", np.inf), usage.get("acceleration_fraction", np.inf)) - 1.0
        terms["r_avoid"] = self.coeffs.avoid * (1.0 + min(max(excess, 0.0), JOINT_EXCESS_CAP))
        info: dict[str, Any] = {**terms, **extra, "is_success": bool(success),
                                "avoid": dict(self._monitor.avoid), "sim_time_s": self.scene.time}
        self._arm_info(info)
        return self.observation(), float(sum(terms.values())), True, False, info

    def _arm_info(self, info: dict[str, Any]) -> None:
        if self.arm_check is None or self._arm_verdict is None:
            return
        info["joint_feasible"] = self._arm_verdict.ok
        info["joint_usage"] = dict(self._arm_verdict.usage)
        if not self._arm_verdict.ok:
            info["joint_limit_reason"] = self._arm_verdict.reason
            info["joint_limit_kind"] = self._arm_verdict.kind

    def _simulate(self, nsteps: int) -> None:
        """Follow the trajectory for ``nsteps`` physics steps, checking constraints as we go.

        With a ``frame_hook`` set, the steps are cut at every multiple of the control period (40 ms of
        simulated time) and the hook is called there, e.g. to render a 25 Hz video of a single-step episode.
        """
        if self.frame_hook is None:
            self._simulate_span(nsteps)
            return
        k = self._steps_per_control
        while nsteps > 0:
            step_index = int(round(self.scene.time / self._dt))
            chunk = min(nsteps, k - step_index % k)
            self._simulate_span(chunk)
            nsteps -= chunk
            if int(round(self.scene.time / self._dt)) % k == 0:
                self.frame_hook(self)
            if not self.scene.is_finite():
                return

    def _simulate_span(
        self, nsteps: int, refs: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
    ) -> None:
        if nsteps <= 0:
            return
        if refs is None:
            refs = self._replanner.references(self.scene.time + self._dt * np.arange(nsteps))
        ref_p, ref_v = refs
        scene = self.scene
        push = self.cable_push
        if push is not None and not self._pushed:
            # Split the span at the first monitor instant at or after the push (so the monitor keeps its 2 ms
            # grid), push there, and go on.
            k = int(np.ceil((push.time_s - scene.time) / self._dt - 1e-9))
            k = max(0, -(-k // self._steps_per_monitor) * self._steps_per_monitor)
            if k < nsteps:
                self._simulate_span(k, (ref_p[:k], ref_v[:k]))
                if scene.is_finite():
                    node = scene.config.cable.num_nodes // 2 if push.node is None else push.node
                    scene.push_cable(node, push.impulse_n_s)
                self._pushed = True
                self._simulate_span(nsteps - k, (ref_p[k:], ref_v[k:]))
                return
        if self.batch_monitor:
            # The plan is open loop over these steps: run them in MuJoCo's C rollout and check the constraints
            # on the recorded states afterwards, at the same monitor instants as the loop below.
            t0 = scene.time
            qpos, qvel, finite = scene.rollout(scene.tcp_controls(ref_p, ref_v))
            samples = np.arange(self._steps_per_monitor - 1, finite, self._steps_per_monitor)
            if samples.size:
                self._sample_monitor_batch(t0 + self._dt * (samples + 1), qpos[samples], qvel[samples])
            return
        for k in range(nsteps):
            scene.set_tcp_reference(ref_p[k], ref_v[k])
            scene.step()
            if (k + 1) % self._steps_per_monitor == 0:
                self._sample_monitor()
                if not scene.is_finite():
                    return

    def _sample_monitor_batch(
        self, times: NDArray[np.float64], qpos: NDArray[np.float64], qvel: NDArray[np.float64]
    ) -> None:
        """:meth:`_sample_monitor` for K recorded states at once."""
        scene = self.scene
        p, v = scene.tcp_from_state(qpos, qvel)
        p_dlo = scene.nodes_from_qpos(qpos)[:, self.task.p_dlo_node(scene)]
        self._record_samples(times, p, v, p_dlo)

    def _sample_monitor(self) -> None:
        scene = self.scene
        p_dlo = scene.cable_nodes()[self.task.p_dlo_node(scene)]
        p, v = scene.tcp_positions()[None], scene.tcp_velocities()[None]
        self._record_samples(np.array([scene.time]), p, v, p_dlo[None])

    def _record_samples(self, times: NDArray[np.float64], p: NDArray[np.float64], v: NDArray[np.float64],
                        p_dlo: NDArray[np.float64]) -> None:
        """Update the monitor with K samples (K,), (K, n_g, 3), (K, n_g, 3), (K, 3), then call the task."""
        record_samples(self.task, self._monitor, self._goal, times, p, v, p_dlo)

    def observation(self) -> NDArray[np.float32]:
        """The table-II observation of the simulator's true state now (what ``reset`` and ``step`` return)."""
        scene = self.scene
        return observation_vector(scene.tcp_positions(), scene.tcp_velocities(), self.p_dlo(), self._goal)

    # ------------------------------------------------------------------ for the control loop (SimRobot)
    def p_dlo(self) -> NDArray[np.float64]:
        """True position of the cable's section of interest (P_DLO) now."""
        return self.scene.cable_nodes()[self.task.p_dlo_node(self.scene)]

    def follow(self, times: NDArray[np.float64], positions: NDArray[np.float64],
               velocities: NDArray[np.float64]) -> None:
        """Simulate while the grippers follow externally planned setpoints, monitoring as :meth:`step` does.

        The setpoints (K,), (K, n_g, 3), (K, n_g, 3) cover ``[times[0], times[-1] + period)``; each physics
        step takes the latest setpoint at or before its start time (sample and hold, exact when the setpoint
        period is the physics timestep).
        """
        times = np.asarray(times, dtype=float)
        period = float(times[1] - times[0]) if times.size > 1 else self._dt
        end = times[-1] + period
        nsteps = int(round((end - self.scene.time) / self._dt))
        if nsteps <= 0:
            return
        t = self.scene.time + self._dt * np.arange(nsteps)
        index = np.clip(np.searchsorted(times, t + 1e-9, side="right") - 1, 0, times.size - 1)
        self._simulate_span(nsteps, (np.asarray(positions)[index], np.asarray(velocities)[index]))
        # Bring derived quantities (what a camera renders) up to the state; the state itself is unchanged.
        mujoco.mj_forward(self.scene.model, self.scene.data)

    def outcome(self) -> tuple[float, bool, dict[str, Any]]:
        """Reward, success and info of the episode as it stands, evaluated as its final step.

        A blow-up since the reset (also one while the control loop drove the scene through :meth:`follow`)
        scores as in :meth:`step`: an avoid condition, no success, ``info["diverged"]``.
        """
        self._monitor.diverged = self._monitor.diverged or not self.scene.is_finite()
        terms, success, extra = self.task.evaluate(self.scene, self._goal, self._monitor, True)
        info = {**terms, **extra, "is_success": bool(success), "avoid": dict(self._monitor.avoid),
                "sim_time_s": self.scene.time}
        if self._monitor.diverged:
            info["diverged"] = True
        self._arm_info(info)
        return float(sum(terms.values())), bool(success), info

    def is_done_early(self) -> bool:
        """Whether the task says the episode may end now (e.g. the target was hit)."""
        return bool(self.task.is_done_early(self.scene, self._goal, self._monitor))


def record_samples(
    task: Task, monitor: EpisodeMonitor, goal: NDArray[np.float64], times: NDArray[np.float64],
    p: NDArray[np.float64], v: NDArray[np.float64], p_dlo: NDArray[np.float64],
) -> None:
    """Update ``monitor`` with K samples (K,), (K, n_g, 3), (K, n_g, 3), (K, 3), then call
    ``task.on_samples``."""
    mon = monitor
    flags = avoid_flags(p, v, p_dlo, task.limits, task.check_collision)
    for key, value in flags.items():
        mon.avoid[key] = mon.avoid[key] or value
    mon.max_tcp_speed_m_s = max(mon.max_tcp_speed_m_s, float(np.linalg.norm(v, axis=2).max()))
    mon.max_mean_height_m = max(mon.max_mean_height_m, float(p[:, :, 2].mean(axis=1).max()))
    dist = task.goal_distances(p, p_dlo, goal)
    if task.swept_goal_check:
        # The distance to the goal of the segment P_DLO moved along since the previous sample, so a fast
        # tip cannot pass through the target between two samples unnoticed.
        previous = p_dlo[:1] if mon.last_p_dlo is None else mon.last_p_dlo[None]
        starts = np.vstack([previous, p_dlo[:-1]])
        dist = np.minimum(dist, _segment_point_distances(starts, p_dlo, goal))
    running = np.minimum.accumulate(np.minimum(dist, mon.min_goal_distance_m))
    mon.min_goal_distance_m = float(running[-1])
    mon.last_p_dlo = p_dlo[-1].copy()
    mon.samples += len(times)
    task.on_samples(times, p, v, p_dlo, running, mon)


def observation_vector(
    tcp_positions: NDArray[np.float64], tcp_velocities: NDArray[np.float64], p_dlo: NDArray[np.float64],
    goal: NDArray[np.float64],
) -> NDArray[np.float32]:
    """Table II: gripper positions (3 n_g), gripper velocities (3 n_g), P_DLO (3), P* (3), as float32.

    Shared by the environment (true state) and the control loop (estimated P_DLO).
    """
    return np.concatenate([np.ravel(tcp_positions), np.ravel(tcp_velocities), np.ravel(p_dlo),
                           np.ravel(goal)]).astype(np.float32)


def _segment_point_distances(
    a: NDArray[np.float64], b: NDArray[np.float64], c: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Distance of point ``c`` to each segment ``a[i]``-``b[i]``, (K, 3) -> (K,)."""
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    s = np.where(denom > 0, np.einsum("ij,ij->i", c - a, ab) / np.where(denom > 0, denom, 1.0), 0.0)
    s = np.clip(s, 0.0, 1.0)
    return np.linalg.norm(a + s[:, None] * ab - c, axis=1)

