"""The perception pipeline: frames of one or two views -> the held cable's ordered nodes -> the tracked point
-> a filtered estimate that says whether it was measured, continued, predicted or lost.

One object, :class:`CablePipeline`, built from one typed configuration (:class:`PipelineConfig`), runs every
step for ``dyndlo-vision track``, the simulated control loop and ``run`` (``segment`` uses its segmenter
alone, one photo at a time):

1. segment each view (:mod:`~dyndlo_vision.tracking.segmenters`: the network or a background model, the
   gripper cleared where the robot says it is, regions too thick to be cable removed);
2. the ordered centreline (:func:`~dyndlo_vision.tracking.centerline.extract_centerline`), walked from the
   end nearest where the held end should be;
3. which end is held (:mod:`~dyndlo_vision.tracking.identity`): continuity of the held end's motion, the
   last frame's nodes registered to the new centreline, and the robot's pose where it is known, checked
   again in every frame. A frame whose ends cannot be told apart is not measured;
4. 3D: rays intersected with the motion plane (and the floor), a depth image, or two views triangulated;
5. the tracked point (the tip, or a fraction of the cable from the held end), measured only where the cable
   ends free at it: not at the image border, not inside a region too thick to be cable, and not shorter or
   longer than the cable (its length given, or learned from the frames where both ends are seen). A
   polyline shorter than a given cable length is continued straight to the tip when the robot's pose or the
   gripper's template places the held end and at least 80 % of the cable is seen. Without the robot's pose,
   a tip where the clicked gripper's template matches is not measured;
6. the Kalman filter (:mod:`~dyndlo_vision.tracking.filter`), updated at the frame's capture time.

Each frame's :class:`FrameResult` says what happened and why; :meth:`CablePipeline.estimate` predicts the
filtered point to any time (the controller's ``t_now``).

Statuses (:class:`Status`), true by construction:

* ``measured``: the point is this frame's measurement, accepted by the filter;
* ``continued``: this frame's cable, continued past where it disappears (a hidden tip), or an inner point
  interpolated across a bridged gap, accepted by the filter;
* ``predicted``: no accepted measurement this frame; the filter's prediction;
* ``lost``: no estimate (nothing accepted for longer than the filter's coasting limit).
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.tracking.identity import GripperTemplate, HeldEnd, IdentityParams, Orientation, orient
from dyndlo_vision.tracking.params import TRACK_FILTER, FilterParams
from dyndlo_vision.tracking.segmenters import SegmenterConfig, ViewSegmenter
from dyndlo_vision.tracking.tracker import (
    Measurement,
    Plane,
    lift_with_depth,
    lift_with_plane,
)

__all__ = ["CablePipeline", "FrameResult", "PipelineConfig", "Status", "point_on_nodes"]

#: The image scale assumed without a calibration (pixels per metre): a cable filling a 640 px wide image from
#: about a metre away.
NOMINAL_PX_PER_M = 500.0


class Status(StrEnum):
    """What an estimate rests on (see the module docstring)."""

    MEASURED = "measured"
    CONTINUED = "continued"
    PREDICTED = "predicted"
    LOST = "lost"

    @property
    def seen(self) -> bool:
        """This frame's measurement (or its continuation) entered the estimate."""
        return self in (Status.MEASURED, Status.CONTINUED)


@dataclass(frozen=True)
class PipelineConfig:
    """Everything the pipeline does, checked once (ValueError naming the bad value).

    Attributes:
        segmenter: The segmenter (:class:`~dyndlo_vision.tracking.segmenters.SegmenterConfig`).
        nodes: Centreline nodes N (node 0 at the held end).
        point: The tracked point: the tip (1.0) or this fraction of the cable from the held end, in [0, 1].
        cable_length_m: The cable's length from the held end, if known: a shorter polyline is continued to
            the tip, and an inner point is that share of the length along the cable with two views. None:
            the length is learned from the frames (world units, or pixels without a calibration) and used only
            to refuse polylines that are too short or too long to end at the tip.
        plane: One view: the world plane the cable moves in (its rays are intersected with it).
        floor: With ``plane``: the plane the cable cannot go below.
        filter: The point's Kalman filter (world units; pixels are scaled by :data:`NOMINAL_PX_PER_M`).
        gripper_radius_m: Where the robot reports the held end: clear a sphere of this radius around it in
            every view (None: nothing cleared).
        max_width_share: Remove regions thicker than this share of the image's shorter side (None: no shape
            test).
        max_width_ratio: With ``max_width_share``: also those thicker than this many cable widths (None: off).
        reach_margin_m: Where the robot reports the held end and ``cable_length_m`` is known: segment only
            within the cable's length plus this of it (None: the whole frame).
        follow_px: With ``reach_margin_m`` and a learned segmenter: follow the last mask's box grown by this.
        long_tolerance: A polyline longer than ``1 + long_tolerance`` times the cable does not end at its tip
            (the walk went on into something else): the tip is not measured.
        short_tolerance: A polyline shorter than the cable by more than this share of it does not end at the
            tip, and the tip is not measured, except as ``min_seen_given`` says: where the held end is found
            from the cable alone, a shortfall may as well be at the held end (a cable cut below the gripper)
            as at the tip.
        min_seen_given: With a given length (``cable_length_m``) and the held end placed by the robot's pose
            or the gripper's template, a shorter polyline is continued straight to the tip by the missing
            length when at least this share of the cable is seen, else the tip is not measured: the hidden
            part bends, and in a whip a straight continuation of a quarter of the cable missed the tip by up
            to 98 mm.
        identity: The held end's identification (:class:`~dyndlo_vision.tracking.identity.IdentityParams`).
        learn_length_frames: The learned length is the longest length that at least ``min_length_frames``,
            and ``min_length_share``, of the last this many clean frames (both ends seen free, no gap bridged,
            the held end identified) agree with, within ``max_length_spread`` of it (their median), seen in
            at least ``min_length_poses`` poses of the cable. A faint or hidden tip shortens a
            polyline, often and for long (a cable hanging still with its tip over a patch of its own colour);
            a length learned from such frames would report the cable's middle as its tip, while one learned
            too long only withholds tips. Frames with a gap bridged are kept apart: when enough of them agree
            on a longer length (beyond ``long_tolerance``), the learned one is in doubt and not used. Without
            a length, given or learned, the tip is not measured: the end of a polyline of unknown length may
            be anywhere along the cable.
        min_length_frames: See ``learn_length_frames``.
        min_length_share: See ``learn_length_frames`` (a few frames whose path ran on into the gripper's blob
            or a shadow agree on a length a little too long).
        min_length_poses: See ``learn_length_frames``: frames of a cable at rest are one view of it, repeated
            (its far part faint over one patch of the background in all of them). A frame is a new pose when
            the cable's quarter, middle and three-quarter points moved by more than a tenth of its length
            since the last clean frame counted as one.
        max_length_spread: See ``learn_length_frames``.
    """

    segmenter: SegmenterConfig = field(default_factory=SegmenterConfig)
    nodes: int = 20
    point: float = 1.0
    cable_length_m: float | None = None
    plane: Plane | None = None
    floor: Plane | None = None
    filter: FilterParams = TRACK_FILTER
    gripper_radius_m: float | None = None
    max_width_share: float | None = 0.1
    max_width_ratio: float | None = 3.0
    reach_margin_m: float | None = None
    follow_px: int | None = None
    short_tolerance: float = 0.03
    long_tolerance: float = 0.15
    min_seen_given: float = 0.8
    identity: IdentityParams = field(default_factory=IdentityParams)
    learn_length_frames: int = 1000
    min_length_frames: int = 5
    min_length_share: float = 0.1
    min_length_poses: int = 3
    max_length_spread: float = 0.03

    def __post_init__(self) -> None:
        if not isinstance(self.segmenter, SegmenterConfig):
            raise ValueError(f"segmenter must be a SegmenterConfig, got {self.segmenter!r}")
        if isinstance(self.nodes, bool) or not isinstance(self.nodes, int) or self.nodes < 2:
            raise ValueError(f"nodes must be an int of at least 2, got {self.nodes!r}")
        if not (isinstance(self.point, int | float) and 0.0 <= self.point <= 1.0):
            raise ValueError(
                f"point must be a fraction of the cable in [0, 1] (1: the tip), got {self.point!r}"
            )
        for name in ("cable_length_m", "gripper_radius_m", "reach_margin_m"):
            value = getattr(self, name)
            if value is not None and not (
                isinstance(value, int | float) and math.isfinite(value) and value > 0
            ):
                raise ValueError(f"{name} must be a positive length in metres (or None), got {value!r}")
        if self.max_width_share is not None and not 0 < self.max_width_share <= 1:
            raise ValueError(f"max_width_share must be in (0, 1] (or None), got {self.max_width_share!r}")
        if self.max_width_ratio is not None and not self.max_width_ratio > 1:
            raise ValueError(f"max_width_ratio must be above 1 (or None), got {self.max_width_ratio!r}")
        if self.floor is not None and self.plane is None:
            raise ValueError("a floor needs the motion plane")
        for name in ("short_tolerance", "long_tolerance", "min_seen_given"):
            value = getattr(self, name)
            if not 0 < value < 1:
                raise ValueError(f"{name} must be in (0, 1), got {value!r}")
        if self.min_length_frames < 1 or self.learn_length_frames < self.min_length_frames:
            raise ValueError(
                f"need 1 <= min_length_frames <= learn_length_frames, got {self.min_length_frames}, "
                f"{self.learn_length_frames}"
            )
        if not 0.0 <= self.min_length_share <= 1.0:
            raise ValueError(f"min_length_share must be in [0, 1], got {self.min_length_share}")
        if self.min_length_poses < 1:
            raise ValueError(f"min_length_poses must be at least 1, got {self.min_length_poses}")
        if not isinstance(self.filter, FilterParams):
            raise ValueError(f"filter must be a FilterParams, got {self.filter!r}")

    @property
    def tip(self) -> bool:
        """Whether the tracked point is the tip."""
        return self.point == 1.0


def point_on_nodes(
    nodes: NDArray[np.float64], visible: NDArray[np.bool_], fraction: float
) -> NDArray[np.float64] | None:
    """The point at ``fraction`` of the node chain (linear between the two nearest nodes), or None.

    Nodes are equally spaced along the cable, so node ``i`` of ``N`` is at fraction ``i / (N - 1)``. The point
    is measured only where the nodes it is interpolated from are visible and finite.
    """
    n = nodes.shape[0]
    s = fraction * (n - 1)
    i0 = min(int(math.floor(s)), n - 2)
    w = s - i0
    used = [i0] if w == 0 else ([i0 + 1] if w == 1 else [i0, i0 + 1])
    if not all(visible[i] and np.all(np.isfinite(nodes[i])) for i in used):
        return None
    return (1.0 - w) * nodes[i0] + w * nodes[i0 + 1]


def bridged_point(
    nodes: NDArray[np.float64], visible: NDArray[np.bool_], fraction: float
) -> NDArray[np.float64] | None:
    """An inner point on a bridged gap (nodes unseen there, seen on both sides), interpolated between the
    nearest seen nodes along the node index (the nodes are evenly spaced along the cable); None for a point
    at either end or without seen nodes on both sides."""
    n = nodes.shape[0]
    s = fraction * (n - 1)
    seen = np.flatnonzero(visible & np.all(np.isfinite(nodes), axis=1))
    if seen.size < 2 or not seen[0] < s < seen[-1]:
        return None
    after = int(np.searchsorted(seen, s))
    a, b = int(seen[after - 1]), int(seen[after])
    w = (s - a) / (b - a)
    return np.asarray((1.0 - w) * nodes[a] + w * nodes[b], dtype=np.float64)


@dataclass(frozen=True)
class ViewResult:
    """One view's part of a frame: its oriented centreline (None where none was found or its ends could
    not be told apart), how its held end was identified, and where it was expected."""

    centerline: Any
    orientation: Orientation | None
    held_uv: NDArray[np.float64] | None
    gate_px: float
    reason: str = ""
    #: Where the gripper's template matched in this frame (its centre; None: not followed, or no match).
    gripper_uv: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class FrameResult:
    """What the pipeline made of one frame.

    Attributes:
        t: The frame's capture time.
        status: :class:`Status` of the estimate at ``t``.
        point: This frame's measured (or continued) point, world (m) or ``(u, v, 0)`` pixels without a
            calibration; None when not measured.
        point_uv: Its pixel in the first view.
        estimate: The filter's :class:`~dyndlo_vision.tracking.filter.Estimate` at ``t``.
        measurement: The frame's nodes (world and first-view pixels; triangulated with two views).
        views: Each view's :class:`ViewResult`.
        reason: Why the point was not measured ("" when it was).
        length: The measured cable's length from the held end (world m, or px), NaN when none.
        stage_ms: Wall time of the frame's stages (ms): ``track`` (segmentation to the point) and ``filter``;
            and within ``track``: ``segment``, ``centreline`` (both summed over the views), ``identity`` (the
            rest of the views' work: which end is held) and ``lift`` (3-D, length checks, the point).
    """

    t: float
    status: Status
    point: NDArray[np.float64] | None
    point_uv: NDArray[np.float64] | None
    estimate: Any
    measurement: Measurement
    views: tuple[ViewResult, ...]
    reason: str = ""
    length: float = float("nan")
    stage_ms: dict[str, float] = field(default_factory=dict)


class _View:
    """One camera's state: its segmenter, calibration, held end track and last nodes."""

    #: The cable is still when its quarter, middle and three-quarter points moved less than this share of its
    #: length on the image, in each of the last two frames (a swinging cable moves farther; at the top of a
    #: swing it is still for less).
    STILL_SHARE = 0.02
    #: The cable is slow when those points moved less than this many of its lengths per second since the last
    #: frame. A cable upside down (held end well below its tip) falls, or is whipped: it is slow only at the
    #: top of a throw, so a slow one upside down is not measured (its ends may be swapped).
    SLOW_LENGTHS_PER_S = 1.5
    #: A lost held end is found again at the upper end of a cable that is still (two frames), or slow for this
    #: long: an upside-down cable falls, or is thrown, faster (it drops a third of a metre in a quarter
    #: second).
    REACQUIRE_SLOW_S = 0.25

    def __init__(
        self, camera: Any, segmenter: ViewSegmenter, anchor_uv: Any, config: PipelineConfig, px_per_m: float
    ) -> None:
        self.camera = camera
        self.segmenter = segmenter
        self.anchor = None if anchor_uv is None else np.asarray(anchor_uv, dtype=np.float64).reshape(2)
        self.config = config
        self.held = HeldEnd(config.identity, px_per_m)
        #: The held end's pixel, time and noise waiting for :meth:`settle`.
        self.pending: tuple[NDArray[np.float64], float, float] | None = None
        self.px_per_m = px_per_m
        #: The last :meth:`measure`'s segmentation and centreline times (ms).
        self.ms = {"segment": 0.0, "centreline": 0.0}
        self.reset()

    def reset(self) -> None:
        self.held.reset()
        self.gripper: GripperTemplate | None = None
        self.offsets: deque[NDArray[np.float64]] = deque(maxlen=9)
        self.prev_nodes: NDArray[np.float64] | None = None
        self.prev_t = -math.inf
        self.prev_ends: NDArray[np.float64] | None = None
        self.still_frames = 0
        self.slow_frames = 0
        self.slow_s = 0.0
        self.still_t = -math.inf
        self.first_rule = ""
        reset = getattr(self.segmenter.reach, "reset", None)
        if reset is not None:
            reset()

    def _stillness(self, cl: Any, t: float) -> None:
        """Counts the frames in a row in which the cable stayed where it was: its ends and its middle (the
        points at a quarter, half and three quarters of it, from either end: a flickering tip moves its ends
        and little else)."""
        s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(cl.path_uv, axis=0).T))))
        marks = np.array(
            [np.interp(f * s[-1], s, cl.path_uv[:, k]) for f in (0.25, 0.5, 0.75) for k in (0, 1)]
        )
        marks = marks.reshape(3, 2)
        dt = t - self.still_t
        if self.prev_ends is None or len(self.prev_ends) != 3 or not 0 < dt <= 0.1:
            self.still_frames = self.slow_frames = 0
            self.slow_s = 0.0
        else:
            moved = _marks_moved(marks, self.prev_ends)
            self.still_frames = self.still_frames + 1 if moved <= self.STILL_SHARE * cl.length_px else 0
            slow = moved <= self.SLOW_LENGTHS_PER_S * dt * cl.length_px
            self.slow_frames = self.slow_frames + 1 if slow else 0
            self.slow_s = self.slow_s + dt if slow else 0.0
        self.still_t = t
        self.prev_ends = marks

    def _upper_end(self, cl: Any) -> tuple[int, float] | None:
        """Which end of the path is higher in the world (0: its start, 1: its end) and by how much (m); None
        without a calibration and a plane."""
        if self.camera is None or self.config.plane is None:
            return None
        try:
            ends = lift_with_plane(cl.path_uv[[0, -1]], self.camera, self.config.plane)
        except ValueError:
            return None
        if not np.all(np.isfinite(ends)):
            return None
        return (0 if ends[0, 2] >= ends[1, 2] else 1), float(abs(ends[0, 2] - ends[1, 2]))

    def _at_rest_upper(self, cl: Any, slow: bool = False) -> int | None:
        """At rest (still for two frames, or slow for ``REACQUIRE_SLOW_S``; with ``slow``: slow since the last
        frame), the clearly upper end (0 or 1): a hanging cable's held end."""
        if slow:
            if self.slow_frames < 1:
                return None
        elif self.still_frames < 2 and self.slow_s < self.REACQUIRE_SLOW_S:
            return None
        upper = self._upper_end(cl)
        length_m = cl.length_px / max(self.px_per_m, 1e-9)
        if upper is None or upper[1] < 0.25 * length_m:
            return None
        return upper[0]

    def measure(
        self,
        rgb: NDArray[np.uint8],
        t: float,
        held_world: NDArray[np.float64] | None,
        first_view_held: tuple[Any, NDArray[np.float64]] | None = None,
    ) -> ViewResult:
        """Segment, centreline, and which end is held."""
        from dyndlo_vision.tracking.centerline import extract_centerline

        cfg = self.config
        ident = cfg.identity
        self.pending = None
        known_uv = None
        radius_px = None
        if held_world is not None and self.camera is not None:
            held3 = np.asarray(held_world, dtype=np.float64).reshape(1, 3)
            depth = float(self.camera.world_to_camera(held3)[0, 2])
            if depth <= 0:
                raise ValueError(
                    f"the held end at {np.round(held3[0], 3).tolist()} m is behind the camera; is it "
                    "in the calibration's world frame?"
                )
            known_uv = self.camera.project(held3)[0]
            if cfg.gripper_radius_m is not None:
                radius_px = cfg.gripper_radius_m * float(self.camera.K[0, 0]) / depth
        self.segmenter.hold(held_world, known_uv, radius_px)
        t0 = time.perf_counter()
        mask = self.segmenter(rgb)
        self.ms["segment"] = 1e3 * (time.perf_counter() - t0)
        if known_uv is None and self.gripper is None and self.anchor is not None:
            self.gripper = GripperTemplate(rgb, self.anchor, self._template_size(rgb))
        lost = self.held.lost_at(t)
        gripper_uv = centre = None
        if known_uv is None and self.gripper is not None and self.gripper.usable:
            if not self.offsets:
                centre = self.anchor  # the first frame: the click
            else:
                dt = abs(t - self.gripper.t) if math.isfinite(self.gripper.t) else 0.0
                search = 0.5 * self.gripper.size + ident.max_speed_m_s * max(dt, 0.04) * self.px_per_m
                centre = self.gripper.locate(rgb, t, search)
                if centre is not None:
                    gripper_uv = centre + np.median(np.array(self.offsets), axis=0)
                    # The template's word only where the held end's own track allows it (a gripper that looks
                    # like something else nearby, a blurred one).
                    if not lost and np.hypot(*(gripper_uv - self.held.predict(t))) > self.held.gate(
                        t, 2.0, math.inf, noise_px=0.5 * self.gripper.size
                    ):
                        gripper_uv = centre = None
        if known_uv is not None:
            hint = known_uv
        elif gripper_uv is not None:
            hint = gripper_uv
        elif self.held.known:
            hint = self.held.predict(t) if not lost else self.held.uv
        else:
            hint = self.anchor
        t1 = time.perf_counter()
        cl = extract_centerline(mask, cfg.nodes, anchor_uv=hint)
        self.ms["centreline"] = 1e3 * (time.perf_counter() - t1)
        if not cl.any_visible:
            self.prev_ends = None
            return ViewResult(None, None, hint, float("nan"), "no cable found")
        self._stillness(cl, t)
        width = float(cl.width_px) if np.isfinite(cl.width_px) else 2.0
        recent = self.prev_nodes is not None and t - self.prev_t <= 0.1
        prev = self.prev_nodes if recent else None
        shift = None
        if known_uv is not None:
            gripper = radius_px if radius_px is not None else 0.0
            gate = 1.5 * gripper + max(ident.min_gate_px, 3.0 * width)
            if prev is not None and self.held.known:
                shift = known_uv - self.held.uv
        elif gripper_uv is not None:
            gate = max(ident.min_gate_px, 3.0 * width, 0.6 * self.gripper.size)
            if prev is not None and self.held.known:
                shift = hint - self.held.uv
        elif self.held.known and not lost:
            gate = self.held.gate(t, width, cl.length_px, noise_px=max(2.0, width))
            if prev is not None:
                shift = hint - self.held.uv
        elif self.held.known:
            # Lost: found again only where the cable hangs still, at its upper end.
            upper = self._at_rest_upper(cl)
            if upper is None:
                return ViewResult(
                    None, None, hint, float("nan"), "held end lost: waiting for the cable to hang still"
                )
            return self._oriented(
                cl, upper == 0, Orientation(upper == 0, "gravity"), mask.shape, t, hint, float("nan")
            )
        elif self.anchor is not None:
            # First found from the user's click: the end nearest it, the other end well apart.
            gate = max(ident.min_gate_px * 3, 0.25 * cl.length_px)
            prev = None
        else:
            return self._first_without_hint(cl, mask.shape, first_view_held, t)
        register = max(ident.register_widths * width, ident.min_gate_px, 0.1 * cl.length_px)
        decision = orient(cl.path_uv, hint, gate, prev, register, ident, shift)
        if decision.held_at_start is None:
            return ViewResult(None, decision, hint, gate, decision.reason)
        upper = self._at_rest_upper(cl, slow=True)
        if upper is not None and known_uv is None and (upper == 0) != decision.held_at_start:
            why = "the held end is below the tip while the cable is slow"
            return ViewResult(None, Orientation(None, why), hint, gate, why)
        # The held end's track moves to this frame's cable start at once where that start is pinned down: at
        # the robot's reported gripper, at the gripper's template, or within a few cable widths of the
        # prediction. Within half the gate, only once the frame's length explains it (see settle). A cable cut
        # below the gripper starts lower down; followed, the track would creep along the cable to its tip.
        start = cl.path_uv[0] if decision.held_at_start else cl.path_uv[-1]
        dist = float(np.hypot(*(start - hint)))
        pinned = (
            known_uv is not None
            or gripper_uv is not None
            or decision.reason == "registration"
            or dist <= max(ident.min_gate_px, 3.0 * width)
        )
        anchored: bool | None = True if pinned else (None if dist <= 0.5 * gate else False)
        return replace(
            self._oriented(cl, decision.held_at_start, decision, mask.shape, t, hint, gate, anchored),
            gripper_uv=centre,
        )

    def settle(self, explained: bool) -> None:
        """Moves the held end's track to this frame's cable start, when it waited for the frame's outcome:
        ``explained``, the cable's length from that start agrees with the cable's (or its shortfall is the
        tip's, cut off), so the start is the held end and not a cut below it."""
        if self.pending is not None and explained:
            uv, t, noise = self.pending
            self.held.update(uv, t, noise_px=noise)
        self.pending = None

    def _oriented(
        self,
        cl: Any,
        held_at_start: bool,
        decision: Orientation,
        shape: tuple[int, ...],
        t: float,
        hint: Any,
        gate: float,
        anchored: bool | None = True,
    ) -> ViewResult:
        if not held_at_start:
            cl = cl.reversed(None, shape)
        self._identified(cl, t, anchored)
        return ViewResult(cl, decision, hint, gate)

    def _first_without_hint(
        self, cl: Any, shape: tuple[int, ...], first_view_held: Any, t: float
    ) -> ViewResult:
        """No click, no robot pose, never identified: the held end is the cable end on the first view's held
        end's epipolar line (a second view), else the upper end (a hanging cable's held end)."""
        flip = bool(cl.path_uv[-1, 1] < cl.path_uv[0, 1])
        self.first_rule = "the upper cable end"
        if first_view_held is not None and self.camera is not None:
            from dyndlo_vision.tracking.stereo import essential_matrix

            cam_a, uv_a = first_view_held
            xa = np.append(cam_a.normalized_coords(np.asarray(uv_a, dtype=float).reshape(1, 2))[0], 1.0)
            line = essential_matrix(cam_a, self.camera) @ xa
            ends = cl.path_uv[[0, -1]]
            xb = np.column_stack([self.camera.normalized_coords(ends), np.ones(2)])
            gaps = np.abs(xb @ line) / max(float(np.linalg.norm(line[:2])), 1e-300)
            if abs(gaps[0] - gaps[1]) > 1e-3:  # normalised units: about half a pixel at f = 500
                flip = bool(gaps[1] < gaps[0])
                self.first_rule = "the cable end on the epipolar line of the first view's held end"
        return self._oriented(
            cl, not flip, Orientation(not flip, "first frame, no anchor"), shape, t, None, float("nan")
        )

    @staticmethod
    def _template_size(rgb: NDArray[np.uint8]) -> int:
        """The gripper template's side: 8 % of the image's shorter side, 25-71 px."""
        return int(np.clip(round(0.08 * min(rgb.shape[:2])), 25, 71))

    def _identified(self, cl: Any, t: float, anchored: bool | None = True) -> None:
        """The frame's cable, held end first: its start moves the held end's track (``anchored`` True), or
        waits for :meth:`settle` (None), or not (False)."""
        noise = max(2.0, float(cl.width_px))
        if not cl.start_at_border and anchored is None:
            self.pending = (cl.path_uv[0].copy(), t, noise)
        if not cl.start_at_border and anchored:
            self.held.update(cl.path_uv[0], t, noise_px=noise)
            if (
                self.gripper is not None
                and abs(self.gripper.t - t) < 1e-9
                or (self.gripper is not None and not self.offsets)
            ):
                self.offsets.append(cl.path_uv[0] - self.gripper.uv)
        self.prev_nodes = np.where(cl.visible[:, None], cl.nodes_uv, np.nan)
        self.prev_t = t


#: Outcomes of a frame in which the cable's length from its start is explained: the start is the held end.
#: (Not a cut tip: a cable oriented the wrong way round has its "tip" in the gripper's blob, cut.)
_LENGTH_EXPLAINED = frozenset({"", "the cable's length is not known yet"})


class CablePipeline:
    """One or two views of a held cable, tracked through time (see the module docstring).

    Args:
        config: What the pipeline does.
        cameras: Each view's calibration (:class:`~dyndlo_vision.tracking.camera_model.PinholeCamera`); one
            view may be None (pixel mode: no world positions); two views need both.
        segmenters: Each view's segmenter stack (:func:`~dyndlo_vision.tracking.segmenters.
            build_view_segmenter`).
        anchors: Each view's held end clicked in the first frame with a cable (pixels), or None.
    """

    def __init__(
        self,
        config: PipelineConfig,
        cameras: Sequence[Any],
        segmenters: Sequence[ViewSegmenter],
        anchors: Sequence[Any] | None = None,
    ) -> None:
        from dyndlo_vision.tracking.filter import PointFilter

        if len(cameras) not in (1, 2) or len(segmenters) != len(cameras):
            raise ValueError(
                f"expected one or two views with a segmenter each, got {len(cameras)} cameras and "
                f"{len(segmenters)} segmenters"
            )
        if len(cameras) == 2 and any(c is None for c in cameras):
            raise ValueError("two views need both calibrations")
        if len(cameras) == 1 and cameras[0] is not None and config.plane is None:
            raise ValueError(
                "one calibrated view needs the motion plane (or a depth image per frame: give the "
                "plane anyway, depth replaces it)"
            )
        anchors = list(anchors) if anchors is not None else [None] * len(cameras)
        self.config = config
        self.world = cameras[0] is not None
        self.stereo = len(cameras) == 2
        self.views = [
            _View(cam, seg, anchor, config, self._px_per_m(cam, anchor))
            for cam, seg, anchor in zip(cameras, segmenters, anchors, strict=True)
        ]
        params = config.filter if self.world else config.filter.scaled(NOMINAL_PX_PER_M)
        self.filter = PointFilter(params)
        self._lengths: deque[tuple[float, bool]] = deque(maxlen=config.learn_length_frames)
        self._bridged_lengths: deque[tuple[float, bool]] = deque(maxlen=config.learn_length_frames)
        #: The first view's pose (its quarter points, px) at the last clean frame counted as a new pose.
        self._pose: NDArray[np.float64] | None = None
        #: Frames seen, and why points were not measured (reason -> frames).
        self.n_frames = 0
        self.reasons: Counter[str] = Counter()
        self.n_measured = 0
        self.n_continued = 0

    def _px_per_m(self, camera: Any, anchor: Any) -> float:
        if camera is None or self.config.plane is None:
            return NOMINAL_PX_PER_M if camera is None else float(camera.K[0, 0])
        uv = np.asarray(
            anchor if anchor is not None else [(camera.width - 1) / 2, (camera.height - 1) / 2],
            dtype=np.float64,
        ).reshape(1, 2)
        try:
            p = camera.intersect_plane(uv, self.config.plane.normal, self.config.plane.d)[0]
        except ValueError:
            return float(camera.K[0, 0])
        depth = float(camera.world_to_camera(p[None])[0, 2])
        return float(camera.K[0, 0]) / max(depth, 1e-6)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forgets the cable, the held end and the filter (a new episode or video)."""
        for view in self.views:
            view.reset()
        self.filter.reset()
        self._lengths.clear()
        self._bridged_lengths.clear()
        self._pose = None

    @property
    def learned_length(self) -> float | None:
        """The cable's length learned from the frames (world m, or px), None until enough agreeing ones were
        seen, or while it is in doubt (:attr:`length_doubt`)."""
        length, doubt = self._length_state()
        return None if doubt else length

    @property
    def length_doubt(self) -> bool:
        """Frames show the cable longer than the length learned (beyond ``long_tolerance``): frames bridged
        across a gap agree on a longer length, or a tenth of all frames (at least two) are longer. The
        cable's far part is faint, and what looked like its tip may be its middle."""
        return self._length_state()[1]

    def _length_state(self) -> tuple[float | None, bool]:
        """(the longest length the clean frames agree on, or None; whether it is in doubt), one pass."""
        length = self._longest_agreed(self._lengths)
        if length is None:
            return None, False
        longest = length * (1.0 + self.config.long_tolerance)
        bridged = self._longest_agreed(self._bridged_lengths, poses=0)  # doubt needs less evidence
        every = [v for v, _ in self._lengths] + [v for v, _ in self._bridged_lengths]
        longer = sum(v > longest for v in every)
        return length, (bridged is not None and bridged > longest) or longer >= max(2, 0.1 * len(every))

    def _longest_agreed(self, values: deque[tuple[float, bool]], poses: int | None = None) -> float | None:
        """The median of the longest group of lengths within ``max_length_spread`` of one of them, with at
        least ``min_length_frames`` (and ``min_length_share``) of them, from ``poses`` poses (default
        ``min_length_poses``); None without one."""
        cfg = self.config
        if len(values) < cfg.min_length_frames:
            return None
        pairs = np.asarray(values, dtype=np.float64)
        order = np.argsort(pairs[:, 0])
        lengths, new_pose = pairs[order, 0], np.concatenate(([0], np.cumsum(pairs[order, 1])))
        lo = np.searchsorted(lengths, lengths * (1.0 - cfg.max_length_spread), side="left")
        hi = np.searchsorted(lengths, lengths * (1.0 + cfg.max_length_spread), side="right")
        least = max(cfg.min_length_frames, cfg.min_length_share * len(lengths))
        seen_in = new_pose[hi] - new_pose[lo]
        need = cfg.min_length_poses if poses is None else poses
        ok = np.flatnonzero((hi - lo >= least) & (seen_in >= need) & (lengths > 0))
        if ok.size == 0:
            return None
        k = ok[-1]
        return float(np.median(lengths[lo[k] : hi[k]]))

    @property
    def first_view_rule(self) -> str:
        """How the first view's held end was first chosen without a click or a robot pose ("" otherwise)."""
        return self.views[0].first_rule

    def estimate(self, t: float) -> Any:
        """The filtered point predicted to ``t`` (the filter's
        :class:`~dyndlo_vision.tracking.filter.Estimate`; ``lost`` when it has no estimate)."""
        return self.filter.estimate(t)

    # ------------------------------------------------------------------ one frame
    def step(
        self,
        images: Sequence[NDArray[np.uint8]],
        t_capture: float,
        held_world: NDArray[np.float64] | None = None,
        depth: NDArray[np.floating] | None = None,
    ) -> FrameResult:
        """Tracks one frame (one image per view, taken at ``t_capture``).

        Args:
            images: RGB uint8 frames, one per view.
            t_capture: The frames' capture time (s).
            held_world: The held end (the gripper's TCP) in the world frame, where the robot reports it.
            depth: One view: a depth image aligned with it, which replaces the plane.
        """
        if len(images) != len(self.views):
            raise ValueError(f"expected {len(self.views)} images, got {len(images)}")
        t0 = time.perf_counter()
        t = float(t_capture)
        held = None if held_world is None else np.asarray(held_world, dtype=np.float64).reshape(3)
        results = []
        for k, (view, rgb) in enumerate(zip(self.views, images, strict=True)):
            first = None
            if k == 1 and results[0].centerline is not None:
                first = (self.views[0].camera, results[0].centerline.path_uv[0])
            results.append(view.measure(rgb, t, held, first))
        t_views = time.perf_counter()
        measurement, held_xyz, reason = self._measurement(results, t, held, depth)
        point, point_uv, length, continued = None, None, float("nan"), False
        if not reason:
            point, point_uv, length, continued, reason = self._point(measurement, results, held_xyz)
        if not reason and point_uv is not None and self.config.tip and held is None:
            reason = self._looks_held(images[0], point_uv)
            if reason:
                point, point_uv, continued = None, None, False
        explained = reason in _LENGTH_EXPLAINED
        for view in self.views:
            view.settle(explained)
        detail = {k: sum(v.ms[k] for v in self.views) for k in ("segment", "centreline")}
        detail["identity"] = 1e3 * (t_views - t0) - detail["segment"] - detail["centreline"]
        detail["lift"] = 1e3 * (time.perf_counter() - t_views)
        return self._filtered(
            t, point, point_uv, continued, reason, measurement, tuple(results), length, t0, detail
        )

    def skip(self, t_capture: float, reason: str) -> FrameResult:
        """A frame that cannot be measured (``reason``): the filter predicts."""
        return self._filtered(
            float(t_capture),
            None,
            None,
            False,
            reason,
            self._empty(float(t_capture)),
            (),
            float("nan"),
            time.perf_counter(),
        )

    def _filtered(
        self,
        t: float,
        point: Any,
        point_uv: Any,
        continued: bool,
        reason: str,
        measurement: Measurement,
        results: tuple[ViewResult, ...],
        length: float,
        t0: float,
        detail: dict[str, float] | None = None,
    ) -> FrameResult:
        """Updates the filter with the frame's point (None: not measured) and says what it rests on
        (``detail``: the ``track`` stage's parts, ms)."""
        t1 = time.perf_counter()
        self.n_frames += 1
        accepted = self.filter.update(point, t)
        if point is not None and not accepted:
            reason = "rejected by the filter's gate"
        estimate = self.filter.estimate(t)
        if accepted:
            status = Status.CONTINUED if continued else Status.MEASURED
            self.n_measured += 1
            self.n_continued += int(continued)
        else:
            status = Status.LOST if estimate.lost else Status.PREDICTED
            self.reasons[reason] += 1
        stage = {"track": 1e3 * (t1 - t0), "filter": 1e3 * (time.perf_counter() - t1), **(detail or {})}
        return FrameResult(
            t,
            status,
            point if accepted else None,
            point_uv if accepted else None,
            estimate,
            measurement,
            results,
            "" if accepted else reason,
            length,
            stage,
        )

    def _empty(self, t: float, cl: Any = None) -> Measurement:
        n = self.config.nodes
        return Measurement(np.full((n, 3), np.nan), np.full((n, 2), np.nan), np.zeros(n, dtype=bool), t, cl)

    def _measurement(
        self, results: list[ViewResult], t: float, held: NDArray[np.float64] | None, depth: Any
    ) -> tuple[Measurement, NDArray[np.float64] | None, str]:
        """The frame's nodes (world, or pixels with NaN world), the held end in the world, and why there are
        none ("" when there are)."""
        for r in results:
            if r.centerline is None:
                return self._empty(t), held, r.reason
        cl = results[0].centerline
        view = self.views[0]
        if not self.stereo:
            if not self.world:
                return (
                    Measurement(np.full((cl.n_nodes, 3), np.nan), cl.nodes_uv, cl.visible.copy(), t, cl),
                    None,
                    "",
                )
            if depth is not None:
                xyz = lift_with_depth(cl.nodes_uv, depth, view.camera, cl.visible)
            else:
                xyz = lift_with_plane(
                    cl.nodes_uv, view.camera, self.config.plane, cl.visible, self.config.floor
                )
            visible = cl.visible & np.all(np.isfinite(xyz), axis=1)
            meas = Measurement(xyz, cl.nodes_uv, visible, t, cl)
            if held is None and results[0].gripper_uv is not None:  # the gripper, where its template matched
                grip = lift_with_plane(results[0].gripper_uv[None], view.camera, self.config.plane)[0]
                held = grip if np.all(np.isfinite(grip)) else None
            if held is None and visible[0]:
                held = xyz[0].copy()
            return meas, held, ""
        from dyndlo_vision.tracking.stereo import stereo_measurement, triangulate

        cams = [v.camera for v in self.views]
        metas = [
            Measurement(
                np.full((r.centerline.n_nodes, 3), np.nan),
                r.centerline.nodes_uv,
                r.centerline.visible,
                t,
                r.centerline,
            )
            for r in results
        ]
        if held is None:  # where the two centrelines start
            starts = [r.centerline.path_uv[0] for r in results]
            held = triangulate(cams[0], starts[0][None], cams[1], starts[1][None])[0][0]
            if not np.all(np.isfinite(held)):
                return self._empty(t, cl), None, "the two views' held ends do not triangulate"
        length = self.config.cable_length_m if not self.config.tip else None
        meas = stereo_measurement(metas[0], cams[0], metas[1], cams[1], held, length)
        if not meas.visible.any():
            return meas, held, "the two views' centrelines do not match"
        return meas, held, ""

    def _new_pose(self) -> bool:
        """Whether the first view's cable moved by more than a tenth of its length since the last new pose."""
        marks = self.views[0].prev_ends
        if marks is None:
            return False
        if self._pose is not None:
            moved = _marks_moved(marks, self._pose)
            span = float(np.hypot(*(marks[0] - marks[-1]).T))  # half the cable's length, or less where bent
            if moved <= 0.2 * span:
                return False
        self._pose = marks.copy()
        return True

    def _cut(self, results: list[ViewResult]) -> str:
        """Why fractions of the cable mean nothing in this frame ("" when they do): in some view the cable
        runs out of the image, or into a region too thick to be cable, at an end the point is counted from."""
        need_end, need_start = self.config.point > 0, self.config.point < 1
        for view, r in zip(self.views, results, strict=True):
            cl = r.centerline
            start_zone, end_zone = view.segmenter.ends_in_zone(cl.path_uv, cl.width_px)
            if (need_end and cl.end_at_border) or (need_start and cl.start_at_border):
                return "the cable leaves the image"
            if (need_end and end_zone) or (need_start and start_zone):
                return "the cable runs into a region too thick to be cable"
        return ""

    def _path_length(
        self, meas: Measurement, held: NDArray[np.float64] | None, gripper_uv: NDArray[np.float64] | None
    ) -> float:
        """The measured cable's length from the held end (the robot's TCP, the gripper where its template
        matched, else the polyline's start): world (m) through the lifted nodes, or pixels."""
        view = self.views[0]
        radius_px = 0.0 if gripper_uv is None or view.gripper is None else 0.5 * view.gripper.size
        if self.world:
            if held is None or not meas.lifted.any():
                return float("nan")
            points = meas.nodes_xyz[meas.lifted]
            if not self.stereo and meas.centerline is not None:  # the dense path, lifted as the nodes are
                path = lift_with_plane(
                    meas.centerline.path_uv, view.camera, self.config.plane, None, self.config.floor
                )
                points = path[np.all(np.isfinite(path), axis=1)]
            return _length_from(points, held, radius_px / view.px_per_m)
        cl = meas.centerline
        if cl is None:
            return float("nan")
        if gripper_uv is None:
            return float(cl.length_px)
        return _length_from(cl.path_uv, gripper_uv, radius_px)

    def _looks_held(self, rgb: NDArray[np.uint8], tip_uv: NDArray[np.float64]) -> str:
        """Why the tip at ``tip_uv`` is not measured ("" when it may be): the gripper's template matches
        there. A tip reported on the gripper is the worst wrong answer: the held end and the tip swapped, or
        the tip so close to the gripper that they cannot be told apart. (With the robot's pose the gripper is
        masked out of the segmentation instead.) The template is searched within the cable start's offset
        from it plus half its size."""
        view = self.views[0]
        grip = view.gripper
        if grip is None or not grip.usable or not view.offsets:
            return ""
        offset = float(np.hypot(*np.median(np.array(view.offsets), axis=0)))
        if grip.seen_near(rgb, tip_uv, offset + 0.5 * grip.size):
            return "the tip looks like the gripper"
        return ""

    def _point(
        self, meas: Measurement, results: list[ViewResult], held: NDArray[np.float64] | None
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None, float, bool, str]:
        """(point, its first-view pixel, the measured length, continued?, why not measured)."""
        cfg = self.config
        cut = self._cut(results)
        length = self._path_length(meas, held, results[0].gripper_uv)
        bridged = any(np.any(~r.centerline.path_visible) for r in results)
        clean = (
            not cut
            and all(
                r.orientation is not None
                and r.orientation.reason in ("continuity", "registration", "gravity")
                for r in results
            )
            and np.isfinite(length)
            and not self.stereo
        )
        if cut:
            return None, None, length, False, cut
        if clean:
            (self._bridged_lengths if bridged else self._lengths).append((length, self._new_pose()))
        reference = cfg.cable_length_m if self.world else None
        learned, doubt = (None, False) if reference is not None else self._length_state()
        ref = reference if reference is not None else (None if doubt else learned)
        point_space = (
            meas.nodes_xyz if self.world else np.column_stack([meas.nodes_uv, np.zeros(len(meas.nodes_uv))])
        )
        if cfg.tip:
            seen = np.flatnonzero(meas.visible & np.all(np.isfinite(point_space), axis=1))
            if seen.size == 0:
                return None, None, length, False, "the tip's node is not seen"
            if ref is None and self.stereo and not _reaches_far_ends(meas, self.views, results):
                why = "the triangulated cable does not reach its far end in both views"
                return None, None, length, False, why
            if any(_doubles_back(r.centerline) for r in results):
                return None, None, length, False, "the cable doubles back along itself at its end"
            stereo_reach = ref is None and self.stereo  # two views reaching both far ends: no length needed
            if not stereo_reach and ref is None and doubt:
                why = "the cable's length is in doubt: bridged frames show it longer"
                return None, None, length, False, why
            if not stereo_reach and ref is None:
                return None, None, length, False, "the cable's length is not known yet"
            if not stereo_reach and np.isfinite(length):
                ratio = length / ref
                if ratio > 1.0 + cfg.long_tolerance:
                    return None, None, length, False, "longer than the cable"
                # Continued only from a held end the robot's pose or the gripper's template places, with the
                # cable's length given: elsewhere the missing part may be at the held end.
                placed = reference is not None and (held is not None or results[0].gripper_uv is not None)
                if ratio < 1.0 - (0.0 if placed else cfg.short_tolerance):
                    if not placed or ratio < cfg.min_seen_given:
                        return None, None, length, False, "shorter than the cable: its tip is hidden"
                    if self.world:
                        start = held if held is not None else point_space[seen[0]]
                    else:
                        grip = results[0].gripper_uv
                        start = None if grip is None else np.append(grip, 0.0)
                    tip = _continued(point_space, meas.visible, ref - length, start)
                    if tip is None:
                        return None, None, length, False, "shorter than the cable: its tip is hidden"
                    uv = self.views[0].camera.project(tip[None])[0] if self.world else tip[:2].copy()
                    return tip, uv, length, True, ""
            if seen[-1] != len(meas.visible) - 1:
                return None, None, length, False, "the tip's node is not seen"
            return point_space[-1].copy(), meas.nodes_uv[-1].copy(), length, False, ""
        if (
            self.stereo
            and cfg.cable_length_m is None
            and cfg.point > 0
            and not _reaches_far_ends(meas, self.views, results)
        ):
            return (
                None,
                None,
                length,
                False,
                "the triangulated cable does not reach its far end in both views",
            )
        point = point_on_nodes(point_space, meas.visible, cfg.point)
        continued = False
        if point is None:
            point = bridged_point(point_space, meas.visible, cfg.point)
            continued = point is not None
        if point is None:
            return None, None, length, False, "the point's nodes are not seen"
        uv = self.views[0].camera.project(point[None])[0] if self.world else point[:2].copy()
        return point, uv, length, continued, ""


def _marks_moved(marks: NDArray[np.float64], previous: NDArray[np.float64]) -> float:
    """How far (px) a cable's quarter, middle and three-quarter points moved from ``previous``: the largest
    of the three, for the ordering of the two that fits best (a cable's path may run either way)."""
    return float(min(np.max(np.hypot(*(marks - previous).T)), np.max(np.hypot(*(marks[::-1] - previous).T))))


def _doubles_back(cl: Any, share: float = 0.1) -> bool:
    """Whether the last ``share`` of the centreline's path runs back along an earlier part of it, within two
    cable widths (beyond that tail's own length back along the path): a mask split along the cable (a
    highlight, a seam) walked down one strand and back up the other ends in the cable's middle, not at its
    tip."""
    path = np.asarray(cl.path_uv, dtype=np.float64)
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))))
    if len(path) < 4 or not s[-1] > 0:
        return False
    tail_len = share * s[-1]
    tail, earlier = path[s >= s[-1] - tail_len], path[s < s[-1] - 2.0 * tail_len]
    if len(tail) == 0 or len(earlier) == 0:
        return False
    width = float(cl.width_px) if np.isfinite(cl.width_px) else 2.0
    near = np.min(np.linalg.norm(tail[:, None, :] - earlier[None, :, :], axis=2), axis=1)
    return bool(np.median(near) <= 2.0 * width + 1.0)


def _length_from(points: NDArray[np.float64], held: NDArray[np.float64], radius: float = 0.0) -> float:
    """The length of a polyline from ``held``: straight to where it last leaves the disc of ``radius`` around
    ``held`` (among its first half; else to its start), then along it. A skeleton that wanders into the
    gripper's blob (segmented with the cable) adds nothing."""
    pts = np.asarray(points, dtype=np.float64)
    held = np.asarray(held, dtype=np.float64).reshape(-1)[: pts.shape[1]]
    head = max(1, (len(pts) + 1) // 2)
    inside = np.flatnonzero(np.linalg.norm(pts[:head] - held, axis=1) <= radius)
    j = int(inside[-1]) if inside.size else 0
    return float(np.linalg.norm(pts[j] - held) + np.linalg.norm(np.diff(pts[j:], axis=0), axis=1).sum())


def _continued(
    points: NDArray[np.float64], visible: NDArray[np.bool_], missing: float, start: NDArray[np.float64] | None
) -> NDArray[np.float64] | None:
    """The tip of a polyline (its seen nodes, after ``start`` when given) continued straight by ``missing``,
    along its last two segments (less pixel noise than the last one); None for a polyline of one point."""
    pts = points[visible & np.all(np.isfinite(points), axis=1)]
    if start is not None:
        pts = np.vstack([np.asarray(start, dtype=np.float64).reshape(1, 3), pts])
    if len(pts) < 2:
        return None
    direction = pts[-1] - pts[max(0, len(pts) - 3)]
    norm = float(np.linalg.norm(direction))
    if norm < 1e-12:
        return None
    return pts[-1] + direction / norm * missing


#: Two views: a point past the held end is measured only if the triangulated cable's far end lies this close
#: to the far end of the cable in each image (px), plus two of the matching's sample spacings along the longer
#: of the two centrelines: else one view hides part of the cable and the far end is not the cable's.
_STEREO_END_TOL_PX = 3.0


def _reaches_far_ends(meas: Measurement, views: list[_View], results: list[ViewResult]) -> bool:
    """Whether the triangulated cable's last node projects onto the far end of the cable in every view."""
    from dyndlo_vision.tracking.stereo import StereoParams

    last = meas.nodes_xyz[np.all(np.isfinite(meas.nodes_xyz), axis=1)]
    if len(last) == 0:
        return False
    longest = max(float(r.centerline.length_px) for r in results)
    tol = _STEREO_END_TOL_PX + 2.0 * longest / max(StereoParams().samples - 1, 1)
    for view, r in zip(views, results, strict=True):
        end = r.centerline.path_uv[-1]
        if float(np.linalg.norm(view.camera.project(last[-1:])[0] - end)) > tol:
            return False
    return True
