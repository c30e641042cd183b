"""``seg-train``: a short run trains, checkpoints, resumes and exports an ONNX network ONNX Runtime runs."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.learning.segdata import SegDataConfig, write_dataset
from dyndlo_vision.learning.segtrain import (
    ARCHITECTURES,
    MIN_SCALE,
    TrainConfig,
    _augment,
    _batch,
    build_net,
    deepened,
    export_onnx,
    external_split,
    full_res_logits,
    net_from_onnx,
    train,
    widened,
)
from dyndlo_vision.tracking.learned import LearnedSegmenter, from_blocks, to_blocks


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


def test_a_checkpoint_from_before_an_option_resumes_with_its_default(dataset: Path, tmp_path: Path) -> None:
    import torch

    out = tmp_path / "run"
    cfg = TrainConfig(steps=4, batch=2, crop_h=64, crop_w=64, checkpoint_every=2)
    train(dataset, out, cfg, progress=False)
    checkpoint = torch.load(out / "checkpoint.pt", weights_only=False)
    for option in ("max_scale", "blocks", "external_balanced"):  # options added after the first runs
        del checkpoint["config"][option]
    torch.save(checkpoint, out / "checkpoint.pt")
    assert train(dataset, out, cfg, resume=True, progress=False)["train_config"]["steps"] == 4
    with pytest.raises(ValueError, match="other settings"):  # a default is not any value
        train(dataset, out, replace(cfg, max_scale=2.0), resume=True, progress=False)


def test_several_datasets_are_pooled(dataset: Path, tmp_path: Path) -> None:
    assert main(["seg-train", "--data", str(dataset), str(dataset), "--out", str(tmp_path / "r"), "--quiet",
                 "--steps", "1", "--batch", "1"]) == 0
    meta = json.loads((tmp_path / "r" / "cable_segmenter.json").read_text())
    assert meta["samples"] == 8 and meta["data"] == [str(dataset)] * 2
    assert len(meta["data_manifest"]) == 2


@pytest.mark.parametrize("arch", ARCHITECTURES)
def test_onnx_matches_torch(arch: str) -> None:
    """What runs (ONNX Runtime on the ONNX file, blocks laid out in numpy) is what was trained (torch)."""
    import torch

    torch.manual_seed(0)
    net = build_net(arch)
    for m in net.modules():  # batch-norm statistics away from the identity, so their folding counts
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 2.0)
    net.eval()
    seg = LearnedSegmenter(export_onnx(net), short_side=None)
    assert seg.blocks == (arch == "cablenet-s2d4")
    rgb = np.random.default_rng(0).integers(0, 255, (64, 96, 3), dtype=np.uint8)
    x = torch.from_numpy(rgb.astype(np.float32).transpose(2, 0, 1)[None] / 255.0 - 0.5)
    with torch.inference_mode():
        ref = full_res_logits(net, x, arch)[0, 0].numpy()
    got = seg.logits_full(rgb)
    assert np.abs(got - ref).max() < 1e-4
    np.testing.assert_array_equal(seg(rgb), ref > 0)


def test_blocks_are_pixel_unshuffle() -> None:
    import torch

    rgb = np.random.default_rng(1).integers(0, 255, (8, 12, 3), dtype=np.uint8)
    x = torch.from_numpy(rgb.astype(np.float32).transpose(2, 0, 1)[None] / 255.0 - 0.5)
    ref = torch.nn.functional.pixel_unshuffle(x, 4).numpy()
    np.testing.assert_allclose(to_blocks(rgb), ref, atol=1e-6)
    np.testing.assert_array_equal(from_blocks(ref[0, :16]), torch.nn.functional.pixel_shuffle(
        torch.from_numpy(ref[:, :16]), 4)[0, 0].numpy())


def test_frames_of_any_size_keep_their_size() -> None:
    seg = LearnedSegmenter(export_onnx(build_net("cablenet-s2d4").eval()))
    for shape in ((50, 70, 3), (480, 640, 3), (17, 33, 3)):
        assert seg(np.zeros(shape, np.uint8)).shape == shape[:2]
    assert LearnedSegmenter(export_onnx(build_net("cablenet-s2d4").eval()), short_side=96).input_size(
        480, 640
    ) == (128, 96)


def test_init_needs_the_same_architecture(dataset: Path, tmp_path: Path) -> None:
    cfg = TrainConfig(steps=1, batch=1, crop_h=64, crop_w=64, arch="cablenet")
    train(dataset, tmp_path / "a", cfg, progress=False)
    with pytest.raises(ValueError, match="--arch cablenet"):
        train(dataset, tmp_path / "b", TrainConfig(steps=1, batch=1, crop_h=64, crop_w=64), progress=False,
              init=tmp_path / "a" / "checkpoint.pt")
    assert not (tmp_path / "b").exists()


def test_block_crops_must_be_multiples_of_16(dataset: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="multiples of 16"):
        train(dataset, tmp_path / "r", TrainConfig(steps=1, crop_h=60, crop_w=64), progress=False)
    with pytest.raises(ValueError, match="arch must be one of"):
        train(dataset, tmp_path / "r", TrainConfig(steps=1, arch="unet"), progress=False)
    assert not (tmp_path / "r").exists()


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
    for extra, word in ((["--steps", "0"], "--steps"), (["--external-share", "0.5"], "--external"),
                        (["--pos-weight", "0"], "--pos-weight"), (["--max-scale", "0.5"], "max_scale"),
                        (["--max-scale", "nan"], "max_scale"), (["--max-scale", "5"], "got 5.0")):
        with pytest.raises(SystemExit) as exc:
            main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "r"), "--quiet", *extra])
        assert exc.value.code == 2
        assert word in capsys.readouterr().err
        assert not (tmp_path / "r").exists()
    with pytest.raises(SystemExit):
        main(["seg-train", "--data", str(tmp_path), "--out", str(tmp_path / "r2"), "--quiet", "--steps", "1"])
    assert "no dataset.json" in capsys.readouterr().err


def test_widths_build_train_and_guard_init(dataset: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """``--widths`` builds a narrower network (fewer parameters, recorded in the JSON); ``--init`` from other
    widths, and widths that are not three positive integers, are refused before anything is written."""
    assert main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "n"), "--quiet", "--steps", "1",
                 "--batch", "1", "--widths", "4,16,32"]) == 0
    meta = json.loads((tmp_path / "n" / "cable_segmenter.json").read_text())
    assert meta["architecture"] == "cablenet-s2d4(c1=4, c2=16, c3=32)"
    assert meta["parameters"] < sum(p.numel() for p in build_net("cablenet-s2d4").parameters())
    assert LearnedSegmenter((tmp_path / "n" / "cable_segmenter.onnx").read_bytes()).blocks
    with pytest.raises(ValueError, match="--widths 4,16,32"):
        train(dataset, tmp_path / "d", TrainConfig(steps=1, batch=1, crop_h=64, crop_w=64), progress=False,
              init=tmp_path / "n" / "checkpoint.pt")
    assert not (tmp_path / "d").exists()
    for bad in ("4,16", "4,0,32", "a,b,c"):
        with pytest.raises(SystemExit) as exc:
            main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "b"), "--quiet",
                  "--widths", bad])
        assert exc.value.code == 2 and "--widths" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()
    # A checkpoint from before the option (no "widths" in its config) resumes as the default widths.
    import torch

    run = tmp_path / "old"
    cfg = TrainConfig(steps=2, batch=1, crop_h=64, crop_w=64, checkpoint_every=1)
    train(dataset, run, cfg, progress=False)
    ck = torch.load(run / "checkpoint.pt", weights_only=False)
    del ck["config"]["widths"]
    ck["step"] = 1
    torch.save(ck, run / "checkpoint.pt")
    train(dataset, run, cfg, resume=True, progress=False)


def _random_eval_net(arch: str, seed: int, widths: tuple[int, int, int] = (8, 16, 32), blocks: int = 0
                     ) -> object:
    """A network with batch-norm statistics and affines away from the identity (eval mode)."""
    import torch

    torch.manual_seed(seed)
    net = build_net(arch, *widths, blocks=blocks)
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 2.0)
            m.weight.data.uniform_(0.5, 1.5)
            m.bias.data.uniform_(-0.3, 0.3)
    return net.eval()


@pytest.mark.parametrize(("arch", "blocks"), [(arch, 0) for arch in ARCHITECTURES] + [("cablenet-s2d4", 2)])
def test_a_network_read_back_from_onnx_computes_the_same(arch: str, blocks: int) -> None:
    """``net_from_onnx`` undoes the export (batch norms folded into the convolutions): same architecture,
    widths, residual blocks and logits, so the shipped networks can be fine-tuned without their
    checkpoints."""
    import torch

    widths = (6, 12, 24)
    net = _random_eval_net(arch, 3, widths, blocks)
    back, got_arch, got_widths, got_blocks = net_from_onnx(export_onnx(net))
    assert (got_arch, got_widths, got_blocks) == (arch, widths, blocks)
    x = torch.from_numpy(np.random.default_rng(2).uniform(-0.5, 0.5, (1, 3, 64, 96)).astype(np.float32))
    with torch.inference_mode():
        ref = full_res_logits(net, x, arch)
        out = full_res_logits(back, x, arch)
    assert float(ref.abs().max()) > 0.1  # not a trivially small output
    assert float((out - ref).abs().max()) < 1e-4
    with pytest.raises(ValueError, match="not a cablenet ONNX file"):
        net_from_onnx(_onnx_with_one_conv())


def _onnx_with_one_conv() -> bytes:
    import io

    import torch

    buf = io.BytesIO()
    torch.onnx.export(torch.nn.Conv2d(3, 4, 3).eval(), torch.zeros(1, 3, 8, 8), buf, dynamo=False)
    return buf.getvalue()


def test_fine_tuning_an_onnx_network_keeps_its_batch_norms_frozen(dataset: Path, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``--init NET.onnx`` starts from the network's own function: with the batch norms frozen, a step at a
    vanishing learning rate exports the same network (batch statistics would have changed every layer).
    Without frozen batch norms the library refuses, before writing anything."""
    import torch

    onnx_file = tmp_path / "start.onnx"
    start = _random_eval_net("cablenet-s2d4", 5)
    onnx_file.write_bytes(export_onnx(start))
    cfg = TrainConfig(steps=1, batch=2, crop_h=64, crop_w=64, lr=1e-12)
    with pytest.raises(ValueError, match="frozen_batch_norm"):
        train(dataset, tmp_path / "refused", cfg, progress=False, init=onnx_file)
    assert not (tmp_path / "refused").exists()
    assert main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "ft"), "--quiet",
                 "--steps", "1", "--batch", "2", "--lr", "1e-12", "--init", str(onnx_file)]) == 0
    meta = json.loads((tmp_path / "ft" / "cable_segmenter.json").read_text())
    assert meta["train_config"]["frozen_batch_norm"] is True
    tuned, _, _, _ = net_from_onnx((tmp_path / "ft" / "cable_segmenter.onnx").read_bytes())
    x = torch.from_numpy(np.random.default_rng(4).uniform(-0.5, 0.5, (1, 3, 64, 64)).astype(np.float32))
    with torch.inference_mode():
        ref = full_res_logits(start, x, "cablenet-s2d4")
        out = full_res_logits(tuned, x, "cablenet-s2d4")
    assert float((out - ref).abs().max()) < 1e-3
    # Its checkpoint goes on with frozen batch norms: the command sees it, the library insists.
    with pytest.raises(ValueError, match="frozen_batch_norm"):
        train(dataset, tmp_path / "refused2", cfg, progress=False, init=tmp_path / "ft" / "checkpoint.pt")
    assert main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "ft2"), "--quiet",
                 "--steps", "1", "--batch", "2", "--init", str(tmp_path / "ft" / "checkpoint.pt")]) == 0
    assert json.loads((tmp_path / "ft2" / "cable_segmenter.json").read_text())["train_config"][
        "frozen_batch_norm"] is True
    with pytest.raises(ValueError, match="not an ONNX file"):
        net_from_onnx(b"not a network")
    # A shipped network by name: its widths and architecture are checked like a checkpoint's.
    with pytest.raises(SystemExit) as exc:
        main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "s"), "--quiet", "--steps", "1",
              "--arch", "cablenet-s2d4", "--init", "cable-segmenter"])
    assert exc.value.code == 2 and "--arch cablenet" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_external_photos_at_their_scale_and_sources_balanced(dataset: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """``--external-short-side`` and ``--external-balanced`` reach the run and its JSON; a short side under
    64 px is refused before anything is written."""
    import cv2

    root = tmp_path / "external"
    for folder, names, label in ((root / "mbest" / "S1", ["img0", "img1", "img2"], "_labels.png"),
                                 (root / "cables_dataset", ["00000", "00001"], "_mask_all.png")):
        folder.mkdir(parents=True)
        for name in names:
            img = np.full((120, 160, 3), 90, np.uint8)
            cv2.line(img, (10, 60), (150, 60), (20, 200, 20), 5)
            cv2.imwrite(str(folder / f"{name}.jpg"), img)
            cv2.imwrite(str(folder / f"{name}{label}"), (img[..., 1] > 150).astype(np.uint8) * 255)
    out = tmp_path / "run"
    assert main(["seg-train", "--data", str(dataset), "--out", str(out), "--quiet", "--steps", "1",
                 "--batch", "2", "--external", str(root), "--external-share", "1", "--external-balanced",
                 "--external-short-side", "96"]) == 0
    meta = json.loads((out / "cable_segmenter.json").read_text())
    assert meta["external_train_images"] == 3  # mBEST's img0, img2 and cables_dataset's 00000
    assert meta["train_config"]["external_short_side"] == 96
    assert meta["train_config"]["external_balanced"] is True
    assert meta["train_config"]["max_scale"] == 1.5
    again = tmp_path / "run2"
    assert main(["seg-train", "--data", str(dataset), "--out", str(again), "--quiet", "--steps", "1",
                 "--batch", "2", "--max-scale", "2.2"]) == 0
    assert json.loads((again / "cable_segmenter.json").read_text())["train_config"]["max_scale"] == 2.2
    with pytest.raises(SystemExit) as exc:
        main(["seg-train", "--data", str(dataset), "--out", str(tmp_path / "bad"), "--quiet",
              "--external", str(root), "--external-share", "0.5", "--external-short-side", "32"])
    assert exc.value.code == 2 and "external_short_side" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def _stripes() -> tuple[np.ndarray, np.ndarray]:
    """A 576x768 image of vertical 10 px stripes (period 20 px), large enough that no scale of the
    augmentation is raised to hold the 160x224 crop, and its mask."""
    image = np.zeros((576, 768, 3), np.uint8)
    mask = np.zeros((576, 768), np.uint8)
    for x in range(0, 768, 20):
        image[:, x : x + 10] = 255
        mask[:, x : x + 10] = 1
    return image, mask


def _run_widths(y: np.ndarray) -> float:
    """Median width of the whole stripes (not those the crop's sides cut) along a crop's middle row."""
    row = np.concatenate([[0.0], y[80], [0.0]])
    edges = np.flatnonzero(np.diff(row))
    return float(np.median((edges[1::2] - edges[::2])[1:-1]))


def _stripe_widths(max_scale: float | None, draws: int = 300) -> np.ndarray:
    """The stripes' widths in ``draws`` augmented crops: 10 times the scale each was resized by."""
    image, mask = _stripes()
    rng = np.random.default_rng(0)
    args = () if max_scale is None else (max_scale,)
    return np.array([_run_widths(_augment(rng, image, mask, (160, 224), *args)[1]) for _ in range(draws)])


def test_the_scale_augmentation_spans_its_range() -> None:
    """Images are resized by a scale from 0.6 to ``max_scale`` (1.5 unless asked for more) before the crop."""
    default = _stripe_widths(None)
    assert 10.0 * MIN_SCALE - 0.6 <= default.min() <= 10.0 * MIN_SCALE + 0.6
    assert 14.0 <= default.max() <= 15.0 + 0.6
    wider = _stripe_widths(2.2)
    assert 20.0 <= wider.max() <= 22.0 + 0.6 and wider.min() <= 10.0 * MIN_SCALE + 0.6
    assert np.mean(wider > 16.0) > 0.2
    np.testing.assert_array_equal(_stripe_widths(1.5), default)  # the default stream, unchanged


@pytest.mark.parametrize("external_share", [0.0, 1.0])
def test_a_batch_takes_the_configured_scale_for_generated_and_external_images(external_share: float) -> None:
    image, mask = _stripes()
    config = TrainConfig(batch=40, external_share=external_share, max_scale=2.2)
    rng = np.random.default_rng(1)
    _, yb = _batch(rng, config, [image], [mask], [image], [mask], [[0]])
    widths = np.array([_run_widths(y[0].numpy()) for y in yb])
    assert widths.max() > 16.0, widths  # beyond 1.5's 15 px


def test_balanced_external_sampling_draws_each_source_equally_often() -> None:
    """Unbalanced, a photo of the source with 5 photos is drawn a fifth of the time beside one with 20;
    balanced, each source half of the time, its photos evenly."""
    from dyndlo_vision.learning.segtrain import _draw_external

    by_source = [list(range(20)), list(range(20, 25))]
    for balanced, share in ((False, 0.2), (True, 0.5)):
        rng = np.random.default_rng(0)
        draws = np.array([_draw_external(rng, by_source, balanced) for _ in range(4000)])
        assert abs(float(np.mean(draws >= 20)) - share) < 0.03, balanced
        assert set(draws.tolist()) == set(range(25))


@pytest.mark.parametrize("arch", ARCHITECTURES)
def test_a_widened_network_computes_the_same_and_its_copies_learn_apart(arch: str) -> None:
    """``widened`` doubles every hidden layer without changing the logits; a channel and its copy get
    different gradients, or they would stay copies for ever."""
    import torch

    widths = (4, 8, 16)
    net = _random_eval_net(arch, 5, widths)
    wide = widened(net, arch, widths, seed=1)
    assert [m.weight.shape[0] for m in wide.modules() if isinstance(m, torch.nn.Conv2d)][:3] == (
        [16, 16, 32] if arch == "cablenet-s2d4" else [8, 16, 32])  # doubled (s2d4: e1 is 2 c1 wide)
    x = torch.from_numpy(np.random.default_rng(4).uniform(-0.5, 0.5, (2, 3, 64, 96)).astype(np.float32))
    with torch.no_grad():
        ref = full_res_logits(net, x, arch)
        out = full_res_logits(wide, x, arch)
    assert float(ref.abs().max()) > 0.1
    assert float((out - ref).abs().max()) < 1e-4
    full_res_logits(wide, x, arch).square().mean().backward()
    grad = wide.e2[0].weight.grad
    half = grad.shape[0] // 2
    assert float((grad[:half] - grad[half:]).abs().max()) > 1e-3 * float(grad.abs().max())


def test_seg_train_widens_a_network_half_as_wide(dataset: Path, tmp_path: Path) -> None:
    """``--init`` a network with ``--widths`` twice its own starts from it, widened; any other widths are
    refused, naming both."""
    narrow = tmp_path / "narrow.onnx"
    narrow.write_bytes(export_onnx(_random_eval_net("cablenet-s2d4", 6, (4, 8, 16))))
    config = TrainConfig(steps=1, batch=1, crop_h=64, crop_w=64, lr=1e-9, widths=(8, 16, 32),
                         frozen_batch_norm=True)
    train(dataset, tmp_path / "wide", config, init=narrow, progress=False)
    frame = np.random.default_rng(0).integers(0, 255, (96, 128, 3), np.uint8)
    before = LearnedSegmenter(narrow.read_bytes(), short_side=None).logits(frame)
    after = LearnedSegmenter((tmp_path / "wide" / "cable_segmenter.onnx").read_bytes(), short_side=None)
    assert np.abs(after.logits(frame) - before).max() < 1e-3 * np.abs(before).max()
    with pytest.raises(ValueError, match=r"widths \(4, 8, 16\).*--widths 4,8,16, or 8,16,32 to widen"):
        train(dataset, tmp_path / "other", replace(config, widths=(8, 16, 16)), init=narrow, progress=False)


@pytest.mark.parametrize("blocks", [0, 1])
def test_a_deepened_network_computes_the_same_and_its_new_blocks_learn(blocks: int) -> None:
    """``deepened`` adds residual blocks without changing the logits, also through an ONNX file (whose
    exporter names the added blocks' equal zero tensors once, through Identity nodes); the new blocks get
    gradients, or they would stay identities for ever. Fewer blocks than the network has are refused."""
    import torch

    arch, widths = "cablenet-s2d4", (4, 8, 16)
    net = _random_eval_net(arch, 6, widths, blocks)
    deep = deepened(net, arch, widths, blocks, 3, seed=2)
    assert len(deep.fine) == 3
    x = torch.from_numpy(np.random.default_rng(5).uniform(-0.5, 0.5, (2, 3, 64, 96)).astype(np.float32))
    with torch.no_grad():
        ref = full_res_logits(net, x, arch)
        out = full_res_logits(deep, x, arch)
        back, _, _, got_blocks = net_from_onnx(export_onnx(deep))
        again = full_res_logits(back, x, arch)
    assert float(ref.abs().max()) > 0.1
    assert float((out - ref).abs().max()) < 1e-5
    assert got_blocks == 3 and float((again - ref).abs().max()) < 1e-4
    deep.train()
    full_res_logits(deep, x, arch).square().mean().backward()
    assert float(deep.fine[2].b[1].weight.grad.abs().max()) > 0  # the new block's zeroed scale moves
    with pytest.raises(ValueError, match="to_blocks"):
        deepened(deep, arch, widths, 3, 2)


def test_seg_train_deepens_a_checkpoint_and_refuses_what_it_cannot_do(
        dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--blocks`` above the ``--init`` network's deepens it (the JSON says so); fewer blocks, more blocks
    at other widths, widening a network with blocks, and a negative count are refused before anything is
    written."""
    base = ["seg-train", "--data", str(dataset), "--quiet", "--steps", "1", "--batch", "2",
            "--widths", "4,8,16"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 0
    ckpt = str(tmp_path / "a" / "checkpoint.pt")
    assert main([*base, "--out", str(tmp_path / "b"), "--init", ckpt, "--blocks", "2"]) == 0
    meta = json.loads((tmp_path / "b" / "cable_segmenter.json").read_text())
    assert meta["architecture"] == "cablenet-s2d4(c1=4, c2=8, c3=16, blocks=2)"
    assert meta["train_config"]["blocks"] == 2
    deeper = str(tmp_path / "b" / "checkpoint.pt")
    refused = {
        "fewer": [*base, "--init", deeper, "--blocks", "1"],
        "other widths": ["seg-train", "--data", str(dataset), "--quiet", "--steps", "1", "--widths", "4,8,32",
                         "--init", ckpt, "--blocks", "1"],
        "widen with blocks": ["seg-train", "--data", str(dataset), "--quiet", "--steps", "1", "--widths",
                              "8,16,32", "--init", deeper, "--blocks", "2"],
        "negative": [*base, "--blocks", "-1"],
    }
    for case, argv in refused.items():
        out = tmp_path / case.replace(" ", "-")
        with pytest.raises(SystemExit) as exc:
            main([*argv, "--out", str(out)])
        assert exc.value.code == 2 and "blocks" in capsys.readouterr().err, case
        assert not out.exists(), case
