"""Training of the learned cable segmenter on ``seg-data`` datasets, ONNX export.

Two architectures (:func:`build_net`), both small encoder-decoders (about 30 k parameters at the default
widths; ``--widths`` and ``--blocks`` make them wider and deeper, and with ``--init`` start from a narrower or
shallower network's function: :func:`widened`, :func:`deepened`):
``cablenet-s2d4`` (``seg-train``'s default; shipped as ``cable-segmenter-fine``) takes the frame as 4x4
blocks and gives 16 sub-pixel logits per block, so its mask has the frame's full resolution; ``cablenet``
(shipped as ``cable-segmenter``, the default network) gives logits at half its input, which the run-time
side upsamples. A cable 1.6 px wide in a 640x480 frame, the loop's camera, is 0.4 px at ``cablenet``'s
output when it runs at 320x240, and comes out in fragments.
Training computes the loss on the logits at the input's resolution exactly as they are made at run time
(:func:`full_res_logits`), so what is trained is what runs. Inference runs through ONNX Runtime on the
exported ONNX file (:class:`dyndlo_vision.tracking.learned.LearnedSegmenter`;
``benchmarks/segmenter_engines.py`` compares it with OpenCV's ``cv2.dnn``, itself several times faster than
torch on one core).

Fine-tuning on labelled real photos (``--external``) mixes them into the batches; only the ``train`` half
of :func:`external_split` is used, the other half is held out for reporting.
"""

from __future__ import annotations

import io
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision._atomic import interrupts_held, write_atomic

__all__ = [
    "ARCHITECTURES",
    "CableNet",
    "TrainConfig",
    "build_net",
    "export_onnx",
    "is_onnx_init",
    "needs_frozen_batch_norm",
    "net_from_onnx",
    "external_source",
    "external_split",
    "full_res_logits",
    "load_external",
    "train",
]


def _torch() -> Any:
    import torch

    return torch


#: Architectures :func:`build_net` knows. ``cablenet``: the first shipped network (RGB in, logits at half the
#: input). ``cablenet-s2d4``: the frame enters as 4x4 space-to-depth blocks (48 channels at 1/4 of the frame,
#: every pixel kept) and leaves as 16 sub-pixel logits per block, so the mask has the frame's own resolution
#: and a cable 1-2 px wide is not lost to downsampling.
ARCHITECTURES = ("cablenet", "cablenet-s2d4")

#: Block size of the ``cablenet-s2d4`` layout (the run-time side reads it from the network's channel counts).
S2D_BLOCK = 4


#: :func:`build_net`'s default channels (c1, c2, c3): those of both shipped networks.
DEFAULT_WIDTHS = (8, 16, 32)


def build_net(arch: str = "cablenet", c1: int = 8, c2: int = 16, c3: int = 32, blocks: int = 0) -> Any:
    """The network of architecture ``arch`` (see :data:`ARCHITECTURES`; torch is imported only here).

    ``cablenet``: three stride-2 convolutions to 1/8 of the input, two dilated convolutions (dilation 2 and
    4) for context, and two decoder stages with skips back to 1/2, where one logit per pixel is produced.
    ``cablenet-s2d4``: the same encoder-decoder one level lower: its input is the frame in 4x4 blocks
    (N x 48 x H/4 x W/4, channel ``c * 16 + 4 * i + j`` = colour ``c`` of pixel ``(i, j)`` of the block, as
    ``torch.nn.functional.pixel_unshuffle``), a 1x1 convolution mixes each block, two stride-2
    convolutions go to 1/16 of the frame, and the output is 16 logits per block (``pixel_shuffle`` order).
    ``blocks``: residual blocks (two 3x3 convolutions, the second's output added to the block's input) at the
    finest level, just before the output, where a cable's edges are told from a cable-like shadow or stroke
    beside it (``cablenet-s2d4``: 1/4 of the frame, ``2 c1`` channels, the only 3x3 convolutions at that
    level, each block ``72 c1**2`` parameters; ``cablenet``: 1/2 of its input, ``c1`` channels).
    """
    if arch not in ARCHITECTURES:
        raise ValueError(f"arch must be one of {ARCHITECTURES}, got {arch!r}")
    if isinstance(blocks, bool) or not isinstance(blocks, int) or blocks < 0:
        raise ValueError(f"blocks must be an int >= 0, got {blocks!r}")
    torch = _torch()
    nn = torch.nn
    functional = torch.nn.functional

    def cbr(i: int, o: int, k: int = 3, s: int = 1, d: int = 1) -> Any:
        return nn.Sequential(
            nn.Conv2d(i, o, k, s, padding=d * (k // 2), dilation=d, bias=False), nn.BatchNorm2d(o), nn.ReLU()
        )

    def up(x: Any) -> Any:
        return functional.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)

    s2d = arch == "cablenet-s2d4"
    w1 = 2 * c1 if s2d else c1  # width of the finest level

    class Residual(nn.Module):  # type: ignore[misc,name-defined]
        """``relu(x + bn(conv(relu(bn(conv(x))))))``: the identity while the second batch norm's scale and
        shift are 0, which is how :func:`deepened` adds one."""

        def __init__(self, c: int) -> None:
            super().__init__()
            self.a = cbr(c, c)
            self.b = nn.Sequential(nn.Conv2d(c, c, 3, 1, padding=1, bias=False), nn.BatchNorm2d(c))

        def forward(self, x: Any) -> Any:
            return functional.relu(x + self.b(self.a(x)))

    class CableNet(nn.Module):  # type: ignore[misc,name-defined]
        def __init__(self) -> None:
            super().__init__()
            if s2d:  # 4x4 blocks in: one 1x1 convolution mixes each block's 48 values
                self.e1 = cbr(3 * S2D_BLOCK * S2D_BLOCK, w1, k=1)
            else:  # RGB in: a stride-2 convolution to half the input
                self.e1 = cbr(3, w1, s=2)
            self.e2, self.e3 = cbr(w1, c2, s=2), cbr(c2, c3, s=2)
            self.e4, self.e5 = cbr(c3, c3, d=2), cbr(c3, c3, d=4)
            self.d2, self.d2b = cbr(c3 + c2, c2, k=1), cbr(c2, c2)
            self.d1 = cbr(c2 + w1, w1, k=1)
            # Registered between d1 and out, the order they run in: net_from_onnx pairs modules and the ONNX
            # file's convolutions by position.
            self.fine = nn.Sequential(*[Residual(w1) for _ in range(blocks)])
            self.out = nn.Conv2d(w1, S2D_BLOCK * S2D_BLOCK if s2d else 1, 1)

        def forward(self, x: Any) -> Any:
            e1 = self.e1(x)
            e2 = self.e2(e1)
            e = self.e5(self.e4(self.e3(e2)))
            d = self.d2b(self.d2(torch.cat([up(e), e2], 1)))
            return self.out(self.fine(self.d1(torch.cat([up(d), e1], 1))))

    return CableNet()


def full_res_logits(net: Any, x: Any, arch: str) -> Any:
    """Logits of a batch of RGB inputs ``x`` (N x 3 x H x W, ``RGB / 255 - 0.5``) at the input's size: the
    ``cablenet-s2d4`` blocks go in and out with ``pixel_unshuffle``/``pixel_shuffle`` (H, W multiples of 16);
    ``cablenet``'s half-size logits are upsampled bilinearly, as at run time."""
    functional = _torch().nn.functional
    if arch == "cablenet-s2d4":
        return functional.pixel_shuffle(net(functional.pixel_unshuffle(x, S2D_BLOCK)), S2D_BLOCK)
    return functional.interpolate(net(x), size=x.shape[2:], mode="bilinear", align_corners=False)


CableNet = build_net  # the factory is the public name of the architecture


def export_onnx(net: Any) -> bytes:
    """The network (eval mode, batch norm folded by the exporter) as ONNX bytes with dynamic H, W.

    Its input is what the network takes: RGB for ``cablenet``, 4x4 blocks for ``cablenet-s2d4`` (the
    run-time side tells them apart by the number of input channels)."""
    torch = _torch()
    net = net.eval()
    buf = io.BytesIO()
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net,
            torch.zeros(1, net_in_channels(net), 64, 80),
            buf,
            dynamo=False,
            input_names=["rgb"],
            output_names=["logit"],
            dynamic_axes={"rgb": {2: "h", 3: "w"}, "logit": {2: "h2", 3: "w2"}},
            opset_version=13,
        )
    return buf.getvalue()


def net_from_onnx(data: bytes) -> tuple[Any, str, tuple[int, int, int], int]:
    """The :func:`build_net` network an exported ONNX file holds (``net``, ``arch``, ``widths``,
    ``blocks``).

    The export folded each batch norm into its convolution, so the weights come back as the folded
    convolution and a batch norm that is the identity plus the folded bias (mean 0, variance 1 - eps,
    scale 1). In eval mode the network computes what the ONNX file does. Fine-tune it with the batch norms
    in eval mode (:attr:`TrainConfig.frozen_batch_norm`): their statistics are gone, and batch statistics
    would change every layer's output at the first step. Needs the ``onnx`` package.

    Raises:
        ValueError: the file is not a network :func:`build_net` exports.
    """
    try:
        import onnx
        from onnx import numpy_helper
    except ImportError as e:  # pragma: no cover - the train-segmenter extra
        raise ImportError("reading an ONNX network needs the onnx package: pip install onnx") from e
    torch = _torch()
    try:
        model = onnx.load_from_string(data)
    except Exception as e:  # protobuf's DecodeError and kin
        raise ValueError(f"not an ONNX file ({type(e).__name__}: {e})") from e
    weights = {t.name: np.array(numpy_helper.to_array(t)) for t in model.graph.initializer}
    # The exporter keeps one copy of equal tensors (zero biases, the zeroed convolutions of a block just added
    # by deepened) and names the others through Identity nodes.
    weights.update({n.output[0]: weights[n.input[0]] for n in model.graph.node
                    if n.op_type == "Identity" and n.input and n.input[0] in weights})
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    if len(convs) < 9 or len(convs) % 2 == 0 or not all(len(n.input) == 3 and n.input[1] in weights
                                                          for n in convs):
        raise ValueError(f"not a cablenet ONNX file: {len(convs)} convolutions, expected 9 (and two more per "
                         "residual block) with weights and bias")
    blocks = (len(convs) - 9) // 2
    shapes = [weights[n.input[1]].shape for n in convs]
    arch = "cablenet-s2d4" if shapes[0][1] == 3 * S2D_BLOCK * S2D_BLOCK else "cablenet"
    widths = (shapes[0][0] // 2 if arch == "cablenet-s2d4" else shapes[0][0], shapes[1][0], shapes[2][0])
    net = build_net(arch, *widths, blocks=blocks)
    modules = [m for m in net.modules() if isinstance(m, torch.nn.Conv2d)]
    norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    if [tuple(m.weight.shape) for m in modules] != [tuple(s) for s in shapes]:
        raise ValueError(f"not a cablenet ONNX file: convolution shapes {shapes}")
    with torch.no_grad():
        for k, (module, node) in enumerate(zip(modules, convs, strict=True)):
            module.weight.copy_(torch.from_numpy(weights[node.input[1]]))
            bias = torch.from_numpy(weights[node.input[2]])
            if k < len(norms):  # a convolution without bias, then its batch norm
                bn = norms[k]
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0 - bn.eps)
                bn.weight.fill_(1.0)
                bn.bias.copy_(bias)
            else:  # the output convolution
                module.bias.copy_(bias)
    return net.eval(), arch, widths, blocks


def net_in_channels(net: Any) -> int:
    """Input channels of a :func:`build_net` network (3: RGB; 48: 4x4 blocks)."""
    return int(net.e1[0].in_channels)


# ----------------------------------------------------------------------------- data
def _read_rgb(path: Path) -> NDArray[np.uint8]:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"cannot read image {path}")
    return np.ascontiguousarray(bgr[..., ::-1])


def load_dataset(folder: Path) -> tuple[list[NDArray[np.uint8]], list[NDArray[np.uint8]]]:
    """Images and 0/1 masks of a ``seg-data`` folder (samples with both files)."""
    folder = Path(folder)
    if not (folder / "dataset.json").is_file():
        raise ValueError(f"{folder} is not a seg-data dataset (no dataset.json)")
    images, masks = [], []
    for mp in sorted(folder.glob("[0-9]*_mask.png")):
        ip = mp.with_name(mp.name.replace("_mask", ""))
        if not ip.is_file():
            continue
        images.append(_read_rgb(ip))
        masks.append((cv2.imread(str(mp), cv2.IMREAD_GRAYSCALE) > 127).astype(np.uint8))
    if not images:
        raise ValueError(f"{folder} holds no samples")
    return images, masks


def external_source(image: Path) -> str:
    """Which source an image of :func:`external_split` comes from: ``mbest`` or ``cables_dataset``."""
    return "mbest" if "mbest" in Path(image).parts else "cables_dataset"


def external_split(root: Path) -> dict[str, list[tuple[Path, Path]]]:
    """(image, mask) pairs of ``root`` (the shared external data) split in two halves, by sorted order.

    mBEST (``mbest/S*/imgN.jpg`` with ``imgN_labels.png``, any label > 0 is cable) and cables_dataset
    (``NNNNN.jpg`` with ``NNNNN_mask_all.png``): within each folder, images in even positions of the sorted
    list are ``train``, odd positions ``heldout``.
    """
    root = Path(root)
    pairs: dict[str, list[tuple[Path, Path]]] = {"train": [], "heldout": []}
    folders = sorted((root / "mbest").glob("S*")) + [root / "cables_dataset"]
    for folder in folders:
        items = []
        for img in sorted(folder.glob("*.jpg"), key=lambda p: (len(p.stem), p.stem)):
            lab = img.with_name(img.stem + "_labels.png")
            if not lab.is_file():
                lab = img.with_name(img.stem + "_mask_all.png")
            if lab.is_file():
                items.append((img, lab))
        for k, item in enumerate(items):
            pairs["train" if k % 2 == 0 else "heldout"].append(item)
    return pairs


def load_external(pairs: list[tuple[Path, Path]], short_side: int = 240) -> tuple[list[Any], list[Any]]:
    """Images and 0/1 masks, resized so the shorter side is ``short_side`` (as the segmenter sees them)."""
    images, masks = [], []
    for img_path, lab_path in pairs:
        rgb = _read_rgb(img_path)
        lab = cv2.imread(str(lab_path), cv2.IMREAD_GRAYSCALE)
        s = short_side / min(rgb.shape[:2])
        size = (int(round(rgb.shape[1] * s)), int(round(rgb.shape[0] * s)))
        images.append(cv2.resize(rgb, size, interpolation=cv2.INTER_AREA))
        m = cv2.resize((lab > 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)
        masks.append((m >= 0.5).astype(np.uint8))
    return images, masks


#: Least scale of :func:`_augment` (the image is resized by a log-uniform draw from here to ``max_scale``),
#: and the largest one unless a run asks for another (``TrainConfig.max_scale``).
MIN_SCALE, DEFAULT_MAX_SCALE = 0.6, 1.5


def _augment(
    rng: np.random.Generator, rgb: NDArray[np.uint8], mask: NDArray[np.uint8], crop: tuple[int, int],
    max_scale: float = DEFAULT_MAX_SCALE,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    ch, cw = crop
    s = float(np.exp(rng.uniform(math.log(MIN_SCALE), math.log(max_scale))))
    h, w = rgb.shape[:2]
    s = max(s, ch / h + 1e-3, cw / w + 1e-3)
    size = (int(math.ceil(w * s)), int(math.ceil(h * s)))
    img = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    m = cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_LINEAR)
    y = int(rng.integers(0, size[1] - ch + 1))
    x = int(rng.integers(0, size[0] - cw + 1))
    img, m = img[y : y + ch, x : x + cw], m[y : y + ch, x : x + cw]
    if rng.random() < 0.5:
        img, m = img[:, ::-1], m[:, ::-1]
    if rng.random() < 0.5:
        img, m = img[::-1], m[::-1]
    x_in = img.astype(np.float32) * (1.0 / 255.0) - 0.5
    if rng.random() < 0.15:  # colour jitter: channel shuffle (not grey: a cable set apart by colour alone
        x_in = x_in[..., rng.permutation(3)]  # would vanish while its label stays)
    return np.ascontiguousarray(x_in.transpose(2, 0, 1)), (m >= 0.4).astype(np.float32)


_LAYOUTS = {
    "cablenet": "RGB float32 NCHW, value/255 - 0.5; logits at 1/2 of the input; upsampled, > 0 = cable",
    "cablenet-s2d4": "RGB value/255 - 0.5 as 4x4 blocks (pixel_unshuffle, 48 channels at 1/4); 16 logits per "
    "block (pixel_shuffle order) give the input's resolution; > 0 = cable",
}


@dataclass(frozen=True)
class TrainConfig:
    """Hyperparameters of :func:`train` (stored in the checkpoint and the shipped JSON)."""

    steps: int = 6000
    batch: int = 8
    crop_h: int = 160
    crop_w: int = 224
    lr: float = 3e-3
    pos_weight: float = 3.0
    seed: int = 0
    #: Network architecture (:data:`ARCHITECTURES`).
    arch: str = "cablenet-s2d4"
    #: Channels (c1, c2, c3) of :func:`build_net`'s levels.
    widths: tuple[int, int, int] = DEFAULT_WIDTHS
    #: Residual blocks at the finest level (:func:`build_net`).
    blocks: int = 0
    #: Share of each batch drawn from the external train split (0: synthetic only).
    external_share: float = 0.0
    #: The external photos are resized to this short side before augmentation (the scale the network will
    #: see them at; 240: the first shipped networks').
    external_short_side: int = 240
    #: Each external source equally likely, then an image within it (False: every image equally likely, so
    #: a source with few photos, such as cables_dataset's 5 beside mBEST's 20, is seldom drawn).
    external_balanced: bool = False
    checkpoint_every: int = 250
    #: Batch norms in eval mode while training (their statistics fixed, scale and shift still trained): how a
    #: network read back from ONNX (:func:`net_from_onnx`) is fine-tuned.
    frozen_batch_norm: bool = False
    #: Largest scale an image is resized by before its crop (:func:`_augment`; least: :data:`MIN_SCALE`).
    #: ``segment`` enlarges a 384x288 photo 1.67x to its 480 px short side, 2x a 320x240 one.
    max_scale: float = DEFAULT_MAX_SCALE


def _with_widths(config: dict[str, Any]) -> dict[str, Any]:
    """A stored training config with ``widths`` as a tuple; options it predates at their defaults."""
    return {"frozen_batch_norm": False, "external_short_side": 240, "external_balanced": False, "blocks": 0,
            "max_scale": DEFAULT_MAX_SCALE, **config,
            "widths": tuple(config.get("widths", DEFAULT_WIDTHS))}


def is_onnx_init(init: str | Path) -> bool:
    """Whether ``--init`` names an ONNX network (a ``.onnx`` file or a shipped segmenter's name), which
    :func:`train` reads with :func:`net_from_onnx`, rather than a ``seg-train`` checkpoint."""
    from dyndlo_vision.tracking.networks import SHIPPED_NAMES

    return str(init) in SHIPPED_NAMES or Path(init).suffix.lower() == ".onnx"


def needs_frozen_batch_norm(init: str | Path) -> bool:
    """Whether fine-tuning from ``init`` must keep the batch norms frozen: an ONNX network (its statistics
    were folded away), or a checkpoint of a run that froze them (its statistics are still the identities)."""
    if is_onnx_init(init):
        return True
    state = _torch().load(Path(init), weights_only=False)
    return bool(state.get("config", {}).get("frozen_batch_norm", False))


def _draw_external(rng: np.random.Generator, by_source: list[list[int]], balanced: bool) -> int:
    """An index into the external photos: every photo equally likely, or (``balanced``) a source first, each
    equally likely, then one of its photos."""
    if balanced:
        members = by_source[int(rng.integers(len(by_source)))]
        return members[int(rng.integers(len(members)))]
    return int(rng.integers(sum(len(m) for m in by_source)))


def _atomic_save(obj: Any, path: Path) -> None:
    """``torch.save`` to ``path`` whole or not at all; a Ctrl-C meanwhile is raised once it is written."""
    torch = _torch()
    with interrupts_held():
        write_atomic(path, lambda tmp: torch.save(obj, tmp))


def train(
    data: Path | list[Path],
    out: Path,
    config: TrainConfig,
    *,
    resume: bool = False,
    external: Path | None = None,
    init: Path | None = None,
    progress: bool = True,
    threads: int = 1,
) -> dict[str, Any]:
    """Trains (or resumes) a :func:`build_net` network; writes ``out/checkpoint.pt``, ``history.json``, and at
    the end ``cable_segmenter.onnx`` with ``cable_segmenter.json``. Returns the metadata written to the
    JSON."""
    torch = _torch()
    from tqdm import tqdm

    torch.set_num_threads(int(threads))
    out = Path(out)
    ckpt_path = out / "checkpoint.pt"
    if resume:
        if not ckpt_path.is_file():
            raise FileNotFoundError(f"--resume: no checkpoint at {ckpt_path}")
    elif out.exists() and any(out.iterdir()):
        raise FileExistsError(f"--out {out} already holds files; use --resume to continue, or another folder")
    _check_config(config, external)
    init_weights = None if init is None or resume else _init_weights(init, config)
    folders = [Path(f) for f in (data if isinstance(data, (list, tuple)) else [data])]
    images, masks, ext_images, ext_masks, by_source = _load_training_data(folders, external, config)
    out.mkdir(parents=True, exist_ok=True)
    net = build_net(config.arch, *config.widths, blocks=config.blocks)
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    step = 0
    history: list[dict[str, float]] = []
    rng = np.random.default_rng(config.seed)
    if resume:
        ck = torch.load(ckpt_path, weights_only=False)
        # Checkpoints from before the widths option hold the default ones.
        if _with_widths(ck["config"]) != _with_widths(asdict(config)):
            raise ValueError(
                f"--resume with other settings than the checkpoint's: {ck['config']} vs {asdict(config)}"
            )
        net.load_state_dict(ck["net"])
        opt.load_state_dict(ck["opt"])
        step, history = int(ck["step"]), list(ck["history"])
        rng.bit_generator.state = ck["rng"]
    elif init_weights is not None:
        net.load_state_dict(init_weights)
    pos_weight = torch.tensor([config.pos_weight])
    bar = tqdm(
        total=config.steps,
        initial=step,
        desc="seg-train",
        unit="step",
        file=sys.stderr,
        disable=not progress,
        dynamic_ncols=True,
    )

    def save_checkpoint() -> None:
        """Everything a resumed run needs: weights, optimiser, step, history and the random stream."""
        state = {"net": net.state_dict(), "opt": opt.state_dict(), "step": step, "history": history,
                 "rng": rng.bit_generator.state, "config": asdict(config)}
        _atomic_save(state, ckpt_path)

    net.train()
    if config.frozen_batch_norm:
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.eval()
    t0 = time.perf_counter()
    running = 0.0
    try:
        while step < config.steps:
            lr = config.lr * (0.03 + 0.97 * 0.5 * (1 + math.cos(math.pi * step / config.steps)))
            for g in opt.param_groups:
                g["lr"] = lr
            xb, yb = _batch(rng, config, images, masks, ext_images, ext_masks, by_source)
            logit = full_res_logits(net, xb, config.arch)
            bce = torch.nn.functional.binary_cross_entropy_with_logits(logit, yb, pos_weight=pos_weight)
            p = torch.sigmoid(logit)
            inter = (p * yb).sum(dim=(1, 2, 3))
            dice = 1 - (2 * inter + 1) / (p.sum(dim=(1, 2, 3)) + yb.sum(dim=(1, 2, 3)) + 1)
            loss = bce + dice.mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            running = 0.98 * running + 0.02 * float(loss.detach()) if step > 1 else float(loss.detach())
            bar.update(1)
            bar.set_postfix(loss=f"{running:.3f}")
            if step % 50 == 0:
                history.append({"step": step, "loss": running, "lr": lr, "wall_s": time.perf_counter() - t0})
            if step % config.checkpoint_every == 0 or step == config.steps:
                save_checkpoint()
    except KeyboardInterrupt:
        save_checkpoint()
        bar.close()
        raise
    bar.close()
    (out / "history.json").write_text(json.dumps(history))
    onnx = export_onnx(net)
    (out / "cable_segmenter.onnx").write_bytes(onnx)
    meta = _metadata(config, net, folders, len(images), len(ext_images), init, running)
    (out / "cable_segmenter.json").write_text(json.dumps(meta, indent=1))
    return meta


def _check_config(config: TrainConfig, external: Path | None) -> None:
    """Settings :func:`train` refuses (ValueError)."""
    if config.external_share > 0 and external is None:
        raise ValueError("external_share > 0 needs --external DIR")
    if isinstance(config.external_short_side, bool) or not isinstance(config.external_short_side, int) or (
            config.external_short_side < 64):
        raise ValueError(f"external_short_side must be an int >= 64, got {config.external_short_side!r}")
    if config.arch not in ARCHITECTURES:
        raise ValueError(f"arch must be one of {ARCHITECTURES}, got {config.arch!r}")
    if len(config.widths) != 3 or not all(isinstance(c, int) and c >= 1 for c in config.widths):
        raise ValueError(f"widths must be three positive ints (c1, c2, c3), got {config.widths!r}")
    if isinstance(config.blocks, bool) or not isinstance(config.blocks, int) or config.blocks < 0:
        raise ValueError(f"blocks must be an int >= 0, got {config.blocks!r}")
    if not (isinstance(config.max_scale, (int, float)) and math.isfinite(config.max_scale)
            and MIN_SCALE <= config.max_scale <= 4.0):
        raise ValueError(f"max_scale must be a number in [{MIN_SCALE}, 4], got {config.max_scale!r}")
    if config.arch == "cablenet-s2d4" and (config.crop_h % 16 or config.crop_w % 16):
        raise ValueError(
            f"cablenet-s2d4 needs crops in multiples of 16 px, got {config.crop_h}x{config.crop_w}"
        )


def _init_weights(init: str | Path, config: TrainConfig) -> Any:
    """The weights of ``--init`` (a checkpoint or a shipped ONNX network) for a network of ``config``."""
    torch = _torch()
    if is_onnx_init(init):
        from dyndlo_vision.tracking.networks import onnx_bytes

        if not config.frozen_batch_norm:
            raise ValueError(f"--init {init} is an ONNX network, whose batch-norm statistics the export "
                             "folded away: fine-tune it with frozen_batch_norm=True")
        init_net, init_arch, init_widths, init_blocks = net_from_onnx(onnx_bytes(init))
        init_weights = init_net.state_dict()
    else:
        init_state = torch.load(Path(init), weights_only=False)
        if init_state.get("config", {}).get("frozen_batch_norm", False) and not config.frozen_batch_norm:
            raise ValueError(f"--init {init} comes from a run with frozen batch norms (its statistics "
                             "are identities): fine-tune it with frozen_batch_norm=True")
        init_weights = init_state["net"]
        init_arch = init_state.get("config", {}).get("arch", "cablenet")  # before the choice: cablenet
        init_widths = tuple(init_state.get("config", {}).get("widths", DEFAULT_WIDTHS))
        init_blocks = int(init_state.get("config", {}).get("blocks", 0))
    if init_arch != config.arch:
        raise ValueError(f"--init {init} holds a {init_arch} network; train it with --arch {init_arch}")
    if config.blocks != init_blocks:
        if config.blocks < init_blocks or tuple(config.widths) != tuple(init_widths):
            raise ValueError(f"--init {init} holds a network of widths {init_widths} with {init_blocks} "
                             f"residual blocks; train it with --blocks {init_blocks} or more and --widths "
                             f"{','.join(map(str, init_widths))} (more blocks deepen it)")
        shallow = build_net(init_arch, *init_widths, blocks=init_blocks)
        shallow.load_state_dict(init_weights)
        return deepened(shallow, init_arch, init_widths, init_blocks, config.blocks, config.seed).state_dict()
    if tuple(config.widths) == tuple(2 * c for c in init_widths):
        if init_blocks:
            raise ValueError(f"--init {init} has {init_blocks} residual blocks: widening is for networks "
                             "without (--blocks 0)")
        narrow = build_net(init_arch, *init_widths)
        narrow.load_state_dict(init_weights)
        return widened(narrow, init_arch, init_widths, config.seed).state_dict()
    if init_widths != tuple(config.widths):
        doubled = ",".join(str(2 * c) for c in init_widths)
        raise ValueError(f"--init {init} holds a network of widths {init_widths}; train it with --widths "
                         f"{','.join(map(str, init_widths))}, or {doubled} to widen it")
    return init_weights


def deepened(net: Any, arch: str, widths: tuple[int, int, int], blocks: int, to_blocks: int,
             seed: int = 0) -> Any:
    """A :func:`build_net` network with ``to_blocks`` residual blocks instead of ``net``'s ``blocks`` that
    computes the same logits (Net2DeeperNet): the added blocks get random convolutions (``seed``) and a
    second batch norm of scale and shift 0, so each starts as the identity and learns from there."""
    torch = _torch()
    if to_blocks < blocks:
        raise ValueError(f"deepened: to_blocks must be >= blocks ({blocks}), got {to_blocks}")
    with torch.random.fork_rng():  # the added blocks' draws leave the caller's random stream as it was
        torch.manual_seed(int(seed))
        deep = build_net(arch, *widths, blocks=to_blocks).train(net.training)
    missing, unexpected = deep.load_state_dict(net.state_dict(), strict=False)
    assert not unexpected and all(k.startswith("fine.") for k in missing), (missing, unexpected)
    with torch.no_grad():
        for block in list(deep.fine)[blocks:]:
            block.b[1].weight.zero_()
            block.b[1].bias.zero_()
    return deep


def widened(net: Any, arch: str, widths: tuple[int, int, int], seed: int = 0) -> Any:
    """A :func:`build_net` network twice as wide as ``net`` (of ``arch`` and ``widths``) that computes the
    same logits (Net2WiderNet): every hidden channel is copied, and each layer that reads a channel and its
    copy gets the original weight split between the two at a random ratio in 0.4-0.6 (``seed``), so the pair
    sums to what it was and learns apart. A wider network starts from what a narrower one has learnt."""
    torch = _torch()
    c1, c2, c3 = widths
    w1 = 2 * c1 if arch == "cablenet-s2d4" else c1
    wide = build_net(arch, 2 * c1, 2 * c2, 2 * c3).train(net.training)
    gen = torch.Generator().manual_seed(int(seed))
    # Each layer's input, as the parts it concatenates (None: the frame, which is not widened).
    inputs = {"e1": None, "e2": [w1], "e3": [c2], "e4": [c3], "e5": [c3], "d2": [c3, c2], "d2b": [c2],
              "d1": [c2, w1], "out": [w1]}

    def split(weight: Any, parts: list[int]) -> Any:
        """(O, sum(parts), k, k) -> (O, 2 sum(parts), k, k): each part's channels, then their copies."""
        out, start = [], 0
        for size in parts:
            w = weight[:, start : start + size]
            start += size
            share = 0.4 + 0.2 * torch.rand(w.shape, generator=gen)
            out += [w * share, w * (1.0 - share)]
        return torch.cat(out, 1)

    with torch.no_grad():
        for name, parts in inputs.items():
            old, new = getattr(net, name), getattr(wide, name)
            conv, wide_conv = (old, new) if name == "out" else (old[0], new[0])
            weight = conv.weight if parts is None else split(conv.weight, parts)
            if name == "out":
                wide_conv.weight.copy_(weight)
                wide_conv.bias.copy_(conv.bias)
                continue
            wide_conv.weight.copy_(torch.cat([weight, weight], 0))
            for attr in ("weight", "bias", "running_mean", "running_var"):
                getattr(new[1], attr).copy_(torch.cat([getattr(old[1], attr)] * 2, 0))
    return wide


def _load_training_data(folders: list[Path], external: Path | None, config: TrainConfig) -> tuple[
        list[Any], list[Any], list[Any], list[Any], list[list[int]]]:
    """The datasets' images and masks, the external training photos and masks, and the photos' indices per
    source."""
    images, masks = [], []
    for folder in folders:  # every sample of every folder equally likely
        folder_images, folder_masks = load_dataset(folder)
        images += folder_images
        masks += folder_masks
    ext_images: list[Any] = []
    ext_masks: list[Any] = []
    by_source: list[list[int]] = []  # indices of ext_images per external source
    if external is not None and config.external_share > 0:
        pairs = external_split(Path(external))["train"]
        ext_images, ext_masks = load_external(pairs, config.external_short_side)
        if not ext_images:
            raise ValueError(f"no labelled images found under {external}")
        sources = [external_source(pair[0]) for pair in pairs]
        by_source = [[k for k, name in enumerate(sources) if name == source]
                     for source in sorted(set(sources))]
    return images, masks, ext_images, ext_masks, by_source


def _batch(rng: np.random.Generator, config: TrainConfig, images: list[Any], masks: list[Any],
           ext_images: list[Any], ext_masks: list[Any], by_source: list[list[int]]) -> tuple[Any, Any]:
    """One augmented batch: inputs (B, C, H, W) and masks (B, 1, H, W) as tensors."""
    torch = _torch()
    xs, ys = [], []
    for _ in range(config.batch):
        if ext_images and rng.random() < config.external_share:
            k = _draw_external(rng, by_source, config.external_balanced)
            x, y = _augment(rng, ext_images[k], ext_masks[k], (config.crop_h, config.crop_w),
                            config.max_scale)
        else:
            k = int(rng.integers(len(images)))
            x, y = _augment(rng, images[k], masks[k], (config.crop_h, config.crop_w),
                            config.max_scale)
        xs.append(x)
        ys.append(y)
    xb = torch.from_numpy(np.stack(xs))
    yb = torch.from_numpy(np.stack(ys))[:, None]
    return xb, yb


def _metadata(config: TrainConfig, net: Any, folders: list[Path], samples: int, external_images: int,
              init: Path | None, final_loss: float) -> dict[str, Any]:
    """What ``cable_segmenter.json`` says of the network and how it was trained."""
    torch = _torch()
    return {
        "architecture": f"{config.arch}(c1={config.widths[0]}, c2={config.widths[1]}, c3={config.widths[2]}"
        + (f", blocks={config.blocks})" if config.blocks else ")"),
        "parameters": int(sum(p.numel() for p in net.parameters())),
        "input": _LAYOUTS[config.arch],
        "train_config": asdict(config),
        "data": str(folders[0]) if len(folders) == 1 else [str(f) for f in folders],
        "data_manifest": json.loads((folders[0] / "dataset.json").read_text()) if len(folders) == 1
        else [json.loads((f / "dataset.json").read_text()) for f in folders],
        "samples": samples,
        "external_train_images": external_images,
        "external_split": "dyndlo_vision.learning.segtrain.external_split: even positions train, odd held out"
        if external_images
        else None,
        "init": str(init) if init is not None else None,
        "final_loss": final_loss,
        "torch": torch.__version__,
    }
