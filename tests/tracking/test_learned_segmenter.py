"""The shipped learned segmenter (ONNX through ONNX Runtime) and the multi-cable polylines."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dyndlo_vision.tracking import dice
from dyndlo_vision.tracking.learned import ENGINE_THREADS, OUTSIDE_LOGIT, LearnedSegmenter
from dyndlo_vision.tracking.networks import (
    FINE_NAME,
    PHOTO_NAME,
    SHIPPED_NAME,
    SHIPPED_NAMES,
    SHIPPED_SUMMARIES,
    onnx_bytes,
    segmenter_metadata,
)
from dyndlo_vision.tracking.polylines import extract_polylines
from dyndlo_vision.tracking.synthetic import render_cable, s_curve


@pytest.fixture(scope="module")
def seg() -> LearnedSegmenter:
    return LearnedSegmenter(onnx_bytes())


@pytest.fixture(scope="module")
def fine() -> LearnedSegmenter:
    return LearnedSegmenter(onnx_bytes(FINE_NAME))


@pytest.fixture(scope="module")
def photo() -> LearnedSegmenter:
    return LearnedSegmenter(onnx_bytes(PHOTO_NAME))


def _textured(h: int, w: int, seed: int) -> np.ndarray:
    """A grey blotchy texture with a slight colour tint (a wall, a mat)."""
    rng = np.random.default_rng(seed)
    grey = rng.uniform(70, 190, (h // 16, w // 16)).astype(np.float32)
    grey = cv2.resize(grey, (w, h), interpolation=cv2.INTER_CUBIC)
    tint = rng.uniform(0.85, 1.15, 3).astype(np.float32)
    return np.clip(grey[..., None] * tint, 0, 255).astype(np.uint8)


COLOURS = [(230, 70, 40), (40, 80, 220), (60, 200, 60), (20, 20, 20), (240, 240, 240)]


@pytest.mark.parametrize("name", SHIPPED_NAMES)
def test_shipped_models_are_small_and_documented(name: str) -> None:
    import hashlib

    meta = segmenter_metadata(name)
    assert meta["name"] == name and meta["parameters"] < 300_000
    assert "seg-train" in meta["command"] and "seg-data" in meta["data_command"]
    assert meta["onnx_sha256"] == hashlib.sha256(onnx_bytes(name)).hexdigest()
    with pytest.raises(ValueError, match="no shipped segmenter"):
        segmenter_metadata("cable-segmenter-huge")


def test_the_option_help_lists_every_shipped_network() -> None:
    """``--segmenter-model``'s help is built from one table of the shipped networks, which names each."""
    import argparse

    from dyndlo_vision.commands._options import add_segmenter_model

    assert set(SHIPPED_SUMMARIES) == set(SHIPPED_NAMES)
    p = argparse.ArgumentParser()
    add_segmenter_model(p, PHOTO_NAME)
    text = next(a.help for a in p._actions if "--segmenter-model" in a.option_strings)
    for name, summary in SHIPPED_SUMMARIES.items():
        assert f"{name} ({summary})" in text


def test_the_fine_network_keeps_the_frame_resolution(fine: LearnedSegmenter, seg: LearnedSegmenter) -> None:
    assert fine.blocks and fine.short_side == 480 and fine.input_size(480, 640) == (640, 480)
    assert not seg.blocks and seg.short_side == 240


def test_the_default_stays_the_fast_network(photo: LearnedSegmenter) -> None:
    # The real robot's camera and ``track`` run onnx_bytes(): the network with the loop's time budget; the
    # photo network (3.0-4.8x slower at 640x480, docs/segmentation.md) is ``segment``'s default
    # only.
    assert SHIPPED_NAME == "cable-segmenter" and onnx_bytes() == onnx_bytes("cable-segmenter")
    assert photo.blocks and photo.short_side == 480 and photo.input_size(480, 640) == (640, 480)
    assert segmenter_metadata(PHOTO_NAME)["init"].startswith("cable-segmenter-photo (widened")
    assert segmenter_metadata("cable-segmenter-photo")["init"] == FINE_NAME


@pytest.mark.parametrize("background", [(150, 150, 150), (200, 190, 170), (40, 40, 40)])
def test_the_photo_network_finds_flat_cables_on_plain_walls(
    photo: LearnedSegmenter, background: tuple[int, int, int]
) -> None:
    # Measured 0.79-0.98 (median 0.94; the lowest: flat black cables on the dark wall; earlier weights
    # 0.32-0.96, lowest flat black 11 px cables on the light walls, cause not established;
    # cable-segmenter-photo 0.38-0.93, median 0.81; the first network min 0.78, median 0.90) on these
    # flat-coloured drawings, which no photo looks like; a floor against regressions.
    scores = []
    for colour in COLOURS:
        for thickness in (3, 7, 11):
            curve = s_curve(80, 560, 240, amp=90)
            rgb, truth = render_cable(curve, (480, 640), thickness, colour, background)
            scores.append(dice(photo(rgb), truth))
    assert min(scores) > 0.3 and np.median(scores) > 0.7, np.round(scores, 2)
    assert photo(np.full((480, 640, 3), background, np.uint8)).mean() < 0.002


@pytest.mark.xfail(
    strict=True,
    reason="known weakness of the photo networks (docs/segmentation.md): a flat dark or white 7 px cable on "
    "a blotchy grey texture is missed (DICE 0.14-0.21; cable-segmenter 0.41-0.53)",
)
def test_the_photo_network_finds_dark_and_white_cables_on_texture(photo: LearnedSegmenter) -> None:
    scores = []
    for colour in ((20, 20, 20), (240, 240, 240)):
        for seed in range(3):
            rgb, truth = render_cable(
                s_curve(80, 560, 240, amp=90), (480, 640), 7, colour, _textured(480, 640, seed)
            )
            scores.append(dice(photo(rgb), truth))
    assert min(scores) > 0.35, np.round(scores, 2)


@pytest.mark.parametrize("background", [(150, 150, 150), (200, 190, 170), (40, 40, 40)])
@pytest.mark.parametrize("colour", COLOURS)
def test_segments_cables_of_any_colour_and_width(
    seg: LearnedSegmenter, colour: tuple[int, int, int], background: tuple[int, int, int]
) -> None:
    for thickness in (3, 7, 11):
        rgb, truth = render_cable(s_curve(80, 560, 240, amp=90), (480, 640), thickness, colour, background)
        mask = seg(rgb)
        assert mask.shape == truth.shape and mask.dtype == bool
        assert dice(mask, truth) > 0.75, f"{colour} on {background}, {thickness} px: {dice(mask, truth):.2f}"


@pytest.mark.parametrize("colour", [(20, 20, 20), (240, 240, 240)])
def test_segments_dark_and_white_cables_on_texture(
    seg: LearnedSegmenter, colour: tuple[int, int, int]
) -> None:
    for seed in range(3):
        rgb, truth = render_cable(
            s_curve(80, 560, 240, amp=90), (480, 640), 7, colour, _textured(480, 640, seed)
        )
        # Measured 0.41-0.53 with the shipped network (0.6-0.9 with the one before its last fine-tuning stage,
        # which scored lower on the real photos; docs/RESULTS.md): a floor against regressions, not a target.
        assert dice(seg(rgb), truth) > 0.35, f"{colour}, texture {seed}: {dice(seg(rgb), truth):.2f}"


@pytest.mark.xfail(
    strict=True,
    reason="known weakness (docs/RESULTS.md): a saturated cable whose brightness "
    "matches a blotchy texture is missed; the network leans on brightness contrast",
)
def test_segments_coloured_cables_on_texture(seg: LearnedSegmenter) -> None:
    scores = []
    for seed in range(3):
        for colour in COLOURS[:3]:
            rgb, truth = render_cable(
                s_curve(80, 560, 240, amp=90), (480, 640), 7, colour, _textured(480, 640, seed)
            )
            scores.append(dice(seg(rgb), truth))
    assert min(scores) > 0.5, np.round(scores, 2)


@pytest.mark.xfail(
    strict=True,
    reason="known weakness of cable-segmenter-fine (docs/RESULTS.md): a wide cable of one flat colour is "
    "mostly missed (median DICE 0.19 at 11 px); the default network finds it (0.92)",
)
def test_the_fine_network_finds_wide_flat_cables(fine: LearnedSegmenter) -> None:
    scores = []
    for colour in COLOURS:
        rgb, truth = render_cable(s_curve(80, 560, 240, amp=90), (480, 640), 11, colour, (200, 190, 170))
        scores.append(dice(fine(rgb), truth))
    assert min(scores) > 0.6, np.round(scores, 2)


def test_a_blob_is_not_cable(seg: LearnedSegmenter) -> None:
    # A dark sphere (a gripper) and a box on a plain wall, no cable: (almost) nothing is cable.
    rgb = np.full((480, 640, 3), 190, np.uint8)
    cv2.circle(rgb, (300, 200), 30, (30, 30, 30), -1, cv2.LINE_AA)
    cv2.rectangle(rgb, (420, 300), (520, 380), (40, 60, 160), -1)
    assert seg(rgb).mean() < 0.002


@pytest.mark.parametrize("shape", [(333, 517), (480, 640), (97, 61)])
def test_mask_has_the_input_size(seg: LearnedSegmenter, shape: tuple[int, int]) -> None:
    rgb = np.random.default_rng(0).integers(0, 255, (*shape, 3), dtype=np.uint8)
    assert seg(rgb).shape == shape
    assert seg.probability(rgb).shape == shape


def test_bad_input_is_refused(seg: LearnedSegmenter) -> None:
    with pytest.raises(ValueError, match="uint8 RGB"):
        seg(np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match="uint8 RGB"):
        seg(np.zeros((10, 10, 3), np.float32))
    with pytest.raises(ValueError, match="ONNX"):
        LearnedSegmenter(b"not a network")
    with pytest.raises(ValueError, match="short_side"):
        LearnedSegmenter(b"x", short_side=4)
    with pytest.raises(FileNotFoundError, match="nowhere.onnx"):
        onnx_bytes("/nowhere.onnx")
    for empty in (b"", "cable-segmenter"):
        with pytest.raises(ValueError, match=f"onnx must be non-empty bytes, got {type(empty).__name__}"):
            LearnedSegmenter(empty)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="threshold must be finite, got nan"):
        LearnedSegmenter(onnx_bytes(), threshold=float("nan"))
    for threads in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match=f"threads must be an int >= 1, got {threads!r}"):
            LearnedSegmenter(onnx_bytes(), threads=threads)  # type: ignore[arg-type]


def test_the_engine_runs_the_threads_asked_for(seg: LearnedSegmenter) -> None:
    rgb = np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    one = LearnedSegmenter(onnx_bytes(), threads=1)
    assert one._session.get_session_options().intra_op_num_threads == 1
    assert seg._session.get_session_options().intra_op_num_threads == ENGINE_THREADS
    np.testing.assert_array_equal(one(rgb), seg(rgb))


def _identity_onnx(channels: int, outputs: int = 1) -> bytes:
    """An ONNX graph whose ``outputs`` outputs each repeat its 1 x ``channels`` x H x W input."""
    pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("rgb", TensorProto.FLOAT, [1, channels, "h", "w"])
    ys = [helper.make_tensor_value_info(f"y{k}", TensorProto.FLOAT, [1, channels, "h", "w"])
          for k in range(outputs)]
    nodes = [helper.make_node("Identity", ["rgb"], [f"y{k}"]) for k in range(outputs)]
    graph = helper.make_graph(nodes, "identity", [x], ys)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    return bytes(model.SerializeToString())


def test_a_network_of_neither_layout_or_with_two_outputs_is_refused() -> None:
    # 48 channels in, 48 out: the block layout's input, but not its 16 logits per block.
    with pytest.raises(ValueError, match="neither 48-channel 4x4 blocks"):
        LearnedSegmenter(_identity_onnx(48))
    with pytest.raises(ValueError, match="neither 48-channel 4x4 blocks"):
        LearnedSegmenter(_identity_onnx(5))
    with pytest.raises(ValueError, match="one input and one output, got 1 and 2"):
        LearnedSegmenter(_identity_onnx(3, outputs=2))
    # Three channels in, one out: read as an RGB network.
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("rgb", TensorProto.FLOAT, [1, 3, "h", "w"])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 1, "h", "w"])
    node = helper.make_node("ReduceMean", ["rgb"], ["y"], axes=[1], keepdims=1)
    model = helper.make_model(helper.make_graph([node], "mean", [x], [y]),
                              opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    assert LearnedSegmenter(bytes(model.SerializeToString())).blocks is False
    # 48 channels in, one out: neither layout (not an RGB network because it has one output channel).
    x48 = helper.make_tensor_value_info("rgb", TensorProto.FLOAT, [1, 48, "h", "w"])
    model = helper.make_model(helper.make_graph([node], "mean48", [x48], [y]),
                              opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    with pytest.raises(ValueError, match="neither 48-channel 4x4 blocks"):
        LearnedSegmenter(bytes(model.SerializeToString()))


def test_polylines_of_two_crossing_cables() -> None:
    mask = np.zeros((200, 300), np.uint8)
    cv2.line(mask, (20, 30), (280, 170), 1, 4)
    cv2.line(mask, (40, 180), (260, 20), 1, 4)
    polys = extract_polylines(mask)
    assert len(polys) == 2
    for p in polys:
        assert p.length_px > 200 and p.start_free and p.end_free
        json.dumps(p.to_json())
    # A cable that leaves the image has one free end.
    mask = np.zeros((100, 200), np.uint8)
    cv2.line(mask, (0, 50), (150, 50), 1, 3)
    (p,) = extract_polylines(mask)
    assert p.start_free != p.end_free
    assert extract_polylines(np.zeros((50, 50), bool)) == []
    with pytest.raises(ValueError, match="2-D"):
        extract_polylines(np.zeros((5, 5, 3)))


@pytest.mark.parametrize("short_side", [720, 960, 600])
def test_an_enlarged_region_is_computed_from_its_part_exactly(short_side: int) -> None:
    """A block network enlarging the frame by p / q (720: 3/2, 960: 2/1, 600: 5/4) computes a region from
    the frame's part alone (``_enlarged_part``), and its mask equals the one from the whole frame's resizes
    (``logits_full``, thresholded), pixel for pixel, for regions anywhere, at the frame's edges too."""
    seg = LearnedSegmenter(onnx_bytes(FINE_NAME), short_side=short_side)
    curve = s_curve(60, 580, 240, 140, 1.1)
    rgb, _ = render_cable(curve, thickness=2, color=(200, 60, 40), background=(150, 150, 150), seed=5)
    regions = [(0, 0, 200, 150), (37, 21, 603, 459), (300, 200, 640, 480), (101, 97, 131, 140),
               (250, 0, 420, 480)]
    for region in regions:
        assert seg._enlarged_part(rgb, region) is not None
        _, whole = cv2.threshold(seg.logits_full(rgb, region), seg.threshold, 1, cv2.THRESH_BINARY)
        part = seg.segment(rgb, region=region)
        np.testing.assert_array_equal(part, whole.astype(bool))
    assert seg.segment(rgb, region=(37, 21, 603, 459)).sum() > 300  # the cable is there to be compared
    assert LearnedSegmenter(onnx_bytes(FINE_NAME))._enlarged_part(rgb, regions[0]) is None  # not enlarged


def _smooth_frame(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Smooth random colours with a few dark curves: neither flat nor noise."""
    rng = np.random.default_rng(seed)
    rgb = cv2.resize(rng.integers(0, 256, (max(2, h // 24), max(2, w // 24), 3), dtype=np.uint8), (w, h),
                     interpolation=cv2.INTER_CUBIC)
    for k in range(3):
        xs = np.linspace(0, w - 1, 20)
        pts = np.column_stack([xs, h / 2 + h / 3 * np.sin(xs / w * 6 + k)]).astype(np.int32)
        cv2.polylines(rgb, [pts], False, (25, 25, 25), 3)
    return rgb


def _reference_blocks(rgb: np.ndarray) -> np.ndarray:
    """``RGB / 255 - 0.5`` as 4x4 blocks, channel ``c * 16 + 4 * i + j`` = colour c of pixel (i, j)."""
    h, w = rgb.shape[:2]
    x = rgb.astype(np.float64) / 255.0 - 0.5
    x = x.reshape(h // 4, 4, w // 4, 4, 3).transpose(4, 1, 3, 0, 2).reshape(1, 48, h // 4, w // 4)
    return x.astype(np.float32)


def test_a_block_network_sees_the_frame_as_training_resized_and_padded_it(photo: LearnedSegmenter) -> None:
    # Shrunk (960x720 -> 640x480) with area averaging, as segtrain.load_external resizes the photos.
    big = _smooth_frame(720, 960)
    small = cv2.resize(big, (640, 480), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(photo.network_input(big), _reference_blocks(small), atol=1e-6)
    # At its own size, a frame is padded to a multiple of 16 by repeating its last row and column.
    own = LearnedSegmenter(onnx_bytes(PHOTO_NAME), short_side=None)
    odd = _smooth_frame(70, 100, seed=1)
    padded = np.pad(odd, ((0, 10), (0, 12), (0, 0)), mode="edge")
    np.testing.assert_allclose(own.network_input(odd), _reference_blocks(padded), atol=1e-6)


def test_an_rgb_network_sees_the_resized_frame_in_rgb_order(seg: LearnedSegmenter) -> None:
    rgb = _smooth_frame(480, 640)
    small = cv2.resize(rgb, (320, 240), interpolation=cv2.INTER_AREA)
    expected = (small.astype(np.float32) / 255.0 - 0.5).transpose(2, 0, 1)[None]
    np.testing.assert_allclose(seg.network_input(rgb), expected, atol=1e-6)
    # Enlarged (short side 720 from 480) bilinearly.
    big = LearnedSegmenter(onnx_bytes(), short_side=720)
    enlarged = cv2.resize(rgb, (960, 720), interpolation=cv2.INTER_LINEAR)
    expected = (enlarged.astype(np.float32) / 255.0 - 0.5).transpose(2, 0, 1)[None]
    np.testing.assert_allclose(big.network_input(rgb), expected, atol=1e-6)


def test_the_input_size_without_a_short_side_is_the_frames_own() -> None:
    blocks = LearnedSegmenter(onnx_bytes(PHOTO_NAME), short_side=None)
    rgb_net = LearnedSegmenter(onnx_bytes(), short_side=None)
    assert blocks.input_size(70, 100) == (100, 70)
    assert rgb_net.input_size(70, 100) == (96, 72)  # RGB networks take multiples of 8
    assert blocks.input_size(3, 2) == (4, 4) and rgb_net.input_size(3, 2) == (8, 8)  # the smallest inputs
    assert LearnedSegmenter(onnx_bytes(), short_side=16).short_side == 16  # the least short side allowed
    for bad in (15, 480.0, True):
        with pytest.raises(ValueError, match=f"short_side must be 'auto', None or an int >= 16, got {bad!r}"):
            LearnedSegmenter(onnx_bytes(), short_side=bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("name", [SHIPPED_NAME, PHOTO_NAME])
def test_a_pixel_is_cable_where_its_logit_is_above_the_threshold(name: str) -> None:
    rgb = _smooth_frame(240, 320, seed=2)
    default = LearnedSegmenter(onnx_bytes(name))
    logits = default.logits_full(rgb)
    assert default.threshold == 0.0
    np.testing.assert_array_equal(default(rgb), logits > 0)
    assert 0 < (logits > 0).sum() and (logits > 1.0).sum() < (logits > 0).sum()
    np.testing.assert_array_equal(LearnedSegmenter(onnx_bytes(name), threshold=1.0)(rgb), logits > 1.0)
    probability = default.probability(rgb)
    assert probability.dtype == np.float32
    np.testing.assert_allclose(probability, 1.0 / (1.0 + np.exp(-logits)), atol=1e-6)


def test_small_parts_of_the_mask_are_dropped_below_min_area(photo: LearnedSegmenter) -> None:
    rgb = _smooth_frame(240, 320, seed=3)
    for k in range(6):  # short pieces of cable: small parts of the mask
        cv2.line(rgb, (30 + 45 * k, 200), (30 + 45 * k + 4 + 3 * k, 215), (20, 20, 20), 3)
    whole = photo(rgb)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(whole.astype(np.uint8), connectivity=8)
    areas = np.sort(stats[1:, cv2.CC_STAT_AREA])
    assert len(areas) >= 3 and areas[0] < areas[-1]
    sizes = np.unique(areas)  # most parts may be single pixels: cut at the middle size, not the middle part
    cut = int(sizes[len(sizes) // 2])  # parts of exactly this area are kept
    kept = LearnedSegmenter(onnx_bytes(PHOTO_NAME), min_area=cut)(rgb)
    expected = np.isin(labels, 1 + np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= cut))
    np.testing.assert_array_equal(kept, expected)
    assert kept.sum() < whole.sum()
    np.testing.assert_array_equal(LearnedSegmenter(onnx_bytes(PHOTO_NAME), min_area=1)(rgb), whole)


def test_a_region_is_computed_on_the_networks_grid_and_outside_it_there_is_no_cable() -> None:
    seg = LearnedSegmenter(onnx_bytes(PHOTO_NAME))  # 960x720 is shrunk to 640x480: 2/3
    assert seg.grid_box((300, 150, 600, 450), 720, 960) == (192, 96, 400, 304)
    assert seg.grid_box((0, 0, 30, 30), 720, 960) == (0, 0, 32, 32)
    assert seg.grid_box((960, 100, 990, 200), 720, 960) == (0, 0, 0, 0)  # beyond the right edge
    rgb = _smooth_frame(480, 640, seed=4)
    logits = seg.logits(rgb, (100, 100, 300, 200))
    outside = np.ones(logits.shape, bool)
    outside[96:208, 96:304] = False
    assert logits.dtype == np.float32 and np.all(logits[outside] == OUTSIDE_LOGIT)
    # A frame whose size is no multiple of 16, with a region at its far corner: the part is padded and cut.
    own = LearnedSegmenter(onnx_bytes(PHOTO_NAME), short_side=None)
    odd = _smooth_frame(150, 200, seed=5)
    part = own.segment(odd, (40, 40, 200, 150))
    assert part.shape == (150, 200) and not part[:32].any() and not part[:, :32].any()
    # Inside, the mask is the whole frame's but where the network's view (about 100 px) crosses the edge.
    assert dice(part[32:, 32:], own.segment(odd)[32:, 32:]) > 0.8


def _red_blocks_onnx() -> bytes:
    """A block-layout network whose logits are the red channel, ``R / 255 - 0.5``, of every pixel: its mask
    is exactly the pixels with R > 127, so the rules after the network can be checked pixel by pixel."""
    pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    x = helper.make_tensor_value_info("rgb", TensorProto.FLOAT, [1, 48, "h", "w"])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 16, "h", "w"])
    consts = [numpy_helper.from_array(np.array([v], np.int64), name) for v, name in
              ((0, "starts"), (16, "ends"), (1, "axes"))]
    node = helper.make_node("Slice", ["rgb", "starts", "ends", "axes"], ["y"])
    model = helper.make_model(helper.make_graph([node], "red", [x], [y], initializer=consts),
                              opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    return bytes(model.SerializeToString())


def test_min_area_drops_parts_smaller_than_it_and_keeps_the_rest() -> None:
    rgb = np.zeros((64, 96, 3), np.uint8)
    rgb[5, 5, 0] = 255  # 1 pixel
    rgb[5, 20:22, 0] = 255  # 2 pixels
    rgb[20, 5:10, 0] = 255  # 5 pixels
    rgb[40:43, 40:50, 0] = 255  # 30 pixels
    rgb[60, 90:92, 0] = 200  # 2 pixels at the frame's corner
    onnx = _red_blocks_onnx()
    everything = LearnedSegmenter(onnx, short_side=None)(rgb)
    np.testing.assert_array_equal(everything, rgb[..., 0] > 127)
    for min_area, kept in ((0, 40), (1, 40), (2, 39), (3, 35), (6, 30), (30, 30), (31, 0)):
        mask = LearnedSegmenter(onnx, short_side=None, min_area=min_area)(rgb)
        assert mask.sum() == kept, min_area
        assert not (mask & ~everything).any()


def test_a_region_at_or_beyond_the_frames_edge_is_empty() -> None:
    rgb = np.full((48, 64, 3), 255, np.uint8)  # cable everywhere for the red network
    own = LearnedSegmenter(_red_blocks_onnx(), short_side=None)
    assert own.grid_box((10, 48, 30, 60), 48, 64) == (0, 0, 0, 0)  # starts at the bottom edge
    assert own.grid_box((64, 10, 80, 20), 48, 64) == (0, 0, 0, 0)  # starts at the right edge
    for region in ((10, 48, 30, 60), (64, 10, 80, 20), (-30, -30, -1, -1)):
        assert not own.segment(rgb, region).any()
    # Enlarged 3/2 (a part of the frame enlarged on its own): the same.
    big = LearnedSegmenter(_red_blocks_onnx(), short_side=72)
    assert big.input_size(48, 64) == (96, 72)
    for region in ((10, 48, 30, 60), (64, 10, 80, 20)):
        assert not big.segment(rgb, region).any()
    part = big.segment(rgb, (16, 16, 40, 32))
    assert part[16:32, 16:40].all() and part.sum() < part.size
