"""Segmentation masks made safe to follow: the robot's gripper cleared, and regions not shaped like a cable.

Each wraps a segmenter (``rgb -> bool mask``) and is a segmenter itself, so they stack in front of the
pipeline (:func:`~dyndlo_vision.tracking.segmenters.build_view_segmenter`):

* :class:`GripperMaskedSegmenter` clears a disk around the gripper where the robot's pose says it is (the
  loop knows it every frame; ``track --tcp-log`` reads it from a log). A gripper segmented as cable is the
  worst confident wrong answer: the centreline ends on it and the tip is reported at the hand.
* :class:`CableReachSegmenter` segments only the image of the ball the held cable can reach (its length
  around the gripper): nothing beyond it is this cable, and the learned segmenter computes only that part.
* :class:`CableShapedMask` removes regions too thick to be cable: thicker than an absolute share of the image
  (a whole floor the background model does not describe), or than a few times the cable's own width, which
  it measures in the mask (a gripper, a box). It remembers where it cut, so that a centreline that runs into
  such a region is not taken to end at the tip there.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

#: A followed mask (:class:`CableReachSegmenter`) this close (px) to its box's edge may be cut there: the
#: frame is computed again on the whole ball. The learned segmenter's mask thins near a region's edge.
FOLLOW_EDGE_PX = 8
#: A region is not cable where it is thicker than this many times the cable's measured width ...
MAX_WIDTH_RATIO = 3.0
#: ... but never below this half-width (px): a 1-2 px cable's width is measured to a pixel at best, and
#: crossings and motion blur widen a cable locally.
MIN_CUT_RADIUS_PX = 4.0


class GripperMaskedSegmenter:
    """A segmenter that clears a disk around the robot's gripper, whose pose the robot reports.

    Set :attr:`center_uv` (and, for a gripper whose distance to the camera changes, :attr:`radius_px`) before
    each frame; a centre of None or NaN clears nothing.

    Args:
        base: The frame -> mask function.
        radius_px: Radius of the cleared disk.
    """

    def __init__(self, base: Any, radius_px: float) -> None:
        self.base = base
        self.radius_px = float(radius_px)
        self.center_uv: NDArray[np.float64] | None = None

    def __call__(self, rgb: NDArray[np.uint8]) -> NDArray[np.bool_]:
        mask = np.asarray(self.base(rgb), dtype=bool)
        if self.center_uv is not None and np.all(np.isfinite(self.center_uv)) and self.radius_px > 0:
            h, w = mask.shape
            u, v = self.center_uv
            r = self.radius_px
            u0, u1 = int(max(0, np.floor(u - r))), int(min(w, np.ceil(u + r) + 1))
            v0, v1 = int(max(0, np.floor(v - r))), int(min(h, np.ceil(v + r) + 1))
            if u0 < u1 and v0 < v1:
                vv, uu = np.mgrid[v0:v1, u0:u1]
                mask[v0:v1, u0:u1] &= (uu - u) ** 2 + (vv - v) ** 2 > r * r
        return mask


def _sphere_directions(n: int) -> NDArray[np.float64]:
    """``n`` unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / n)
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    return np.column_stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])


#: Directions whose images bound a ball's image. Every direction lies within 0.135 rad of one of them (the
#: largest gap over 200 000 random directions: 0.134), and 1 / cos 0.135 = 1.009, so the points of a ball
#: drawn 1 % larger than asked reach as far as the whole ball in any direction
#: (``CableReachSegmenter.region``; tests/tracking/test_cable_reach.py checks it against the closed form).
_BALL_DIRECTIONS = _sphere_directions(400)
_BALL_INFLATION = 1.01


class CableReachSegmenter:
    """A segmenter that looks for the cable only where it can be: within its length of the held end.

    The cable is inextensible and held at one end, whose world position the robot reports every frame; every
    point of it lies in the ball of the cable's length around that end. This segments the image of that ball
    (its bounding box, :meth:`region`) and reports no cable elsewhere. A base that can compute a region alone
    (``base.segment(rgb, region=...)``, as :class:`~dyndlo_vision.tracking.learned.LearnedSegmenter`) computes
    only the region: the learned segmenter is then faster by the share of the frame the ball leaves out. Any
    other base segments the whole frame and its mask is cleared outside the region: whatever it found there
    (another cable, a box) is not this cable.

    Set :attr:`held_world` before each frame; None (or NaN) segments the whole frame.

    With ``follow_px`` (a base that computes regions only), consecutive frames of one video are followed: the
    cable moves little in a frame period, so the region is the last mask's bounding box grown by
    ``follow_px`` on every side, within the ball. A mask that comes within :data:`FOLLOW_EDGE_PX` of that
    box's edge where the ball goes on (the cable may go on past it), or an empty one, is computed again on the
    whole ball, so a cable that moved farther is not cut; so is the first frame.

    Args:
        base: The frame -> mask function.
        camera: The camera's calibration (``project``, ``world_to_camera``), world frame of the held end.
        reach_m: Radius of the ball: the cable's length plus a margin for its thickness and the gripper.
        follow_px: The margin (px) around the last mask's box; None: every frame on the whole ball.
    """

    def __init__(self, base: Any, camera: Any, reach_m: float, follow_px: int | None = None) -> None:
        if not (np.isfinite(reach_m) and reach_m > 0):
            raise ValueError(f"reach_m must be a positive length in m, got {reach_m!r}")
        if follow_px is not None and (isinstance(follow_px, bool) or not isinstance(follow_px, int)
                                      or follow_px < 1):
            raise ValueError(f"follow_px must be None or a positive number of pixels, got {follow_px!r}")
        self.base = base
        self.camera = camera
        self.reach_m = float(reach_m)
        self.held_world: NDArray[np.float64] | None = None
        #: Whether the base computes a region alone (else it segments the whole frame, cleared outside).
        self.computes_region = callable(getattr(base, "grid_box", None))
        self.follow_px = follow_px if self.computes_region else None
        #: The last mask's bounding box (u0, v0, u1, v1), None before the first or after an empty one.
        self.last_box: tuple[int, int, int, int] | None = None
        #: Frames computed on the box around the last mask, and frames computed again on the ball after it.
        self.followed = self.recomputed = 0

    def region(self, height: int, width: int) -> tuple[int, int, int, int] | None:
        """(u0, v0, u1, v1): the pixels of a ``height`` x ``width`` frame the ball around the held end covers,
        clipped to the frame; (0, 0, 0, 0) when it misses the frame, None when it cannot be bounded (no held
        end, or a ball that reaches behind the camera)."""
        held = self.held_world
        if held is None or not np.all(np.isfinite(held)):
            return None
        radius = self.reach_m * _BALL_INFLATION
        points = np.asarray(held, dtype=float).reshape(1, 3) + radius * _BALL_DIRECTIONS
        if np.min(self.camera.world_to_camera(points)[:, 2]) <= 1e-3:
            return None
        uv = self.camera.project(points)
        if not np.all(np.isfinite(uv)):
            return None
        u0, v0 = np.floor(uv.min(axis=0)).astype(int)
        u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + 1
        u0, v0, u1, v1 = max(0, u0), max(0, v0), min(width, u1), min(height, v1)
        if u0 >= u1 or v0 >= v1:
            return (0, 0, 0, 0)
        return int(u0), int(v0), int(u1), int(v1)

    def __call__(self, rgb: NDArray[np.uint8]) -> NDArray[np.bool_]:
        h, w = rgb.shape[:2]
        region = self.region(h, w)
        if region is None:
            self.last_box = None
            return np.asarray(self.base(rgb), dtype=bool)
        if self.computes_region:
            if self.follow_px is not None and self.last_box is not None and region != (0, 0, 0, 0):
                mask = self._followed(rgb, region, self.last_box)
                if mask is not None:
                    return mask
            mask = np.asarray(self.base.segment(rgb, region=region), dtype=bool)
            self.last_box = _bounding_box(mask)
            return mask
        whole = np.asarray(self.base(rgb), dtype=bool)
        u0, v0, u1, v1 = region
        mask = np.zeros_like(whole)
        mask[v0:v1, u0:u1] = whole[v0:v1, u0:u1]
        return mask

    def _followed(self, rgb: NDArray[np.uint8], ball: tuple[int, int, int, int],
                  last: tuple[int, int, int, int]) -> NDArray[np.bool_] | None:
        """The mask computed on ``last`` grown by :attr:`follow_px` within ``ball``; None where it is empty or
        comes near an edge of that box the ball goes on past."""
        m = int(self.follow_px or 0)
        u0, v0, u1, v1 = ball
        box = (max(u0, last[0] - m), max(v0, last[1] - m), min(u1, last[2] + m), min(v1, last[3] + m))
        if box[0] >= box[2] or box[1] >= box[3]:
            return None
        mask = np.asarray(self.base.segment(rgb, region=box), dtype=bool)
        found = _bounding_box(mask)
        edge = FOLLOW_EDGE_PX
        if found is None or (
            (box[0] > u0 and found[0] < box[0] + edge) or (box[1] > v0 and found[1] < box[1] + edge)
            or (box[2] < u1 and found[2] > box[2] - edge) or (box[3] < v1 and found[3] > box[3] - edge)
        ):
            self.recomputed += 1
            return None
        self.followed += 1
        self.last_box = found
        return mask


def _bounding_box(mask: NDArray[np.bool_]) -> tuple[int, int, int, int] | None:
    """(u0, v0, u1, v1) of the mask's pixels (ends exclusive); None for an empty mask."""
    u, v, w, h = cv2.boundingRect(np.ascontiguousarray(mask).view(np.uint8))
    return None if w == 0 else (u, v, u + w, v + h)


def cable_half_width_px(depth: NDArray[np.float32], mask: NDArray[np.bool_]) -> float:
    """The cable's half-width in pixels: the median distance transform on the mask's ridges.

    Ridge pixels (local maxima of ``depth`` in their 3x3 neighbourhood) lie on the medial axis of each region.
    A long thin cable contributes ridge pixels all along its length at its half-width; a compact blob (a
    gripper) contributes a few at its centre, so the median is the cable's. NaN for an empty mask.
    """
    import cv2

    if not mask.any():
        return float("nan")
    ridge = mask & (depth >= cv2.dilate(depth, np.ones((3, 3), np.uint8)))
    return float(np.median(depth[ridge]))


class CableShapedMask:
    """Removes mask regions too thick to be a cable, and remembers where they were.

    Two limits, the tighter of which applies:

    * absolute: regions thicker than ``max_width_share`` of the image's shorter side. A background model that
      does not fit the scene (one colour per frame in front of a floor and a dark backdrop, a lighting change
      under a median background) segments whole surfaces; the skeleton of such a region is a line as long as
      the region, which the tracker would follow as the cable;
    * relative (``max_width_ratio``): regions thicker than that many times the cable's own width, measured in
      each frame's mask (:func:`cable_half_width_px`), but at least ``2 * min_cut_radius_px``: a gripper, a
      box, a hand. Off with ``max_width_ratio=None``.

    Pixels of the too-thick regions (a morphological opening with a disk of the limit's diameter, by distance
    transforms), and a band of half that width around them, are removed from the mask; :meth:`ends_in_zone`
    tells whether a centreline ran into that zone, where the cable may continue unseen, so that the end is not
    its tip.

    Args:
        segment: The frame -> mask function.
        max_width_share: Widest cable as a share of the image's shorter side.
        max_width_ratio: Widest cable as a multiple of the measured cable width (None: no relative limit).
        min_cut_radius_px: Smallest half-width the relative limit cuts at.
    """

    def __init__(
        self,
        segment: Callable[[NDArray[np.uint8]], NDArray[np.bool_]],
        max_width_share: float,
        max_width_ratio: float | None = MAX_WIDTH_RATIO,
        min_cut_radius_px: float = MIN_CUT_RADIUS_PX,
    ) -> None:
        if not 0 < max_width_share <= 1:
            raise ValueError(f"max_width_share must be in (0, 1], got {max_width_share!r}")
        if max_width_ratio is not None and not max_width_ratio > 1:
            raise ValueError(f"max_width_ratio must be above 1 (or None), got {max_width_ratio!r}")
        self.segment = segment
        self.max_width_share = float(max_width_share)
        self.max_width_ratio = None if max_width_ratio is None else float(max_width_ratio)
        self.min_cut_radius_px = float(min_cut_radius_px)
        #: The last frame's excluded zone (regions too thick plus the band), None where there was none.
        self.zone: NDArray[np.bool_] | None = None
        #: The last frame's cut radius (px): half the widest region kept.
        self.cut_radius_px = float("nan")
        #: Frames in which a zone was found.
        self.frames_with_zone = 0

    def cut_radius(self, depth: NDArray[np.float32], mask: NDArray[np.bool_]) -> float:
        """Half the widest region that is kept, in pixels, for a mask and its distance transform."""
        radius = 0.5 * self.max_width_share * min(mask.shape)
        if self.max_width_ratio is not None:
            half_width = cable_half_width_px(depth, mask)
            if np.isfinite(half_width):
                radius = min(radius, max(self.max_width_ratio * half_width, self.min_cut_radius_px))
        return radius

    def __call__(self, rgb: NDArray[np.uint8]) -> NDArray[np.bool_]:
        import cv2

        mask = np.asarray(self.segment(rgb), dtype=bool)
        # Distance of each mask pixel to the nearest non-mask pixel (OpenCV counts the image's outside as
        # mask, so a floor cut by the image border stays thick up to the border).
        depth = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
        radius = self.cut_radius(depth, mask)
        self.cut_radius_px = radius
        core = depth > radius
        if not core.any():
            self.zone = None
            return mask
        # Disks of the radius around the core pixels are the opening; the band beyond them swallows the
        # slivers an opening leaves at the region's corners.
        to_core = cv2.distanceTransform((~core).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
        self.zone = to_core <= 1.5 * radius
        self.frames_with_zone += 1
        return mask & ~self.zone

    def ends_in_zone(
        self, path_uv: NDArray[np.float64], width_px: float, mask: NDArray[np.bool_]
    ) -> tuple[bool, bool]:
        """Whether the start and the end of a centreline path run into the last frame's zone.

        The mask components the path lies on are looked up; their pixels next to the zone are where the cable
        was cut, and each is assigned to the nearest point of the path: near its start or its end, that end is
        cut (a skeleton stops short of its mask's end, so the end point itself may lie a little away from the
        zone; cuts between bridged gaps in the middle of the path do not count).
        """
        import cv2

        if self.zone is None or path_uv.shape[0] < 2:
            return False, False
        h, w = mask.shape
        m8 = mask.astype(np.uint8)
        _, labels = cv2.connectedComponents(m8, connectivity=8)
        px = np.rint(path_uv).astype(np.int64)
        px[:, 0] = np.clip(px[:, 0], 0, w - 1)
        px[:, 1] = np.clip(px[:, 1], 0, h - 1)
        on_path = np.unique(labels[px[:, 1], px[:, 0]])
        on_path = on_path[on_path > 0]
        if on_path.size == 0:
            return False, False
        beside_zone = cv2.dilate(self.zone.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        rows, cols = np.nonzero(beside_zone & np.isin(labels, on_path))
        if rows.size == 0:
            return False, False
        seg = np.hypot(*np.diff(path_uv, axis=0).T)
        s = np.concatenate(([0.0], np.cumsum(seg)))
        contact = np.column_stack((cols, rows)).astype(np.float64)
        nearest = np.empty(contact.shape[0], dtype=np.int64)
        for i0 in range(0, contact.shape[0], 256):  # bounded memory for long contacts
            chunk = contact[i0 : i0 + 256]
            d2 = np.sum((chunk[:, None, :] - path_uv[None, :, :]) ** 2, axis=2)
            nearest[i0 : i0 + 256] = np.argmin(d2, axis=1)
        s_contact = s[nearest]
        tol = 2.0 * width_px + 2.0
        return bool(np.any(s_contact <= tol)), bool(np.any(s_contact >= s[-1] - tol))
