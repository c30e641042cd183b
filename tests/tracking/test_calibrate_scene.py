"""Tests of ``dyndlo-vision calibrate --scene``: the calibration of a simulated camera is where MuJoCo renders
the scene."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.tracking.camera_model import PinholeCamera


def _render_scene(camera_name: str, width: int, height: int, targets: np.ndarray) -> tuple[list, np.ndarray]:
    """Renders tip control's scene with its target sphere at each world point; also returns the cable nodes.

    Returns ``(images, nodes)``: one RGB image per target position (the cable hangs still) and the cable's
    (N, 3) world nodes.
    """
    import gymnasium as gym
    import mujoco

    from dyndlo_vision.cameras.simulated import MujocoCamera

    env = gym.make("DynDLO/TipControl-v0")
    try:
        base = env.unwrapped
        env.reset(seed=0)
        images = []
        with MujocoCamera(base.model, base.data, camera_name, width=width, height=height) as camera:
            for p in targets:
                base.scene.set_target(p)
                mujoco.mj_forward(base.model, base.data)
                images.append(camera.read().rgb)
        return images, base.cable_nodes()
    finally:
        env.close()


def _write_calib(tmp_path: Path, *args: str) -> PinholeCamera:
    out = tmp_path / "camera.json"
    assert main(["calibrate", *args, "--out", str(out)]) == 0
    return PinholeCamera.from_json(out)  # the loader track --calib uses


#: World points for the target sphere: off the hanging cable, spread across the image and in depth.
TARGETS = np.array(
    [
        [0.0, 0.0, 0.2],
        [1.1, 0.0, 0.9],
        [0.1, 0.25, 1.0],
        [1.2, -0.3, 0.15],
        [0.75, 0.0, 0.55],
        [0.9, 0.3, 0.3],
        [0.2, -0.2, 0.6],
    ]
)


@pytest.mark.parametrize(
    ("camera", "width", "height", "task"),
    [
        ("tracking", 640, 480, "tip-control"),
        ("oblique", 320, 240, "tip-control"),
        ("front", 640, 480, "hooking"),
    ],
)
def test_calibration_projects_world_points_where_mujoco_renders_them(
    tmp_path: Path, camera: str, width: int, height: int, task: str
) -> None:
    """The target sphere's silhouette is centred on its projected centre, and the cable on its projection.

    The scene's cameras are the same in every task; the hooking case checks that --scene builds that scene.
    """
    args = ["--camera", camera, "--scene", task]
    if (width, height) != (640, 480):
        args += ["--width", str(width), "--height", str(height)]
    calib = _write_calib(tmp_path, *args)
    assert (calib.width, calib.height, calib.fps) == (width, height, 25.0)
    assert not calib.has_distortion
    uv_targets = calib.project(TARGETS)
    inside = np.all((uv_targets > 15) & (uv_targets < [width - 15, height - 15]), axis=1)
    assert inside.sum() >= 4, uv_targets  # enough of them in view to test the whole model
    images, nodes = _render_scene(camera, width, height, TARGETS[inside])
    vv, uu = np.mgrid[0:height, 0:width]
    errors = []
    for rgb, uv in zip(images, uv_targets[inside], strict=True):
        img = rgb.astype(int)
        # The sphere is translucent green, over a black sky or a grey floor: green dominates. Its silhouette
        # is a disk whose centroid is the projected centre (shading would bias an intensity-weighted one).
        green = (img[..., 1] - np.maximum(img[..., 0], img[..., 2]) > 25) & (
            np.hypot(uu - uv[0], vv - uv[1]) < 40
        )
        assert green.sum() > 20
        errors.append([uu[green].mean() - uv[0], vv[green].mean() - uv[1]])
    errors_px = np.array(errors)
    # Measured: |mean| <= 0.03 px, max 0.18 px. A principal point off by half a pixel shows as a 0.5 px bias.
    assert np.abs(errors_px.mean(axis=0)).max() < 0.2, errors_px
    assert np.abs(errors_px).max() < 0.5, errors_px
    # The red 2 mm cable lies on its projected nodes (1-2 px wide at 640x480).
    img = images[0].astype(int)
    red = (img[..., 0] > 100) & (img[..., 0] > 2 * img[..., 1]) & (img[..., 0] > 2 * img[..., 2])
    rows, cols = np.nonzero(red)
    assert rows.size > 30
    curve = calib.project(nodes)
    # The chain's capsules end in hemispherical caps: the drawn cable reaches one radius (2 mm) past its free
    # end node, so the centreline the pixels are measured against does too.
    free_end = nodes[-1] + 0.002 * (nodes[-1] - nodes[-2]) / np.linalg.norm(nodes[-1] - nodes[-2])
    dense_curve = np.vstack([curve, calib.project(free_end[None])])
    dense = np.concatenate(
        [
            np.linspace(a, b, 20, endpoint=False)
            for a, b in zip(dense_curve[:-1], dense_curve[1:], strict=True)
        ]
        + [dense_curve[-1:]]
    )
    to_curve = np.hypot(cols[:, None] - dense[None, :, 0], rows[:, None] - dense[None, :, 1]).min(axis=1)
    in_view = np.all((curve > 2) & (curve < [width - 3, height - 3]), axis=1)
    to_red = np.hypot(curve[in_view, 0, None] - cols[None], curve[in_view, 1, None] - rows[None]).min(axis=1)
    # Every cable pixel within 1 px of the projected centreline (measured 0.62 px; 0.29 px at 320x240).
    assert to_curve.max() < 1.0, to_curve.max()
    if width >= 640:
        # ... and every projected node within 1.5 px of a cable pixel (measured 0.65 and 0.9 px), except the
        # first, under the gripper sphere. At 320x240 the 2 mm cable is too thin to be drawn without gaps.
        assert np.sort(to_red)[-2] < 1.5, to_red


def test_file_is_exactly_the_format_track_reads(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "camera.json"
    assert main(["calibrate", "--scene", "tip-control", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert sorted(data) == ["K", "R", "dist", "fps", "height", "t", "width"]
    assert (data["width"], data["height"], data["fps"], data["dist"]) == (640, 480, 25.0, [])
    calib = PinholeCamera.from_dict(data)
    # The demo's camera: "tracking" at (0.65, -1.45, 0.575) looking along +y (OpenCV's z), fovy 45 deg.
    np.testing.assert_allclose(calib.center, [0.65, -1.45, 0.575], atol=1e-9)
    np.testing.assert_allclose(calib.R @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(calib.K[0, 0], 240.0 / np.tan(np.radians(22.5)), rtol=1e-12)
    np.testing.assert_allclose(calib.K[:2, 2], [319.5, 239.5])
    assert "wrote" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["camera.json"]  # no temporary file left


def test_overwrites_an_existing_file(tmp_path: Path) -> None:
    out = tmp_path / "camera.json"
    out.write_text("old")
    assert main(["calibrate", "--scene", "tip-control", "--width", "320", "--height", "240", "--out",
                 str(out)]) == 0
    assert PinholeCamera.from_json(out).width == 320


BAD_INPUTS = {
    "unknown camera": (
        ["--camera", "side"],
        r"--camera 'side' is not a camera.*\['front', 'tracking', 'oblique'\]",
    ),
    "unknown task": (["--scene", "knitting"], r"invalid choice: 'knitting'.*tip-control"),
    "missing folder": (["--out", "{tmp}/no/such/camera.json"], r"folder .*no/such does not exist"),
    "out is a folder": (["--out", "{tmp}"], r"is a folder"),
    "zero width": (["--width", "0"], r"--width must be a positive number of pixels, got 0"),
    "negative height": (["--height", "-480"], r"--height must be a positive number of pixels, got -480"),
    "too large for the scene": (["--width", "1280", "--height", "960"], r"at most 640x480"),
    "fps not finite": (["--fps", "nan"], r"--fps must be a positive finite number, got nan"),
    "fps zero": (["--fps", "0"], r"--fps must be a positive finite number"),
    # One command, two modes: each refuses the other's options.
    "photos with --scene": (
        ["{tmp}"], r"--scene tip-control takes its camera from the scene, not from photos"
    ),
    "board with --scene": (["--board", "9x6"], r"--board is for photos of a board, not --scene"),
    "camera without --scene": (["--no-scene", "{tmp}", "--camera", "tracking"],
                               r"--camera is for a simulated camera: it needs --scene TASK"),
    "no photos, no --scene": (
        ["--no-scene"], r"give photos of a checkerboard \(IMAGE ...\), or --scene TASK"
    ),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_exits_2_and_writes_nothing(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    argv, message = BAD_INPUTS[case]
    argv = [a.format(tmp=tmp_path) for a in argv]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "camera.json")]
    if "--no-scene" in argv:
        argv.remove("--no-scene")
    elif "--scene" not in argv:
        argv += ["--scene", "tip-control"]
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert re.search(message, err), err
    assert list(tmp_path.iterdir()) == []


def test_run_raises_value_error_for_an_unknown_task(tmp_path: Path) -> None:
    """Called directly (no argparse choices), the command still names the task and the valid ones."""
    from dyndlo_vision.cli import build_parser
    from dyndlo_vision.commands import calibrate

    argv = ["calibrate", "--scene", "tip-control", "--out", str(tmp_path / "c.json")]
    args = build_parser().parse_args(argv)
    args.scene = "knitting"
    with pytest.raises(ValueError, match=r"--scene 'knitting' is not a task; expected one of \['hooking'"):
        calibrate.run(args)
    assert list(tmp_path.iterdir()) == []
