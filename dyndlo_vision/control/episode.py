"""One closed-loop episode in simulation: the 25 Hz loop on the task's TCP, on true, noisy or tracked P_DLO,
run to the task's outcome and scored exactly as ``env.step`` scores it.

:func:`run_loop_episode` is what the demo, the loop benchmarks and the loop tests run. It draws nothing: a
``watch`` callback sees every moment the demo films (each control cycle, and the instants after the last
re-plan up to the outcome) with the truth, the cycle's record and a camera that renders the present.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.control.loop import ControlLoop, CycleRecord
from dyndlo_vision.control.sim_env import as_sim_env
from dyndlo_vision.control.sim_robot import DelayedRobot, SimRobot
from dyndlo_vision.control.state_sources import FrozenState, NoisyState, TrueState
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S

#: Where the loop's P_DLO comes from: the simulator, the simulator through the fitted noise model, the
#: task's camera through the tracker and filter, or the simulator's P_DLO frozen at reset (the ablation).
OBSERVATIONS = ("true", "noisy", "tracked", "frozen")
#: The cable parameters an episode's record lists (those cable randomisation draws).
CABLE_FIELDS = ("length_m", "mass_kg", "young_pa", "damping_s")
#: How long a single-step loop episode may run at most (s of simulated time); its plan ends well before.
SINGLE_STEP_MAX_S = 10.0


def outcome_text(env: Any, success: bool, final_distance_m: float) -> str:
    """The outcome in words, as the video's last frame shows it (tip control: hit or miss, and how far)."""
    task = as_sim_env(env).task
    if hasattr(task, "success_radius_m"):
        return f"{'HIT' if success else 'miss'}, tip {100 * final_distance_m:.1f} cm from target centre"
    return f"{type(task).__name__}: {'SUCCESS' if success else 'failure'}"


@dataclass(frozen=True)
class EpisodeMoment:
    """What a ``watch`` callback sees at one instant of a loop episode.

    Attributes:
        t: Simulated time, s.
        p_dlo_true: (3,) the simulator's P_DLO at ``t``.
        goal: (3,) the episode's target.
        cycle: The control cycle's record (None after the last re-plan and at the outcome).
        frame: The frame the tracker used in this cycle (None without the tracker or a new frame).
        status: What happens at an instant without a cycle (``"following the last plan"``, the outcome).
        camera: A camera on the scene that renders the present (None unless a camera was asked for).
        second_view: With two tracking cameras, the second one's frame in this cycle and the cable its
            tracker found there (None otherwise, and with a camera delay).
    """

    t: float
    p_dlo_true: NDArray[np.float64]
    goal: NDArray[np.float64]
    cycle: CycleRecord | None = None
    frame: Any = None
    status: str | None = None
    camera: Any = None
    second_view: SecondView | None = None


@dataclass
class SecondView:
    """The second tracking camera's frame of a cycle, for drawing.

    Attributes:
        rgb: The frame.
        polyline_uv: (N, 2) the cable its tracker found in it (NaN where not seen).
        calibration: The camera's calibration (to draw world points into the frame).
    """

    rgb: NDArray[np.uint8]
    polyline_uv: NDArray[np.float64]
    calibration: Any


def _second_view(source: Any) -> SecondView | None:
    """A two-camera source's second frame and 2D cable (None for any other source, or before a frame)."""
    frames = getattr(source, "last_frames", [])
    result = getattr(source, "last_result", None)
    if len(frames) < 2 or frames[1] is None or result is None or len(result.views) < 2:
        return None
    cl = result.views[1].centerline
    polyline = (np.full((len(result.measurement.visible), 2), np.nan) if cl is None
                else np.where(cl.visible[:, None], cl.nodes_uv, np.nan))
    return SecondView(frames[1].rgb, polyline, source.pipeline.views[1].camera)


def p_dlo_trace(cycles: list[CycleRecord], truth_t: list[float], truth: list[NDArray[np.float64]],
                goal: NDArray[np.float64], task: Any, replan_end_t: float, success: bool,
                min_distance_m: float) -> dict[str, Any]:
    """The P_DLO plot's data (``commands.demo._write_plot``): the loop's estimate at each cycle, the truth at
    ``truth_t``, the goal, and the outcome."""
    return {
        "t": [c.t for c in cycles],
        "estimate": [c.p_dlo_estimate.tolist() for c in cycles],
        "measured": [c.measured for c in cycles],
        "truth_t": truth_t,
        "truth": [p.tolist() for p in truth],
        "goal": goal.tolist(),
        "success_radius_m": getattr(task, "success_radius_m", None),
        "replan_end_t": replan_end_t,
        "success": bool(success),
        "min_distance_m": min_distance_m,
    }


def run_loop_episode(
    env: Any,
    act: Callable[[NDArray[np.float32]], NDArray[np.float32]],
    seed: int,
    observation: str = "true",
    camera_name: str = "tracking",
    perception: Any = None,
    watch: Callable[[EpisodeMoment], None] | None = None,
    open_camera: bool = False,
    actuation_latency_s: float = 0.0,
    noise_model: Any = None,
) -> dict[str, Any]:
    """One closed-loop episode from ``env.reset(seed=seed)``; returns its record.

    The loop re-plans every 40 ms (multi-step) or plans once (single-step). A multi-step episode that runs
    its full length then follows its last plan for the task's settle time, one period at a time, as the
    environment does; the outcome is the environment's own (:meth:`DynDLOEnv.outcome`).

    Args:
        env: A DynDLO environment (``gym.make`` or :func:`dyndlo_vision.tasks.make_env`).
        act: The policy, ``observation -> action``.
        seed: The episode's reset seed (also the noise stream's for ``"noisy"``).
        observation: One of :data:`OBSERVATIONS`.
        camera_name: The scene camera the tracker (and ``watch``'s camera) looks through.
        perception: Tracked observation: how the loop sees the cable (a
            :class:`~dyndlo_vision.control.sim_perception.LoopPerception`: segmenter, views, the camera's
            latency, the filter; None: the scene's defaults).
        watch: Called at every control cycle and at every instant after the last re-plan up to the outcome.
        open_camera: Give ``watch`` a camera on the scene that renders the present (the tracker's own
            camera when tracking without delay).
        actuation_latency_s: The simulated arm executes every setpoint this long after its time
            (:class:`~dyndlo_vision.control.sim_robot.DelayedRobot`); 0: at once.
        noise_model: Noisy observation: the ``ObservationNoiseModel`` or its JSON file (default: the packaged
            one).

    Returns:
        The record: ``seed``, ``success``, ``final_distance_m`` (the truth at the outcome),
        ``min_distance_m``, ``estimate_rmse_m``, controller-time percentiles, ``deadline_misses``,
        ``cycles``, ``stop_reason``, ``avoid``, a ``trace`` (estimates and truth in time) and the raw
        per-cycle times under ``_cycle_ms`` and ``_stage_ms``.

    Raises:
        ValueError: For an unknown ``observation``.
    """
    if observation not in OBSERVATIONS:
        raise ValueError(f"observation={observation!r}; expected one of {list(OBSERVATIONS)}")
    if noise_model is not None and observation != "noisy":
        raise ValueError(f"noise_model is for the noisy observation, not {observation!r}")
    if perception is not None and observation != "tracked":
        raise ValueError(f"perception is for the tracked observation, not {observation!r}")
    latency_s = 0.0 if perception is None else perception.latency_s
    base = as_sim_env(env)
    env.reset(seed=seed)
    goal = np.asarray(base.goal, dtype=float)
    camera = None
    if observation == "tracked":
        from dyndlo_vision.control.sim_perception import tracked_state

        source, camera = tracked_state(env, camera_name, perception)
    elif observation == "noisy":
        source = NoisyState(env, noise_model, seed=seed)
    elif observation == "frozen":
        source = FrozenState(env)
    else:
        source = TrueState(env)
    if open_camera and camera is None:
        from dyndlo_vision.cameras.simulated import MujocoCamera

        camera = MujocoCamera(base.model, base.data, camera_name)
    robot: Any = SimRobot(env)
    if actuation_latency_s:
        robot = DelayedRobot(robot, actuation_latency_s)
    robot.connect()
    loop = ControlLoop(
        source,
        robot,
        act,
        base.replanner,
        goal,
        period_s=CONTROL_PERIOD_S,
        setpoint_period_s=base.scene.timestep,
        truth=base.p_dlo,
    )
    shown = camera if open_camera else None
    truth_t: list[float] = []
    truth: list[NDArray[np.float64]] = []

    def on_cycle(record: CycleRecord, frame: Any) -> None:
        truth_t.append(float(record.t))
        truth.append(np.asarray(record.p_dlo_true, dtype=float))
        if watch is not None:
            # With a delay the cycle's frame is old; the watcher's camera shows the present.
            fresh = None if latency_s else frame
            second = None if latency_s else _second_view(source)
            watch(EpisodeMoment(truth_t[-1], truth[-1], goal, cycle=record, frame=fresh, camera=shown,
                                second_view=second))

    def snapshot(status: str) -> None:
        # The truth (and a moment to watch) where no cycle records one: after the last plan, and at the end.
        truth_t.append(float(base.scene.time))
        truth.append(np.asarray(base.p_dlo(), dtype=float))
        if watch is not None:
            watch(EpisodeMoment(truth_t[-1], truth[-1], goal, status=status, camera=shown))

    try:
        if base.multi_step:
            report = loop.run(base.task.episode_s, done=base.is_done_early, on_cycle=on_cycle)
            replan_end_t = float(base.scene.time)
            if report.stop_reason == "duration":
                # As in the environment: after the last re-plan the TCP follows that plan for the settle time
                # (it ends at rest). Sent one period at a time (the same setpoints as in one piece) so that
                # the moments go on to the outcome.
                dt = base.scene.timestep
                remaining = int(round(base.task.settle_s / dt))
                per_period = int(round(CONTROL_PERIOD_S / dt))
                while remaining > 0:
                    snapshot("following the last plan")
                    steps = min(per_period, remaining)
                    loop.finish_plan(steps * dt)
                    remaining -= steps
        else:
            report = loop.run(
                SINGLE_STEP_MAX_S,
                done=lambda: base.scene.time >= base.trajectory.t_end + base.task.settle_s - 1e-9,
                on_cycle=on_cycle,
                replan_every_cycle=False,
            )
            replan_end_t = float(base.scene.time)
        _, success, info = base.outcome()
        outcome = outcome_text(base, success, float(np.linalg.norm(base.p_dlo() - goal)))
        snapshot(outcome)
    finally:
        if camera is not None:
            camera.close()
        close_source = getattr(source, "close", None)  # a two-camera source's second camera
        if close_source is not None:
            close_source()
    return _episode_record(base, seed, report, truth_t, truth, goal, replan_end_t, success, info, outcome)


def _episode_record(base: Any, seed: int, report: Any, truth_t: list[float], truth: list[NDArray[np.float64]],
                    goal: NDArray[np.float64], replan_end_t: float, success: bool, info: dict[str, Any],
                    outcome: str) -> dict[str, Any]:
    """:func:`run_loop_episode`'s record of the loop's ``report`` and the truth ``truth`` at ``truth_t``."""
    errors = report.estimate_errors()
    controller = report.controller_ms()
    # Tip control reports the closest approach on the swept path; other tasks the monitor's 2 ms samples.
    min_distance = float(info.get("min_distance_m", base.monitor.min_goal_distance_m))
    trace = p_dlo_trace(report.cycles, truth_t, truth, goal, base.task, replan_end_t, success, min_distance)
    trace["outcome"] = outcome
    cable = base.scene.config.cable
    return {
        "seed": seed,
        "cable": {name: float(getattr(cable, name)) for name in CABLE_FIELDS},
        "success": bool(success),
        # The last point of the trace (and the last moment watched) is this state.
        "final_distance_m": float(np.linalg.norm(truth[-1] - goal)),
        "final_p_dlo_m": truth[-1].tolist(),
        "end_time_s": truth_t[-1],
        "min_distance_m": min_distance,
        "estimate_rmse_m": float(np.sqrt(np.mean(errors**2))) if errors.size else None,
        "cycle_ms_p50": float(np.percentile(controller, 50)),
        "cycle_ms_p95": float(np.percentile(controller, 95)),
        "stage_ms_p50": report.stage_percentiles(50),
        "stage_ms_p95": report.stage_percentiles(95),
        "deadline_misses": int(sum(c.deadline_missed for c in report.cycles)),
        "cycles": len(report.cycles),
        "lost_cycles": int(sum(c.lost for c in report.cycles)),
        "stop_reason": report.stop_reason,
        "avoid": info["avoid"],
        "diverged": bool(info.get("diverged", False)),
        "trace": trace,
        "_cycle_ms": controller.tolist(),
        "_stage_ms": {
            k: [c.stage_ms.get(k, 0.0) for c in report.cycles]
            for k in sorted({k for c in report.cycles for k in c.stage_ms})
        },
    }
