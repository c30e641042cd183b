"""Tests of dyndlo_vision.tracking.metrics: polyline error, flips, onsets, speed bands, summaries."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dyndlo_vision.tracking.metrics import (
    count_onsets,
    error_summary,
    is_flipped,
    polyline_prefix,
    speed_band_index,
    speed_band_labels,
    symmetric_polyline_error,
)


def test_symmetric_polyline_error_matches_hand_computation() -> None:
    # Truth: x from 0 to 2 on y = 0. Estimate: x from 0 to 1 on y = 1 (short and offset).
    # Estimate -> truth: every point is 1 away.
    # Truth -> estimate: 1 for x <= 1, sqrt((x - 1)^2 + 1) beyond; mean over [0, 2] is
    # (1 + integral_0^1 sqrt(u^2 + 1) du) / 2 = (1 + (sqrt(2) + asinh(1)) / 2) / 2.
    truth = np.array([[0.0, 0.0], [2.0, 0.0]])
    estimate = np.array([[0.0, 1.0], [1.0, 1.0]])
    truth_to_est = (1.0 + (math.sqrt(2.0) + math.asinh(1.0)) / 2.0) / 2.0
    expected = 0.5 * (1.0 + truth_to_est)  # 1.03695
    got = symmetric_polyline_error(estimate, truth, n_samples=4001)
    assert got == pytest.approx(expected, abs=1e-4)
    # Symmetric in its arguments, and zero for identical polylines in 3D.
    assert symmetric_polyline_error(truth, estimate, n_samples=4001) == pytest.approx(got, abs=1e-12)
    curve = np.column_stack((np.linspace(0, 1, 7), np.sin(np.linspace(0, 3, 7)), np.zeros(7)))
    assert symmetric_polyline_error(curve, curve) == pytest.approx(0.0, abs=1e-12)


def test_symmetric_polyline_error_drops_invisible_nodes_and_needs_two() -> None:
    truth = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    est = np.array([[0.0, 0.5, 0.0], [np.nan, np.nan, np.nan], [1.0, 0.5, 0.0]])
    assert symmetric_polyline_error(est, truth) == pytest.approx(0.5)
    assert math.isnan(symmetric_polyline_error(est[:2], truth))
    with pytest.raises(ValueError, match="dimension"):
        symmetric_polyline_error(est, truth[:, :2])
    with pytest.raises(ValueError, match="n_samples"):
        symmetric_polyline_error(est, truth, n_samples=1)


def test_polyline_prefix_cuts_by_arc_length() -> None:
    poly = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]])  # length 4
    np.testing.assert_allclose(polyline_prefix(poly, 0.5), [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    np.testing.assert_allclose(polyline_prefix(poly, 1.0), poly)
    np.testing.assert_allclose(polyline_prefix(poly, 0.125), [[0.0, 0.0], [0.5, 0.0]])
    with pytest.raises(ValueError, match="fraction"):
        polyline_prefix(poly, 0.0)


def test_flip_detection() -> None:
    truth = np.column_stack((np.linspace(0.0, 0.5, 21), np.zeros(21), np.full(21, 0.6)))
    assert not is_flipped(truth + 0.002, truth)
    assert is_flipped(truth[::-1] + 0.002, truth)
    # Only the first half seen (tip occluded): still judged by its visible ends.
    half = truth.copy()
    half[11:] = np.nan
    assert not is_flipped(half, truth)
    rev = truth[::-1].copy()
    rev[11:] = np.nan
    assert is_flipped(rev, truth)
    # A wrong turn in the middle (ends right) is not a flip.
    bent = truth.copy()
    bent[5:16] = truth[15:4:-1]
    assert not is_flipped(bent, truth)
    # One visible node: no orientation to judge.
    one = np.full_like(truth, np.nan)
    one[3] = truth[17]
    assert not is_flipped(one, truth)


def test_count_onsets() -> None:
    assert count_onsets([]) == 0
    assert count_onsets([False, False]) == 0
    assert count_onsets([True, True, False, True, False, False, True]) == 3
    assert count_onsets([False, True, True, True]) == 1


def test_speed_bands() -> None:
    assert speed_band_labels() == ["<0.5", "0.5-2", "2-5", ">5"]
    np.testing.assert_array_equal(
        speed_band_index([0.0, 0.49, 0.5, 1.9, 2.0, 4.99, 5.0, 40.0]), [0, 0, 1, 1, 2, 2, 3, 3]
    )
    with pytest.raises(ValueError, match="increasing"):
        speed_band_labels([2.0, 1.0])


def test_error_summary_counts_missing_frames_as_failures() -> None:
    s = error_summary([1.0, 3.0, 30.0, np.nan], thresholds=(10.0, 20.0))
    assert s["n"] == 4 and s["available"] == 0.75
    assert s["mean"] == pytest.approx(34.0 / 3.0) and s["median"] == 3.0
    assert s["under"] == {10.0: 0.5, 20.0: 0.5}
    empty = error_summary([np.nan, np.nan])
    assert math.isnan(empty["mean"]) and empty["under"][0.01] == 0.0
