"""``seg-train``: a short run trains, checkpoints, resumes and exports an ONNX network cv2.dnn runs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.learning.segdata import SegDataConfig, write_dataset
from dyndlo_vision.learning.segtrain import TrainConfig, build_net, export_onnx, external_split, train
from dyndlo_vision.tracking.learned import LearnedSegmenter


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("segdata") / "ds"
    write_dataset(out, 4, 0, SegDataConfig(width=128, height=96, samples_per_scene=2))
    return out


def test_train_resume_export(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    cfg = TrainConfig(steps=4, batch=2, crop_h=64, crop_w=64, checkpoint_every=2)
    meta = train(dataset, out, cfg, progress=False)
    assert meta["parameters"] < 300_000 and meta["samples"] == 4
    seg = LearnedSegmenter((out / "cable_segmenter.onnx").read_bytes())
    assert seg(np.zeros((50, 70, 3), np.uint8)).shape == (50, 70)
    assert json.loads((out / "cable_segmenter.json").read_text())["train_config"]["steps"] == 4
    with pytest.raises(FileExistsError, match="--resume"):
        train(dataset, out, cfg, progress=False)
    longer = TrainConfig(steps=6, batch=2, crop_h=64, crop_w=64, checkpoint_every=2)
    with pytest.raises(ValueError, match="other settings"):
        train(dataset, out, longer, resume=True, progress=False)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        train(dataset, tmp_path / "none", cfg, resume=True, progress=False)


def test_onnx_matches_torch() -> None:
    import torch

    net = build_net().eval()
    seg = LearnedSegmenter(export_onnx(net), short_side=None)
    rgb = np.random.default_rng(0).integers(0, 255, (64, 96, 3), dtype=np.uint8)
    x = torch.from_numpy(rgb.astype(np.float32).transpose(2, 0, 1)[None] / 255.0 - 0.5)
    with torch.inference_mode():
        ref = net(x)[0, 0].numpy()
    assert np.abs(seg.logits(rgb) - ref).max() < 1e-4


def test_external_split_halves(tmp_path: Path) -> None:
    folder = tmp_path / "cables_dataset"
    folder.mkdir()
    for k in range(5):
        (folder / f"{k:05d}.jpg").write_bytes(b"x")
        (folder / f"{k:05d}_mask_all.png").write_bytes(b"x")
    split = external_split(tmp_path)
    assert [p[0].name for p in split["train"]] == ["00000.jpg", "00002.jpg", "00004.jpg"]
    assert [p[0].name for p in split["heldout"]] == ["00001.jpg", "00003.jpg"]


def test_command_rejects_bad_options(
    dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for extra, word in ((["--steps", "0"], "--steps"), (["--external-share", "0.5"], "--external")):
        with pytest.raises(SystemExit) as exc:
            main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "r"), "--quiet", *extra])
        assert exc.value.code == 2
        assert word in capsys.readouterr().err
        assert not (tmp_path / "r").exists()
    with pytest.raises(SystemExit):
        main(["seg-train", "--data", str(tmp_path), "--out", str(tmp_path / "r2"), "--quiet", "--steps", "1"])
    assert "no dataset.json" in capsys.readouterr().err
