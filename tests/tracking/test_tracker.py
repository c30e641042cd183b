"""Tests of dyndlo_vision.tracking.tracker: temporal consistency and 3D lifting."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.tracking.camera_model import PinholeCamera
from dyndlo_vision.tracking.centerline import polyline_distance
from dyndlo_vision.tracking.synthetic import draw_occluder, render_cable, s_curve
from dyndlo_vision.tracking.tracker import CableTracker, Plane, lift_with_depth, lift_with_plane


def _moving_curve(k: int) -> np.ndarray:
    """Frame k of a cable that sways, bends and drifts (up to ~10 px per frame)."""
    t = k / 25.0
    return s_curve(
        u0=90 + 30 * np.sin(2.0 * t),
        u1=550 + 40 * np.sin(1.3 * t + 0.5),
        v0=240 + 50 * np.sin(3.0 * t),
        amp=100 * np.cos(2.5 * t),
        periods=0.9 + 0.3 * np.sin(1.7 * t),
        phase=0.8 * np.sin(2.2 * t),
    )


@pytest.mark.parametrize("use_anchor", [False, True])
def test_no_head_tail_flips_over_50_frames(use_anchor: bool) -> None:
    tracker = CableTracker(n_nodes=20)
    flips = 0
    errors = []
    start = None
    for k in range(50):
        curve = _moving_curve(k)
        rgb, _ = render_cable(curve, noise_sigma=4.0, seed=k)
        anchor = curve[0] if use_anchor else None
        meas = tracker.process(rgb, t_capture=k / 25.0, anchor_uv=anchor)
        assert meas.visible.all()
        d0 = np.hypot(*(meas.nodes_uv[0] - curve[0]))
        d1 = np.hypot(*(meas.nodes_uv[0] - curve[-1]))
        if start is None:
            # Without an anchor the first frame may pick either end; it must then stick.
            start = 0 if d0 < d1 else 1
        flips += (0 if d0 < d1 else 1) != start
        gt = curve if start == 0 else curve[::-1]
        errors.append(polyline_distance(meas.nodes_uv, gt))
    if use_anchor:
        assert start == 0
    assert flips == 0
    assert np.mean(errors) < 1.5


def test_tracker_keeps_orientation_when_held_end_is_hidden() -> None:
    """The held end disappears behind an occluder for a while: no anchor, still no flip."""
    tracker = CableTracker(n_nodes=20)
    head_first = None
    for k in range(12):
        curve = _moving_curve(k)
        rgb, _ = render_cable(curve, seed=k)
        if 4 <= k < 8:
            rgb = draw_occluder(rgb, (0, 0), (int(curve[0, 0]) + 40, 479))
        meas = tracker.process(rgb, t_capture=k / 25.0)
        last = meas.nodes_uv[meas.visible][-1]
        tail_is_free_end = np.hypot(*(last - curve[-1])) < np.hypot(*(last - curve[0]))
        if head_first is None:
            head_first = tail_is_free_end
        assert tail_is_free_end == head_first, f"flip at frame {k}"


def test_empty_frame_gives_invisible_measurement(camera: PinholeCamera) -> None:
    tracker = CableTracker(camera, plane=Plane(np.array([0, 0, 1.0]), 0.0))
    meas = tracker.process(np.full((480, 640, 3), 50, np.uint8), t_capture=1.0)
    assert not meas.visible.any() and np.isnan(meas.nodes_xyz).all()
    assert meas.point(-1) is None and meas.t_capture == 1.0


def _planar_scene(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """A 3D S-shaped cable on the world plane z = 0 and its image."""
    s = np.linspace(0, 1, 400)
    xyz = np.column_stack((-0.35 + 0.7 * s, 0.12 * np.sin(2 * np.pi * s), np.zeros_like(s)))
    uv = camera.project(xyz)
    rgb, _ = render_cable(uv, thickness=6)
    return xyz, rgb


def test_lift_with_plane_recovers_3d_curve(camera: PinholeCamera) -> None:
    xyz, rgb = _planar_scene(camera)
    tracker = CableTracker(
        camera, n_nodes=30, plane=Plane(np.array([0, 0, 1.0]), 0.0), anchor_uv=camera.project(xyz[:1])[0]
    )
    meas = tracker.process(rgb, t_capture=0.0)
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
    tracker = CableTracker(camera, plane=plane, floor=floor)
    assert tracker.floor is floor


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
