"""Tests of dyndlo_vision.tracking.camera_model."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from dyndlo_vision.tracking.camera_model import CalibrationError, PinholeCamera

from .helpers import down_camera, look_at_camera


def _points_in_view(cam: PinholeCamera, n: int = 200, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    uv = rng.uniform([20, 20], [cam.width - 20, cam.height - 20], size=(n, 2))
    depth = rng.uniform(0.5, 3.0, size=n)
    xn = cam.normalized_coords(uv)
    p_cam = np.column_stack((xn * depth[:, None], depth))
    return cam.camera_to_world(p_cam)


@pytest.mark.parametrize("fixture", ["camera", "distorted_camera"])
def test_project_ray_round_trip(fixture: str, request: pytest.FixtureRequest) -> None:
    cam: PinholeCamera = request.getfixturevalue(fixture)
    pts = _points_in_view(cam)
    uv = cam.project(pts)
    origins, dirs = cam.pixel_rays(uv)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(origins, np.broadcast_to(cam.center, origins.shape), atol=1e-12)
    # Each world point lies on the ray through its own projection.
    v = pts - origins
    s = np.einsum("ij,ij->i", v, dirs)
    assert np.all(s > 0)
    off_ray = np.linalg.norm(v - s[:, None] * dirs, axis=1)
    assert off_ray.max() < 1e-9
    # And projecting points along the ray gives the same pixel back.
    np.testing.assert_allclose(cam.project(origins + 2.0 * dirs), uv, atol=1e-9)


@pytest.mark.parametrize("fixture", ["camera", "distorted_camera"])
def test_plane_round_trip(fixture: str, request: pytest.FixtureRequest) -> None:
    cam: PinholeCamera = request.getfixturevalue(fixture)
    rng = np.random.default_rng(1)
    normal = np.array([0.1, -0.2, 1.0])
    d = -0.05
    # Points on the plane n.x + d = 0 around the origin (which the camera looks at).
    xy = rng.uniform(-0.3, 0.3, size=(100, 2))
    z = -(d + xy @ normal[:2]) / normal[2]
    pts = np.column_stack((xy, z))
    uv = cam.project(pts)
    back = cam.intersect_plane(uv, normal, d)
    assert np.abs(back - pts).max() < 1e-9


def test_project_matches_explicit_pinhole(camera: PinholeCamera) -> None:
    p = np.array([[0.05, -0.02, 0.01]])
    pc = camera.R @ p[0] + camera.t
    expected = [
        camera.K[0, 0] * pc[0] / pc[2] + camera.K[0, 2],
        camera.K[1, 1] * pc[1] / pc[2] + camera.K[1, 2],
    ]
    np.testing.assert_allclose(camera.project(p)[0], expected, atol=1e-12)


def test_points_behind_camera_project_to_nan(camera: PinholeCamera) -> None:
    behind = camera.center - 0.5 * camera.R[2]  # half a metre behind the optical centre
    uv = camera.project(np.vstack((behind, [0.0, 0.0, 0.0])))
    assert np.all(np.isnan(uv[0])) and np.all(np.isfinite(uv[1]))


def test_intersect_plane_parallel_raises(camera: PinholeCamera) -> None:
    uv = np.array([[319.5, 239.5]])
    _, d = camera.pixel_rays(uv)
    # A plane containing the ray direction: normal perpendicular to it.
    normal = np.cross(d[0], [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=r"parallel to the camera ray through pixel \(319.5,239.5\)"):
        camera.intersect_plane(uv, normal, 0.0)


def test_intersect_plane_behind_raises(camera: PinholeCamera) -> None:
    # The plane z = 2 is above the camera (at z = 1.1) while it looks down.
    with pytest.raises(ValueError, match=r"behind the camera.*pixel \(320,240\)"):
        camera.intersect_plane([[320.0, 240.0]], [0, 0, 1.0], -2.0)


@pytest.mark.parametrize("fps", [None, 30.0])
def test_json_round_trip(tmp_path, distorted_camera: PinholeCamera, fps: float | None) -> None:
    cam = PinholeCamera(
        **{
            **{k: getattr(distorted_camera, k) for k in ("width", "height", "K", "dist", "R", "t")},
            "fps": fps,
        }
    )
    path = tmp_path / "cam.json"
    cam.to_json(path)
    data = json.loads(path.read_text())
    expected_keys = {"width", "height", "K", "dist", "R", "t"} | ({"fps"} if fps else set())
    assert set(data) == expected_keys
    back = PinholeCamera.from_json(path)
    for k in ("K", "dist", "R", "t"):
        np.testing.assert_array_equal(getattr(back, k), getattr(cam, k))
    assert (back.width, back.height, back.fps) == (cam.width, cam.height, cam.fps)
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind


def _good() -> dict:
    cam = look_at_camera(dist=(0.1, 0.01, 0.0, 0.0))
    return cam.to_dict()


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda d: d.pop("K"), r"missing key\(s\) \['K'\]"),
        (lambda d: d.update(distortion=[0, 0, 0, 0]), r"unknown key\(s\) \['distortion'\]"),
        (
            lambda d: d.update(K=[[500, 0, 320], [0, 500, 240]]),
            r"K must have shape \(3, 3\), got shape \(2, 3\)",
        ),
        (lambda d: d.update(t=[0.0, 1.0]), r"t must have shape \(3,\)"),
        (lambda d: d["R"][0].__setitem__(0, 1.01), r"R is not a rotation matrix: R @ R.T deviates"),
        (lambda d: d.update(R=np.diag([1.0, 1.0, -1.0]).tolist()), r"det\(R\) = -1"),
        (lambda d: d["K"][0].__setitem__(0, 0.0), r"positive focal lengths, got fx=0"),
        (lambda d: d["K"][1].__setitem__(1, -5.0), r"positive focal lengths.*fy=-5"),
        (lambda d: d.update(width=0), r"width must be a positive int, got 0"),
        (lambda d: d.update(height=480.5), r"height must be a positive int, got 480.5"),
        (lambda d: d.update(width="640"), r"width must be a positive int, got '640'"),
        (lambda d: d["t"].__setitem__(1, float("nan")), r"t contains non-finite numbers"),
        (lambda d: d["K"][0].__setitem__(2, float("inf")), r"K contains non-finite numbers"),
        (lambda d: d.update(dist=[0.1, 0.2, 0.3]), r"dist must have one of the lengths"),
        (lambda d: d.update(dist=[0.1, float("nan"), 0, 0]), r"dist contains non-finite"),
        (lambda d: d.update(fps=-25), r"fps must be a positive finite number"),
        (lambda d: d["K"][0].__setitem__(1, 3.0), r"no skew"),
    ],
)
def test_bad_calibration_raises(tmp_path, mutate, match: str) -> None:
    data = _good()
    mutate(data)
    path = tmp_path / "bad.json"
    # allow_nan: JSON has no NaN/inf, but Python's json writes them and many tools read them.
    path.write_text(json.dumps(data, allow_nan=True))
    with pytest.raises(CalibrationError, match=match):
        PinholeCamera.from_json(path)


def test_invalid_json_names_file(tmp_path) -> None:
    path = tmp_path / "broken.json"
    path.write_text("{not json")
    with pytest.raises(CalibrationError, match=r"broken.json: not valid JSON"):
        PinholeCamera.from_json(path)


def test_arrays_are_read_only(camera: PinholeCamera) -> None:
    with pytest.raises(ValueError):
        camera.K[0, 0] = 1.0


# ----------------------------------------------------------------------------- MuJoCo


def _mujoco_pixel(fovy_deg: float, width: int, height: int, pos, xmat, p) -> np.ndarray:
    """Independent pixel computation in MuJoCo's own terms.

    MuJoCo renders with an OpenGL frustum whose vertical extent is ``tan(fovy/2)`` at unit
    distance, mapped onto the full image height edge to edge (square pixels). In pixel-edge
    coordinates (0 at the left/top edge of the image) a point at normalised device
    coordinates (x_ndc, y_ndc) lands at ((x_ndc + 1) W / 2, (1 - y_ndc) H / 2); OpenCV puts
    pixel centres at integers, i.e. subtracts 0.5.
    """
    local = np.asarray(xmat).reshape(3, 3).T @ (np.asarray(p) - np.asarray(pos))
    depth = -local[2]  # MuJoCo cameras look along -z
    half_h = math.tan(math.radians(fovy_deg) / 2)
    half_w = half_h * width / height
    x_ndc = local[0] / depth / half_w
    y_ndc = local[1] / depth / half_h  # y up
    return np.array([(x_ndc + 1) * width / 2 - 0.5, (1 - y_ndc) * height / 2 - 0.5])


def _euler_xmat(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = (
        math.cos(rx),
        math.sin(rx),
        math.cos(ry),
        math.sin(ry),
        math.cos(rz),
        math.sin(rz),
    )
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@pytest.mark.parametrize(("width", "height", "fovy"), [(640, 480, 45.0), (641, 360, 60.0), (96, 128, 30.0)])
def test_from_mujoco_matches_independent_projection(width: int, height: int, fovy: float) -> None:
    rng = np.random.default_rng(width)
    xmat = _euler_xmat(0.9, 0.1, 0.4)
    pos = np.array([0.3, -1.2, 1.0])
    cam = PinholeCamera.from_mujoco(fovy, width, height, pos, xmat.reshape(-1))
    forward = -xmat[:, 2]
    for _ in range(20):
        p = pos + forward * rng.uniform(0.5, 3) + xmat[:, :2] @ rng.uniform(-0.2, 0.2, 2)
        np.testing.assert_allclose(
            cam.project(p)[0], _mujoco_pixel(fovy, width, height, pos, xmat, p), atol=1e-9
        )
    # The optical axis hits the image centre, between pixels for even sizes.
    np.testing.assert_allclose(cam.project(pos + forward)[0], [(width - 1) / 2, (height - 1) / 2], atol=1e-9)


def test_from_mujoco_against_rendered_image() -> None:
    """Renders a small bright sphere in MuJoCo and compares its centroid with project()."""
    import mujoco

    import dyndlo_vision  # noqa: F401  (chooses the off-screen GL backend before rendering)
    xml = """<mujoco><visual><global offwidth="700" offheight="500"/></visual>
    <asset><material name="e" emission="1" rgba="1 1 1 1"/></asset>
    <worldbody><camera name="c" pos="0.1 -0.8 0.6" xyaxes="1 0.1 0 -0.05 0.6 0.8" fovy="50"/>
    <body name="b" mocap="true">
      <geom type="sphere" size=".02" material="e" contype="0" conaffinity="0"/>
    </body>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    width, height = 641, 480  # odd width: the half-pixel convention matters on both axes
    renderer = mujoco.Renderer(model, height, width)  # no skip: rendering is required (CI installs OSMesa)
    try:
        mujoco.mj_forward(model, data)
        cam = PinholeCamera.from_mujoco(model.cam_fovy[0], width, height, data.cam_xpos[0], data.cam_xmat[0])
        rng = np.random.default_rng(0)
        errors = []
        vv, uu = np.mgrid[0:height, 0:width]
        for _ in range(6):
            p = rng.uniform([-0.25, -0.1, -0.1], [0.25, 0.2, 0.15])
            data.mocap_pos[0] = p
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, "c")
            img = renderer.render().astype(float).sum(axis=2)
            w = img / img.max()
            w[w < 0.05] = 0
            centroid = np.array([(w * uu).sum() / w.sum(), (w * vv).sum() / w.sum()])
            errors.append(centroid - cam.project(p)[0])
    finally:
        renderer.close()
    errors = np.array(errors)
    # A half-pixel convention error would show as a 0.5 px bias.
    assert np.abs(errors.mean(axis=0)).max() < 0.1
    assert np.abs(errors).max() < 0.25


# ----------------------------------------------------------------------------- fields, by hand
def test_fields_are_normalised_and_checked() -> None:
    base = look_at_camera()
    kw = {"width": np.int64(640), "height": 480, "K": base.K.tolist(), "dist": [[0.0, 0.0, 0.0, 0.0, 0.0]],
          "R": base.R.tolist(), "t": base.t.reshape(3, 1).tolist(), "fps": 30}
    cam = PinholeCamera(**kw)
    assert type(cam.width) is int and cam.dist.shape == (5,) and cam.t.shape == (3,)
    assert cam.fps == 30.0 and type(cam.fps) is float and not cam.has_distortion
    assert not PinholeCamera(**{**kw, "dist": []}).has_distortion
    assert PinholeCamera(**{**kw, "dist": [0.0, 0.0, 0.0, 1e-9]}).has_distortion
    for field, value, match in (
        ("width", True, r"^width must be a positive int, got True$"),
        ("dist", [[0.1, 0.2], [0.3, 0.4]], r"^dist must be a flat list, got shape \(2, 2\)$"),
        ("dist", ["a", 0, 0, 0], r"^dist must be a list of numbers"),
        ("fps", True, r"^fps must be a positive number or null, got True$"),
        ("fps", float("inf"), r"^fps must be a positive finite number, got inf$"),
        ("fps", 0, r"^fps must be a positive finite number, got 0"),
        ("K", [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 2.0]], r"no skew"),
        ("K", [[500.0, 0, 320], [1.0, 500.0, 240], [0, 0, 1.0]], r"no skew"),
        ("R", (np.asarray(base.R) * (1 + 2e-6)).tolist(), r"^R is not a rotation matrix: R @ R\.T deviates"),
    ):
        with pytest.raises(CalibrationError, match=match):
            PinholeCamera(**{**kw, field: value})
    # Within the rotation tolerance is a rotation.
    assert PinholeCamera(**{**kw, "R": (np.asarray(base.R) * (1 + 1e-7)).tolist()}).R.shape == (3, 3)


def test_the_camera_centre_and_frames_by_hand() -> None:
    # Camera 2 m above the origin looking straight down: x_cam = x_world, y_cam = -y_world, z_cam = 2 - z.
    R = np.diag([1.0, -1.0, -1.0])
    K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
    cam = PinholeCamera(101, 81, K, np.zeros(0), R, np.array([0.0, 0.0, 2.0]))
    np.testing.assert_allclose(cam.center, [0.0, 0.0, 2.0])
    np.testing.assert_allclose(cam.world_to_camera([0.1, 0.2, 0.5]), [[0.1, -0.2, 1.5]])
    np.testing.assert_allclose(cam.camera_to_world([[0.1, -0.2, 1.5]]), [[0.1, 0.2, 0.5]])
    np.testing.assert_allclose(cam.project([[0.2, 0.4, 0.0]]), [[60.0, 20.0]])  # 100 * 0.2 / 2 + 50, ...
    np.testing.assert_allclose(cam.normalized_coords([[60.0, 20.0]]), [[0.1, -0.2]])
    origins, dirs = cam.pixel_rays([60.0, 20.0])
    np.testing.assert_allclose(origins, [[0.0, 0.0, 2.0]])
    np.testing.assert_allclose(dirs, [np.array([0.1, 0.2, -1.0]) / np.linalg.norm([0.1, 0.2, -1.0])])
    np.testing.assert_allclose(cam.intersect_plane([[60.0, 20.0]], [0.0, 0.0, 2.0], 0.0), [[0.2, 0.4, 0.0]])
    assert np.isnan(cam.project([[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]])).all()  # behind and in the camera plane


def test_bad_planes_and_dicts_are_refused() -> None:
    cam = look_at_camera()
    for normal in ([0.0, 0.0, 0.0], [0.0, np.nan, 1.0], [0.0, 1.0]):
        with pytest.raises(ValueError, match=r"^plane normal must be a finite non-zero 3-vector, got"):
            cam.intersect_plane([[320.0, 240.0]], normal, 0.0)
    with pytest.raises(CalibrationError, match=r"^cam\.json: expected a JSON object, got list$"):
        PinholeCamera.from_dict([1, 2], source="cam.json")
    with pytest.raises(CalibrationError, match=r"^calibration: K must have shape \(3, 3\)"):
        PinholeCamera.from_dict({**cam.to_dict(), "K": [1, 2]})
    no_fps = {k: v for k, v in cam.to_dict().items() if k != "fps"}
    assert "fps" not in PinholeCamera.from_dict(no_fps).to_dict()


@pytest.mark.parametrize("fovy", [0.0, 180.0, -10.0])
def test_from_mujoco_needs_a_field_of_view_between_0_and_180_degrees(fovy: float) -> None:
    with pytest.raises(CalibrationError, match=r"^fovy_deg must be in \(0, 180\), got"):
        PinholeCamera.from_mujoco(fovy, 64, 48, np.zeros(3), np.eye(3).ravel())


def test_distorted_pixels_that_are_nan_stay_nan(distorted_camera: PinholeCamera) -> None:
    xn = distorted_camera.normalized_coords([[320.0, 240.0], [np.nan, 10.0]])
    assert np.isfinite(xn[0]).all() and np.isnan(xn[1]).all()
    assert distorted_camera.normalized_coords(np.zeros((0, 2))).shape == (0, 2)


# ----------------------------------------------------------------------------- rays and planes, by hand
def test_a_plane_normal_as_a_column_or_a_row_is_the_same_plane() -> None:
    cam = down_camera()
    for normal in ([0.0, 0.0, 2.0], [[0.0], [0.0], [2.0]], [[0.0, 0.0, 2.0]], [0, 0, 1]):
        np.testing.assert_allclose(cam.intersect_plane([[60.0, 20.0]], normal, 0.0), [[0.2, 0.4, 0.0]])


def test_the_parallel_limit_is_1e_9_of_the_normal_whatever_its_scale() -> None:
    cam = down_camera()
    axis = [[50.0, 40.0]]  # the ray straight down
    for k in (1e-6, 1.0, 1e6):
        # cos(ray, normal) = 5e-10: parallel at every scale of the normal.
        with pytest.raises(ValueError, match="parallel"):
            cam.intersect_plane(axis, np.array([1.0, 0.0, 5e-10]) * k, 0.0)
        # cos = 2e-9: meets the plane x + 2e-9 (z - 1) = 0 at (0, 0, 1).
        np.testing.assert_allclose(cam.intersect_plane(axis, np.array([1.0, 0.0, 2e-9]) * k, -2e-9 * k),
                                   [[0.0, 0.0, 1.0]], atol=1e-9)
    # Exactly at the limit (|ray . n| = 1e-9 |n|) is not parallel yet.
    at_limit = cam.intersect_plane(axis, [1.0, 0.0, 1e-9], -1e-9)
    np.testing.assert_allclose(at_limit, [[0.0, 0.0, 1.0]], atol=1e-9)


def test_a_plane_through_the_camera_centre_is_refused_one_closer_than_a_metre_is_not() -> None:
    cam = down_camera()
    with pytest.raises(ValueError, match=r"behind the camera .*pixel \(50,40\) \(ray parameter 0 m <= 0\)"):
        cam.intersect_plane([[50.0, 40.0]], [0.0, 0.0, 1.0], -2.0)  # z = 2: the camera's own height
    # z = 1.5, half a metre below the camera.
    np.testing.assert_allclose(cam.intersect_plane([[50.0, 40.0], [60.0, 20.0]], [0.0, 0.0, 1.0], -1.5),
                               [[0.0, 0.0, 1.5], [0.05, 0.1, 1.5]], atol=1e-12)


def test_the_error_names_the_first_pixel_whose_ray_misses() -> None:
    cam = down_camera()
    uv = [[50.0, 40.0], [100.0, 40.0], [150.0, 40.0]]  # rays along (0,0,-1), (0.5,0,-1), (1,0,-1)
    # Normal (1, 0, 0.5) is perpendicular to the second ray only.
    with pytest.raises(ValueError, match=r"parallel to the camera ray through pixel \(100,40\)"):
        cam.intersect_plane(uv, [1.0, 0.0, 0.5], 0.0)
    # The plane z = 1 - 3x: the first ray meets it 1 m down, the second and third behind the camera.
    with pytest.raises(ValueError, match=r"behind the camera along the ray through pixel \(100,40\)"):
        cam.intersect_plane(uv, [3.0, 0.0, 1.0], -1.0)


def test_integer_pixels_undistort_like_float_pixels(distorted_camera: PinholeCamera) -> None:
    uv = [[320, 240], [10, 20], [600, 450]]
    np.testing.assert_array_equal(distorted_camera.normalized_coords(uv),
                                  distorted_camera.normalized_coords(np.asarray(uv, dtype=float)))
    # Far from the centre, barrel distortion (k1 < 0) pulls pixels in: undistorted, they lie further out.
    xn = distorted_camera.normalized_coords(uv)
    assert abs(xn[1, 0]) > abs((10 - distorted_camera.K[0, 2]) / distorted_camera.K[0, 0])


# ----------------------------------------------------------------------------- the calibration file
def test_the_calibration_file_is_indented_json_with_fps_last(tmp_path) -> None:
    cam = PinholeCamera(**{**down_camera().to_dict(), "fps": 30.0})
    path = tmp_path / "cam.json"
    cam.to_json(path)
    text = path.read_text(encoding="utf-8")
    assert text.startswith('{\n  "width": 101,\n  "height": 81,\n  "K": [\n    [\n      100.0,\n      0.0,\n')
    assert text.endswith('\n  "t": [\n    0.0,\n    0.0,\n    2.0\n  ],\n  "fps": 30.0\n}\n')


def test_the_calibration_is_written_next_to_its_file_and_renamed_over_it(tmp_path, monkeypatch) -> None:
    import os

    from dyndlo_vision.tracking import camera_model

    path = tmp_path / "cam.json"
    renames = []
    real_replace = os.replace

    def replace(src, dst):
        renames.append((Path(src), Path(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(camera_model.os, "replace", replace)
    down_camera().to_json(path)
    [(tmp, dst)] = renames
    assert dst == path and tmp.parent == tmp_path  # same folder: the rename is atomic
    assert tmp.name.startswith(".cam.json.") and tmp.name.endswith(".tmp")  # hidden, named after its file
    assert PinholeCamera.from_json(path).to_dict() == down_camera().to_dict()


def test_a_failed_write_keeps_the_old_calibration_and_leaves_no_temporary_file(tmp_path, monkeypatch) -> None:
    from dyndlo_vision.tracking import camera_model

    path = tmp_path / "cam.json"
    look_at_camera().to_json(path)
    before = path.read_text(encoding="utf-8")

    def replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(camera_model.os, "replace", replace)
    with pytest.raises(OSError, match="disk full"):
        down_camera().to_json(path)
    assert path.read_text(encoding="utf-8") == before
    assert list(tmp_path.iterdir()) == [path]


def test_a_bad_calibration_file_is_named_in_the_error(tmp_path) -> None:
    path = tmp_path / "left.json"
    path.write_text(json.dumps({**down_camera().to_dict(), "width": 0}), encoding="utf-8")
    with pytest.raises(CalibrationError) as exc:
        PinholeCamera.from_json(path)
    assert str(exc.value) == f"{path}: width must be a positive int, got 0"
