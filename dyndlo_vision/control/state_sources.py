"""Where the control loop gets P_DLO from: the simulator's truth, a noise model, or a camera and tracker.

Each source answers ``read(t_now, tcp_state) -> PDloReading``: the estimate of P_DLO for the time the
controller uses it, whether it rests on a fresh measurement, and how long each perception stage took.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.cameras.protocol import Camera
from dyndlo_vision.control.clocks import ClockSync
from dyndlo_vision.control.sim_env import SimEnv, as_sim_env
from dyndlo_vision.robots.protocol import TcpState
from dyndlo_vision.tracking.tracker import tip_from_polyline

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
            disappears (the polyline was shorter than the known cable:
            :func:`~dyndlo_vision.tracking.tracker.tip_from_polyline`), or an inner point was interpolated
            across a gap in the tracked cable (:func:`bridged_point`).
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


def bridged_point(measurement: Any, index: int) -> NDArray[np.float64] | None:
    """An inner node the tracker left unseen on a gap it bridged, interpolated between the nearest seen
    nodes on either side (3D, along the node index: the nodes are evenly spaced along the centreline).

    The tracker marks nodes on a bridged gap (an occluder, a segmentation hole) invisible. For the tip that
    is right: beyond the last seen node nothing says where the cable goes. An inner point (vaulting's middle)
    with the cable seen on both sides lies between them. Returns None for the end nodes, a node seen
    already, or one without seen nodes on both sides.
    """
    n = len(measurement.visible)
    k = index % n
    seen = np.flatnonzero(measurement.visible & np.all(np.isfinite(measurement.nodes_xyz), axis=1))
    if measurement.visible[k] or seen.size < 2 or not seen[0] < k < seen[-1]:
        return None
    after = int(np.searchsorted(seen, k))
    a, b = int(seen[after - 1]), int(seen[after])
    w = (k - a) / (b - a)
    return np.asarray((1.0 - w) * measurement.nodes_xyz[a] + w * measurement.nodes_xyz[b], dtype=float)


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
    (issue 16's row (4)). The value is taken when the source is built (after ``env.reset``) and again at
    :meth:`reset`.
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
    """P_DLO from camera frames: track the cable, filter the chosen point, predict to the controller's time.

    Args:
        camera: The frame source.
        tracker: The cable tracker (segmentation, ordered centreline, 3D lifting).
        point_filter: Kalman filter of the tracked point.
        point_index: Centreline node of P_DLO (-1: the free tip).
        project: Optional ``world (3,) -> pixel (2,)`` map used to give the tracker the held end's pixel (the
            gripper position projected into the image), which fixes the cable's orientation in every frame.
            The gripper position used is the one at the frame's capture time, interpolated in the TCP states
            the source was read with, when the capture time lies among them (a delayed camera); otherwise
            the current one.
        max_missing_frames: Consecutive frames the camera may fail to deliver before the source reports lost.
        cable_length_m: The cable's length, if known (the loop knows its cable). The tip (``point_index`` -1)
            is then :func:`~dyndlo_vision.tracking.tracker.tip_from_polyline`: a polyline shorter than the
            cable ends where the cable disappears, so the missing length is continued straight; under
            :data:`~dyndlo_vision.tracking.tracker.MIN_SEEN_LENGTH_FRACTION` of the cable the tip is not seen
            and the filter predicts. None: the polyline's end is the tip.
        clock_sync: Maps the camera's capture times onto the robot's clock (the TCP states' ``t``), so the
            filter updates and predicts on one clock. ``"auto"`` (default): a :class:`~dyndlo_vision.control.
            clocks.ClockSync` on ``time.monotonic()`` when the camera's ``clock`` is ``"monotonic"`` (a live
            camera beside a robot driver), else none (a simulated camera stamps with the simulator's time,
            which is the simulated robot's clock). ``None``: capture times are used as they are.

    Raises:
        ValueError: ``clock_sync`` neither ``"auto"``, None nor a ``ClockSync``.
    """

    def __init__(
        self,
        camera: Camera,
        tracker: Any,
        point_filter: Any,
        point_index: int = -1,
        project: Any = None,
        max_missing_frames: int = 3,
        clock_sync: ClockSync | str | None = "auto",
        cable_length_m: float | None = None,
    ) -> None:
        if cable_length_m is not None and not cable_length_m > 0:
            raise ValueError(f"cable_length_m must be positive or None, got {cable_length_m!r}")
        if clock_sync == "auto":
            clock_sync = ClockSync() if getattr(camera, "clock", None) == "monotonic" else None
        if clock_sync is not None and not isinstance(clock_sync, ClockSync):
            raise ValueError(f"clock_sync must be 'auto', None or a ClockSync, got {clock_sync!r}")
        self.clock_sync = clock_sync
        self.camera = camera
        self.tracker = tracker
        self.filter = point_filter
        self.point_index = point_index
        self.project = project
        self.max_missing_frames = max_missing_frames
        self.cable_length_m = cable_length_m
        #: Frames whose tip was continued past the polyline's end, and frames whose polyline was too short for
        #: a tip (diagnostics; with ``cable_length_m``).
        self.extended_tips = 0
        self.unseen_tips = 0
        self.missing_frames = 0
        self.last_frame: Any = None
        self._tcp_history: deque[tuple[float, NDArray[np.float64]]] = deque(maxlen=TCP_HISTORY_LENGTH)

    def reset(self) -> None:
        """Forget the cable and the filter state."""
        self.tracker.reset()
        self.filter.reset()
        self.missing_frames = 0
        self._tcp_history.clear()
        if self.clock_sync is not None:
            self.clock_sync.reset()

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

    def _grab(self) -> Any:
        """The next frame (None if the camera delivered none)."""
        return self.camera.read()

    def _measure(self, frame: Any, t_capture: float, held: NDArray[np.float64]) -> Any:
        """The tracker's measurement of ``frame``, the held end at ``held`` (world) anchoring it."""
        anchor = None if self.project is None else self.project(held)
        return self.tracker.process(frame.rgb, t_capture, depth=frame.depth, anchor_uv=anchor)

    def read(self, t_now: float, tcp: TcpState) -> PDloReading:
        """Grab a frame, track, update the filter at the capture time, and predict to ``t_now``."""
        stage: dict[str, float] = {}
        if self._tcp_history and tcp.t <= self._tcp_history[-1][0]:
            self._tcp_history.clear()  # time went back: a new episode
        self._tcp_history.append((float(tcp.t), np.array(tcp.position, dtype=float)[0]))
        if self.clock_sync is not None:
            self.clock_sync.observe(float(tcp.t))
        t0 = time.perf_counter()
        frame = self._grab()
        stage["camera"] = 1e3 * (time.perf_counter() - t0)
        pixel = polyline = None
        measured = continued = False
        if frame is None:
            self.missing_frames += 1
            log.warning("camera delivered no frame (%d in a row): predicting P_DLO", self.missing_frames)
            stage["track"] = stage["filter"] = 0.0
        else:
            self.missing_frames = 0
            self.last_frame = frame
            t1 = time.perf_counter()
            # The capture time on the robot's clock: the clock of the TCP history, the filter and ``t_now``.
            t_capture = frame.t_capture
            if self.clock_sync is not None:
                t_capture = self.clock_sync.to_robot(t_capture)
            held = self._tcp_position_at(t_capture)
            meas = self._measure(frame, t_capture, held)
            point = meas.point(self.point_index)
            if point is not None:
                pixel = meas.nodes_uv[self.point_index]
            elif self.point_index != -1:
                point = bridged_point(meas, self.point_index)
                if point is not None:
                    pixel, continued = meas.nodes_uv[self.point_index], True
            if self.point_index == -1 and self.cable_length_m is not None and meas.visible.any():
                tip = tip_from_polyline(meas, held, self.cable_length_m)
                if tip is None:
                    point = pixel = None  # too little of the cable to place its tip: not seen
                    self.unseen_tips += 1
                elif point is None or not np.array_equal(tip, point):
                    point = tip  # continued past where the cable disappears
                    continued = True
                    # The tracker's camera, not self.project: that one also moves the gripper mask.
                    camera = getattr(self.tracker, "camera", None)
                    pixel = None if camera is None else camera.project(tip[None])[0]
                    self.extended_tips += 1
            polyline = np.where(meas.visible[:, None], meas.nodes_uv, np.nan)
            t2 = time.perf_counter()
            stage["track"] = 1e3 * (t2 - t1)
            measured = self.filter.update(point, t_capture)
            stage["filter"] = 1e3 * (time.perf_counter() - t2)
        t3 = time.perf_counter()
        est = self.filter.estimate(t_now)
        stage["filter"] += 1e3 * (time.perf_counter() - t3)
        lost = bool(est.lost or self.missing_frames > self.max_missing_frames)
        return PDloReading(est.position, t_now, measured, lost, stage, pixel, polyline, frame,
                           continued=measured and continued)


class StereoTrackedState(TrackedState):
    """:class:`TrackedState` on two synchronised cameras: the cable's 3D centreline by triangulation.

    One camera lifts the cable onto a known plane; a cable that leaves it (vaulting's middle swings sideways)
    is misplaced by as much as it leaves it. Here both views are tracked, each anchored at the gripper's
    projection into it, and :func:`~dyndlo_vision.tracking.stereo.stereo_measurement` matches the two
    centrelines along epipolar lines and triangulates them. The nodes are spaced by arc length along the 3D
    centreline from the gripper, with the known cable length when given, so an inner node is the same
    material point in every frame. Drawing (``pixel``, ``polyline_uv``) is in the first camera.

    Args:
        camera, second_camera: Frame sources whose frames are taken at the same time (the simulated cameras of
            one scene, or two hardware-synchronised cameras).
        tracker, second_tracker: A 2D tracker per camera (their ``camera`` is the calibration used).
        project, second_project: ``world (3,) -> pixel (2,)`` per camera (the gripper's anchor pixel; see
            :class:`TrackedState`).
        stereo_params: Tuning of the matching.
        max_sync_s: Largest difference between the two frames' capture times for them to be matched; a pair
            further apart is not measured (the filter predicts): the cable moves centimetres in 10 ms.
        Others: as :class:`TrackedState`.
    """

    def __init__(self, camera: Camera, second_camera: Camera, tracker: Any, second_tracker: Any,
                 point_filter: Any, point_index: int = -1, project: Any = None, second_project: Any = None,
                 max_missing_frames: int = 3, clock_sync: ClockSync | str | None = "auto",
                 cable_length_m: float | None = None, stereo_params: Any = None,
                 max_sync_s: float = 0.002) -> None:
        if not max_sync_s >= 0:
            raise ValueError(f"max_sync_s must be >= 0, got {max_sync_s!r}")
        super().__init__(camera, tracker, point_filter, point_index=point_index, project=project,
                         max_missing_frames=max_missing_frames, clock_sync=clock_sync,
                         cable_length_m=cable_length_m)
        for name, trk in (("tracker", tracker), ("second_tracker", second_tracker)):
            if getattr(trk, "camera", None) is None:
                raise ValueError(f"{name} has no camera calibration: two views need both")
        self.second_camera = second_camera
        self.second_tracker = second_tracker
        self.second_project = second_project
        self.stereo_params = stereo_params
        self.max_sync_s = float(max_sync_s)
        #: Frame pairs left unmatched because their capture times were too far apart (diagnostics).
        self.unsynchronised_pairs = 0
        #: The second camera's latest frame and its tracker's 2D measurement (for drawing).
        self.second_frame: Any = None
        self.second_measurement: Any = None

    def reset(self) -> None:
        """Forget the cable in both views and the filter state."""
        super().reset()
        self.second_tracker.reset()
        self.second_frame = self.second_measurement = None

    def close(self) -> None:
        """Close the second camera (the first is the caller's, as with :class:`TrackedState`)."""
        close = getattr(self.second_camera, "close", None)
        if close is not None:
            close()

    def _grab(self) -> Any:
        """Both cameras' frames; None unless both delivered one."""
        frame = self.camera.read()
        self.second_frame = self.second_camera.read()
        return None if frame is None or self.second_frame is None else frame

    def _measure(self, frame: Any, t_capture: float, held: NDArray[np.float64]) -> Any:
        from dyndlo_vision.tracking.stereo import stereo_measurement

        first = super()._measure(frame, t_capture, held)
        gap = abs(float(self.second_frame.t_capture) - float(frame.t_capture))
        if gap > self.max_sync_s:
            self.unsynchronised_pairs += 1
            log.warning("the two cameras' frames are %.1f ms apart (at most %.1f ms): not matched",
                        1e3 * gap, 1e3 * self.max_sync_s)
            n = len(first.visible)
            return replace(first, nodes_xyz=np.full((n, 3), np.nan), visible=np.zeros(n, dtype=bool))
        anchor = None if self.second_project is None else self.second_project(held)
        second = self.second_tracker.process(self.second_frame.rgb, t_capture, anchor_uv=anchor)
        self.second_measurement = second
        return stereo_measurement(first, self.tracker.camera, second, self.second_tracker.camera, held,
                                  self.cable_length_m, self.stereo_params)
