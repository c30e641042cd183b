"""Tests of dyndlo_vision.tracking.tracker: 3D lifting of centreline nodes."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.tracking.camera_model import PinholeCamera
from dyndlo_vision.tracking.centerline import extract_centerline
from dyndlo_vision.tracking.segmentation import BackgroundSegmenter
from dyndlo_vision.tracking.synthetic import render_cable
from dyndlo_vision.tracking.tracker import Measurement, Plane, lift_with_depth, lift_with_plane

from .helpers import down_camera


def _planar_scene(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """A 3D S-shaped cable on the world plane z = 0 and its image."""
    s = np.linspace(0, 1, 400)
    xyz = np.column_stack((-0.35 + 0.7 * s, 0.12 * np.sin(2 * np.pi * s), np.zeros_like(s)))
    uv = camera.project(xyz)
    rgb, _ = render_cable(uv, thickness=6)
    return xyz, rgb


def test_lift_with_plane_recovers_3d_curve(camera: PinholeCamera) -> None:
    xyz, rgb = _planar_scene(camera)
    cl = extract_centerline(BackgroundSegmenter()(rgb), 30, anchor_uv=camera.project(xyz[:1])[0])
    nodes = lift_with_plane(cl.nodes_uv, camera, Plane(np.array([0, 0, 1.0]), 0.0), cl.visible)
    meas = Measurement(nodes, cl.nodes_uv, cl.visible, 0.0, cl)
    assert meas.visible.all()
    # Mean distance of the lifted nodes to the true 3D curve: sub-millimetre at ~1.4 m.
    d = np.min(np.linalg.norm(meas.nodes_xyz[:, None] - xyz[None], axis=2), axis=1)
    assert d.mean() < 1e-3 and d.max() < 3e-3
    assert np.linalg.norm(meas.point(-1) - xyz[-1]) < 5e-3
    np.testing.assert_allclose(meas.nodes_xyz[:, 2], 0.0, atol=1e-12)


def test_lift_with_plane_puts_what_lies_on_the_floor_off_the_plane_on_the_floor() -> None:
    """Vaulting's cable starts on the floor, 16 cm in front of the motion plane y = 0: lifted onto the plane
    alone it came out 10 cm under the floor. With the floor, points on it come back exactly; points in the
    plane above the floor are unchanged."""
    from .helpers import look_at_camera

    camera = look_at_camera(eye=(0.7, -1.5, 0.85), target=(0.7, 0.0, 0.3))
    plane, floor = Plane(np.array([0.0, 1.0, 0.0]), 0.0), Plane(np.array([0.0, 0.0, 1.0]), -0.01)
    on_floor = np.array([[0.45, -0.164, 0.01], [0.6, -0.1, 0.01]])  # in front of the plane
    in_plane = np.array([[0.5, 0.0, 0.3], [0.8, 0.0, 0.02]])
    behind = np.array([[0.9, 0.05, 0.01]])  # on the floor behind the plane: its ray meets the plane first
    uv = camera.project(np.vstack([on_floor, in_plane, behind]))
    plain = lift_with_plane(uv, camera, plane)
    assert np.all(plain[:2, 2] < -0.01)  # under the floor without it
    lifted = lift_with_plane(uv, camera, plane, floor=floor)
    np.testing.assert_allclose(lifted[:2], on_floor, atol=1e-9)
    np.testing.assert_allclose(lifted[2:4], in_plane, atol=1e-9)
    assert plain[4, 2] > 0.01 and np.array_equal(lifted[4], plain[4])  # above the floor: the plane's answer


def test_lift_with_depth_matches_plane(camera: PinholeCamera) -> None:
    h, w = camera.height, camera.width
    vv, uu = np.mgrid[0:h, 0:w]
    uv = np.column_stack((uu.ravel(), vv.ravel())).astype(float)
    pts = camera.intersect_plane(uv, [0, 0, 1.0], 0.0)
    depth = camera.world_to_camera(pts)[:, 2].reshape(h, w)
    nodes = np.array([[300.0, 200.0], [320.4, 260.6], [100.0, 400.0], [np.nan, np.nan]])
    lifted = lift_with_depth(nodes, depth, camera)
    expected = lift_with_plane(nodes, camera, Plane(np.array([0, 0, 1.0]), 0.0))
    np.testing.assert_allclose(lifted[:3], expected[:3], atol=2e-3)
    assert np.isnan(lifted[3]).all()
    # Invalid depth (0, NaN) and invisible nodes give NaN rows.
    bad = depth.copy()
    bad[190:211, 290:311] = 0.0
    bad[250:271, 310:331] = np.nan
    out = lift_with_depth(nodes, bad, camera, visible=[True, True, False, True])
    assert np.isnan(out).all()


def test_lift_with_plane_parallel_raises(camera: PinholeCamera) -> None:
    uv = np.array([[319.5, 239.5]])
    _, d = camera.pixel_rays(uv)
    normal = np.cross(d[0], [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="parallel"):
        lift_with_plane(uv, camera, (normal, 0.0))


# ----------------------------------------------------------------------------- lifting, by hand
def _tiny_camera(width: int = 4, height: int = 4) -> PinholeCamera:
    """Camera frame = world frame, f = 10 px: pixel (u, v) at depth z lifts to
    ((u - cx) z / 10, (v - cy) z / 10, z)."""
    K = np.array([[10.0, 0.0, (width - 1) / 2], [0.0, 10.0, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return PinholeCamera(width, height, K, np.zeros(0), np.eye(3), np.zeros(3))


def _at_depth(uv: list[list[float]], z: list[float], c: float = 1.5) -> np.ndarray:
    uv_a, z_a = np.asarray(uv, dtype=float), np.asarray(z, dtype=float)
    return np.column_stack(((uv_a - c) * z_a[:, None] / 10.0, z_a))


def test_lift_with_depth_reads_the_pixel_each_coordinate_rounds_to() -> None:
    rows, cols = np.mgrid[0:4, 0:4]
    depth = 0.5 + 0.1 * rows + 0.01 * cols  # under a metre, every pixel different
    uv = [[2.4, 0.6], [0.6, 2.4], [-0.4, 3.4], [3.4, -0.4], [np.nan, 1.0]]
    # (col, row) = (2, 1), (1, 2), (0, 3), (3, 0): the image's first and last rows and columns included.
    expected = _at_depth(uv[:4], [0.62, 0.71, 0.80, 0.53])
    lifted = lift_with_depth(uv, depth, _tiny_camera(), window=0)
    np.testing.assert_allclose(lifted[:4], expected, atol=1e-12)
    assert np.isnan(lifted[4]).all()
    # A depth image with a channel axis, (H, W, 1), reads the same.
    np.testing.assert_allclose(lift_with_depth(uv, depth[:, :, None], _tiny_camera(), window=0), lifted)


def test_lift_with_depth_gives_nan_for_pixels_off_the_image() -> None:
    depth = np.full((4, 4), 0.5)
    # Columns -1 and 4, rows -1 and 4 after rounding; the last one is inside.
    uv = [[-0.6, 1.0], [3.6, 1.0], [1.0, -0.6], [1.0, 3.6], [-0.6, -0.6], [1.0, 1.0]]
    lifted = lift_with_depth(uv, depth, _tiny_camera())
    assert np.isnan(lifted[:5]).all()
    np.testing.assert_allclose(lifted[5], [-0.025, -0.025, 0.5], atol=1e-12)


@pytest.mark.parametrize("transpose", [False, True])
def test_lift_with_depth_cuts_the_window_at_the_border_instead_of_wrapping(transpose: bool) -> None:
    rows = np.mgrid[0:4, 0:4][0]
    depth = 0.5 + 0.1 * rows  # depth grows down the image (or to the right, transposed)
    uv = np.array([[1.0, 0.0], [1.0, 3.0]])
    if transpose:
        depth, uv = depth.T, uv[:, ::-1]
    # The 3x3 window at the first row holds rows (0, 0, 1): median 0.5; at the last row (2, 3, 3): 0.8.
    np.testing.assert_allclose(lift_with_depth(uv, depth, _tiny_camera())[:, 2], [0.5, 0.8], atol=1e-12)


def test_lift_with_depth_takes_the_median_of_the_3x3_window_by_default() -> None:
    depth = np.full((7, 7), 0.5)
    depth[2, 2:5] = 2.0  # background above the cable pixel (3, 3) ...
    depth[3, 2] = 2.0  # ... and to its left: 4 of its 9 window pixels
    cam, uv = _tiny_camera(7, 7), [[3.0, 3.0]]
    assert lift_with_depth(uv, depth, cam)[0, 2] == 0.5  # a minority: the cable's depth
    depth[4, 2] = 2.0  # 5 of 9: the background's
    assert lift_with_depth(uv, depth, cam)[0, 2] == 2.0
    assert lift_with_depth(uv, depth, cam, window=0)[0, 2] == 0.5  # the pixel alone
    assert lift_with_depth(uv, depth, cam, window=2)[0, 2] == 0.5  # 5 of 25


def test_lift_with_depth_ignores_invalid_depths_in_the_window() -> None:
    depth = np.full((4, 4), np.nan)
    depth[1, 1], depth[1, 2], depth[2, 1] = 0.0, -1.0, np.inf
    depth[2, 2], depth[0, 0] = 0.6, 0.9  # the only valid depths in (1, 1)'s window
    lifted = lift_with_depth([[1.0, 1.0]], depth, _tiny_camera())
    np.testing.assert_allclose(lifted, _at_depth([[1, 1]], [0.75]))
    assert np.isnan(lift_with_depth([[1.0, 1.0]], depth, _tiny_camera(), window=0)).all()


def test_lifting_takes_visibility_as_any_0_1_mask() -> None:
    depth = np.full((4, 4), 0.5)
    uv = [[1.0, 1.0], [2.0, 2.0], [1.0, 2.0]]
    for visible in ([1, 0, 1], [[True], [False], [True]], np.array([1.0, 0.0, 1.0])):
        lifted = lift_with_depth(uv, depth, _tiny_camera(), visible=visible)
        np.testing.assert_allclose(lifted[[0, 2]], _at_depth([uv[0], uv[2]], [0.5, 0.5]), atol=1e-12)
        assert np.isnan(lifted[1]).all()
        on_plane = lift_with_plane(uv, _tiny_camera(), Plane(np.array([0.0, 0.0, 1.0]), -0.5), visible)
        np.testing.assert_allclose(on_plane[[0, 2]], lifted[[0, 2]], atol=1e-12)
        assert np.isnan(on_plane[1]).all()


def test_lift_with_plane_skips_invisible_and_nan_pixels() -> None:
    uv = [[60.0, 20.0], [np.nan, 20.0], [50.0, 40.0], [60.0, 20.0]]
    ground = Plane(np.array([0.0, 0.0, 1.0]), 0.0)
    lifted = lift_with_plane(uv, down_camera(), ground, visible=[True, True, True, False])
    np.testing.assert_allclose(lifted[[0, 2]], [[0.2, 0.4, 0.0], [0.0, 0.0, 0.0]], atol=1e-12)
    assert np.isnan(lifted[[1, 3]]).all()
    np.testing.assert_allclose(lift_with_plane(uv, down_camera(), ground)[[0, 2, 3]],
                               [[0.2, 0.4, 0.0], [0.0, 0.0, 0.0], [0.2, 0.4, 0.0]], atol=1e-12)


def test_lift_with_plane_moves_only_points_under_the_floor_onto_it() -> None:
    uv, ground = [[60.0, 20.0], [50.0, 40.0]], (np.array([0.0, 0.0, 1.0]), 0.0)
    # The floor z = 0.5 is above the plane z = 0: the rays meet it first.
    high = lift_with_plane(uv, down_camera(), ground, floor=Plane(np.array([0.0, 0.0, 1.0]), -0.5))
    np.testing.assert_allclose(high, [[0.15, 0.3, 0.5], [0.0, 0.0, 0.5]], atol=1e-12)
    # The floor z = -0.5 is under the plane: nothing changes.
    low = lift_with_plane(uv, down_camera(), ground, floor=Plane(np.array([0.0, 0.0, 1.0]), 0.5))
    np.testing.assert_allclose(low, [[0.2, 0.4, 0.0], [0.0, 0.0, 0.0]], atol=1e-12)


def test_a_node_is_measured_only_when_visible_and_finite() -> None:
    xyz = np.array([[0.1, 0.2, 0.3], [np.nan, 0.0, 0.0], [0.4, 0.5, 0.6]])
    m = Measurement(xyz, np.zeros((3, 2)), np.array([False, True, True]), 0.0)
    assert m.point(0) is None  # hidden, even with a position
    assert m.point(1) is None  # visible but not lifted
    p = m.point()
    np.testing.assert_array_equal(p, [0.4, 0.5, 0.6])
    p[0] = 9.0
    assert m.nodes_xyz[2, 0] == 0.4  # a copy
