"""Where the control loop gets P_DLO from: the simulator's truth, a noise model, or a camera and tracker.

Each source answers ``read(t_now, tcp_state) -> PDloReading``: the estimate of P_DLO for the time the
controller uses it, whether it rests on a fresh measurement, and how long each perception stage took.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.cameras.protocol import Camera
from dyndlo_vision.control.clocks import ClockSync
from dyndlo_vision.control.sim_env import SimEnv, as_sim_env
from dyndlo_vision.robots.protocol import TcpState
from dyndlo_vision.tracking.pipeline import Status

log = logging.getLogger(__name__)

#: TCP states a :class:`TrackedState` keeps to find the gripper at a delayed frame's capture time (at 25 Hz,
#: 2.5 s: longer than any sensible camera latency).
TCP_HISTORY_LENGTH = 64


@dataclass
class PDloReading:
    """One answer of a state source.

    Attributes:
        position: (3,) estimated P_DLO at ``t`` (NaN if there is no estimate at all).
        t: Time the estimate holds for.
        measured: A new measurement of P_DLO entered this reading (else it is a prediction).
        lost: The source has no usable estimate (never seen, or coasted too long).
        stage_ms: Wall time per perception stage, e.g. {"camera": 12.1, "track": 3.9, "filter": 0.2}.
        pixel: (2,) pixel of the tracked point in the latest frame, when a camera was used.
        polyline_uv: (N, 2) tracked centreline in the latest frame, when a camera was used.
        continued: The measurement was not seen directly: the tip was placed past where the tracked cable
            disappears, or an inner point was interpolated across a gap in the tracked cable (the pipeline's
            ``continued`` status, :class:`~dyndlo_vision.tracking.pipeline.Status`).
        observed_tcp: The gripper state the policy is to see in place of the robot's own, when the source
            models what the robot reports (:class:`NoisyState` with TCP noise); None: the robot's.
    """

    position: NDArray[np.float64]
    t: float
    measured: bool
    lost: bool = False
    stage_ms: dict[str, float] = field(default_factory=dict)
    pixel: NDArray[np.float64] | None = None
    polyline_uv: NDArray[np.float64] | None = None
    frame: Any = None
    continued: bool = False
    observed_tcp: TcpState | None = None


class TrueState:
    """The simulator's own P_DLO (what training sees without noise)."""

    def __init__(self, env: Any) -> None:
        self.env: SimEnv = as_sim_env(env)

    def reset(self) -> None:
        """Nothing to forget."""

    def read(self, t_now: float, tcp: TcpState) -> PDloReading:
        """P_DLO now."""
        return PDloReading(self.env.p_dlo(), t_now, measured=True)


class FrozenState:
    """P_DLO as it was at the episode's start, whatever the cable does: the ablation of the feedback.

    A policy that does as well on this as on :class:`TrueState` does not use the cable's state it is given
    (the feedback table's "frozen" row, docs/results.md). The value is taken when the source is built (after
    ``env.reset``) and again at :meth:`reset`.
    """

    def __init__(self, env: Any) -> None:
        self.env: SimEnv = as_sim_env(env)
        self.position = np.array(self.env.p_dlo(), dtype=float)

    def reset(self) -> None:
        """Take P_DLO now as the frozen value."""
        self.position = np.array(self.env.p_dlo(), dtype=float)

    def read(self, t_now: float, tcp: TcpState) -> PDloReading:
        """The frozen P_DLO, reported as a measurement (the policy cannot tell it apart)."""
        return PDloReading(self.position.copy(), t_now, measured=True)


class NoisyState:
    """The simulator's P_DLO corrupted by a fitted observation-noise model, as in noisy-observation training.

    The same :class:`~dyndlo_vision.tasks.noise.NoiseProcess` as noisy-observation training (latency, bias,
    speed-dependent noise, dropouts that coast), one draw per control cycle. A model with TCP noise also
    gives the gripper state the policy sees (``PDloReading.observed_tcp``), as the training wrapper does.

    Args:
        env: The DynDLO environment (after ``reset``).
        model: An ``ObservationNoiseModel`` or the path of its JSON file (default: the packaged tracker fit).
        seed: Seed of the noise stream.
    """

    def __init__(self, env: Any, model: Any = None, seed: int | None = None) -> None:
        from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
        from dyndlo_vision.tasks.noise import NoiseProcess, packaged_noise_model_path

        self.env: SimEnv = as_sim_env(env)
        model = model if model is not None else packaged_noise_model_path()
        self.noise = NoiseProcess(model, CONTROL_PERIOD_S, multi_step=bool(self.env.multi_step))
        self.noise.reset(seed)
        self.seed = seed

    def reset(self) -> None:
        """Restart the noise stream from the seed."""
        self.noise.reset(self.seed)

    def read(self, t_now: float, tcp: TcpState) -> PDloReading:
        """The corrupted P_DLO for now, and the corrupted TCP state where the model has TCP noise."""
        p, measured = self.noise.corrupt(self.env.p_dlo())
        observed_tcp = None
        if self.noise.model.perturbs_tcp:
            position, velocity = self.noise.corrupt_tcp(tcp.position, tcp.velocity)
            observed_tcp = TcpState(position, velocity, tcp.t)
        return PDloReading(p, t_now, measured=measured, observed_tcp=observed_tcp)


class TrackedState:
    """P_DLO from camera frames: the perception pipeline run on each frame, predicted to the controller's
    time.

    Each :meth:`read` grabs a frame from every camera, runs :class:`~dyndlo_vision.tracking.pipeline.
    CablePipeline` on them at their capture time with the held end where the robot says the gripper was then
    (interpolated in the TCP states the source was read with, for a delayed camera), and predicts the
    filtered point to ``t_now``.

    Args:
        cameras: The frame source, or two whose frames are taken at the same time (the simulated cameras of
            one scene, or two hardware-synchronised cameras): the pipeline triangulates the cable.
        pipeline: The perception pipeline, one view per camera.
        max_missing_frames: Consecutive frames the cameras may fail to deliver before the source reports lost.
        clock_sync: Maps the camera's capture times onto the robot's clock (the TCP states' ``t``), so the
            filter updates and predicts on one clock. ``"auto"`` (default): a :class:`~dyndlo_vision.control.
            clocks.ClockSync` on ``time.monotonic()`` when the camera's ``clock`` is ``"monotonic"`` (a live
            camera beside a robot driver), else none (a simulated camera stamps with the simulator's time,
            which is the simulated robot's clock). ``None``: capture times are used as they are.
        max_sync_s: Two cameras: the largest difference between the frames' capture times for them to be
            matched; a pair further apart is not measured (the filter predicts): the cable moves centimetres
            in 10 ms.

    Raises:
        ValueError: ``clock_sync`` neither ``"auto"``, None nor a ``ClockSync``; cameras and views that do not
            match.
    """

    def __init__(
        self,
        cameras: Camera | Sequence[Camera],
        pipeline: Any,
        max_missing_frames: int = 3,
        clock_sync: ClockSync | str | None = "auto",
        max_sync_s: float = 0.002,
    ) -> None:
        cams = list(cameras) if isinstance(cameras, list | tuple) else [cameras]
        if pipeline is not None and len(cams) != len(pipeline.views):
            raise ValueError(f"{len(cams)} cameras for a pipeline of {len(pipeline.views)} views")
        if not max_sync_s >= 0:
            raise ValueError(f"max_sync_s must be >= 0, got {max_sync_s!r}")
        if clock_sync == "auto":
            clock_sync = ClockSync() if getattr(cams[0], "clock", None) == "monotonic" else None
        if clock_sync is not None and not isinstance(clock_sync, ClockSync):
            raise ValueError(f"clock_sync must be 'auto', None or a ClockSync, got {clock_sync!r}")
        self.clock_sync = clock_sync
        self.cameras = cams
        self.pipeline = pipeline
        self.max_missing_frames = max_missing_frames
        self.max_sync_s = float(max_sync_s)
        self.missing_frames = 0
        #: Frame pairs left unmatched because their capture times were too far apart (diagnostics).
        self.unsynchronised_pairs = 0
        #: The latest frames (one per camera) and the pipeline's latest frame result (for drawing).
        self.last_frames: list[Any] = [None] * len(cams)
        self.last_result: Any = None
        self._tcp_history: deque[tuple[float, NDArray[np.float64]]] = deque(maxlen=TCP_HISTORY_LENGTH)

    @property
    def camera(self) -> Camera:
        """The first camera (the one drawn)."""
        return self.cameras[0]

    @camera.setter
    def camera(self, camera: Camera) -> None:
        self.cameras[0] = camera

    @property
    def last_frame(self) -> Any:
        """The first camera's latest frame."""
        return self.last_frames[0]

    def reset(self) -> None:
        """Forget the cable and the filter state."""
        self.pipeline.reset()
        self.missing_frames = 0
        self._tcp_history.clear()
        if self.clock_sync is not None:
            self.clock_sync.reset()

    def close(self) -> None:
        """Close every camera but the first (the caller's)."""
        for camera in self.cameras[1:]:
            close = getattr(camera, "close", None)
            if close is not None:
                close()

    def _tcp_position_at(self, t: float) -> NDArray[np.float64]:
        """The held end at time ``t``, interpolated in the recorded TCP states (else the latest one)."""
        times = np.array([h[0] for h in self._tcp_history])
        if times.size < 2 or not times[0] <= t <= times[-1]:
            return self._tcp_history[-1][1]
        k = int(np.searchsorted(times, t))
        if times[k] == t:
            return self._tcp_history[k][1]
        w = (t - times[k - 1]) / (times[k] - times[k - 1])
        return (1.0 - w) * self._tcp_history[k - 1][1] + w * self._tcp_history[k][1]

    def read(self, t_now: float, tcp: TcpState) -> PDloReading:
        """Grab the frames, run the pipeline at their capture time, and predict to ``t_now``."""
        stage: dict[str, float] = {}
        if self._tcp_history and tcp.t <= self._tcp_history[-1][0]:
            self._tcp_history.clear()  # time went back: a new episode
        self._tcp_history.append((float(tcp.t), np.array(tcp.position, dtype=float)[0]))
        if self.clock_sync is not None:
            self.clock_sync.observe(float(tcp.t))
        t0 = time.perf_counter()
        frames = [camera.read() for camera in self.cameras]
        stage["camera"] = 1e3 * (time.perf_counter() - t0)
        self.last_frames = frames
        pixel = polyline = None
        measured = continued = False
        stage["track"] = stage["filter"] = 0.0
        if any(f is None for f in frames):
            self.missing_frames += 1
            log.warning("camera delivered no frame (%d in a row): predicting P_DLO", self.missing_frames)
        else:
            self.missing_frames = 0
            # The capture time on the robot's clock: the clock of the TCP history, the filter and ``t_now``.
            t_capture = frames[0].t_capture
            if self.clock_sync is not None:
                t_capture = self.clock_sync.to_robot(t_capture)
            held = self._tcp_position_at(t_capture)
            gap = max(abs(float(f.t_capture) - float(frames[0].t_capture)) for f in frames)
            if gap > self.max_sync_s:
                self.unsynchronised_pairs += 1
                log.warning(
                    "the cameras' frames are %.1f ms apart (at most %.1f ms): not matched",
                    1e3 * gap,
                    1e3 * self.max_sync_s,
                )
                self.last_result = result = self.pipeline.skip(
                    t_capture, "the cameras' frames are not in sync"
                )
            else:
                self.last_result = result = self.pipeline.step(
                    [f.rgb for f in frames], t_capture, held_world=held, depth=frames[0].depth
                )
            stage.update(result.stage_ms)
            measured = result.status.seen
            continued = result.status is Status.CONTINUED
            pixel = result.point_uv
            meas = result.measurement
            polyline = np.where(meas.visible[:, None], meas.nodes_uv, np.nan)
        t3 = time.perf_counter()
        est = self.pipeline.estimate(t_now)
        stage["filter"] += 1e3 * (time.perf_counter() - t3)
        lost = bool(est.lost or self.missing_frames > self.max_missing_frames)
        return PDloReading(
            est.position, t_now, measured, lost, stage, pixel, polyline, frames[0], continued=continued
        )
