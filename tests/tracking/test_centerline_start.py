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


# ---------------------------------------------------------------- the start rule on hand-made skeleton graphs


def _graph(*strands: list[tuple[float, float]]):
    """A skeleton graph of straight strands, each sampled every pixel (a polyline: one branch per strand)."""
    from dyndlo_vision.tracking.centerline import _Branch, _Graph

    g = _Graph()
    for strand in strands:
        pieces = []
        for a, b in zip(strand[:-1], strand[1:], strict=True):
            a, b = np.array(a, float), np.array(b, float)
            n = max(1, int(round(np.hypot(*(b - a)))))
            pieces.append(a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a))
        pts = np.vstack([pieces[0]] + [p[1:] for p in pieces[1:]])
        g.branches.append(_Branch(pts, [g.add_node(pts[0], "end"), g.add_node(pts[-1], "end")]))
    return g


def _start(g, hint, width: float = 1.0):
    """The first step (branch, end) and the length of the walk chosen."""
    from dyndlo_vision.tracking.centerline import CenterlineParams, _choose_start

    hint = None if hint is None else np.array(hint, float)
    walk, _ = _choose_start(g, g.ports(), hint, width, CenterlineParams())
    return walk.steps[0][:2], walk.length


def test_the_walk_starts_at_the_free_end_nearest_the_hint_not_at_a_junction() -> None:
    from dyndlo_vision.tracking.centerline import _Branch, _Graph

    # A T: arms to (-50, 0) and (50, 0), a stem to (0, 30). The hint (0, 5) is nearest the junction, but the
    # walk starts at a free end: the stem's, 25 px away (the arms' ends, 50 px away, are beyond 25 + 20 px).
    g = _Graph()
    j = g.add_node(np.zeros(2), "junction")
    t = np.arange(51.0)[:, None]
    for pts in (t * [-1.0, 0.0], t * [1.0, 0.0], t[:31] * [0.0, 1.0]):
        g.branches.append(_Branch(pts, [j, g.add_node(pts[-1], "end")]))
    assert _start(g, (0.0, 5.0)) == ((2, 1), pytest.approx(30.0))


def test_the_distance_to_the_hint_is_measured_from_the_end_itself() -> None:
    from dyndlo_vision.tracking.centerline import _Branch, _Graph

    # A branch of two points (a direct link): its end 0 is 10 px from the hint, its end 1 200 px.
    g = _Graph()
    pts = np.array([[0.0, 10.0], [0.0, 200.0]])
    g.branches.append(_Branch(pts, [g.add_node(pts[0], "end"), g.add_node(pts[1], "end")]))
    assert _start(g, (0.0, 0.0))[0] == (0, 0)


# A 30 px stub at the hint (a gripper blob cut off from the cable thins into one) pointing away from a 200 px
# cable whose end lies ``gap`` px from the hint along u: the cable is taken when its end is within
# max(20 px, 5 widths) of the stub's end, its walk being more than 1.5 times longer.
STUB = [(0.0, 0.0), (0.0, -30.0)]


def _cable(gap: float) -> list[tuple[float, float]]:
    return [(gap, 0.0), (gap + 200.0, 0.0)]


@pytest.mark.parametrize(
    ("gap", "width", "cable"),
    [(20.0, 1.0, True), (20.5, 1.0, False), (22.0, 5.0, True), (24.9, 5.0, True), (25.5, 5.0, False)],
)
def test_a_longer_walk_near_the_hint_beats_a_stub(gap: float, width: float, cable: bool) -> None:
    start, length = _start(_graph(STUB, _cable(gap)), (0.0, 0.0), width)
    assert (start, length) == (((1, 0), pytest.approx(200.0)) if cable else ((0, 0), pytest.approx(30.0)))


def test_a_walk_exactly_one_and_a_half_times_longer_does_not_beat_the_nearest() -> None:
    # A 10 px stub at the hint and a 15 px strand 15 px away: not more than 1.5 times longer, the stub stays.
    assert _start(_graph([(0.0, 0.0), (0.0, -10.0)], [(15.0, 0.0), (30.0, 0.0)]), (0.0, 0.0)) == (
        (0, 0), pytest.approx(10.0))
    assert _start(_graph([(0.0, 0.0), (0.0, -10.0)], [(15.0, 0.0), (31.0, 0.0)]), (0.0, 0.0)) == (
        (1, 0), pytest.approx(16.0))


def test_without_a_hint_the_longest_strand_wins_over_more_clutter_than_is_tried() -> None:
    # Four 20 px pieces of clutter (8 ends: as many as are tried) stored before a 300 px strand, 200 px apart.
    clutter = [[(x, 0.0), (x, 20.0)] for x in (0.0, 200.0, 400.0, 600.0)]
    start, length = _start(_graph(*clutter, [(0.0, 300.0), (300.0, 300.0)]), None)
    assert start[0] == 4 and length == pytest.approx(300.0)


def test_without_a_hint_the_longest_walk_wins_by_half_a_pixel() -> None:
    # A 100 px strand, and 200 px below it a 100.5 px one broken by a 2 px crack (60 + 2 + 38.5 px).
    g = _graph([(0.0, 0.0), (100.0, 0.0)], [(0.0, 200.0), (60.0, 200.0)], [(62.0, 200.0), (100.5, 200.0)])
    start, length = _start(g, None)
    assert start[0] in (1, 2) and length == pytest.approx(100.5)


def test_a_cable_end_as_near_the_hint_as_a_stub_wins_whatever_the_order_of_the_ends() -> None:
    import itertools

    from dyndlo_vision.tracking.centerline import CenterlineParams, _choose_start

    # The hint midway between a 30 px stub's end (-5, 0) and a 200 px cable's end (5, 0).
    g = _graph([(-5.0, 0.0), (-5.0, -30.0)], [(5.0, 0.0), (205.0, 0.0)])
    items = list(g.ports().items())
    for order in itertools.permutations(range(len(items))):
        walk, _ = _choose_start(g, dict(items[i] for i in order), np.zeros(2), 1.0, CenterlineParams())
        assert walk.steps[0][:2] == (1, 0) and walk.length == pytest.approx(200.0), order


@pytest.mark.parametrize("anchor", [(35, 60), None])
def test_pinholes_near_both_ends_leave_no_free_end_but_the_cable_is_found(anchor) -> None:
    """A pinhole a few pixels from each end of a thick cable closes a tiny loop there; pruned, it leaves each
    end a junction with one branch: a skeleton without a free end, whose walk starts at one of those."""
    m = np.zeros((120, 200), np.uint8)
    cv2.line(m, (40, 60), (160, 60), 255, 9)
    m[60, 43] = m[60, 157] = 0
    cl = extract_centerline(m > 0, 10, anchor_uv=anchor)
    assert cl.visible.all() and 105.0 < cl.length_px < 121.0
    assert np.all(np.abs(cl.nodes_uv[:, 1] - 60.0) < 1.0)
    if anchor is not None:
        assert cl.nodes_uv[0, 0] < 50.0 and cl.nodes_uv[-1, 0] > 150.0
