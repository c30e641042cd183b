"""The perception pipeline on drawn videos of a held cable: the held end keeps its identity through rests,
whips, a tip that passes the gripper and a cable that crosses itself; a frame whose ends cannot be told apart
is not measured; every status it reports is true."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from dyndlo_vision.tracking.identity import HeldEnd, IdentityParams, order_correlation, orient
from dyndlo_vision.tracking.pipeline import (
    CablePipeline,
    PipelineConfig,
    Status,
    bridged_point,
    point_on_nodes,
)
from dyndlo_vision.tracking.segmenters import SegmenterConfig, build_segmenter, build_view_segmenter
from dyndlo_vision.tracking.synthetic import render_cable

SHAPE = (480, 640)
GRIPPER = np.array([320.0, 70.0])
LENGTH_PX = 300.0
FPS = 25.0


def arc(start: np.ndarray, heading_deg: float, turn_deg: float, length: float = LENGTH_PX,
        n: int = 400) -> np.ndarray:
    """A curve of constant curvature from ``start``: ``heading`` at the start (image axes, 90 = down),
    turning by ``turn_deg`` over its ``length``."""
    s = np.linspace(0.0, length, n)
    theta = np.radians(heading_deg) + np.radians(turn_deg) * s / length
    step = length / (n - 1)
    pts = np.cumsum(np.column_stack((np.cos(theta), np.sin(theta))) * step, axis=0)
    return np.vstack([start, start + pts[:-1]])


def frame(curve: np.ndarray, gripper: np.ndarray = GRIPPER) -> np.ndarray:
    """The cable drawn in red on a plain background, held by a dark grey block (the gripper)."""
    rgb, _ = render_cable(curve, SHAPE, thickness=4, background=(200, 200, 195), noise_sigma=2.0)
    u, v = (int(round(c)) for c in gripper)
    cv2.rectangle(rgb, (u - 14, v - 18), (u + 14, v + 4), (60, 60, 60), -1)
    return rgb


def pixel_pipeline(anchor: np.ndarray | None = GRIPPER, **overrides: object) -> CablePipeline:
    """``track``'s pipeline in pixel mode (no calibration), against the plain background."""
    config = PipelineConfig(SegmenterConfig("background"), **overrides)  # type: ignore[arg-type]
    background = np.full((*SHAPE, 3), (200, 200, 195), np.uint8)
    base, _ = build_segmenter(config.segmenter, background_image=background)
    view = build_view_segmenter(base, max_width_share=config.max_width_share,
                                max_width_ratio=config.max_width_ratio)
    return CablePipeline(config, [None], [view], [anchor])


def run(pipeline: CablePipeline, curves: list[np.ndarray], grippers: list[np.ndarray] | None = None) -> list:
    grippers = grippers or [GRIPPER] * len(curves)
    return [
        pipeline.step([frame(c, g)], k / FPS) for k, (c, g) in enumerate(zip(curves, grippers, strict=True))
    ]


def hanging(n: int) -> list[np.ndarray]:
    return [arc(GRIPPER + [0, 8], 90.0, 0.0)] * n


def check_truthful(results: list, curves: list[np.ndarray], tol_px: float = 8.0) -> tuple[int, int]:
    """Every measured point lies on the true tip; returns (measured, not measured)."""
    measured = 0
    for k, (r, c) in enumerate(zip(results, curves, strict=True)):
        if r.status.seen:
            measured += 1
            err = float(np.hypot(*(r.point[:2] - c[-1])))
            assert err < tol_px, f"frame {k}: the reported tip is {err:.0f} px from the true tip ({r.status})"
    return measured, len(results) - measured


def test_a_hanging_cable_whipped_and_hanging_again_keeps_its_held_end() -> None:
    """The issue's situation: rests where the cable hangs still below the gripper, whips between them."""
    whip = [arc(GRIPPER + [0, 8], 90.0 + 50 * math.sin(k / 3), 160 * math.sin(k / 2.5)) for k in range(25)]
    curves = hanging(10) + whip + hanging(10)
    results = run(pixel_pipeline(), curves)
    check_truthful(results, curves)
    # Once the length is learned (in the whip: a cable at rest is one pose), the frames it can measure are.
    learned = next(k for k, r in enumerate(results) if r.status.seen)
    assert learned < 20
    inside = [
        k
        for k, c in enumerate(curves)
        if np.all((c >= 4) & (c <= np.array(SHAPE[::-1]) - 5)) and k >= learned
    ]
    assert sum(results[k].status.seen for k in inside) >= 0.9 * len(inside)
    assert all(r.status.seen for r in results[-8:])  # hanging again: measured, the right end


def test_a_tip_that_passes_the_gripper_is_never_reported_at_the_gripper() -> None:
    """The cable curls round until its tip reaches the gripper and back: near the gripper the two ends are
    told apart by the last frames' nodes or not at all (not measured), never swapped."""
    turns = list(np.linspace(0, 330, 12)) + list(np.linspace(330, 0, 12))
    curves = hanging(6) + [arc(GRIPPER + [0, 8], 90.0, t, LENGTH_PX) for t in turns] + hanging(6)
    results = run(pixel_pipeline(), curves)
    check_truthful(results, curves)
    closest = [k for k, c in enumerate(curves) if np.hypot(*(c[-1] - GRIPPER)) < 40]
    assert closest, "the drawn tip must come near the gripper"
    for k in closest:  # reported, if at all, on the tip itself (check_truthful), which is near the gripper
        assert results[k].status in (Status.MEASURED, Status.CONTINUED, Status.PREDICTED, Status.LOST)
    assert all(r.status.seen for r in results[-4:])


def test_a_cable_that_crosses_itself_keeps_its_held_end() -> None:
    curves = hanging(5) + [arc(GRIPPER + [0, 8], 90.0 - t / 3, t, LENGTH_PX) for t in np.linspace(0, 420, 15)]
    results = run(pixel_pipeline(), curves)
    check_truthful(results, curves)


def test_a_gripper_that_jumps_where_the_tip_was_does_not_take_the_tip_for_the_held_end() -> None:
    """Between two frames the gripper moves to within a few pixels of where the tip was (a fast move, the
    cable swinging the other way). Following the end nearest the last held end would swap the two for the
    rest of the video; the held end's motion model and the gripper's own appearance keep them apart."""
    first = arc(GRIPPER + [0, 8], 0.0, 0.0, 200)  # held out sideways, the tip 200 px to the right
    moved = GRIPPER + [150, 0]
    second = arc(moved + [0, 8], 180.0, 0.0, 200)  # the gripper near the old tip, the cable back to the left
    curves = hanging(5) + [first] * 5 + [second] * 5
    grippers = [GRIPPER] * 10 + [moved] * 5
    results = run(pixel_pipeline(), curves, grippers)
    check_truthful(results, curves)


def test_frames_are_not_measured_before_the_cable_length_is_known() -> None:
    """Without --cable-length the end of a polyline of unknown length may be anywhere along the cable: the
    tip is measured once a length is learned from frames where both ends are seen, in three poses."""
    curves = [_swinging(k) for k in range(12)]
    pipe = pixel_pipeline()
    results = run(pipe, curves)
    first_measured = next(k for k, r in enumerate(results) if r.status.seen)
    assert pipe.config.min_length_frames - 1 <= first_measured <= 8
    assert sum(r.status.seen for r in results[first_measured:]) >= 0.8 * (len(results) - first_measured)
    assert results[0].reason == "the cable's length is not known yet"
    assert pipe.learned_length == pytest.approx(LENGTH_PX + 8, abs=6)  # from the clicked gripper


def test_a_cable_longer_or_shorter_than_learned_does_not_end_at_its_tip() -> None:
    pipe = pixel_pipeline()
    run(pipe, [_swinging(k) for k in range(12)] + hanging(2))
    too_long = pipe.step([frame(arc(GRIPPER + [0, 8], 90.0, 0.0, 1.3 * LENGTH_PX))], 14 / FPS)
    assert not too_long.status.seen and too_long.reason == "longer than the cable"
    hidden = pipe.step([frame(arc(GRIPPER + [0, 8], 90.0, 0.0, 0.5 * LENGTH_PX))], 15 / FPS)
    assert not hidden.status.seen and hidden.reason == "shorter than the cable: its tip is hidden"
    # A little short (5 %, a faint tip): with a learned length the shortfall may be at either end, so the tip
    # is not measured; within 3 % the polyline's end is the tip.
    short = pipe.step([frame(arc(GRIPPER + [0, 8], 90.0, 0.0, 0.95 * LENGTH_PX))], 16 / FPS)
    assert not short.status.seen and short.reason == "shorter than the cable: its tip is hidden"
    near = pipe.step([frame(arc(GRIPPER + [0, 8], 90.0, 0.0, 0.99 * LENGTH_PX))], 17 / FPS)
    assert near.status is Status.MEASURED
    assert near.point[1] == pytest.approx(GRIPPER[1] + 8 + 0.99 * LENGTH_PX, abs=6)


def test_a_point_the_filter_rejects_is_not_reported_measured() -> None:
    from dyndlo_vision.tracking.params import FilterParams

    pipe = pixel_pipeline(filter=FilterParams(sigma_accel=0.01, reinit_speed=1e-6))
    run(pipe, [_swinging(k) for k in range(12)] + hanging(8))
    jump = pipe.step([frame(arc(GRIPPER + [0, 8], 60.0, 0.0))], 20 / FPS)
    assert jump.reason == "rejected by the filter's gate"
    assert jump.status is Status.PREDICTED and jump.point is None
    assert not np.allclose(jump.estimate.position[:2], arc(GRIPPER + [0, 8], 60.0, 0.0)[-1], atol=20)


def test_without_an_anchor_the_upper_end_is_held() -> None:
    pipe = pixel_pipeline(anchor=None)
    results = run(pipe, hanging(8))
    assert pipe.first_view_rule == "the upper cable end"
    check_truthful(results, hanging(8))


def _moving_curve(k: int) -> np.ndarray:
    """Frame k of a cable that sways, bends and drifts (up to ~10 px per frame)."""
    from dyndlo_vision.tracking.synthetic import s_curve

    t = k / 25.0
    return s_curve(
        u0=90 + 30 * np.sin(2.0 * t),
        u1=550 + 40 * np.sin(1.3 * t + 0.5),
        v0=240 + 50 * np.sin(3.0 * t),
        amp=100 * np.cos(2.5 * t),
        periods=0.9 + 0.3 * np.sin(1.7 * t),
        phase=0.8 * np.sin(2.2 * t),
    )


def _plain(curve: np.ndarray, k: int) -> np.ndarray:
    return render_cable(curve, SHAPE, thickness=6, background=(200, 200, 195), noise_sigma=4.0, seed=k)[0]


@pytest.mark.parametrize("use_anchor", [False, True])
def test_no_head_tail_flips_over_50_frames(use_anchor: bool) -> None:
    from dyndlo_vision.tracking.centerline import polyline_distance

    pipe = pixel_pipeline(_moving_curve(0)[0] if use_anchor else None)
    start, errors = None, []
    for k in range(50):
        curve = _moving_curve(k)
        cl = pipe.step([_plain(curve, k)], k / 25.0).views[0].centerline
        assert cl is not None and cl.visible.all(), f"frame {k}"
        first = 0 if np.hypot(*(cl.nodes_uv[0] - curve[0])) < np.hypot(*(cl.nodes_uv[0] - curve[-1])) else 1
        start = first if start is None else start  # without an anchor the first frame's rule picks an end
        assert first == start, f"flip at frame {k}"
        errors.append(polyline_distance(cl.nodes_uv, curve if start == 0 else curve[::-1]))
    assert start == 0 or not use_anchor
    assert np.mean(errors) < 1.5


def test_the_held_end_hidden_for_a_while_is_not_swapped() -> None:
    """The held end disappears behind an occluder for four frames: those frames are not identified (or right),
    and after them the held end is found again where it was, never at the tip."""
    from dyndlo_vision.tracking.synthetic import draw_occluder

    pipe = pixel_pipeline(_moving_curve(0)[0])
    for k in range(14):
        curve = _moving_curve(k)
        rgb = _plain(curve, k)
        if 4 <= k < 8:
            rgb = draw_occluder(rgb, (0, 0), (int(curve[0, 0]) + 40, 479))
        cl = pipe.step([rgb], k / 25.0).views[0].centerline
        if k >= 9:
            assert cl is not None, f"frame {k}: not found again"
        if cl is not None:
            assert np.hypot(*(cl.path_uv[0] - curve[0])) < np.hypot(*(cl.path_uv[0] - curve[-1])), (
                f"flip at {k}"
            )


# ------------------------------------------------------------------------------------------- identity


PARAMS = IdentityParams()


def test_orient_by_continuity_when_the_other_end_is_far() -> None:
    path = arc(np.array([100.0, 100.0]), 90.0, 0.0, 200)
    assert orient(path, np.array([102.0, 98.0]), 20.0, None, 10.0, PARAMS).held_at_start is True
    assert orient(path[::-1], np.array([102.0, 98.0]), 20.0, None, 10.0, PARAMS).held_at_start is False
    far = orient(path, np.array([300.0, 100.0]), 20.0, None, 10.0, PARAMS)
    assert far.held_at_start is None and far.reason == "held end not seen"


def test_orient_lets_registration_decide_between_ends_near_the_held_end_or_not_at_all() -> None:
    loop = arc(np.array([200.0, 100.0]), 90.0, 340.0, 300)  # the tip comes back near the start
    held = loop[0] + [1.0, 1.0]
    gap = float(np.hypot(*(loop[-1] - loop[0])))
    assert gap < 30.0
    blind = orient(loop, held, 40.0, None, 10.0, PARAMS)
    assert blind.held_at_start is None and blind.reason == "ends too close to tell apart"
    nodes = loop[np.linspace(0, len(loop) - 1, 20).astype(int)]
    assert orient(loop, held, 40.0, nodes, 10.0, PARAMS).held_at_start is True
    assert orient(loop[::-1], held, 40.0, nodes, 10.0, PARAMS).held_at_start is False


def test_orient_refuses_when_continuity_and_registration_disagree() -> None:
    path = arc(np.array([100.0, 100.0]), 90.0, 0.0, 200)
    reversed_nodes = path[np.linspace(len(path) - 1, 0, 20).astype(int)]
    out = orient(path, path[0], 20.0, reversed_nodes, 10.0, PARAMS)
    assert out.held_at_start is None and out.reason == "continuity and registration disagree"


def test_order_correlation_reads_the_direction_of_the_registered_nodes() -> None:
    path = arc(np.array([0.0, 0.0]), 0.0, 90.0, 200)
    nodes = path[np.linspace(0, len(path) - 1, 10).astype(int)]
    assert order_correlation(nodes, path, 5.0) == pytest.approx((1.0, 10))
    assert order_correlation(nodes[::-1], path, 5.0)[0] == pytest.approx(-1.0)
    assert order_correlation(nodes + 300.0, path, 5.0) == (0.0, 0)  # nothing registers


def test_held_end_gate_grows_while_unseen_within_its_limits() -> None:
    held = HeldEnd(PARAMS, px_per_m=500.0)
    held.update(np.array([100.0, 100.0]), 0.0)
    held.update(np.array([100.0, 100.0]), 0.04)
    gates = [held.gate(0.04 + dt, 2.0, 3000.0) for dt in (0.04, 0.08, 0.2)]
    assert gates[0] < gates[1] < gates[2]
    for dt, gate in zip((0.04, 0.08, 0.2), gates, strict=True):  # no faster than the gripper's top speed
        assert gate <= PARAMS.min_gate_px + PARAMS.max_speed_m_s * dt * 500.0 + 1e-9
    assert held.gate(0.04 + 0.2, 2.0, 300.0) == pytest.approx(0.5 * 300.0)  # at most half the cable
    assert not held.lost_at(0.4) and held.lost_at(0.5)


def test_bridged_and_interpolated_points() -> None:
    """Vaulting's P_DLO is the cable's middle. Where the tracker bridged a gap (the box in front of the
    cable), its nodes are unseen; the middle, with the cable seen on both sides, lies between them."""
    xyz = np.column_stack([np.linspace(0.4, 1.0, 7), np.zeros(7), np.linspace(0.2, 0.0, 7)])
    visible = np.array([True, True, False, False, False, True, True])
    nodes = np.where(visible[:, None], xyz, np.nan)
    for k in (2, 3, 4):
        np.testing.assert_allclose(bridged_point(nodes, visible, k / 6), xyz[k], atol=1e-12)
    assert bridged_point(nodes, visible, 1.0) is None  # the tip is never bridged
    assert point_on_nodes(nodes, visible, 3 / 6) is None
    np.testing.assert_allclose(point_on_nodes(nodes, visible, 0.5 / 6), 0.5 * (xyz[0] + xyz[1]))


# -------------------------------------------------------------------------------- the cable's length


def _swinging(k: int, length: float = LENGTH_PX) -> np.ndarray:
    """Frame k of a cable swinging gently about the vertical (a new pose every frame or two)."""
    return arc(GRIPPER + [0, 8], 90.0 + 25.0 * math.sin(k / 2.0), 30.0 * math.sin(k / 3.0), length)


def _hidden_beyond(curve: np.ndarray, share: float) -> np.ndarray:
    """The frame of ``curve`` with its far ``share`` painted over in the background's colour (a tip over a
    patch of its own colour)."""
    rgb = frame(curve)
    n = len(curve)
    rgb2, mask = render_cable(
        curve[int((1.0 - share) * n) :], SHAPE, thickness=8, background=(200, 200, 195), noise_sigma=0.0
    )
    rgb[mask] = (200, 200, 195)
    return rgb


def test_the_learned_length_is_the_longest_that_enough_frames_agree_on() -> None:
    """The tip is faint (its last 40 % unseen) in two frames of three: a length learned from most frames, or
    from their median, would put the tip at the cable's middle. The longest length that enough frames agree
    on is the cable's; the short frames are not measured."""
    pipe = pixel_pipeline()
    curves = [_swinging(k) for k in range(45)]
    results = []
    for k, c in enumerate(curves):
        rgb = frame(c) if k % 3 == 0 else _hidden_beyond(c, 0.4)
        results.append(pipe.step([rgb], k / FPS))
    check_truthful(results, curves)
    assert pipe.learned_length == pytest.approx(LENGTH_PX + 8, abs=8)
    assert sum(r.status.seen for r in results) >= 10


def test_a_few_frames_a_little_too_long_do_not_set_the_length() -> None:
    """Six frames of ninety-six run on past the tip by 6 % (a shadow, the gripper's blob): fewer than a tenth
    of the clean frames, they do not make the length, so the true tips after them are not continued past
    themselves."""
    pipe = pixel_pipeline()
    curves = [_swinging(k) for k in range(96)]
    drawn = [_swinging(k, 1.06 * LENGTH_PX) if 80 <= k < 86 else c for k, c in enumerate(curves)]
    results = run(pipe, drawn)
    check_truthful(results[86:], curves[86:])
    assert pipe.learned_length == pytest.approx(LENGTH_PX + 8, abs=6)


def test_a_cable_at_rest_is_one_pose_and_does_not_teach_its_length() -> None:
    """A cable hanging still with its far part unseen looks the same in every frame: a hundred such frames
    are one view of it, so its length is not learned from them, and nothing is measured until it moves."""
    pipe = pixel_pipeline()
    still = hanging(1)[0]
    results = [pipe.step([_hidden_beyond(still, 0.4)], k / FPS) for k in range(30)]
    assert pipe.learned_length is None
    assert not any(r.status.seen for r in results)
    assert results[-1].reason == "the cable's length is not known yet"


def test_a_longer_length_across_gaps_puts_the_learned_one_in_doubt() -> None:
    """Frames with the cable's middle unseen (a gap the centreline bridges) agree on a length longer than the
    one the frames without a gap show (only the cable's upper half is ever seen whole): that one is in doubt,
    and nothing is measured at the upper half's end."""
    pipe = pixel_pipeline()
    results, curves = [], []
    for k in range(40):
        curve = _swinging(k)
        rgb = frame(curve)
        n = len(curve)
        painted = curve[int(0.45 * n) : int(0.55 * n)] if k % 2 else curve[int(0.5 * n) :]
        _, mask = render_cable(painted, SHAPE, thickness=8, background=(200, 200, 195), noise_sigma=0.0)
        rgb[mask] = (200, 200, 195)
        results.append(pipe.step([rgb], k / FPS))
        curves.append(curve)
    check_truthful(results, curves)
    assert pipe.length_doubt and pipe.learned_length is None
    assert "the cable's length is in doubt: bridged frames show it longer" in pipe.reasons


def test_a_centreline_walked_down_one_strand_and_back_up_the_other_doubles_back() -> None:
    """A mask split along the cable (two strands 8 px apart, joined near the tip): the centreline runs down
    one and back up the other, and its end lies in the cable's middle. A cable that curls at its tip, or
    hangs straight, does not double back."""
    from types import SimpleNamespace

    from dyndlo_vision.tracking.pipeline import _doubles_back

    down = np.column_stack((np.full(200, 320.0), np.linspace(80.0, 280.0, 200)))
    up = np.column_stack((np.full(40, 328.0), np.linspace(280.0, 240.0, 40)))
    assert _doubles_back(SimpleNamespace(path_uv=np.vstack([down, up]), width_px=4.0))
    assert not _doubles_back(SimpleNamespace(path_uv=down, width_px=4.0))
    hook = arc(np.array([320.0, 80.0]), 90.0, 200.0, 260.0)  # curls round, 40 px across at the tip
    assert not _doubles_back(SimpleNamespace(path_uv=hook, width_px=4.0))
    wide = np.vstack([down, up + [30.0, 0.0]])  # the second strand 38 px away: another cable part, not a fold
    assert not _doubles_back(SimpleNamespace(path_uv=wide, width_px=4.0))


def test_a_cable_cut_ever_lower_below_the_gripper_does_not_drag_its_held_end_to_the_tip() -> None:
    """An occluder grows down from the gripper over the cable hanging still, then leaves. Each frame's cable
    starts a little lower than the last: a held end that followed it would end near the tip, which would then
    be taken for the held end, and the gripper reported as the tip."""
    pipe = pixel_pipeline(anchor=None)  # no gripper template: the cable alone tells where its held end is
    curves = [_swinging(k) for k in range(12)]
    results = run(pipe, curves)
    still = _swinging(12)
    n = len(still)
    for j, share in enumerate(np.linspace(0.05, 0.6, 7)):
        rgb = frame(still)
        _, mask = render_cable(
            still[: int(share * n)], SHAPE, thickness=8, background=(200, 200, 195), noise_sigma=0.0
        )
        rgb[mask] = (200, 200, 195)
        results.append(pipe.step([rgb], (12 + j) / FPS))
        curves.append(still)
    back = [_swinging(12 + 7 + k) for k in range(8)]
    results += [pipe.step([frame(c)], (19 + k) / FPS) for k, c in enumerate(back)]
    curves += back
    check_truthful(results, curves)


def test_a_held_end_below_a_slow_cable_is_not_measured() -> None:
    """The user clicked the cable's lower end (its tip) in the first frame of a cable hanging still: the held
    end's track follows that end, so the gripper would be reported as the tip. A cable upside down does not
    stay slow, so while it is slow such a frame is not measured. The first frame has no motion to judge: it
    trusts the click (measured: the gripper reported there, then never again)."""
    from dyndlo_vision.tracking.tracker import Plane

    from .helpers import look_at_camera

    cam = look_at_camera(eye=(0.05, -1.0, 0.35), target=(0.0, 0.0, 0.3))
    world = np.column_stack((np.zeros(200), np.zeros(200), np.linspace(0.55, 0.05, 200)))  # gripper on top
    uv = cam.project(world)
    config = PipelineConfig(SegmenterConfig("background"), plane=Plane(np.array([0.0, 1.0, 0.0]), 0.0),
                            cable_length_m=0.5)
    background = np.full((cam.height, cam.width, 3), (200, 200, 195), np.uint8)
    base, _ = build_segmenter(config.segmenter, background_image=background)
    view = build_view_segmenter(base, camera=cam, max_width_share=config.max_width_share,
                                max_width_ratio=config.max_width_ratio)
    pipe = CablePipeline(config, [cam], [view], [uv[-1]])  # the click on the tip
    results = []
    for k in range(12):
        rgb, _ = render_cable(uv, (cam.height, cam.width), thickness=4, background=(200, 200, 195),
                              noise_sigma=2.0, seed=k)
        results.append(pipe.step([rgb], k / FPS))
    for k, r in enumerate(results[1:], start=1):
        if r.status.seen:  # never the gripper: a measured point is at the true tip
            assert np.linalg.norm(r.point - world[-1]) < 0.02, f"frame {k}: {r.point} reported as the tip"
    assert "the held end is below the tip while the cable is slow" in pipe.reasons


def test_each_frame_reports_its_stage_times() -> None:
    """``track`` splits into segment, centreline, identity and lift, which add up to it (the loop's profile);
    the views' segmentation is timed around the segmenter's call, so a slow segmenter shows as ``segment``."""
    import time

    pipe = pixel_pipeline()
    view = pipe.views[0].segmenter
    inner = view._top

    def slow(rgb: np.ndarray) -> np.ndarray:
        time.sleep(0.02)
        return inner(rgb)

    view._top = slow
    stage = run(pipe, hanging(2))[-1].stage_ms
    assert set(stage) == {"track", "filter", "segment", "centreline", "identity", "lift"}
    assert all(v >= 0 for v in stage.values())
    assert stage["segment"] >= 20.0
    parts = stage["segment"] + stage["centreline"] + stage["identity"] + stage["lift"]
    assert parts == pytest.approx(stage["track"], abs=0.5)


def test_a_tip_that_looks_like_the_gripper_is_not_measured(monkeypatch: pytest.MonkeyPatch) -> None:
    """The last guard: should the ends' identity be fooled (here: the orientation forced the wrong way round
    once the cable's length is learned, in a frame where the gripper's template was not followed, so the
    length from the gripper does not give the swap away), a tip where the clicked gripper's template matches
    is not measured: the gripper is never reported as the tip."""
    from dyndlo_vision.tracking import pipeline as pipeline_module
    from dyndlo_vision.tracking.identity import GripperTemplate, Orientation

    whip = [arc(GRIPPER + [0, 8], 90.0 + 50 * math.sin(k / 3), 160 * math.sin(k / 2.5)) for k in range(25)]
    pipe = pixel_pipeline()
    run(pipe, hanging(4) + whip)
    assert pipe.learned_length is not None
    real_orient = pipeline_module.orient

    def swapped(*args: object, **kwargs: object) -> Orientation:
        o = real_orient(*args, **kwargs)
        return o if o.held_at_start is None else Orientation(not o.held_at_start, o.reason, o.registered)

    monkeypatch.setattr(pipeline_module, "orient", swapped)
    monkeypatch.setattr(GripperTemplate, "locate", lambda *args, **kwargs: None)
    curve = arc(GRIPPER + [0, 8], 90.0, 0.0)
    result = pipe.step([frame(curve)], 30 / FPS)
    assert result.reason == "the tip looks like the gripper"
    assert not result.status.seen and result.point is None
