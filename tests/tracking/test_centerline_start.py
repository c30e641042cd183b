"""Where the centreline's walk starts: the anchor's end, else the previous start's end, else the longest walk.

``extract_centerline`` documents (module docstring, step 4) that without ``anchor_uv`` and ``prev_nodes_uv``
the walk starts "at the end whose walk is the longest". These masks make the walks from different ends
differ in length, so choosing another walk (the shortest, or the first one tried) shows.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dyndlo_vision.tracking.centerline import extract_centerline

H, W = 480, 640
THICKNESS = 5


def _mask(*polylines: list[tuple[int, int]]) -> np.ndarray:
    m = np.zeros((H, W), np.uint8)
    for pts in polylines:
        cv2.polylines(m, [np.array(pts, np.int32)], False, 255, THICKNESS)
    return m


# A long strand (about 290 px) and, 200 px or more away (beyond the 120 px gap bridge), a short one (63 px).
LONG = [(40, 200), (300, 70)]
SHORT = [(500, 400), (560, 420)]
LONG_PX = float(np.hypot(260, 130))
SHORT_PX = float(np.hypot(60, 20))


def _near(points: np.ndarray, segment: list[tuple[int, int]], tol: float) -> bool:
    """Whether every point lies within ``tol`` px of the segment."""
    a, b = np.array(segment, float)
    ab = b - a
    s = np.clip((points - a) @ ab / (ab @ ab), 0.0, 1.0)
    return bool(np.all(np.hypot(*(a + s[:, None] * ab - points).T) < tol))


def test_without_a_hint_the_longest_walk_is_taken() -> None:
    m = _mask(LONG, SHORT)
    cl = extract_centerline(m, n_nodes=20)
    assert cl.visible.all()
    assert cl.length_px == pytest.approx(LONG_PX, abs=10.0)
    assert _near(cl.nodes_uv, LONG, 3.0)


def test_without_a_hint_the_longest_walk_wins_whatever_the_drawing_order() -> None:
    # The same two strands, the short one drawn first and placed top left.
    short, long_ = [(30, 30), (90, 50)], [(250, 420), (600, 250)]
    cl = extract_centerline(_mask(short, long_), n_nodes=20)
    assert cl.length_px == pytest.approx(float(np.hypot(350, 170)), abs=10.0)
    assert _near(cl.nodes_uv, long_, 3.0)


def test_an_anchor_overrides_the_longest_walk() -> None:
    # The held end is where the anchor says, even on the shorter strand.
    cl = extract_centerline(_mask(LONG, SHORT), n_nodes=10, anchor_uv=SHORT[1])
    assert cl.length_px == pytest.approx(SHORT_PX, abs=8.0)
    assert _near(cl.nodes_uv, SHORT, 3.0)
    assert np.hypot(*(cl.nodes_uv[0] - SHORT[1])) < 6.0  # node 0 at the anchored end


def test_previous_start_overrides_the_longest_walk() -> None:
    prev = np.linspace(SHORT[0], SHORT[1], 10)
    cl = extract_centerline(_mask(LONG, SHORT), n_nodes=10, prev_nodes_uv=prev)
    assert _near(cl.nodes_uv, SHORT, 3.0)
    assert np.hypot(*(cl.nodes_uv[0] - SHORT[0])) < 6.0


# A T: a 400 px bar and a 260 px stem meeting it at right angles (more than the walk's 80 deg turn limit).
# Walks from either end of the bar go straight through the junction (about 400 px); from the stem's end the
# walk stops at the junction (260 px), the bar's ends being 200 px away, beyond the gap bridge. The stem is
# the longest single branch (the bar's halves are 200 px each), so the walk from the end of the longest branch
# is not the longest walk: the walks must be compared.
BAR = [(100, 200), (500, 200)]
STEM = [(300, 200), (300, 460)]


def test_t_junction_without_a_hint_follows_the_bar() -> None:
    cl = extract_centerline(_mask(BAR, STEM), n_nodes=30)
    assert cl.length_px == pytest.approx(400.0, abs=15.0)
    assert np.all(np.abs(cl.nodes_uv[:, 1] - 200.0) < 3.0)
    assert {round(cl.nodes_uv[0, 0] / 100), round(cl.nodes_uv[-1, 0] / 100)} == {1, 5}


def test_t_junction_anchored_at_the_stem_walks_only_the_stem() -> None:
    cl = extract_centerline(_mask(BAR, STEM), n_nodes=10, anchor_uv=STEM[1])
    assert cl.length_px == pytest.approx(260.0, abs=15.0)
    assert np.all(np.abs(cl.nodes_uv[:, 0] - 300.0) < 3.0)


@pytest.mark.parametrize("hole_px", [8, 12, 15])
def test_a_pinhole_near_the_held_end_does_not_make_the_tip_node_0(hole_px: int) -> None:
    """A pinhole in a thick cable's mask near the held end (noise, a gripper mask's ragged cut) closes a small
    loop in the skeleton, so there is no free end there to start the walk from: the walk starts at the tip.
    Node 0 must still be the end nearest the anchor (found on a two-camera clip's frame, where the tip was
    taken for the held end)."""
    m = np.zeros((H, W), np.uint8)
    cv2.line(m, (160, 40), (180, 200), 255, 7)
    y = 40 + hole_px
    x = int(160 + 20 * hole_px / 160)
    m[y : y + 2, x : x + 2] = 0
    cl = extract_centerline(m > 0, 20, anchor_uv=(160, 30))
    assert cl.nodes_uv[0, 1] < 70 and cl.nodes_uv[-1, 1] > 190, (cl.nodes_uv[0], cl.nodes_uv[-1])
    assert cl.path_uv[0, 1] < cl.path_uv[-1, 1]


def test_a_blob_is_no_cable_but_a_short_thin_cable_is() -> None:
    """A blob (a gripper's disk, alone in the mask when the cable is lost) thins into a skeleton about as long
    as the blob is wide: no cable. Before this rule its skeleton was reported as a cable whose "tip" lay on
    the gripper (two-camera whip video, textured and blurred: 5 % of frames). A short cable is kept."""
    disk = np.zeros((H, W), np.uint8)
    cv2.ellipse(disk, (320, 240), (16, 12), 30, 0, 360, 255, -1)
    assert not extract_centerline(disk > 0, 20, anchor_uv=(320, 230)).any_visible
    short = np.zeros((H, W), np.uint8)
    cv2.line(short, (300, 200), (300, 230), 255, 5)  # 30 px long, 5 px wide
    cl = extract_centerline(short > 0, 20, anchor_uv=(300, 195))
    assert cl.any_visible and 20 < cl.length_px < 32
