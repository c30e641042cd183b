"""Tests of dyndlo_vision.tracking.tracker: 3D lifting of centreline nodes."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.tracking.camera_model import PinholeCamera
from dyndlo_vision.tracking.centerline import extract_centerline
from dyndlo_vision.tracking.segmentation import BackgroundSegmenter
from dyndlo_vision.tracking.synthetic import render_cable
from dyndlo_vision.tracking.tracker import Measurement, Plane, lift_with_depth, lift_with_plane


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
