"""The cable's reach: the image of the ball a held cable can reach, and the learned segmenter computed there.

The region is checked against the closed-form image of a ball under a pinhole camera; the learned segmenter's
region mask against its whole-frame mask.
"""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.tracking.camera_model import PinholeCamera
from dyndlo_vision.tracking.learned import LearnedSegmenter
from dyndlo_vision.tracking.masks import CableReachSegmenter
from dyndlo_vision.tracking.networks import FINE_NAME, onnx_bytes
from dyndlo_vision.tracking.synthetic import render_cable, s_curve


def _camera(width: int = 640, height: int = 480, f: float = 500.0) -> PinholeCamera:
    """A camera at the world origin looking along +z (world = camera frame)."""
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    return PinholeCamera(width=width, height=height, K=K, dist=np.zeros(0), R=np.eye(3), t=np.zeros(3))


def _ball_box(camera: PinholeCamera, center: np.ndarray, r: float) -> tuple[float, float, float, float]:
    """The exact bounding box of a ball's image: the planes through the optical centre tangent to the ball.

    A plane x = s z (camera frame) touches the ball where (c_x - s c_z)^2 = r^2 (1 + s^2), a quadratic in s
    whose two roots are the extreme normalised coordinates; likewise for y."""
    fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]
    c = camera.world_to_camera(center[None])[0]

    def extremes(a: float) -> tuple[float, float]:
        root = r * np.sqrt(a * a + c[2] ** 2 - r * r)
        return ((a * c[2] - root) / (c[2] ** 2 - r * r), (a * c[2] + root) / (c[2] ** 2 - r * r))

    (x0, x1), (y0, y1) = extremes(c[0]), extremes(c[1])
    return fx * x0 + cx, fy * y0 + cy, fx * x1 + cx, fy * y1 + cy


@pytest.mark.parametrize("center", [(0.0, 0.0, 3.0), (0.4, -0.3, 2.0), (-0.5, 0.2, 1.2)])
def test_the_region_holds_the_balls_image_and_little_more(center: tuple[float, float, float]) -> None:
    # A large image and ball, so that a region 0.5 % of the radius short shows as pixels, not rounding.
    camera = _camera(4000, 4000, 2000.0)
    reach = CableReachSegmenter(lambda rgb: np.zeros(rgb.shape[:2], bool), camera, 0.8)
    reach.held_world = np.array(center)
    u0, v0, u1, v1 = reach.region(4000, 4000)
    e0, f0, e1, f1 = _ball_box(camera, np.array(center), 0.8)
    radius_px = 0.5 * max(e1 - e0, f1 - f0)
    assert u0 <= max(0.0, e0) and v0 <= max(0.0, f0) and u1 >= min(4000.0, e1) and v1 >= min(4000.0, f1)
    # No more than the 1 % inflation and a pixel of rounding beyond it, on each side inside the frame.
    slack = 0.012 * radius_px + 2
    if e0 > 0:
        assert u0 >= e0 - slack
    if e1 < 4000:
        assert u1 <= e1 + slack
    if f0 > 0:
        assert v0 >= f0 - slack
    if f1 < 4000:
        assert v1 <= f1 + slack


def test_a_ball_behind_the_camera_or_outside_the_frame() -> None:
    camera = _camera()
    reach = CableReachSegmenter(lambda rgb: np.ones(rgb.shape[:2], bool), camera, 0.5)
    assert reach.region(480, 640) is None  # no held end yet: the whole frame
    reach.held_world = np.array([0.0, 0.0, 0.3])  # the ball holds the camera
    assert reach.region(480, 640) is None
    assert reach(np.zeros((480, 640, 3), np.uint8)).all()
    reach.held_world = np.array([20.0, 0.0, 2.0])  # far to the side: no pixel of the frame
    assert reach.region(480, 640) == (0, 0, 0, 0)
    assert not reach(np.zeros((480, 640, 3), np.uint8)).any()
    reach.held_world = np.array([np.nan, 0.0, 2.0])
    assert reach.region(480, 640) is None
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="reach_m"):
            CableReachSegmenter(lambda rgb: rgb, camera, bad)


def test_what_lies_beyond_the_reach_is_not_the_cable() -> None:
    """Two cables: the one held at (0, 0, 2) m is kept, the other, 0.9 m away, is cleared."""
    camera = _camera()
    held = np.array([0.0, 0.0, 2.0])
    near = camera.project(held + np.stack([np.zeros(50), np.linspace(0, 0.3, 50), np.zeros(50)], 1))
    far = camera.project(held + np.stack([np.full(50, 0.9), np.linspace(-0.3, 0.3, 50), np.zeros(50)], 1))
    rgb_near, mask_near = render_cable(near, thickness=4, seed=1)
    rgb_far, mask_far = render_cable(far, thickness=4, seed=2)

    def segment(rgb: np.ndarray) -> np.ndarray:  # a segmenter that finds both
        return mask_near | mask_far

    reach = CableReachSegmenter(segment, camera, 0.35)
    reach.held_world = held
    mask = reach(rgb_near)
    assert not reach.computes_region
    np.testing.assert_array_equal(mask, mask_near)
    reach.held_world = None
    np.testing.assert_array_equal(reach(rgb_far), mask_near | mask_far)


@pytest.mark.parametrize("network", ["cable-segmenter", FINE_NAME])
def test_the_learned_segmenter_computes_a_region_as_in_the_whole_frame(network: str) -> None:
    """Inside the region, beyond the network's context of its edges, the mask is the whole frame's; outside
    it is empty.

    The region is widened to the network's 16-pixel grid, where the network sees the frame as in one pass: a
    region on another grid shifts the 4x4 blocks and two stride-2 levels, and the mask changes inside. Near
    the edges the network misses the frame around the region. Measured on this frame, beyond 32 / 64 / 96 px
    of the box's edges the logits differ by up to 3.5 / 3.0 / 1.8 and 1.1-1.8 / 0.6-1.2 / 0.3-0.8 % of the
    cable's pixels flip (both networks); the bound is 1 % beyond 96 px."""
    seg = LearnedSegmenter(onnx_bytes(network))
    curve = s_curve(80, 560, 240, 120, 1.3)
    rgb, _ = render_cable(curve, thickness=3, color=(200, 60, 40), background=(150, 150, 150), seed=3)
    whole = seg(rgb)
    assert whole.sum() > 500
    region = (37, 21, 603, 459)
    box = seg.grid_box(region, 480, 640)
    assert box is not None
    part = seg.segment(rgb, region=region)
    if seg.blocks:  # at the frame's own size: the box is in frame pixels, on the 16 grid, holding the region
        u0, v0, u1, v1 = box
        assert (u0 % 16, v0 % 16, u1 % 16, v1 % 16) == (0, 0, 0, 0)
        assert u0 <= region[0] and v0 <= region[1] and u1 >= region[2] and v1 >= region[3]
    else:  # the half-resolution network: the box is on its resized input, mapped back
        s = 640 / seg.input_size(480, 640)[0]
        u0, v0, u1, v1 = (int(round(x * s)) for x in box)
    outside = np.ones_like(whole)
    outside[v0:v1, u0:u1] = False
    assert not part[outside].any()
    inner = (slice(v0 + 96, v1 - 96), slice(u0 + 96, u1 - 96))
    assert np.count_nonzero(whole[inner]) > 300
    differ = np.count_nonzero(part[inner] ^ whole[inner])
    assert differ <= 0.01 * np.count_nonzero(whole[inner]), differ
    assert seg.grid_box(None, 480, 640) is None
    assert seg.grid_box((0, 0, 640, 480), 480, 640) is None  # the whole frame: computed as one
    assert seg.grid_box((700, 10, 800, 20), 480, 640) == (0, 0, 0, 0)
    assert not seg.segment(rgb, region=(700, 10, 800, 20)).any()


def test_a_reach_around_the_learned_segmenter_computes_the_region_only() -> None:
    seg = LearnedSegmenter(onnx_bytes(FINE_NAME))
    calls: list[tuple[int, ...]] = []
    net_logits = seg._block_logits

    def spy(small: np.ndarray) -> np.ndarray:
        calls.append(small.shape)
        return net_logits(small)

    seg._block_logits = spy  # type: ignore[method-assign]
    camera = _camera()
    reach = CableReachSegmenter(seg, camera, 0.4)
    assert reach.computes_region
    reach.held_world = np.array([0.0, 0.0, 2.0])
    rgb = np.full((480, 640, 3), 128, np.uint8)
    reach(rgb)
    u0, v0, u1, v1 = reach.region(480, 640)
    assert len(calls) == 1
    h, w = calls[0][:2]
    assert h >= v1 - v0 and w >= u1 - u0  # the network saw the whole region ...
    assert h * w < 0.6 * 480 * 640  # ... and not the frame: a 0.4 m ball at 2 m is about 200 x 200 px


class _RegionSpy:
    """A base that computes regions: it records each region asked for and returns ``masks[k]`` for the k-th
    call, cleared outside the region (as the learned segmenter's mask is False outside what it computes)."""

    def __init__(self, masks: list[np.ndarray]) -> None:
        self.masks, self.regions = masks, []

    def grid_box(self, region: tuple[int, int, int, int], height: int, width: int) -> tuple[int, ...]:
        return region

    def segment(self, rgb: np.ndarray, region: tuple[int, int, int, int]) -> np.ndarray:
        mask = self.masks[len(self.regions)]
        self.regions.append(tuple(region))
        u0, v0, u1, v1 = region
        out = np.zeros_like(mask)
        out[v0:v1, u0:u1] = mask[v0:v1, u0:u1]
        return out

    __call__ = segment


def _line(v: int, u0: int, u1: int) -> np.ndarray:
    mask = np.zeros((480, 640), bool)
    mask[v : v + 2, u0:u1] = True
    return mask


def test_following_computes_the_box_around_the_last_mask_and_the_ball_when_it_may_be_cut() -> None:
    """``follow_px``: frame 1 on the ball; frame 2 on the last mask's box grown by the margin; a mask that
    reaches that box's edge (the cable moved farther) or is empty is computed again on the ball, whole."""
    camera = _camera()
    rgb = np.zeros((480, 640, 3), np.uint8)
    first, near, moved = _line(240, 300, 400), _line(250, 290, 410), _line(250, 290, 470)
    spy = _RegionSpy([first, near, moved, moved, np.zeros_like(first), np.zeros_like(first)])
    reach = CableReachSegmenter(spy, camera, 0.4, follow_px=40)
    reach.held_world = np.array([0.0, 0.0, 1.2])
    ball = reach.region(480, 640)
    assert ball is not None and ball[0] < 200 and ball[2] > 480  # the 0.4 m ball at 1.2 m: about 350 px wide
    np.testing.assert_array_equal(reach(rgb), first)
    assert spy.regions == [ball] and reach.last_box == (300, 240, 400, 242)
    np.testing.assert_array_equal(reach(rgb), near)  # within the box: computed there only
    assert spy.regions[1] == (260, 200, 440, 282) and reach.followed == 1
    np.testing.assert_array_equal(reach(rgb), moved)  # the cable runs out of the box: the ball, whole
    assert spy.regions[2:] == [(250, 210, 450, 292), ball] and reach.recomputed == 1
    assert reach.last_box == (290, 250, 470, 252)
    assert not reach(rgb).any()  # nothing in the box, nor on the ball
    assert spy.regions[4:] == [(250, 210, min(510, ball[2]), 292), ball] and reach.recomputed == 2
    assert reach.last_box is None


def test_following_is_off_by_default_and_checked() -> None:
    camera = _camera()
    spy = _RegionSpy([_line(240, 300, 400)] * 2)
    reach = CableReachSegmenter(spy, camera, 0.4)
    reach.held_world = np.array([0.0, 0.0, 1.2])
    reach(np.zeros((480, 640, 3), np.uint8))
    reach(np.zeros((480, 640, 3), np.uint8))
    assert spy.regions == [reach.region(480, 640)] * 2
    for bad in (0, -5, 2.5, True):
        with pytest.raises(ValueError, match="follow_px must be None or a positive number of pixels"):
            CableReachSegmenter(spy, camera, 0.4, follow_px=bad)
    assert CableReachSegmenter(lambda rgb: rgb[..., 0] > 0, camera, 0.4, follow_px=40).follow_px is None
