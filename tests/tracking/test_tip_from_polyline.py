"""The free tip of a cable of known length from a polyline that stops short of it (tracking.tracker)."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.tracking.tracker import MIN_SEEN_LENGTH_FRACTION, Measurement, tip_from_polyline

HELD = np.array([0.5, 0.0, 0.8])


def _measurement(points: np.ndarray, hidden: tuple[int, ...] = ()) -> Measurement:
    points = np.asarray(points, dtype=float)
    visible = np.ones(len(points), bool)
    visible[list(hidden)] = False
    xyz = np.where(visible[:, None], points, np.nan)
    return Measurement(xyz, np.zeros((len(points), 2)), visible, 0.0)


def _hanging(length_m: float, seen_m: float, n: int = 20) -> np.ndarray:
    """Nodes of a cable hanging straight down from HELD, measured over its first ``seen_m``."""
    s = np.linspace(seen_m / n, seen_m, n)
    return HELD - np.outer(s, [0.0, 0.0, 1.0])


def test_a_whole_cable_gives_its_own_end() -> None:
    m = _measurement(_hanging(0.5, 0.5))
    assert m.length_from(HELD) == pytest.approx(0.5)
    assert tip_from_polyline(m, HELD, 0.5) == pytest.approx(HELD - [0, 0, 0.5])
    # A polyline longer than the cable (lifting errors) is not shortened either.
    longer = _measurement(_hanging(0.5, 0.52))
    assert tip_from_polyline(longer, HELD, 0.5) == pytest.approx(HELD - [0, 0, 0.52])


@pytest.mark.parametrize("seen", [0.26, 0.35, 0.45, 0.49])
def test_a_straight_cable_seen_in_part_is_continued_to_its_tip(seen: float) -> None:
    m = _measurement(_hanging(0.5, seen))
    assert tip_from_polyline(m, HELD, 0.5) == pytest.approx(HELD - [0, 0, 0.5], abs=1e-12)


def test_the_missing_part_continues_the_last_direction_not_the_first() -> None:
    # Down 0.3 m, then 0.1 m along +x, then hidden: the tip is 0.1 m further along +x, not below.
    down = HELD - np.outer(np.linspace(0.03, 0.3, 10), [0, 0, 1])
    along = down[-1] + np.outer(np.linspace(0.02, 0.1, 5), [1, 0, 0])
    m = _measurement(np.vstack([down, along]))
    assert m.length_from(HELD) == pytest.approx(0.4)
    assert tip_from_polyline(m, HELD, 0.5) == pytest.approx(along[-1] + [0.1, 0, 0], abs=1e-12)


def test_invisible_nodes_are_skipped_and_gaps_count_straight() -> None:
    m = _measurement(_hanging(0.5, 0.4), hidden=(5, 6, 7))
    assert m.length_from(HELD) == pytest.approx(0.4)
    assert tip_from_polyline(m, HELD, 0.5) == pytest.approx(HELD - [0, 0, 0.5], abs=1e-12)


def test_too_little_of_the_cable_is_not_a_tip() -> None:
    assert MIN_SEEN_LENGTH_FRACTION == 0.5
    assert tip_from_polyline(_measurement(_hanging(0.5, 0.249)), HELD, 0.5) is None
    assert tip_from_polyline(_measurement(_hanging(0.5, 0.251)), HELD, 0.5) is not None
    nothing = _measurement(_hanging(0.5, 0.4), hidden=tuple(range(20)))
    assert nothing.length_from(HELD) == 0.0 and tip_from_polyline(nothing, HELD, 0.5) is None


@pytest.mark.parametrize("bad", [0.0, -0.5, float("nan")])
def test_the_cable_length_must_be_positive(bad: float) -> None:
    with pytest.raises(ValueError, match="cable_length_m"):
        tip_from_polyline(_measurement(_hanging(0.5, 0.5)), HELD, bad)
