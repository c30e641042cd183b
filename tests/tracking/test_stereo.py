"""Two-view cable geometry (tracking/stereo.py) against curves projected into two known cameras."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from dyndlo_vision.tracking.camera_model import PinholeCamera
from dyndlo_vision.tracking.centerline import Centerline
from dyndlo_vision.tracking.stereo import (
    StereoParams,
    essential_matrix,
    match_centerlines,
    nodes_by_arc_length,
    stereo_measurement,
    triangulate,
)
from dyndlo_vision.tracking.tracker import Measurement, lift_with_plane

from .helpers import look_at_camera

# Two cameras: one in front and raised, one above (the baseline in the y-z plane).
FRONT = look_at_camera(eye=(0.70, -1.7, 0.90), target=(0.70, 0.0, 0.40), f=580.0)
ABOVE = look_at_camera(eye=(0.70, -0.45, 1.7), target=(0.70, 0.0, 0.30), f=580.0)
HELD = np.array([0.4, 0.0, 0.5])


def arch(n: int = 400, sideways_m: float = 0.12) -> np.ndarray:
    """From ``HELD`` out along x, over an arch, down to the floor; its middle ``sideways_m`` off y = 0."""
    s = np.linspace(0.0, 1.0, n)
    return np.column_stack([0.4 + 0.6 * s, -sideways_m * np.sin(np.pi * s),
                            0.5 - 0.49 * s + 0.25 * np.sin(np.pi * s)])


def length(curve: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(curve, axis=0), axis=1).sum())


def stereo_nodes(curve: np.ndarray, n_nodes: int = 41, noise_px: float = 0.0, seed: int = 0,
                 params: StereoParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The nodes triangulated from the curve's projections (its first 2 % hidden by the gripper), and the
    truth's nodes, both by arc length with the true length."""
    rng = np.random.default_rng(seed)
    seen = curve[len(curve) // 50:]
    ua = FRONT.project(seen) + rng.normal(0.0, noise_px, (len(seen), 2))
    ub = ABOVE.project(seen) + rng.normal(0.0, noise_px, (len(seen), 2))
    points = match_centerlines(FRONT, ua, ABOVE, ub, curve[0], params)
    nodes, _ = nodes_by_arc_length(np.vstack([curve[0], points]), n_nodes, length(curve))
    truth, _ = nodes_by_arc_length(curve, n_nodes, length(curve))
    return nodes, truth


def test_triangulate_recovers_world_points_also_through_lens_distortion() -> None:
    distorted = look_at_camera(eye=(0.70, -0.45, 1.7), target=(0.70, 0.0, 0.30), f=580.0,
                               dist=(-0.2, 0.05, 0.001, -0.001, 0.0))
    rng = np.random.default_rng(1)
    points = rng.uniform([0.3, -0.2, 0.0], [1.1, 0.2, 0.8], (50, 3))
    got, gaps = triangulate(FRONT, FRONT.project(points), distorted, distorted.project(points))
    np.testing.assert_allclose(got, points, atol=1e-6)
    assert np.all(gaps < 1e-6)


def test_triangulate_reports_the_rays_gap_for_pixels_that_do_not_correspond() -> None:
    p = np.array([[0.7, 0.0, 0.3]])
    uv_b = ABOVE.project(p) + [[5.0, 0.0]]  # across the epipolar line (which runs about vertically here)
    _, gaps = triangulate(FRONT, FRONT.project(p), ABOVE, uv_b)
    assert gaps[0] > 1e-3


def test_essential_matrix_satisfies_the_epipolar_constraint() -> None:
    rng = np.random.default_rng(2)
    points = rng.uniform([0.3, -0.2, 0.0], [1.1, 0.2, 0.8], (20, 3))
    xa = np.column_stack([FRONT.normalized_coords(FRONT.project(points)), np.ones(20)])
    xb = np.column_stack([ABOVE.normalized_coords(ABOVE.project(points)), np.ones(20)])
    residual = np.einsum("ij,jk,ik->i", xb, essential_matrix(FRONT, ABOVE), xa)
    np.testing.assert_allclose(residual, 0.0, atol=1e-12)
    with pytest.raises(ValueError, match="optical centre"):
        essential_matrix(FRONT, FRONT)


def test_an_arch_that_leaves_the_plane_is_recovered_where_one_view_and_the_plane_are_not() -> None:
    curve = arch()
    nodes, truth = stereo_nodes(curve)
    middle = len(nodes) // 2
    assert np.linalg.norm(nodes[middle] - truth[middle]) < 0.002
    errors = np.linalg.norm(nodes - truth, axis=1)
    assert np.nanmax(errors[:-1]) < 0.003  # the last sample may be unmatched: the tip then is not seen
    # One view lifted onto y = 0 puts the middle 12 cm off: what the loop had for vaulting before.
    on_plane = lift_with_plane(FRONT.project(truth[middle:middle + 1]), FRONT,
                               (np.array([0.0, 1.0, 0.0]), 0.0))
    assert np.linalg.norm(on_plane[0] - truth[middle]) > 0.1


def test_with_independent_pixel_noise_smoothing_keeps_the_middle_within_millimetres() -> None:
    errors = [np.linalg.norm(np.subtract(*[a[20] for a in stereo_nodes(arch(), noise_px=0.5, seed=s,
                                                                       params=StereoParams(smooth=5))]))
              for s in range(5)]
    assert max(errors) < 0.005, errors


def test_unsmoothed_depth_noise_lengthens_the_cable_and_drags_its_far_nodes_in() -> None:
    """Why ``StereoParams.smooth``: without it, the far end's nodes move towards the held end."""
    curve = arch()
    far = [np.linalg.norm(np.subtract(*[a[36] for a in stereo_nodes(curve, noise_px=0.5, seed=s, params=p)]))
           for p in (StereoParams(smooth=1), StereoParams(smooth=5)) for s in range(3)]
    assert min(far[:3]) > 2 * max(far[3:]), far


def test_a_cable_folded_back_is_matched_to_the_run_that_crosses_the_epipolar_line_its_way() -> None:
    """Out along x at y = -0.1, straight across (nearly within an epipolar plane: skipped as ill-posed) and
    back along x at y = +0.1. Each epipolar line crosses both runs in the second view, and after the skipped
    stretch the wrong run's crossing is the nearer one in 3D; the two runs cross the line opposite ways."""
    t = np.linspace(0.0, 1.0, 300)
    down = np.column_stack([0.4 + 0 * t, -0.1 * t, 0.5 - 0.15 * t])
    out = np.column_stack([0.4 + 0.55 * t, -0.1 + 0 * t, 0.35 + 0.05 * t])
    across = np.linspace(out[-1], [0.9, 0.1, 0.4], 100)
    back = np.column_stack([0.9 - 0.45 * t, 0.1 + 0 * t, 0.4 - 0.1 * t])
    curve = np.vstack([down, out[1:], across[1:], back[1:]])
    seen = curve[len(curve) // 50:]
    points = match_centerlines(FRONT, FRONT.project(seen), ABOVE, ABOVE.project(seen), curve[0],
                               StereoParams(samples=160))
    off_cable = np.min(np.linalg.norm(points[:, None] - curve[None], axis=2), axis=1)
    assert len(points) > 100
    assert off_cable.max() < 0.01  # 58 mm when the sense of crossing is not checked
    nodes, truth = stereo_nodes(curve, params=StereoParams(samples=160))
    assert np.nanmax(np.linalg.norm(nodes - truth, axis=1)) < 0.04  # 102 mm unchecked


def test_nodes_by_arc_length_follow_the_closed_form_on_a_straight_cable() -> None:
    line = np.column_stack([np.linspace(0.0, 1.0, 11), np.zeros(11), np.zeros(11)])
    nodes, visible = nodes_by_arc_length(line, 7, cable_length_m=1.2)
    expected = np.arange(7) * 1.2 / 6
    assert visible.tolist() == (expected <= 1.0).tolist()
    np.testing.assert_allclose(nodes[visible, 0], expected[visible], atol=1e-12)
    assert np.all(np.isnan(nodes[~visible]))
    nodes, visible = nodes_by_arc_length(line, 5)
    assert visible.all()
    np.testing.assert_allclose(nodes[:, 0], [0.0, 0.25, 0.5, 0.75, 1.0], atol=1e-12)
    with pytest.raises(ValueError, match="cable_length_m"):
        nodes_by_arc_length(line, 5, cable_length_m=0.0)
    with pytest.raises(ValueError, match="n_nodes"):
        nodes_by_arc_length(line, 1)


def _measurement(curve: np.ndarray | None, camera: object, n: int = 21) -> Measurement:
    if curve is None:
        return Measurement(np.full((n, 3), np.nan), np.full((n, 2), np.nan), np.zeros(n, bool), 0.5,
                           Centerline(np.full((n, 2), np.nan), np.zeros(n, bool), 0.0))
    uv = camera.project(curve)  # type: ignore[attr-defined]
    nodes = uv[np.linspace(0, len(uv) - 1, n).astype(int)]
    return Measurement(np.full((n, 3), np.nan), nodes, np.ones(n, bool), 0.5,
                       Centerline(nodes, np.ones(n, bool), 100.0, path_uv=uv))


def test_stereo_measurement_gives_3d_nodes_and_their_pixels_in_the_first_view() -> None:
    curve = arch()
    meas = stereo_measurement(_measurement(curve[8:], FRONT), FRONT, _measurement(curve[8:], ABOVE), ABOVE,
                              curve[0], cable_length_m=length(curve))
    truth, _ = nodes_by_arc_length(curve, 21, length(curve))
    assert meas.t_capture == 0.5
    assert meas.visible[:-1].all()
    np.testing.assert_allclose(meas.nodes_xyz[meas.visible], truth[meas.visible], atol=0.003)
    np.testing.assert_allclose(meas.nodes_uv[meas.visible], FRONT.project(meas.nodes_xyz[meas.visible]))
    assert meas.point(10) is not None


def test_stereo_measurement_sees_nothing_when_either_view_does() -> None:
    curve = arch()
    for a, b in ((curve, None), (None, curve)):
        meas = stereo_measurement(_measurement(a, FRONT), FRONT, _measurement(b, ABOVE), ABOVE, curve[0])
        assert not meas.visible.any()
        assert meas.point(10) is None


@pytest.mark.parametrize("bad", [dict(samples=1), dict(min_crossing_deg=90.0), dict(max_step_m=0.0),
                                 dict(max_ray_gap_m=-1.0), dict(smooth=2), dict(smooth=0)])
def test_stereo_params_refuse_bad_values_by_name(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(bad))):
        StereoParams(**bad)  # type: ignore[arg-type]


def test_nodes_past_where_the_second_view_loses_the_cable_are_not_seen_not_stretched() -> None:
    """The second view sees the first 70 % of the cable only: the nodes along that part keep their material
    points (spaced by the known length), and those past it are not seen."""
    curve = arch()
    cut = int(0.7 * len(curve))
    meas = stereo_measurement(_measurement(curve[8:], FRONT), FRONT, _measurement(curve[8:cut], ABOVE), ABOVE,
                              curve[0], cable_length_m=length(curve))
    truth, _ = nodes_by_arc_length(curve, 21, length(curve))
    assert 12 <= np.count_nonzero(meas.visible) <= 14 and not meas.visible[15:].any()
    np.testing.assert_allclose(meas.nodes_xyz[meas.visible], truth[meas.visible], atol=0.003)


def test_a_world_point_has_the_same_epipolar_plane_angle_in_both_views() -> None:
    from dyndlo_vision.tracking.stereo import _pencil_angle

    curve = arch()
    np.testing.assert_allclose(_pencil_angle(FRONT, ABOVE, FRONT.project(curve)),
                               _pencil_angle(FRONT, ABOVE, ABOVE.project(curve), second=True), atol=1e-9)


def test_matching_resumes_past_a_stretch_the_second_view_does_not_see() -> None:
    """A third of the cable is a bridged gap in the second view (an occluder): nothing is matched there, and
    past it the cable goes on farther than one step from the last match; the bound grows with the samples
    skipped, so the rest is matched (with a fixed bound nothing after the gap was)."""
    curve = arch()
    seen = curve[8:]
    ub = ABOVE.project(seen)
    hidden = np.zeros(len(seen) - 1, dtype=bool)
    hidden[len(seen) // 3 : 2 * len(seen) // 3] = True
    params = StereoParams(max_step_m=0.05)
    points = match_centerlines(FRONT, FRONT.project(seen), ABOVE, ub, curve[0], params,
                               path_b_visible=~hidden)
    nodes, visible = nodes_by_arc_length(np.vstack([curve[0], points]), 41, length(curve))
    truth, _ = nodes_by_arc_length(curve, 41, length(curve))
    assert visible[:40].all()
    errors = np.linalg.norm(nodes - truth, axis=1)
    # Before the gap exact; past it about 1 cm, the gap having been bridged straight.
    assert errors[:11].max() < 0.003 and errors[28:40].max() < 0.02, errors.round(4)


# Hand-computed cases of the parts: triangulation, the visible segments, the resampling, the smoothing.

def _axis_camera(eye: tuple[float, float, float], R: np.ndarray) -> PinholeCamera:
    """A camera at ``eye`` whose rotation has exact entries (0, +-1), so its centre is exact."""
    K = np.array([[580.0, 0.0, 319.5], [0.0, 580.0, 239.5], [0.0, 0.0, 1.0]])
    return PinholeCamera(640, 480, K, np.zeros(0), R, -R @ np.asarray(eye, float))


CENTRE_PX = [[319.5, 239.5]]  # the principal point: the ray along the optical axis


def test_triangulate_meets_at_a_point_half_a_metre_from_the_first_camera() -> None:
    p = FRONT.center + 0.5 * (np.array([0.70, 0.0, 0.40]) - FRONT.center) / np.linalg.norm(
        np.array([0.70, 0.0, 0.40]) - FRONT.center)
    got, gaps = triangulate(FRONT, FRONT.project(p), ABOVE, ABOVE.project(p))
    np.testing.assert_allclose(got[0], p, atol=1e-9)
    assert gaps[0] < 1e-9


def test_triangulate_refuses_a_meeting_point_behind_either_camera() -> None:
    """A looks along +y from the origin, B from (1, 0, 0) at a point: both axes meet at that point."""
    a = look_at_camera(eye=(0.0, 0.0, 0.0), target=(0.0, 1.0, 0.0))
    for target, expected in (((0.0, 1.0, 0.0), True), ((0.0, -1.0, 0.0), False)):  # in front of A, behind A
        b = look_at_camera(eye=(1.0, 0.0, 0.0), target=target)
        for first, second in ((a, b), (b, a)):
            got, gaps = triangulate(first, CENTRE_PX, second, CENTRE_PX)
            if expected:
                np.testing.assert_allclose(got[0], target, atol=1e-12)
                assert gaps[0] < 1e-12
            else:
                assert np.all(np.isnan(got)) and np.isnan(gaps[0])


def test_triangulate_gives_nan_without_a_warning_for_parallel_rays() -> None:
    a = _axis_camera((0.0, 0.0, 0.0), np.eye(3))
    b = _axis_camera((0.1, 0.0, 0.0), np.eye(3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got, gaps = triangulate(a, CENTRE_PX, b, CENTRE_PX)
    assert np.all(np.isnan(got)) and np.isnan(gaps[0])


def test_essential_matrix_holds_for_rigs_with_baselines_along_any_direction() -> None:
    side = look_at_camera(eye=(1.6, -1.2, 1.1), target=(0.70, 0.0, 0.30), f=580.0)
    near = look_at_camera(eye=(1.0, -1.7, 0.9), target=(0.70, 0.0, 0.40), f=580.0)  # 0.3 m from FRONT
    rng = np.random.default_rng(3)
    points = rng.uniform([0.3, -0.2, 0.0], [1.1, 0.2, 0.8], (20, 3))
    for cam_b in (side, near):
        xa = np.column_stack([FRONT.normalized_coords(FRONT.project(points)), np.ones(20)])
        xb = np.column_stack([cam_b.normalized_coords(cam_b.project(points)), np.ones(20)])
        residual = np.einsum("ij,jk,ik->i", xb, essential_matrix(FRONT, cam_b), xa)
        np.testing.assert_allclose(residual, 0.0, atol=1e-12)


def test_segments_seen_are_the_visible_ones_between_finite_points() -> None:
    from dyndlo_vision.tracking.stereo import _segments_seen

    path = np.array([[0.0, 0.0], [1.0, 0.0], [np.nan, np.nan], [3.0, 0.0], [4.0, 0.0]])
    assert _segments_seen(path, None, "v").tolist() == [True, False, False, True]
    assert _segments_seen(path[[0, 1, 3, 4]], None, "v").tolist() == [True, True, True]
    visible = [False, True, True, True]
    for given in (visible, np.array(visible).reshape(-1, 1), np.array(visible, dtype=float)):
        assert _segments_seen(path, given, "v").tolist() == [False, False, False, True]


def test_match_centerlines_names_a_visibility_of_the_wrong_length() -> None:
    path = np.array([[300.0, 200.0], [320.0, 210.0], [340.0, 220.0], [360.0, 230.0], [380.0, 240.0]])
    for name in ("path_a_visible", "path_b_visible"):
        with pytest.raises(ValueError) as info:
            match_centerlines(FRONT, path, ABOVE, path, HELD, **{name: [True, True, True]})
        assert str(info.value) == f"{name} has 3 entries for a path of 5 points; expected 4 (one per segment)"


def test_samples_on_seen_are_spaced_by_arc_length_over_the_seen_segments_only() -> None:
    from dyndlo_vision.tracking.stereo import _samples_on_seen

    # 4 px seen, 3 px unseen (skipped), 4 px seen: 8 px in all, so a sample every 2 px; the one at 4 px is
    # where the second seen segment starts.
    path = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [8.0, 3.0]])
    np.testing.assert_allclose(_samples_on_seen(path, np.array([True, False, True]), 5),
                               [[0, 0], [2, 0], [4, 3], [6, 3], [8, 3]], atol=1e-12)
    # Segments shorter than a pixel, and an unseen last segment: the last sample ends the seen part.
    path = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.25], [0.5, 2.0]])
    np.testing.assert_allclose(_samples_on_seen(path, np.array([True, True, False]), 4),
                               [[0, 0], [0.25, 0], [0.5, 0], [0.5, 0.25]], atol=1e-12)


def test_moving_average_shrinks_its_window_symmetrically_at_the_ends() -> None:
    from dyndlo_vision.tracking.stereo import _moving_average

    x = np.arange(7.0) ** 2
    points = np.column_stack([x, -x, np.zeros(7)])
    expected = [0.0, 5 / 3, 6.0, 11.0, 18.0, 77 / 3, 36.0]
    np.testing.assert_allclose(_moving_average(points, 5)[:, 0], expected, atol=1e-12)
    np.testing.assert_allclose(_moving_average(points, 5)[:, 1], -np.array(expected), atol=1e-12)
    np.testing.assert_allclose(_moving_average(points[2:5], 3)[:, 0], [4.0, 29 / 3, 16.0], atol=1e-12)
    np.testing.assert_allclose(_moving_average(points, 3)[:, 0],
                               [0.0, 5 / 3, 14 / 3, 29 / 3, 50 / 3, 77 / 3, 36.0], atol=1e-12)


# Matching, on cables whose 3D points are known by construction.

# A straight cable along x: parallel to FRONT's image plane, so samples evenly spaced in that image are evenly
# spaced along it (every 0.1 m with 5 samples). The second view's path runs 5 cm past either end.
P0, P1 = np.array([0.5, 0.0, 0.4]), np.array([0.9, 0.0, 0.4])
STRAIGHT_A = FRONT.project([P0, P1])
STRAIGHT_B = ABOVE.project([P0 - [0.05, 0.0, 0.0], P1 + [0.05, 0.0, 0.0]])
STRAIGHT_5 = P0 + np.linspace(0.0, 1.0, 5)[:, None] * (P1 - P0)


def test_a_straight_cable_seen_as_two_points_in_each_view_is_matched_at_every_sample_in_order() -> None:
    for held in (P0, P0.reshape(3, 1)):
        points = match_centerlines(FRONT, STRAIGHT_A, ABOVE, STRAIGHT_B, held, StereoParams(samples=5))
        np.testing.assert_allclose(points, STRAIGHT_5, atol=1e-9)
    # The second view's path with a vertex between the ends (at x = 0.62): the crossings of either segment.
    path_b = ABOVE.project([P0 - [0.05, 0.0, 0.0], [0.62, 0.0, 0.4], P1 + [0.05, 0.0, 0.0]])
    points = match_centerlines(FRONT, STRAIGHT_A, ABOVE, path_b, P0, StereoParams(samples=5))
    np.testing.assert_allclose(points, STRAIGHT_5, atol=1e-9)


def test_a_first_sample_farther_than_one_step_from_the_held_end_is_skipped_and_the_rest_matched() -> None:
    held = P0 + [0.0, 0.0, 0.15]  # 0.15 m from the first sample, 0.18 m from the second (two steps: 0.24 m)
    params = StereoParams(samples=5, max_step_m=0.12)
    points = match_centerlines(FRONT, STRAIGHT_A, ABOVE, STRAIGHT_B, held, params)
    np.testing.assert_allclose(points, STRAIGHT_5[1:], atol=1e-9)


def test_nothing_is_matched_without_two_points_or_a_seen_segment_in_either_view() -> None:
    cases = [((np.zeros((0, 2)), STRAIGHT_B), {}), ((STRAIGHT_A, np.zeros((0, 2))), {}),
             ((STRAIGHT_A[:1], STRAIGHT_B), {}), ((STRAIGHT_A, STRAIGHT_B[:1]), {}),
             ((STRAIGHT_A, STRAIGHT_B), dict(path_a_visible=[False])),
             ((STRAIGHT_A, STRAIGHT_B), dict(path_b_visible=[False]))]
    for (a, b), visible in cases:
        points = match_centerlines(FRONT, a, ABOVE, b, P0, StereoParams(samples=5), **visible)
        assert points.shape == (0, 3)


def crossing_paths(p: np.ndarray, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """A short path through ``p``'s pixel in FRONT (along the image of +x), and one through its pixel in ABOVE
    that crosses its epipolar line at ``angle_deg``, towards the side the image of +x goes to."""
    ua = FRONT.project([p, p + [0.01, 0.0, 0.0]])
    ub = ABOVE.project([p, p + [0.01, 0.0, 0.0], p + 0.1 * (p - FRONT.center)])  # the last: along p's ray
    along = (ub[2] - ub[0]) / np.linalg.norm(ub[2] - ub[0])
    across = np.array([-along[1], along[0]])
    across *= np.sign(across @ (ub[1] - ub[0]))
    d = np.cos(np.radians(angle_deg)) * along + np.sin(np.radians(angle_deg)) * across
    da = (ua[1] - ua[0]) / np.linalg.norm(ua[1] - ua[0])
    return np.array([ua[0] - 40 * da, ua[0] + 40 * da]), np.array([ub[0] - 20 * d, ub[0] + 20 * d])


@pytest.mark.parametrize("p", [(1.1, 0.1, 0.0), (1.0, 0.1, 0.2)])
def test_a_crossing_is_used_from_min_crossing_deg_on_and_only_the_way_the_first_view_does(p: tuple) -> None:
    """The middle of 3 samples is ``p``'s pixel; the second path crosses its epipolar line at ``p``'s."""
    p = np.array(p)
    for angle, min_crossing_deg, used in ((12.2, 12.0, True), (11.8, 12.0, False), (-12.2, 12.0, False),
                                          (-30.0, 12.0, False), (11.8, 0.0, True), (2.0, 0.0, True)):
        path_a, path_b = crossing_paths(p, angle)
        params = StereoParams(samples=3, min_crossing_deg=min_crossing_deg)
        points = match_centerlines(FRONT, path_a, ABOVE, path_b, p, params)
        if used:
            np.testing.assert_allclose(points, [p], atol=1e-9)
        else:
            assert points.shape == (0, 3), angle


def polyline(*corners: tuple[float, float, float], n: int = 150) -> np.ndarray:
    """Straight runs between the corners, ``n`` points each."""
    runs = [np.linspace(a, b, n)[1:] for a, b in zip(corners[:-1], corners[1:], strict=False)]
    return np.vstack([np.asarray(corners[0], float)[None], *runs])


def test_of_two_crossings_the_same_way_the_one_nearer_the_previous_match_is_taken() -> None:
    """Out along x at y = -0.25, back at y = 0, out again at y = 0.1 (on a table, z = 0.3): each epipolar line
    of the third run crosses the first run the same way too (its crossing comes first along the path), and
    the third run's own crossing is the one near the previous match."""
    curve = polyline((0.45, -0.25, 0.3), (0.9, -0.25, 0.3), (0.9, 0.0, 0.3), (0.6, 0.0, 0.3), (0.6, 0.1, 0.3),
                     (1.0, 0.1, 0.3))
    params = StereoParams(samples=120, max_step_m=0.05)
    points = match_centerlines(FRONT, FRONT.project(curve), ABOVE, ABOVE.project(curve), curve[0], params)
    off_cable = np.min(np.linalg.norm(points[:, None] - curve[None], axis=2), axis=1)
    assert off_cable.max() < 0.015
    nodes, visible = nodes_by_arc_length(np.vstack([curve[0], points]), 41, length(curve))
    truth, _ = nodes_by_arc_length(curve, 41, length(curve))
    assert visible[:40].all()
    assert np.linalg.norm(nodes[:40] - truth[:40], axis=1).max() < 0.02


DOWN = np.diag([1.0, -1.0, -1.0])  # looking straight down, image x along world x
DOWN_ROLLED = np.diag([-1.0, 1.0, -1.0])  # the same, turned upside down (half a turn about its axis)


@pytest.mark.parametrize("eye_a, eye_b", [((-0.2, 0.0, 1.2), (0.2, 0.0, 1.2)),
                                          ((0.0, -0.2, 1.2), (0.0, 0.2, 1.2)),
                                          ((-0.25, -0.25, 1.2), (0.25, 0.25, 1.2)),
                                          ((-0.25, 0.0, 1.0), (0.25, 0.0, 1.5))])
def test_rigs_looking_down_with_baselines_along_axes_and_diagonals_match_a_cable(eye_a: tuple,
                                                                                   eye_b: tuple) -> None:
    """Overhead rigs whose baseline is exactly along x, y, (1, 1, 0) or (1, 0, 1), the second camera upside
    down; a cable arching across the baseline (0.5 m, up to 15 cm high) is matched within millimetres."""
    a, b = _axis_camera(eye_a, DOWN), _axis_camera(eye_b, DOWN_ROLLED)
    baseline = np.subtract(eye_b, eye_a) * [1.0, 1.0, 0.0]
    baseline /= np.linalg.norm(baseline)
    across = np.cross([0.0, 0.0, 1.0], baseline)
    s = np.linspace(0.0, 1.0, 300)[:, None]
    curve = (s - 0.5) * 0.5 * across + np.sin(np.pi * s) * (0.05 * baseline + [0.0, 0.0, 0.15]) + [0, 0, 0.1]
    points = match_centerlines(a, a.project(curve), b, b.project(curve), curve[0])
    assert len(points) >= 60
    assert np.min(np.linalg.norm(points[:, None] - curve[None], axis=2), axis=1).max() < 0.002


def bridged(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The path with its middle third replaced by a straight bridge (a tracker's guess across an occluder),
    and its per-segment visibility."""
    out, m = uv.copy(), len(uv)
    i, j = m // 3, 2 * m // 3
    out[i:j + 1] = np.linspace(uv[i], uv[j], j - i + 1)
    visible = np.ones(m - 1, dtype=bool)
    visible[i:j] = False
    return out, visible


def test_nothing_is_matched_on_a_bridged_gap_in_either_view() -> None:
    curve = arch()
    ua, ub = FRONT.project(curve[8:]), ABOVE.project(curve[8:])
    (ua_bridged, va), (ub_bridged, vb) = bridged(ua), bridged(ub)
    for path_a, path_b, visible in ((ua_bridged, ub, dict(path_a_visible=va)),
                                    (ua, ub_bridged, dict(path_b_visible=vb))):
        points = match_centerlines(FRONT, path_a, ABOVE, path_b, curve[0], **visible)
        assert len(points) > 30
        # Off the cable by 25 mm (bridge in the first view) and 7 mm (in the second) when the bridge is used.
        assert np.min(np.linalg.norm(points[:, None] - curve[None], axis=2), axis=1).max() < 0.003


def test_a_crossing_whose_rays_miss_by_more_than_max_ray_gap_m_is_not_used() -> None:
    """A strongly distorted second view whose path is only the two ends of a long straight cable: the chord
    between them is off the cable's (curved) image by pixels, across the epipolar lines, so the rays through
    the crossings miss each other by up to centimetres."""
    distorted = look_at_camera(eye=(0.70, -0.45, 1.7), target=(0.70, 0.0, 0.30), f=580.0,
                               dist=(-0.3, 0.1, 0.0, 0.0, 0.0))
    p0, p1 = np.array([0.1, -0.2, 0.1]), np.array([0.5, 0.5, 0.1])
    line = np.linspace(p0, p1, 200)
    ends = distorted.project([p0 - 0.05 * (p1 - p0), p1 + 0.05 * (p1 - p0)])
    used = [len(match_centerlines(FRONT, FRONT.project(line), distorted, ends, p0,
                                  StereoParams(samples=9, max_ray_gap_m=gap))) for gap in (0.01, 0.1)]
    assert 3 <= used[0] <= 7 and used[1] == 9, used


# Nodes by arc length, the parameters, and the measurement from two views.

def test_nodes_by_arc_length_on_two_points_and_with_two_nodes() -> None:
    segment = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    nodes, visible = nodes_by_arc_length(segment, 5)
    assert visible.all()
    np.testing.assert_allclose(nodes[:, 0], [0.0, 0.5, 1.0, 1.5, 2.0], atol=1e-12)
    nodes, visible = nodes_by_arc_length(segment, 5, cable_length_m=4.0)
    assert visible.tolist() == [True, True, True, False, False]
    np.testing.assert_allclose(nodes[:3, 0], [0.0, 1.0, 2.0], atol=1e-12)
    nodes, visible = nodes_by_arc_length(np.column_stack([np.linspace(0.0, 1.0, 11), np.zeros((11, 2))]), 2)
    assert visible.all()
    np.testing.assert_allclose(nodes, [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], atol=1e-12)


def test_nodes_by_arc_length_of_fewer_than_two_points_are_not_seen() -> None:
    for points in (np.zeros((0, 3)), [[1.0, 2.0, 3.0]]):
        nodes, visible = nodes_by_arc_length(points, 4)
        assert visible.dtype == bool and visible.tolist() == [False] * 4
        assert nodes.shape == (4, 3) and np.all(np.isnan(nodes[~visible]))


@pytest.mark.parametrize("bad", [dict(smooth=-1), dict(smooth=3.0), dict(samples=2.0)])
def test_stereo_params_refuse_negative_and_non_int_counts(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(bad))):
        StereoParams(**bad)  # type: ignore[arg-type]


def test_two_samples_and_no_least_crossing_angle_are_allowed() -> None:
    params = StereoParams(samples=2, min_crossing_deg=0.0, max_step_m=0.5)
    points = match_centerlines(FRONT, STRAIGHT_A, ABOVE, STRAIGHT_B, P0, params)
    np.testing.assert_allclose(points, [P0, P1], atol=1e-9)


def _seen_nowhere(n: int = 21) -> Measurement:
    return Measurement(np.full((n, 3), np.nan), np.full((n, 2), np.nan), np.zeros(n, bool), 0.5, None)


def test_stereo_measurement_sees_nothing_without_a_centreline_or_a_visible_node_in_either_view() -> None:
    curve = arch()
    seen = _measurement(curve[8:], FRONT), _measurement(curve[8:], ABOVE)
    # A centreline with its path but no visible node (the tracker did not trust it).
    hidden = [Measurement(m.nodes_xyz, m.nodes_uv, m.visible, 0.5,
                          Centerline(m.nodes_uv, np.zeros(21, bool), 100.0, path_uv=m.centerline.path_uv))
              for m in seen]
    cases = [(_seen_nowhere(), seen[1], None), (seen[0], _seen_nowhere(), None),
             (hidden[0], seen[1], None), (seen[0], hidden[1], None),
             # Seen in both, but nothing matched (farther than a step from the held end at every sample).
             (seen[0], seen[1], StereoParams(max_step_m=0.001))]
    for meas_a, meas_b, params in cases:
        meas = stereo_measurement(meas_a, FRONT, meas_b, ABOVE, curve[0] + [0.0, 0.0, 0.05], params=params)
        assert meas.nodes_xyz.shape == (21, 3) and np.all(np.isnan(meas.nodes_xyz))
        assert meas.nodes_uv.shape == (21, 2) and np.all(np.isnan(meas.nodes_uv))
        assert meas.visible.dtype == bool and not meas.visible.any()
        assert meas.t_capture == 0.5 and meas.centerline is meas_a.centerline


def _straight_measurement(uv: np.ndarray, n: int = 5) -> Measurement:
    return Measurement(np.full((n, 3), np.nan), np.full((n, 2), np.nan), np.ones(n, bool), 0.25,
                       Centerline(np.full((n, 2), np.nan), np.ones(n, bool), 100.0, path_uv=uv))


def test_stereo_measurement_spreads_the_nodes_to_a_single_matched_point_with_its_params() -> None:
    """With 5 samples 0.1 m apart and steps of at most 0.05 m, only the first sample (2 cm from the held end)
    is matched: the nodes spread from the held end to it. With the default 64 samples the whole cable is."""
    held = P0 - [0.02, 0.0, 0.0]
    meas_a = _straight_measurement(STRAIGHT_A)
    meas = stereo_measurement(meas_a, FRONT, _straight_measurement(STRAIGHT_B), ABOVE, held.reshape(3, 1),
                              params=StereoParams(samples=5, max_step_m=0.05))
    expected = held + np.linspace(0.0, 0.02, 5)[:, None] * [1.0, 0.0, 0.0]
    assert meas.visible.all()
    np.testing.assert_allclose(meas.nodes_xyz, expected, atol=1e-9)
    np.testing.assert_allclose(meas.nodes_uv, FRONT.project(expected), atol=1e-6)
    assert meas.t_capture == 0.25 and meas.centerline is meas_a.centerline


def hidden_stretch(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A tenth of the path (40 % to 50 %) guessed 15 px off (a bridge across an occluder), not visible."""
    out, m = uv.copy(), len(uv)
    i, j = 4 * m // 10, m // 2
    out[i + 1:j] += [0.0, 15.0]
    visible = np.ones(m - 1, dtype=bool)
    visible[i:j] = False
    return out, visible


def test_stereo_measurement_matches_nothing_on_either_centrelines_bridged_stretch() -> None:
    curve = arch()
    truth, _ = nodes_by_arc_length(curve, 21, length(curve))
    ua, ub = FRONT.project(curve[8:]), ABOVE.project(curve[8:])
    for (path_a, visible_a), (path_b, visible_b) in (
            (hidden_stretch(ua), (ub, np.ones(len(ub) - 1, bool))),
            ((ua, np.ones(len(ua) - 1, bool)), hidden_stretch(ub))):
        views = [Measurement(np.full((21, 3), np.nan), np.full((21, 2), np.nan), np.ones(21, bool), 0.5,
                             Centerline(path[::20][:21], np.ones(21, bool), 100.0, path_uv=path,
                                        path_visible=visible))
                 for path, visible in ((path_a, visible_a), (path_b, visible_b))]
        meas = stereo_measurement(views[0], FRONT, views[1], ABOVE, curve[0], cable_length_m=length(curve))
        assert meas.visible[:20].all()
        # 4 to 8 cm off past the stretch when its guessed pixels are matched.
        assert np.linalg.norm(meas.nodes_xyz[:20] - truth[:20], axis=1).max() < 0.005
