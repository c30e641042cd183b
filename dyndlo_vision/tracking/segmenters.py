"""The one place a cable segmenter is built: a typed configuration, checked once, and the stack around it.

A segmenter maps an RGB frame to a bool cable mask. :class:`SegmenterConfig` names it:

* ``learned``: a shipped network (or an ONNX file from ``seg-train``) run by
  :class:`~dyndlo_vision.tracking.learned.LearnedSegmenter`; no background needed;
* ``background``: :class:`~dyndlo_vision.tracking.segmentation.BackgroundSegmenter` against a background image
  (a clean plate, or the per-pixel median of frames sampled across a video: ``median``), or one colour
  estimated per frame (``frame``); ``auto`` is the median when there are enough frames to learn it from;
* ``hsv``: a fixed HSV range.

:func:`build_view_segmenter` wraps it in what a view of a held cable needs: the part of the frame the cable
can reach, the gripper cleared where the robot says it is, and regions too thick to be cable removed
(:mod:`~dyndlo_vision.tracking.masks`). ``track``, ``segment``, the simulated loop and ``run`` all build their
segmenters here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BACKGROUND_SOURCES",
    "MIN_BACKGROUND_FRAMES",
    "SEGMENTER_KINDS",
    "SegmenterConfig",
    "ViewSegmenter",
    "build_segmenter",
    "build_view_segmenter",
]

#: Kinds of segmenter.
SEGMENTER_KINDS = ("learned", "background", "hsv")
#: Where a ``background`` segmenter's background comes from (besides an image the caller gives).
BACKGROUND_SOURCES = ("auto", "median", "frame")
#: ``auto`` learns the median background from at least this many frames: from fewer, a moving cable covers a
#: pixel in too large a share of them for the median to be background.
MIN_BACKGROUND_FRAMES = 8
#: Range of the learned segmenter's enlargement (``scale``): below 0.5 a 1.6 px cable is under a pixel; above
#: 3 a 640x480 frame is a 1920x1440 input.
MIN_SCALE, MAX_SCALE = 0.5, 3.0


@dataclass(frozen=True)
class SegmenterConfig:
    """Which segmenter, with its settings; checked when made (ValueError naming the bad value).

    Attributes:
        kind: One of :data:`SEGMENTER_KINDS`.
        model: ``learned``: a shipped network's name (:data:`~dyndlo_vision.tracking.networks.SHIPPED_NAMES`)
            or an ONNX file; None: the default network.
        short_side: ``learned``: each frame's shorter side is resized to this before the network (None: the
            network's own, or ``scale``).
        scale: ``learned``: each frame is enlarged this many times before the network (the loop's 1.6 px
            cable), in [0.5, 3]; exclusive with ``short_side``.
        background: ``background``: one of :data:`BACKGROUND_SOURCES` (an image given to
            :func:`build_segmenter` replaces it).
        hsv_lower, hsv_upper: ``hsv``: OpenCV HSV bounds (H 0-179, S and V 0-255); a lower H above the upper H
            wraps through red.
        open_radius: ``background``: radius of the opening that removes speckle (0: none, which keeps cables
            1-2 px wide).
    """

    kind: str = "background"
    model: str | None = None
    short_side: int | None = None
    scale: float | None = None
    background: str = "auto"
    hsv_lower: tuple[int, int, int] | None = None
    hsv_upper: tuple[int, int, int] | None = None
    open_radius: int = 0

    def __post_init__(self) -> None:
        if self.kind not in SEGMENTER_KINDS:
            raise ValueError(f"segmenter {self.kind!r}; expected one of {list(SEGMENTER_KINDS)}")
        learned_only = {"model": self.model, "short_side": self.short_side, "scale": self.scale}
        for name, value in learned_only.items():
            if value is not None and self.kind != "learned":
                raise ValueError(
                    f"the segmenter's {name} {value!r} is for the learned segmenter, not {self.kind!r}"
                )
        if self.model is not None:
            from dyndlo_vision.tracking.networks import check_network

            check_network(self.model, "the segmenter model")
        if self.short_side is not None and (
            isinstance(self.short_side, bool) or not isinstance(self.short_side, int) or self.short_side < 16
        ):
            raise ValueError(
                f"the segmenter's short side must be an int of at least 16 pixels, got {self.short_side!r}"
            )
        if self.scale is not None:
            if (
                isinstance(self.scale, bool)
                or not isinstance(self.scale, int | float)
                or not (MIN_SCALE <= self.scale <= MAX_SCALE)
            ):
                raise ValueError(
                    f"the segmenter's scale must be a number in [{MIN_SCALE:g}, {MAX_SCALE:g}], got "
                    f"{self.scale!r}"
                )
            if self.short_side is not None:
                raise ValueError("give the learned segmenter a scale or a short side, not both")
        if self.background not in BACKGROUND_SOURCES:
            raise ValueError(f"background {self.background!r}; expected one of {list(BACKGROUND_SOURCES)}")
        if (self.hsv_lower is None) != (self.hsv_upper is None):
            raise ValueError("the HSV bounds go together: give both or neither")
        if self.kind == "hsv":
            if self.hsv_lower is None or self.hsv_upper is None:
                raise ValueError("the hsv segmenter needs both HSV bounds")
            for name, hsv in (("lower", self.hsv_lower), ("upper", self.hsv_upper)):
                if (
                    len(hsv) != 3
                    or not (0 <= hsv[0] <= 179 and 0 <= hsv[1] <= 255 and 0 <= hsv[2] <= 255)
                    or any(int(c) != c for c in hsv)
                ):
                    raise ValueError(
                        f"the {name} HSV bound must be three integers with H in 0..179 and S, V in "
                        f"0..255 (OpenCV's HSV), got {hsv!r}"
                    )
            if self.hsv_lower[1] > self.hsv_upper[1] or self.hsv_lower[2] > self.hsv_upper[2]:
                raise ValueError(
                    f"the lower HSV bound's S and V must not exceed the upper's: {self.hsv_lower} "
                    f"against {self.hsv_upper}"
                )
        elif self.hsv_lower is not None:
            raise ValueError(f"HSV bounds are for the hsv segmenter, not {self.kind!r}")
        if (
            isinstance(self.open_radius, bool)
            or not isinstance(self.open_radius, int)
            or self.open_radius < 0
        ):
            raise ValueError(f"the opening radius must be an int >= 0, got {self.open_radius!r}")

    @property
    def name(self) -> str:
        """A short name for records: ``learned:<model>``, ``background:<source>`` or ``hsv``."""
        if self.kind == "learned":
            from dyndlo_vision.tracking.networks import SHIPPED_NAME

            return f"learned:{self.model or SHIPPED_NAME}"
        return f"background:{self.background}" if self.kind == "background" else "hsv"


def build_segmenter(
    config: SegmenterConfig,
    *,
    frame_size: tuple[int, int] | None = None,
    background_image: NDArray[np.uint8] | None = None,
    background_frames: Sequence[NDArray[np.uint8]] | None = None,
) -> tuple[Callable[[NDArray[np.uint8]], NDArray[np.bool_]], str]:
    """The segmenter ``config`` names, and which background it uses (``image``, ``median``, ``frame``) or
    ``learned`` / ``hsv``.

    Args:
        config: The segmenter.
        frame_size: (width, height) of the frames; needed with ``config.scale``.
        background_image: ``background``: the scene without the cable (a clean plate), which replaces
            ``config.background``.
        background_frames: ``background`` with ``median`` or ``auto``: frames sampled across the video, the
            cable moving; ``auto`` with fewer than :data:`MIN_BACKGROUND_FRAMES` falls back to ``frame``.
    """
    if config.kind == "learned":
        from dyndlo_vision.tracking.learned import LearnedSegmenter
        from dyndlo_vision.tracking.networks import onnx_bytes

        short_side: int | str | None = "auto" if config.short_side is None else config.short_side
        if config.scale is not None:
            if frame_size is None:
                raise ValueError("a learned segmenter with a scale needs the frame size")
            short_side = round(config.scale * min(frame_size))
        return LearnedSegmenter(onnx_bytes(config.model), short_side=short_side), "learned"
    if config.kind == "hsv":
        from dyndlo_vision.tracking.segmentation import segment_hsv

        lo, hi = np.array(config.hsv_lower), np.array(config.hsv_upper)
        return (lambda rgb: segment_hsv(rgb, lo, hi, clean=True)), "hsv"
    from dyndlo_vision.tracking.segmentation import BackgroundSegmenter

    segmenter = BackgroundSegmenter(open_radius=config.open_radius)
    if background_image is not None:
        segmenter.set_background(background_image)
        return segmenter, "image"
    if config.background == "frame":
        return segmenter, "frame"
    frames = list(background_frames or [])
    if config.background == "median" and not frames:
        raise ValueError("the median background needs frames to learn it from")
    if len(frames) < (1 if config.background == "median" else MIN_BACKGROUND_FRAMES):
        return segmenter, "frame"
    segmenter.learn(frames)
    return segmenter, "median"


class ViewSegmenter:
    """One view's segmenter stack: the base, then (each optional) the cable's reach, the gripper cleared, and
    regions too thick to be cable removed. Itself a segmenter (``rgb -> mask``).

    Set the held end before each frame (:meth:`hold`) where the robot reports it.

    Attributes:
        base: The frame -> mask function (:func:`build_segmenter`).
        reach: :class:`~dyndlo_vision.tracking.masks.CableReachSegmenter` or None.
        gripper: :class:`~dyndlo_vision.tracking.masks.GripperMaskedSegmenter` or None.
        shape: :class:`~dyndlo_vision.tracking.masks.CableShapedMask` or None.
        last_mask: The last frame's mask (after every stage).
    """

    def __init__(self, base: Any, reach: Any = None, gripper: Any = None, shape: Any = None) -> None:
        self.base, self.reach, self.gripper, self.shape = base, reach, gripper, shape
        top: Any = base
        for stage in (reach, gripper, shape):
            if stage is not None:
                top = stage
        self._top = top
        self.last_mask: NDArray[np.bool_] | None = None

    def hold(
        self,
        held_world: NDArray[np.float64] | None,
        held_uv: NDArray[np.float64] | None,
        gripper_radius_px: float | None = None,
    ) -> None:
        """Where the held end is this frame (world and pixel; None: unknown): the reach is centred on it and
        the gripper cleared around it."""
        if self.reach is not None:
            self.reach.held_world = held_world
        if self.gripper is not None:
            self.gripper.center_uv = held_uv
            if gripper_radius_px is not None:
                self.gripper.radius_px = float(gripper_radius_px)

    def __call__(self, rgb: NDArray[np.uint8]) -> NDArray[np.bool_]:
        mask = np.asarray(self._top(rgb), dtype=bool)
        self.last_mask = mask
        return mask

    @property
    def zone(self) -> NDArray[np.bool_] | None:
        """The last frame's regions too thick to be cable (None: none, or no shape test)."""
        return None if self.shape is None else self.shape.zone

    def ends_in_zone(self, path_uv: NDArray[np.float64], width_px: float) -> tuple[bool, bool]:
        """Whether the path's start and end ran into a region too thick to be cable (see
        :meth:`~dyndlo_vision.tracking.masks.CableShapedMask.ends_in_zone`)."""
        if self.shape is None or self.last_mask is None:
            return False, False
        return self.shape.ends_in_zone(path_uv, width_px, self.last_mask)


def build_view_segmenter(
    base: Any,
    *,
    camera: Any = None,
    reach_m: float | None = None,
    follow_px: int | None = None,
    gripper_radius_px: float | None = None,
    max_width_share: float | None = None,
    max_width_ratio: float | None = None,
) -> ViewSegmenter:
    """``base`` in a :class:`ViewSegmenter`.

    Args:
        base: The segmenter (:func:`build_segmenter`).
        camera: The view's calibration (needed with ``reach_m``).
        reach_m: Look only within this distance of the held end (the cable's length plus a margin).
        follow_px: With ``reach_m`` and a base that computes regions: follow the last mask's box grown by
        this.
        gripper_radius_px: Clear a disk of this radius around the held end's pixel (None: no gripper mask).
        max_width_share: Remove regions thicker than this share of the image's shorter side (None: no shape
            test).
        max_width_ratio: With ``max_width_share``: also those thicker than this many times the cable's width.
    """
    from dyndlo_vision.tracking.masks import CableReachSegmenter, CableShapedMask, GripperMaskedSegmenter

    reach = None
    top = base
    if reach_m is not None:
        if camera is None:
            raise ValueError("the cable's reach needs the view's calibration")
        reach = top = CableReachSegmenter(base, camera, reach_m, follow_px=follow_px)
    gripper = None
    if gripper_radius_px is not None:
        gripper = top = GripperMaskedSegmenter(top, gripper_radius_px)
    shape = None
    if max_width_share is not None:
        shape = CableShapedMask(top, max_width_share, max_width_ratio)
    return ViewSegmenter(base, reach, gripper, shape)


def background_from(path: str | Path) -> NDArray[np.uint8]:
    """A background image (RGB uint8) read from ``path``.

    Raises:
        ValueError: Not an image OpenCV reads, naming the path.
    """
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"not an image OpenCV reads: {path}")
    return np.ascontiguousarray(image[..., ::-1])
