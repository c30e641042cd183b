"""Two-view cable geometry (tracking/stereo.py) against curves projected into two known cameras."""

from __future__ import annotations

import numpy as np
import pytest

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
