"""The composited 2-D scene kinds of ``seg-data``: exact labels, every kind's look, reproducibility."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.learning.segcomposite import COMPOSITE_STYLES, SURFACES, CompositeSampler, surface
from dyndlo_vision.learning.segdata import STYLES, SegDataConfig, make_sampler, write_dataset


def _widths(mask: np.ndarray) -> np.ndarray:
    """Twice the distance transform along the mask's ridge: the label's width where the cable runs."""
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    ridge = (dist >= cv2.dilate(dist, np.ones((3, 3), np.uint8)) - 1e-6) & (dist > 0)
    return 2 * dist[ridge]


@pytest.mark.parametrize("kind", COMPOSITE_STYLES)
def test_every_kind_draws_labelled_cables(kind: str) -> None:
    found = 0
    for group in range(4):
        rgb, mask, meta = CompositeSampler(kind, 192, 144, 1.0, 40.0, seed=0, group=group).sample()
        assert rgb.shape == (144, 192, 3) and rgb.dtype == np.uint8
        assert mask.shape == (144, 192) and set(np.unique(mask)) <= {0, 255}
        assert meta["style"] == kind and meta["surface"] in SURFACES
        assert 1.0 <= meta["width_px"][0] <= meta["width_px"][1] <= 40.0
        found += int((mask > 0).sum() > 50)
    assert found >= 3, "most samples show cables"
    assert kind in STYLES


@pytest.mark.parametrize("width", [3.0, 12.0, 30.0])
def test_the_label_is_as_wide_as_the_drawn_cable(width: float) -> None:
    """With every width drawn the same, the label's width along its ridge is that width (anti-aliased
    coverage of at least about a half makes a label pixel): the label is where the cable is drawn."""
    measured = []
    for group in range(6):
        _, mask, _ = CompositeSampler("wires", 320, 240, width, width, seed=1, group=group).sample()
        measured.append(_widths(mask > 0))
    w = np.concatenate(measured)
    assert abs(float(np.median(w)) - width) <= max(1.5, 0.12 * width), (width, np.median(w))


def test_the_label_matches_the_picture_where_the_cable_is_drawn() -> None:
    """Against the same scene drawn without its cables: labelled pixels changed, unlabelled ones far from
    any label did not (a cable's shadow and blur stay near it: cables up to 8 px here)."""
    import dyndlo_vision.learning.segcomposite as sc

    class NoCables(CompositeSampler):
        def _layout(self):  # type: ignore[no-untyped-def]
            groups, extras = super()._layout()
            for group in groups:
                for wire in group:
                    wire.path = wire.path + 1e5  # far outside the picture: nothing drawn, same draws
            return groups, [(n, a) for n, a in extras if n != "tie"]

    for kind in ("wires", "bundles", "busy"):
        for group in range(3):
            with_cables = CompositeSampler(kind, 320, 240, 2.0, 8.0, seed=3, group=group)
            without = NoCables(kind, 320, 240, 2.0, 8.0, seed=3, group=group)
            rgb, mask, _ = with_cables.sample()
            rgb0, mask0, _ = without.sample()
            assert not mask0.any()
            diff = np.abs(rgb.astype(int) - rgb0.astype(int)).max(axis=2)
            on = mask > 0
            if on.sum() < 30:
                continue
            assert np.median(diff[on]) > 10, "a labelled pixel shows a cable"
            far = cv2.dilate(on.astype(np.uint8), np.ones((41, 41), np.uint8)) == 0
            if far.any():
                assert np.percentile(diff[far], 99) <= 12, "a pixel far from every label is the surface's"
    del sc


def test_kinds_are_reproducible_and_differ_by_seed() -> None:
    a = CompositeSampler("harness", 128, 96, 1.0, 40.0, seed=5, group=2).sample()
    b = CompositeSampler("harness", 128, 96, 1.0, 40.0, seed=5, group=2).sample()
    c = CompositeSampler("harness", 128, 96, 1.0, 40.0, seed=6, group=2).sample()
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])
    with pytest.raises(ValueError, match="kind must be one of"):
        CompositeSampler("photos", 128, 96, 1.0, 40.0, seed=0, group=0)


def test_every_surface_is_drawn() -> None:
    rng = np.random.default_rng(0)
    for kind in SURFACES:
        img = surface(rng, kind, 72, 96)
        assert img.shape == (72, 96, 3) and np.isfinite(img).all()
        assert float(img.std()) > 0.5, kind
    with pytest.raises(ValueError, match="surface kind"):
        surface(rng, "marble", 8, 8)


def test_a_composited_dataset_resumes_and_the_command_sets_its_widths(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = SegDataConfig(width=96, height=64, samples_per_scene=2, style="bundles", min_width_px=1.0,
                        max_width_px=40.0)
    out = tmp_path / "ds"
    assert write_dataset(out, 3, 0, cfg) == 3
    first = cv2.imread(str(out / "000002.png"))
    (out / "000002_mask.png").unlink()
    assert write_dataset(out, 4, 0, cfg) == 2
    assert np.array_equal(cv2.imread(str(out / "000002.png")), first)
    rgb, _, _ = make_sampler(cfg, 0, 1).sample()
    assert np.array_equal(rgb[..., ::-1], first)
    cmd = tmp_path / "cmd"
    assert main(["seg-data", "--out", str(cmd), "--count", "1", "--width", "64", "--height", "48",
                 "--style", "own-colour", "--quiet"]) == 0
    config = json.loads((cmd / "dataset.json").read_text())["config"]
    assert (config["min_width_px"], config["max_width_px"]) == (1.0, 40.0)
    assert main(["seg-data", "--out", str(tmp_path / "m"), "--count", "1", "--width", "64", "--height", "48",
                 "--quiet"]) == 0
    config = json.loads((tmp_path / "m" / "dataset.json").read_text())["config"]
    assert (config["min_width_px"], config["max_width_px"]) == (0.7, 12.0), "the MuJoCo styles' widths"
    with pytest.raises(SystemExit) as exc:
        main(["seg-data", "--out", str(tmp_path / "bad"), "--count", "1", "--style", "wires",
              "--min-width", "8", "--max-width", "4"])
    assert exc.value.code == 2 and "min_width_px" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
