"""Tests of dyndlo_vision.tracking.segmentation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dyndlo_vision.tracking.segmentation import (
    BackgroundSegmenter,
    cable_widths,
    clean_mask,
    dice,
    dice_losses,
    dice_within,
    segment_hsv,
)
from dyndlo_vision.tracking.synthetic import loop_curve, render_cable, s_curve


def _hsv_patch_image() -> np.ndarray:
    """Four 20x20 patches: red (hue ~0), dark red (hue ~175), green, blue."""
    hsv = np.zeros((20, 80, 3), np.uint8)
    for i, h in enumerate((2, 175, 60, 120)):
        hsv[:, 20 * i : 20 * (i + 1)] = (h, 220, 200)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def test_segment_hsv_plain_range() -> None:
    m = segment_hsv(_hsv_patch_image(), (50, 100, 100), (70, 255, 255))
    assert m.dtype == bool
    assert m[:, 40:60].all() and not m[:, :40].any() and not m[:, 60:].any()


def test_segment_hsv_wraps_hue() -> None:
    m = segment_hsv(_hsv_patch_image(), (170, 100, 100), (10, 255, 255))
    assert m[:, :40].all() and not m[:, 40:].any()


def test_segment_hsv_rejects_bad_bounds() -> None:
    with pytest.raises(ValueError, match="H 0..179"):
        segment_hsv(_hsv_patch_image(), (0, 0, 0), (200, 255, 255))


def test_dice() -> None:
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    assert dice(a, b) == 1.0
    a[:5] = True
    assert dice(a, b) == 0.0
    b[:5] = True
    assert dice(a, b) == 1.0
    b[:, :5] = False
    assert dice(a, b) == pytest.approx(2 * 25 / (50 + 25))



def _band(rows: slice, shape: tuple[int, int] = (40, 60)) -> np.ndarray:
    mask = np.zeros(shape, bool)
    mask[rows, 10:50] = True
    return mask


def test_dice_within_forgives_boundaries_off_by_the_tolerance_and_no_more() -> None:
    truth = _band(slice(10, 14))  # a 4 px cable
    beside = _band(slice(11, 15))  # the same, one pixel lower
    assert dice(beside, truth) == pytest.approx(0.75)
    assert dice_within(beside, truth, 1.0) == 1.0
    two_off = _band(slice(12, 16))
    assert dice_within(two_off, truth, 1.0) < 1.0
    assert dice_within(two_off, truth, 2.0) == 1.0
    # Diagonal neighbours are sqrt(2) away: outside a tolerance of 1, inside 1.5.
    diagonal = np.roll(np.roll(truth, 1, 0), 1, 1)
    assert dice_within(diagonal, truth, 1.0) < 1.0
    assert dice_within(diagonal, truth, 1.5) == 1.0


def test_dice_within_is_dice_at_tolerance_zero_and_weighs_both_kinds_of_error() -> None:
    rng = np.random.default_rng(3)
    for _ in range(5):
        a, b = rng.random((30, 30)) < 0.3, rng.random((30, 30)) < 0.3
        assert dice_within(a, b, 0.0) == pytest.approx(dice(a, b), abs=1e-12)
    truth = _band(slice(10, 14))
    extra = truth.copy()
    extra[30:36, 10:50] = True  # 240 extra pixels far from the cable (160 true ones)
    # Precision 160 / 400, recall 1: 2 P R / (P + R) = 4 / 7, the same whichever mask is the prediction.
    assert dice_within(extra, truth) == pytest.approx(4 / 7)
    assert dice_within(truth, extra) == pytest.approx(4 / 7)
    half = truth.copy()
    half[:, 30:] = False  # precision 1, recall 1/2 (plus the one column within a pixel of the cut)
    assert dice_within(half, truth) == pytest.approx(2 * (84 / 160) / (1 + 84 / 160))


def test_dice_within_of_empty_masks_and_bad_input() -> None:
    empty, truth = np.zeros((20, 20), bool), _band(slice(5, 8), (20, 20))
    assert dice_within(empty, empty) == 1.0
    assert dice_within(empty, truth) == 0.0
    assert dice_within(truth, empty) == 0.0
    with pytest.raises(ValueError, match=r"one shape, got \(20, 20\) and \(20, 21\)"):
        dice_within(truth, np.zeros((20, 21), bool))
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="tolerance must be a finite number of pixels >= 0"):
            dice_within(truth, truth, bad)

def _bands(widths: tuple[int, ...], shape: tuple[int, int] = (80, 120)) -> tuple[np.ndarray, list[slice]]:
    """Horizontal cables of the given widths, 8 px apart, from column 10 to 109; and their rows."""
    mask, rows, top = np.zeros(shape, bool), [], 4
    for w in widths:
        rows.append(slice(top, top + w))
        mask[top : top + w, 10:110] = True
        top += w + 8
    return mask, rows


def test_cable_widths_reads_each_cable_s_width_odd_exactly_even_one_short() -> None:
    mask, rows = _bands((1, 2, 3, 4, 7, 12))
    widths = cable_widths(mask)
    assert not widths[~mask].any()
    for w, r in zip((1, 2, 3, 4, 7, 12), rows, strict=True):
        middle = widths[r, 30:90]  # away from the ends, where the skeleton forks
        assert np.all(middle == (w if w % 2 else max(1, w - 1))), (w, np.unique(middle))
    # A diagonal cable reads its width across it, not along a row (which is sqrt(2) times as long).
    diagonal = np.zeros((120, 120), np.uint8)
    cv2.line(diagonal, (10, 10), (110, 110), 1, thickness=5)
    across = diagonal[60].sum() / np.sqrt(2.0)  # 6.4 px: OpenCV draws it wider than 5
    assert abs(np.median(cable_widths(diagonal)[diagonal > 0]) - across) < 1.0
    # A cable along the image's edge reads what is in view (the frame is off the mask), not twice that.
    edge = np.zeros((40, 120), bool)
    edge[:5, :] = True
    assert np.median(cable_widths(edge)[:5, 20:100]) == 5.0
    assert not cable_widths(np.zeros((9, 9), bool)).any()
    with pytest.raises(ValueError, match="2-D"):
        cable_widths(np.zeros((4, 4, 3), bool))


def test_dice_losses_add_up_with_dice_to_one() -> None:
    rng = np.random.default_rng(5)
    truth, _ = _bands((1, 3, 6, 11))
    for _ in range(6):
        pred = (truth & (rng.random(truth.shape) < 0.8)) | (rng.random(truth.shape) < 0.05)
        losses = dice_losses(pred, truth)
        assert losses["dice"] == pytest.approx(dice(pred, truth), abs=1e-12)
        lost = sum(v for k, v in losses.items() if k != "dice")
        assert losses["dice"] + lost == pytest.approx(1.0, abs=1e-12)


def test_dice_losses_put_missed_pixels_in_their_cable_s_width_band() -> None:
    truth, rows = _bands((2, 3, 8, 9))
    total_of = lambda pred: int(pred.sum()) + int(truth.sum())  # noqa: E731
    for missing, band in ((0, "thin"), (1, "mid"), (2, "mid"), (3, "wide")):
        pred = truth.copy()
        pred[rows[missing]] = False
        losses = dice_losses(pred, truth)
        share = int(truth[rows[missing]].sum()) / total_of(pred)
        assert losses[f"missed_{band}"] == pytest.approx(share), band
        others = [k for k in losses if k.startswith("missed_") and k != f"missed_{band}"]
        assert all(losses[k] == 0.0 for k in others), (missing, losses)
        assert losses["extra_near"] == losses["extra_away"] == 0.0
    # The caller's widths are used as given.
    pred = truth.copy()
    pred[rows[3]] = False
    as_thin = dice_losses(pred, truth, widths=np.where(truth, 1.0, 0.0))
    assert as_thin["missed_thin"] > 0.0 and as_thin["missed_wide"] == 0.0


def test_dice_losses_tell_a_fringe_from_things_away_from_the_cable() -> None:
    truth, rows = _bands((4,))
    r = rows[0]
    for gap, kind in ((1, "extra_near"), (2, "extra_near"), (3, "extra_away")):
        pred = truth.copy()
        pred[r.stop - 1 + gap, 10:110] = True  # a row of extra pixels, ``gap`` px below the cable's edge
        losses = dice_losses(pred, truth)
        assert losses[kind] == pytest.approx(100 / (500 + 400)), (gap, losses)
        other = "extra_away" if kind == "extra_near" else "extra_near"
        assert losses[other] == 0.0
    # The extra row 3 px off counts as near once ``near`` reaches 3.
    assert dice_losses(pred, truth, near=3.0)["extra_near"] == pytest.approx(100 / 900)
    # Distances are Euclidean to the pixel: a pixel 2 down and 1 across the cable's end is sqrt(5) = 2.24 off.
    corner = truth.copy()
    corner[r.stop + 1, 110] = True
    assert dice_losses(corner, truth, near=2.25)["extra_near"] > 0.0
    assert dice_losses(corner, truth, near=2.2)["extra_away"] > 0.0


def test_dice_losses_of_empty_masks_and_bad_input() -> None:
    empty, (truth, _) = np.zeros((80, 120), bool), _bands((3,))
    nothing_lost = {k: 0.0 for k in ("missed_thin", "missed_mid", "missed_wide", "extra_near", "extra_away")}
    assert dice_losses(empty, empty) == {"dice": 1.0, **nothing_lost}
    assert dice_losses(empty, truth)["missed_mid"] == 1.0
    assert dice_losses(truth, empty)["extra_away"] == 1.0
    with pytest.raises(ValueError, match=r"one shape, got \(80, 120\) and \(80, 121\)"):
        dice_losses(truth, np.zeros((80, 121), bool))
    with pytest.raises(ValueError, match="2-D"):
        dice_losses(np.zeros((4, 4, 3), bool), np.zeros((4, 4, 3), bool))
    with pytest.raises(ValueError, match=r"widths must have the masks' shape \(80, 120\), got \(3, 3\)"):
        dice_losses(truth, truth, widths=np.zeros((3, 3)))
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="near must be a finite number of pixels >= 0"):
            dice_losses(truth, truth, near=bad)


def test_clean_mask_drops_small_blobs_and_fills_holes() -> None:
    m = np.zeros((100, 100), np.uint8)
    m[20:30, 10:90] = 1
    m[25, 50] = 0  # pin hole
    m[70:72, 70:72] = 1  # small blob
    out = clean_mask(m, min_area=30)
    assert out[25, 50] and not out[70:72, 70:72].any()
    assert out[20:30, 12:88].all()


@pytest.mark.parametrize("curve", [s_curve(), loop_curve()], ids=["s", "loop"])
@pytest.mark.parametrize("noise", [2.0, 8.0])
def test_background_segmenter_auto(curve: np.ndarray, noise: float) -> None:
    rgb, gt = render_cable(curve, noise_sigma=noise, seed=3)
    seg = BackgroundSegmenter()
    m = seg(rgb)
    assert dice(m, gt) > 0.9


def test_background_segmenter_gradient_background_with_explicit_image() -> None:
    h, w = 480, 640
    ramp = np.linspace(30, 200, w, dtype=np.float32)
    bg = np.dstack([np.tile(ramp, (h, 1))] * 3).astype(np.uint8)
    rgb, gt = render_cable(s_curve(), background=bg, color=(200, 40, 40), noise_sigma=3.0)
    seg = BackgroundSegmenter(background=bg)
    assert dice(seg(rgb), gt) > 0.9


def test_background_segmenter_learns_from_moving_frames() -> None:
    frames = []
    for k in range(7):
        rgb, _ = render_cable(s_curve(v0=120 + 40 * k), noise_sigma=3.0, seed=k)
        frames.append(rgb)
    seg = BackgroundSegmenter()
    seg.learn(frames)
    rgb, gt = render_cable(s_curve(v0=250, phase=1.0), noise_sigma=3.0, seed=99)
    assert dice(seg(rgb), gt) > 0.9


def test_background_segmenter_empty_frame_is_empty() -> None:
    rng = np.random.default_rng(0)
    rgb = np.clip(rng.normal(60, 5, (480, 640, 3)), 0, 255).astype(np.uint8)
    assert not BackgroundSegmenter()(rgb).any()
    flat = np.full((480, 640, 3), 90, np.uint8)
    assert not BackgroundSegmenter()(flat).any()


def test_background_segmenter_rejects_wrong_input() -> None:
    with pytest.raises(ValueError, match="uint8 RGB"):
        BackgroundSegmenter()(np.zeros((10, 10), np.uint8))
    seg = BackgroundSegmenter(background=np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ValueError, match="background shape"):
        seg(np.zeros((20, 20, 3), np.uint8))
