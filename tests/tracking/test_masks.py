"""The masks that keep the tracker off what is not cable: the gripper's disk, regions too thick for cable."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dyndlo_vision.tracking.masks import (
    MAX_WIDTH_RATIO,
    MIN_CUT_RADIUS_PX,
    CableShapedMask,
    GripperMaskedSegmenter,
    cable_half_width_px,
)

H, W = 480, 640


def _line_mask(thickness: int, start=(100, 240), end=(540, 260)) -> np.ndarray:
    img = np.zeros((H, W), np.uint8)
    cv2.line(img, start, end, 255, thickness)
    return img > 0


def _with_disk(mask: np.ndarray, centre: tuple[int, int], radius: int) -> np.ndarray:
    img = mask.astype(np.uint8) * 255
    cv2.circle(img, centre, radius, 255, -1)
    return img > 0


def _depth(mask: np.ndarray) -> np.ndarray:
    return cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)


@pytest.mark.parametrize("thickness", [3, 5, 9, 13])
def test_cable_half_width_is_half_the_drawn_width(thickness: int) -> None:
    mask = _line_mask(thickness)
    # The distance transform counts the ridge pixel itself: a band w pixels across has ridge (w + 1) / 2.
    across = int(mask[:, 320].sum())
    assert cable_half_width_px(_depth(mask), mask) == pytest.approx((across + 1) / 2, abs=0.6)
    # A gripper-sized blob on the cable does not move the median: it has few ridge pixels.
    blob = _with_disk(mask, (100, 240), 14)
    assert cable_half_width_px(_depth(blob), blob) == pytest.approx((across + 1) / 2, abs=0.6)


def test_cable_half_width_of_an_empty_mask_is_nan() -> None:
    mask = np.zeros((H, W), bool)
    assert np.isnan(cable_half_width_px(_depth(mask), mask))


def test_a_gripper_blob_is_removed_and_the_cable_kept() -> None:
    mask = _with_disk(_line_mask(3), (100, 240), 14)
    shaped = CableShapedMask(lambda _: mask.copy(), 0.1)
    out = shaped(np.zeros((H, W, 3), np.uint8))
    assert shaped.zone is not None and shaped.frames_with_zone == 1
    vv, uu = np.mgrid[0:H, 0:W]
    assert not out[(uu - 100) ** 2 + (vv - 240) ** 2 <= 14**2].any()
    # Away from the blob and its band, every cable pixel is kept.
    far = _line_mask(3) & (np.arange(W)[None, :] > 100 + 14 + 3 * 14)
    assert out[far].all()


@pytest.mark.parametrize("radius, removed", [(6, False), (10, True)])
def test_the_width_ratio_decides(radius: int, removed: bool) -> None:
    """A cable 5 px across (half-width 3 by the distance transform) is cut above 3 x 3 = 9 px: a disk of
    radius 10 is no cable, one of radius 6 may be a knot or a plug."""
    assert MAX_WIDTH_RATIO == 3.0
    line = _line_mask(3)
    assert line[:, 320].sum() == 5
    mask = _with_disk(line, (540, 260), radius)
    shaped = CableShapedMask(lambda _: mask.copy(), 0.1)
    out = shaped(np.zeros((H, W, 3), np.uint8))
    assert shaped.cut_radius_px == pytest.approx(9.0, abs=1.0)
    assert (not out[260, 540]) is removed
    assert (shaped.zone is not None) is removed


def test_thin_cables_are_cut_no_finer_than_the_floor() -> None:
    """A 1 px cable would make a 3 px blob "too thick"; the floor keeps blobs up to MIN_CUT_RADIUS_PX."""
    mask = _with_disk(_line_mask(1), (540, 260), 3)
    shaped = CableShapedMask(lambda _: mask.copy(), 0.1)
    out = shaped(np.zeros((H, W, 3), np.uint8))
    assert shaped.cut_radius_px == MIN_CUT_RADIUS_PX
    assert out[260, 540] and shaped.zone is None


def test_crossing_cables_are_kept() -> None:
    mask = _line_mask(3) | _line_mask(3, start=(320, 40), end=(330, 440))
    shaped = CableShapedMask(lambda _: mask.copy(), 0.1)
    out = shaped(np.zeros((H, W, 3), np.uint8))
    assert shaped.zone is None
    np.testing.assert_array_equal(out, mask)


def test_without_the_ratio_only_the_absolute_limit_applies() -> None:
    mask = _with_disk(_line_mask(3), (100, 240), 14)
    shaped = CableShapedMask(lambda _: mask.copy(), 0.1, max_width_ratio=None)
    out = shaped(np.zeros((H, W, 3), np.uint8))
    assert shaped.zone is None and out[240, 100]
    # A floor-sized region still goes.
    floor = mask.copy()
    floor[300:, :] = True
    out = CableShapedMask(lambda _: floor.copy(), 0.1, max_width_ratio=None)(np.zeros((H, W, 3), np.uint8))
    assert not out[400, 320]


@pytest.mark.parametrize(
    "kwargs", [{"max_width_share": 0.0}, {"max_width_share": 0.1, "max_width_ratio": 1.0}]
)
def test_bad_limits_are_refused(kwargs: dict) -> None:
    with pytest.raises(ValueError, match="max_width"):
        CableShapedMask(lambda _: np.zeros((2, 2), bool), **kwargs)


def test_gripper_mask_clears_its_disk_only() -> None:
    mask = np.ones((H, W), bool)
    masked = GripperMaskedSegmenter(lambda _: mask.copy(), 10.0)
    np.testing.assert_array_equal(masked(np.zeros((H, W, 3), np.uint8)), mask)  # no pose yet: nothing
    masked.center_uv = np.array([200.0, 100.0])
    out = masked(np.zeros((H, W, 3), np.uint8))
    vv, uu = np.mgrid[0:H, 0:W]
    inside = (uu - 200) ** 2 + (vv - 100) ** 2 <= 100
    assert not out[inside].any() and out[~inside].all()
    masked.center_uv = np.array([np.nan, 5.0])
    assert masked(np.zeros((H, W, 3), np.uint8)).all()
