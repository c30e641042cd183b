"""``dyndlo-vision segment``: per-image outputs of the input's size, progress bar, bad input refused whole."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.tracking.synthetic import render_cable, s_curve


def _photo(path: Path, shape: tuple[int, int], seed: int) -> None:
    h, w = shape
    curve = s_curve(0.1 * w, 0.9 * w, 0.5 * h, amp=0.2 * h)
    rgb, _ = render_cable(
        curve, shape, thickness=6, color=(200, 40, 40), background=(170, 180, 160), seed=seed
    )
    assert cv2.imwrite(str(path), rgb[..., ::-1])


def _run(*args: str) -> int:
    try:
        return main(["segment", *args])
    except SystemExit as exc:  # argparse's error(): exit 2
        return int(exc.code)


def test_mixed_sizes_each_on_its_own(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "photos"
    folder.mkdir()
    _photo(folder / "a.png", (240, 320), 0)
    _photo(folder / "b.jpg", (480, 640), 1)
    _photo(tmp_path / "c.png", (300, 500), 2)
    out = tmp_path / "out"
    assert _run(str(folder), str(tmp_path / "c.png"), "--out", str(out)) == 0
    assert "segment" in capsys.readouterr().err  # the progress bar
    for name, shape in (("a", (240, 320)), ("b", (480, 640)), ("c", (300, 500))):
        mask = cv2.imread(str(out / f"{name}_mask.png"), cv2.IMREAD_UNCHANGED)
        assert mask.shape == shape and set(np.unique(mask)) <= {0, 255}
        assert (mask > 0).mean() > 0.005
        doc = json.loads((out / f"{name}_centerline.json").read_text())
        assert doc["width"] == shape[1] and doc["height"] == shape[0]
        assert doc["polylines"], name
        longest = doc["polylines"][0]
        assert longest["length_px"] > 0.5 * shape[1]
        assert set(longest["ends"]) == {"start", "end"}
    # The same image alone gives the same mask: no memory between images.
    out2 = tmp_path / "out2"
    assert _run(str(folder / "b.jpg"), "--out", str(out2), "--quiet") == 0
    assert capsys.readouterr().err == ""
    a = cv2.imread(str(out / "b_mask.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(a, cv2.imread(str(out2 / "b_mask.png"), cv2.IMREAD_UNCHANGED))


def test_bad_inputs_exit_2_and_write_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.png"
    _photo(good, (120, 160), 0)
    broken = tmp_path / "broken.png"
    broken.write_bytes(good.read_bytes()[:200])  # truncated
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "out"
    cases = [
        ([str(good), str(broken)], "broken.png"),
        ([str(good), str(tmp_path / "missing.png")], "missing.png"),
        ([str(empty)], "holds no images"),
    ]
    for inputs, message in cases:
        assert _run(*inputs, "--out", str(out)) == 2
        assert message in capsys.readouterr().err
        assert not out.exists()
    dup = tmp_path / "d"
    dup.mkdir()
    _photo(dup / "good.jpg", (120, 160), 1)
    assert _run(str(good), str(dup / "good.jpg"), "--out", str(out)) == 2
    assert "rename one" in capsys.readouterr().err
    assert not out.exists()


def test_existing_outputs_need_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    img = tmp_path / "x.png"
    _photo(img, (120, 160), 0)
    out = tmp_path / "out"
    out.mkdir()
    (out / "x_mask.png").write_bytes(b"mine")
    assert _run(str(img), "--out", str(out)) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "x_mask.png").read_bytes() == b"mine"
    assert not (out / "x_centerline.json").exists()
    assert _run(str(img), "--out", str(out), "--overwrite", "--quiet") == 0
    assert cv2.imread(str(out / "x_mask.png"), cv2.IMREAD_UNCHANGED).shape == (120, 160)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_classical_segmenters_are_options(tmp_path: Path) -> None:
    img = tmp_path / "x.png"
    _photo(img, (120, 160), 0)
    for extra in (["--segmenter", "background"], ["--segmenter", "hsv", "--hsv-lower", "0,120,80"]):
        out = tmp_path / extra[1]
        assert _run(str(img), "--out", str(out), "--quiet", *extra) == 0
        doc = json.loads((out / "x_centerline.json").read_text())
        assert doc["segmenter"] == extra[1]
    assert _run(str(img), "--out", str(tmp_path / "h"), "--segmenter", "hsv", "--hsv-lower", "1,2") == 2
    # The bounds are for --segmenter hsv: given to the default (learned) one they are refused, not ignored.
    assert _run(str(img), "--out", str(tmp_path / "l"), "--hsv-lower", "0,120,80") == 2


def test_shipped_networks_by_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--segmenter-model`` takes a shipped network's name as well as a file; an unknown one is refused
    whole."""
    _photo(tmp_path / "a.png", (240, 320), 0)
    out = tmp_path / "out"
    fine = ["--segmenter-model", "cable-segmenter-fine"]
    assert _run(str(tmp_path / "a.png"), "--out", str(out), *fine, "--quiet") == 0
    mask = cv2.imread(str(out / "a_mask.png"), cv2.IMREAD_UNCHANGED)
    assert _run(str(tmp_path / "a.png"), "--out", str(tmp_path / "o1"), "--quiet") == 0
    default = cv2.imread(str(tmp_path / "o1" / "a_mask.png"), cv2.IMREAD_UNCHANGED)
    assert mask.shape == default.shape == (240, 320) and mask.any()
    assert not np.array_equal(mask, default)  # another network ran
    unknown = ["--segmenter-model", "cable-segmenter-xl"]
    assert _run(str(tmp_path / "a.png"), "--out", str(tmp_path / "o2"), *unknown) == 2
    assert "cable-segmenter-fine" in capsys.readouterr().err  # the message lists the shipped names
    assert not (tmp_path / "o2").exists()


def test_the_default_network_is_the_photo_network(tmp_path: Path) -> None:
    """Without ``--segmenter-model``, ``segment`` runs ``cable-segmenter-photo-wide`` (the best on held-out
    photos), not the loop's faster default ``cable-segmenter`` nor the narrower photo network."""
    _photo(tmp_path / "a.png", (300, 400), 3)
    masks = {}
    for name, extra in (("default", []), ("photo", ["--segmenter-model", "cable-segmenter-photo-wide"]),
                        ("narrow", ["--segmenter-model", "cable-segmenter-photo"]),
                        ("first", ["--segmenter-model", "cable-segmenter"])):
        assert _run(str(tmp_path / "a.png"), "--out", str(tmp_path / name), "--quiet", *extra) == 0
        masks[name] = cv2.imread(str(tmp_path / name / "a_mask.png"), cv2.IMREAD_UNCHANGED)
    assert masks["default"].any() and np.array_equal(masks["default"], masks["photo"])
    assert not np.array_equal(masks["default"], masks["narrow"])
    assert not np.array_equal(masks["default"], masks["first"])
