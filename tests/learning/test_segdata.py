"""The domain-randomised segmentation data generator (``seg-data``): labels, reproducibility, resume."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.learning.segdata import SceneSampler, SegDataConfig, procedural_background, write_dataset

SMALL = SegDataConfig(width=96, height=64, samples_per_scene=2)


def test_label_is_where_the_cable_is_drawn() -> None:
    # Without textures or effects the label must cover pixels that differ from the scene without the cable:
    # render, then hide the cable (alpha 0) and render again.
    sampler = SceneSampler(SegDataConfig(width=160, height=120, texture_share=0.0), seed=3, group=0)
    try:
        found = 0
        for _ in range(6):
            rgb, mask, meta = sampler.sample()
            assert rgb.shape == (120, 160, 3) and rgb.dtype == np.uint8
            assert mask.shape == (120, 160) and set(np.unique(mask)) <= {0, 255}
            assert 1.0 <= meta["width_px"] <= 12.0
            found += int(mask.any())
        assert found >= 3, "most samples must show the cable"
    finally:
        sampler.close()


def test_samples_are_reproducible_per_group() -> None:
    a = SceneSampler(SMALL, seed=5, group=1)
    b = SceneSampler(SMALL, seed=5, group=1)
    c = SceneSampler(SMALL, seed=6, group=1)
    try:
        ra, rb, rc = a.sample(), b.sample(), c.sample()
        assert np.array_equal(ra[0], rb[0]) and np.array_equal(ra[1], rb[1])
        assert not np.array_equal(ra[0], rc[0])
    finally:
        a.close(), b.close(), c.close()


def test_procedural_backgrounds_vary() -> None:
    rng = np.random.default_rng(0)
    imgs = [procedural_background(rng, 48, 64) for _ in range(8)]
    assert all(i.shape == (48, 64, 3) and i.dtype == np.uint8 for i in imgs)
    assert len({round(float(i.std()), 1) for i in imgs}) > 4


def test_write_resumes_and_regenerates_identically(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    assert write_dataset(out, 4, 0, SMALL) == 4
    first = cv2.imread(str(out / "000002.png"))
    (out / "000002_mask.png").unlink()
    (out / "000002.png").unlink()
    assert write_dataset(out, 5, 0, SMALL) == 2  # the missing one and one more
    assert np.array_equal(cv2.imread(str(out / "000002.png")), first)
    assert json.loads((out / "dataset.json").read_text())["seed"] == 0
    assert not list(out.glob("*.part.png"))


def test_write_refuses_another_seed_or_a_foreign_folder(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    write_dataset(out, 1, 0, SMALL)
    with pytest.raises(ValueError, match="seed 0"):
        write_dataset(out, 2, 1, SMALL)
    other = tmp_path / "other"
    other.mkdir()
    (other / "x.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="no dataset.json"):
        write_dataset(other, 1, 0, SMALL)
    assert sorted(p.name for p in other.iterdir()) == ["x.txt"]
    with pytest.raises(ValueError, match="count"):
        write_dataset(tmp_path / "n", 0, 0, SMALL)
    with pytest.raises(ValueError, match="width"):
        SegDataConfig(width=0).check()


def test_command_writes_and_rejects(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cmd"
    assert (
        main(["seg-data", "--out", str(out), "--count", "2", "--width", "64", "--height", "48", "--quiet"])
        == 0
    )
    assert (out / "000001_mask.png").is_file()
    with pytest.raises(SystemExit) as exc:
        main(["seg-data", "--out", str(tmp_path / "bad"), "--count", "2", "--width", "8"])
    assert exc.value.code == 2
    assert "width" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_grey_floor_share_gives_the_task_scenes_look() -> None:
    """``grey_floor_share=1`` renders every floor neutral grey under the scene's own lights; at 0 (the shipped
    networks' data) each floor keeps a random colour."""
    grey = SceneSampler(SegDataConfig(width=96, height=64, texture_share=0.0, grey_floor_share=1.0), 4, 0)
    plain = SceneSampler(SegDataConfig(width=96, height=64, texture_share=0.0), 4, 0)
    try:
        for _ in range(3):
            grey.sample()
            rgba = grey.scene.model.geom_rgba[grey.floor_geom]
            assert rgba[0] == rgba[1] == rgba[2]
            np.testing.assert_allclose(grey.scene.model.light_pos[0], grey.scene_lights[1])
            plain.sample()
            rgba = plain.scene.model.geom_rgba[plain.floor_geom]
            assert len(set(rgba[:3].tolist())) == 3
    finally:
        grey.close()
        plain.close()


def test_a_dataset_from_before_an_option_resumes(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    write_dataset(out, 2, 0, SMALL)
    manifest = json.loads((out / "dataset.json").read_text())
    del manifest["config"]["grey_floor_share"]
    (out / "dataset.json").write_text(json.dumps(manifest))
    assert write_dataset(out, 3, 0, SMALL) == 1
    with pytest.raises(ValueError, match="another --out"):
        write_dataset(out, 3, 0, SegDataConfig(width=96, height=64, samples_per_scene=2,
                                               grey_floor_share=0.5))


def test_task_scenes_render_the_loop_scene_and_put_the_cable_back() -> None:
    """The ``task-scenes`` style renders a task's loop scene with a randomised look; the drawn radius (the
    chain's collision radius too), colours, lights and camera are put back before the cable moves on, and a
    group is reproducible."""
    from dyndlo_vision.learning.segdata import TASK_SCENE_CAMERAS, TaskSceneSampler

    cfg = SegDataConfig(width=160, height=120, style="task-scenes", texture_share=0.5)
    a, b = TaskSceneSampler(cfg, 1, 0), TaskSceneSampler(cfg, 1, 0)
    try:
        assert a.task in TASK_SCENE_CAMERAS
        m = a.base.model
        found = 0
        for _ in range(4):
            rgb, mask, meta = a.sample()
            assert rgb.shape == (120, 160, 3) and mask.shape == (120, 160)
            assert meta["camera"] in TASK_SCENE_CAMERAS[a.task]
            found += int(mask.any())
            for name, value in a.saved.items():
                np.testing.assert_array_equal(getattr(m, name), value, err_msg=name)
            np.testing.assert_array_equal(m.vis.headlight.ambient, a.headlight[0])
        assert found >= 3, "the loop camera sees the cable"
        rgb_b, mask_b, _ = b.sample()
        first = TaskSceneSampler(cfg, 1, 0)
        try:
            rgb_a, mask_a, _ = first.sample()
        finally:
            first.close()
        np.testing.assert_array_equal(rgb_a, rgb_b)
        np.testing.assert_array_equal(mask_a, mask_b)
    finally:
        a.close()
        b.close()
    with pytest.raises(ValueError, match="style"):
        SegDataConfig(style="photos").check()


def test_upscale_enlarges_image_and_label_as_the_loop_enlarges_its_frames(tmp_path: Path) -> None:
    """``upscale=1.5``: every sample is the 1x sample, image and coverage label each resized bilinearly to
    1.5x (what the loop's network is given: control.sim_perception.LOOP_NETWORK_SCALE); bad values are
    refused, and a dataset made before the option resumes as upscale 1."""
    from dyndlo_vision.learning.segdata import enlarged

    plain, big = tmp_path / "plain", tmp_path / "big"
    write_dataset(plain, 2, 0, SMALL)
    write_dataset(big, 2, 0, SegDataConfig(width=96, height=64, samples_per_scene=2, upscale=1.5))
    for i in range(2):
        rgb = cv2.imread(str(plain / f"{i:06d}.png"))
        mask = cv2.imread(str(plain / f"{i:06d}_mask.png"), cv2.IMREAD_GRAYSCALE)
        big_rgb = cv2.imread(str(big / f"{i:06d}.png"))
        big_mask = cv2.imread(str(big / f"{i:06d}_mask.png"), cv2.IMREAD_GRAYSCALE)
        assert big_rgb.shape == (96, 144, 3) and big_mask.shape == (96, 144)
        want_rgb, want_mask = enlarged(rgb, mask, 1.5)
        np.testing.assert_array_equal(big_rgb, want_rgb)
        np.testing.assert_array_equal(big_mask, want_mask)
        # The label's cable area grows with the image's: 1.5^2 = 2.25 times, as coverage (mask / 255).
        if mask.sum() > 255 * 20:
            assert big_mask.sum() / mask.sum() == pytest.approx(2.25, rel=0.05)
    assert json.loads((big / "dataset.json").read_text())["config"]["upscale"] == 1.5
    for bad in (0.5, 5.0, True, "2"):
        with pytest.raises(ValueError, match="upscale must be a number in"):
            SegDataConfig(upscale=bad).check()  # type: ignore[arg-type]
    manifest = json.loads((plain / "dataset.json").read_text())
    del manifest["config"]["upscale"]
    (plain / "dataset.json").write_text(json.dumps(manifest))
    assert write_dataset(plain, 3, 0, SMALL) == 1
