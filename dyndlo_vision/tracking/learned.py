"""The learned cable segmenter at run time: a small CNN (ONNX) evaluated with ONNX Runtime on the CPU.

Pure computation on arrays: the network arrives as ONNX bytes (the shipped ones from
:func:`dyndlo_vision.tracking.networks.onnx_bytes`). Two input layouts, told apart by the network's number
of input channels when it is loaded:

* **blocks** (48 channels, ``cablenet-s2d4``, shipped as ``cable-segmenter-fine``): the frame, as
  ``RGB / 255 - 0.5``, enters in 4x4 blocks (every pixel kept) and leaves as 16 logits per block, put back
  in place: the mask has the network input's own resolution, so a cable 1-2 px wide survives. The frame is
  resized to a short side of 480 px (a 640x480 frame runs at its own size) and edge-padded to a multiple
  of 16.
* **RGB** (3 channels, ``cablenet``, shipped as ``cable-segmenter``, the default): the frame is resized to
  ``short_side`` (240), the logits (half that size) are resized bilinearly to the frame.

ONNX Runtime runs these networks 1.4-2.1x as fast as OpenCV's ``cv2.dnn`` (which was faster than torch) on
one thread and 1.2-1.9x on two, with the same logits to 2e-5 (``benchmarks/segmenter_engines.py``); torch is
not needed at run time.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .segmentation import clean_mask

__all__ = ["OUTSIDE_LOGIT", "LearnedSegmenter", "from_blocks", "to_blocks"]

#: Block size of the 48-channel layout (``segtrain.S2D_BLOCK``).
BLOCK = 4
#: Frame sides of the block layout are padded to a multiple of this (the block and two stride-2 levels); a
#: region is computed on this grid, where the network sees what it sees in the whole frame.
_MULTIPLE = 16
#: The logit given outside a computed region (no cable; far below any threshold, finite for resizing).
OUTSIDE_LOGIT = -1.0e4
#: Threads of a network's forward pass. Two: on two cores a 640x480 frame's forward pass takes 0.7-0.9x its
#: time on one (``benchmarks/segmenter_engines.py``); each segmenter holds its own pool.
ENGINE_THREADS = 2


def onnx_session(onnx: bytes, threads: int = ENGINE_THREADS) -> Any:
    """An ONNX Runtime CPU session for ``onnx`` with ``threads`` threads that sleep between calls (a spinning
    pool would take the cores from the renderer and the rest of the loop).

    Raises:
        ValueError: bytes ONNX Runtime cannot load.
    """
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = int(threads)
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(bytes(onnx), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # ONNX Runtime raises its own exception types for unreadable models
        raise ValueError(f"ONNX Runtime cannot read the segmenter's ONNX bytes: {exc}") from exc


def to_blocks(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    """(H, W, 3) uint8 with H, W multiples of 4 -> (1, 48, H/4, W/4) float32 ``RGB / 255 - 0.5``, channel
    ``c * 16 + 4 * i + j`` holding colour ``c`` of pixel ``(i, j)`` of each block (``pixel_unshuffle``).

    Built from whole rows, which is faster than one strided numpy transpose: ``cv2.split`` parts each row
    into the 12 colour-and-column planes of a block row (plane ``3 * j + c``); the planes are then reordered
    as a copy of contiguous rows."""
    h, w = rgb.shape[:2]
    planes = cv2.split(np.ascontiguousarray(rgb).reshape(h, w // BLOCK, 3 * BLOCK))
    by_plane = np.stack(planes).reshape(BLOCK, 3, h // BLOCK, BLOCK, w // BLOCK)  # j, c, y, i, x
    ordered = np.ascontiguousarray(by_plane.transpose(1, 3, 0, 2, 4)).reshape(-1, w // BLOCK)  # c, i, j, y, x
    out = cv2.addWeighted(ordered, 1.0 / 255.0, ordered, 0.0, -0.5, dtype=cv2.CV_32F)
    return out.reshape(1, 3 * BLOCK * BLOCK, h // BLOCK, w // BLOCK)


def from_blocks(blocks: NDArray[np.generic]) -> NDArray[np.generic]:
    """(16, h, w) per-block values -> (4h, 4w) image (``pixel_shuffle``).

    Row ``i`` of every block is its four planes ``4 * i + j`` interleaved pixel by pixel, which ``cv2.merge``
    does in one pass; a bool array goes through as uint8."""
    c, h, w = blocks.shape
    src = np.ascontiguousarray(blocks)
    planes = src.view(np.uint8) if src.dtype == np.bool_ else src
    out = np.empty((h, BLOCK, w * BLOCK), planes.dtype)
    for i in range(BLOCK):
        out[:, i, :] = cv2.merge(list(planes[BLOCK * i : BLOCK * (i + 1)])).reshape(h, w * BLOCK)
    return out.reshape(h * BLOCK, w * BLOCK).view(src.dtype)


class LearnedSegmenter:
    """Segments cables with a CNN; ``segmenter(rgb) -> (H, W) bool mask``.

    Args:
        onnx: The network as ONNX bytes: input ``rgb`` N x 48 x H/4 x W/4 (blocks) with output N x 16 x H/4 x
            W/4, or N x 3 x H x W (RGB) with one logit per pixel at half the input size.
        short_side: The frame's shorter side is resized to this many pixels before the network; None: the
            frame's own size. ``"auto"``: 480 for a block network, 240 for an RGB network (the scales they
            were measured at).
        threshold: Logit above which a pixel is cable (0: probability 0.5).
        min_area: Connected components of the mask smaller than this many pixels are dropped (0: off).
        threads: ONNX Runtime's threads for the forward pass (``ENGINE_THREADS`` by default).

    Raises:
        ValueError: ONNX bytes ONNX Runtime cannot read, a network of neither layout, or bad settings.
    """

    def __init__(
        self,
        onnx: bytes,
        *,
        short_side: int | None | str = "auto",
        threshold: float = 0.0,
        min_area: int = 0,
        threads: int = ENGINE_THREADS,
    ) -> None:
        if not isinstance(onnx, bytes | bytearray) or not onnx:
            raise ValueError(f"onnx must be non-empty bytes, got {type(onnx).__name__}")
        if short_side != "auto" and short_side is not None and (
            isinstance(short_side, bool) or not isinstance(short_side, int) or short_side < 16
        ):
            raise ValueError(f"short_side must be 'auto', None or an int >= 16, got {short_side!r}")
        if not np.isfinite(threshold):
            raise ValueError(f"threshold must be finite, got {threshold!r}")
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"threads must be an int >= 1, got {threads!r}")
        self._session = onnx_session(onnx, threads)
        inputs, outputs = self._session.get_inputs(), self._session.get_outputs()
        if len(inputs) != 1 or len(outputs) != 1:
            raise ValueError(
                "the segmenter's network must have one input and one output, got "
                f"{len(inputs)} and {len(outputs)}"
            )
        self._input_name = inputs[0].name
        self.blocks = self._probe_layout()
        if short_side == "auto":
            short_side = 480 if self.blocks else 240
        self.short_side: int | None = short_side  # type: ignore[assignment]
        self.threshold = float(threshold)
        self.min_area = int(min_area)

    def _forward(self, x: NDArray[np.float32]) -> NDArray[np.float32]:
        """The network's output for the N x C x H x W input ``x``."""
        return np.asarray(self._session.run(None, {self._input_name: x})[0], dtype=np.float32)

    def _probe_layout(self) -> bool:
        """True for the 48-channel block layout, False for RGB (one tiny forward pass of each)."""
        for channels, blocks in ((3 * BLOCK * BLOCK, True), (3, False)):
            try:
                out = self._forward(np.zeros((1, channels, 16, 16), np.float32))
            except Exception:  # ONNX Runtime's error for an input of the wrong shape
                continue
            if out.ndim != 4:
                continue
            if blocks and out.shape[1] == BLOCK * BLOCK:
                return True
            if not blocks and out.shape[1] == 1:
                return False
        raise ValueError(
            "the segmenter's network takes neither 48-channel 4x4 blocks (16 logits out) nor RGB (1 logit "
            "out)"
        )

    def input_size(self, height: int, width: int) -> tuple[int, int]:
        """(w, h) the frame is resized to before the network (a block network pads it further to 16)."""
        s = 1.0 if self.short_side is None else self.short_side / min(height, width)
        if self.blocks:
            return max(4, int(round(width * s))), max(4, int(round(height * s)))
        return max(8, int(round(width * s / 8)) * 8), max(8, int(round(height * s / 8)) * 8)

    def _resized(self, rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"rgb must be an (H, W, 3) uint8 RGB image, got {rgb.dtype} {rgb.shape}")
        h, w = rgb.shape[:2]
        size = self.input_size(h, w)
        if size == (w, h):
            return rgb
        return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA if size[0] < w else cv2.INTER_LINEAR)

    def _input(self, small: NDArray[np.uint8]) -> NDArray[np.float32]:
        """The 1 x C x H x W network input of a (resized) frame or part of one: a block network's blocks of
        the part edge-padded to a multiple of 16, an RGB network's ``RGB / 255 - 0.5``."""
        if not self.blocks:
            return cv2.dnn.blobFromImage(small, 1.0 / 255.0, mean=(127.5, 127.5, 127.5), swapRB=False)
        h, w = small.shape[:2]
        ph, pw = -h % _MULTIPLE, -w % _MULTIPLE
        padded = cv2.copyMakeBorder(small, 0, ph, 0, pw, cv2.BORDER_REPLICATE) if ph or pw else small
        return to_blocks(padded)

    def network_input(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """The 1 x C x H x W input the network gets for the whole RGB frame ``rgb`` (resized and laid out)."""
        return self._input(self._resized(rgb))

    def _block_logits(self, small: NDArray[np.uint8]) -> NDArray[np.float32]:
        """(16, h, w) logits of a block network for the (resized) frame, edge-padded to a multiple of 16."""
        return self._forward(self._input(small))[0]

    def grid_box(self, region: tuple[int, int, int, int] | None, height: int,
                 width: int) -> tuple[int, int, int, int] | None:
        """``region`` (u0, v0, u1, v1) of a ``height`` x ``width`` frame as the box of the network's input
        that covers it, widened outward to the network's 16-pixel grid: inside that box the network computes
        what it computes on the whole frame, except within its receptive field of the box's edges.

        None for None or for a box that covers the whole input (the whole frame is computed); an empty box
        (0, 0, 0, 0) for a region that misses the frame."""
        if region is None:
            return None
        u0, v0, u1, v1 = (float(x) for x in region)
        w_in, h_in = self.input_size(height, width)
        sx, sy = w_in / width, h_in / height
        u0, u1 = max(0, int(np.floor(u0 * sx))), min(w_in, int(np.ceil(u1 * sx)))
        v0, v1 = max(0, int(np.floor(v0 * sy))), min(h_in, int(np.ceil(v1 * sy)))
        if u0 >= u1 or v0 >= v1:
            return (0, 0, 0, 0)
        u0, v0 = u0 - u0 % _MULTIPLE, v0 - v0 % _MULTIPLE
        u1, v1 = min(w_in, u1 + -u1 % _MULTIPLE), min(h_in, v1 + -v1 % _MULTIPLE)
        if (u0, v0, u1, v1) == (0, 0, w_in, h_in):
            return None
        return u0, v0, u1, v1

    def _net_logits(self, small: NDArray[np.uint8]) -> NDArray[np.float32]:
        """The network's logits of a (resized) frame or part of one: at its size (blocks) or half (RGB)."""
        if self.blocks:
            h, w = small.shape[:2]
            return np.ascontiguousarray(from_blocks(self._block_logits(small))[:h, :w])
        return self._forward(self._input(small))[0, 0]

    def logits(self, rgb: NDArray[np.uint8],
               region: tuple[int, int, int, int] | None = None) -> NDArray[np.float32]:
        """The network's logits (h, w): at the resized frame's size (blocks) or half of it (RGB).

        ``region`` (u0, v0, u1, v1), in the frame's pixels: only the part of the input that covers it is
        computed (:meth:`grid_box`); the logits elsewhere are :data:`OUTSIDE_LOGIT` (no cable)."""
        small = self._resized(rgb)
        box = self.grid_box(region, *rgb.shape[:2])
        if box is None:
            return self._net_logits(small)
        h, w = small.shape[:2]
        k = 1 if self.blocks else 2  # an RGB network's logits are at half its input's size
        out = np.full((h // k, w // k), OUTSIDE_LOGIT, np.float32)
        u0, v0, u1, v1 = box
        if u1 > u0:
            part = self._net_logits(np.ascontiguousarray(small[v0:v1, u0:u1]))
            out[v0 // k : v0 // k + part.shape[0], u0 // k : u0 // k + part.shape[1]] = part
        return out

    def logits_full(self, rgb: NDArray[np.uint8],
                    region: tuple[int, int, int, int] | None = None) -> NDArray[np.float32]:
        """The logits at the frame's size (H, W), resized bilinearly where the network's are not
        (``region``: as in :meth:`logits`)."""
        lg = self.logits(rgb, region)
        h, w = rgb.shape[:2]
        if lg.shape == (h, w):
            return lg
        return cv2.resize(lg, (w, h), interpolation=cv2.INTER_LINEAR)

    def probability(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Per-pixel cable probability (H, W) in [0, 1]."""
        return (1.0 / (1.0 + np.exp(-self.logits_full(rgb)))).astype(np.float32)

    def _enlarged_part(self, rgb: NDArray[np.uint8],
                       region: tuple[int, int, int, int] | None) -> NDArray[np.uint8] | None:
        """The 0/1 mask of ``region`` for a block network that enlarges the frame by a ratio ``p / q`` of
        small integers (1.5 = 3 / 2), computed from the region's part of the frame alone: the frame's part is
        cut on the ``q`` grid and enlarged, the logits cut on the ``p`` grid and shrunk back, each with two
        grid steps to spare. Both resizes then sample the pixels the whole frame's resizes sample, with the
        same weights, so the mask equals :meth:`logits_full`'s, thresholded (tests/tracking/
        test_learned_segmenter.py), for a fraction of the work on a small region. None where this does not
        apply."""
        h, w = rgb.shape[:2]
        box = self.grid_box(region, h, w)
        w_in, h_in = self.input_size(h, w)
        ratio = Fraction(w_in, w)
        if not self.blocks or box is None or ratio <= 1 or Fraction(h_in, h) != ratio or ratio.numerator > 16:
            return None
        p, q = ratio.numerator, ratio.denominator
        mask = np.zeros((h, w), np.uint8)
        u0, v0, u1, v1 = box
        if u1 <= u0:
            return mask
        a, b = max(0, u0 // p - 2), min(w_in // p, -(-u1 // p) + 2)  # the part, in steps of p input pixels
        c, d = max(0, v0 // p - 2), min(h_in // p, -(-v1 // p) + 2)
        part = cv2.resize(rgb[c * q : d * q, a * q : b * q], ((b - a) * p, (d - c) * p),
                          interpolation=cv2.INTER_LINEAR)
        x0, y0 = u0 - a * p, v0 - c * p
        logits = np.full(part.shape[:2], OUTSIDE_LOGIT, np.float32)
        net_input = np.ascontiguousarray(part[y0 : y0 + v1 - v0, x0 : x0 + u1 - u0])
        logits[y0 : y0 + v1 - v0, x0 : x0 + u1 - u0] = self._net_logits(net_input)
        shrunk = cv2.resize(logits, ((b - a) * q, (d - c) * q), interpolation=cv2.INTER_LINEAR)
        mask[c * q : d * q, a * q : b * q] = shrunk > self.threshold
        return mask

    def segment(self, rgb: NDArray[np.uint8],
                region: tuple[int, int, int, int] | None = None) -> NDArray[np.bool_]:
        """The (H, W) bool cable mask of one RGB frame.

        ``region`` (u0, v0, u1, v1), in pixels: only the network's 16-pixel grid cells that cover it are
        computed (faster), and the mask is False elsewhere. Within them the mask is the whole frame's except
        near their outer edges, where the network misses the frame around them (its receptive field: about
        100 px).
        :class:`~dyndlo_vision.tracking.masks.CableReachSegmenter` gives the region the cable can reach."""
        h, w = rgb.shape[:2]
        if self.blocks and self.input_size(h, w) == (w, h):  # threshold the blocks, then put them in place
            box = self.grid_box(region, h, w)
            if box is None:
                cable = self._block_logits(self._resized(rgb)) > self.threshold
                mask = np.ascontiguousarray(from_blocks(cable.view(np.uint8))[:h, :w])
            else:
                mask = np.zeros((h, w), np.uint8)
                u0, v0, u1, v1 = box
                if u1 > u0:
                    cable = self._block_logits(np.ascontiguousarray(rgb[v0:v1, u0:u1])) > self.threshold
                    mask[v0:v1, u0:u1] = from_blocks(cable.view(np.uint8))[: v1 - v0, : u1 - u0]
        elif (enlarged := self._enlarged_part(rgb, region)) is not None:
            mask = enlarged
        else:
            _, m = cv2.threshold(self.logits_full(rgb, region), self.threshold, 1, cv2.THRESH_BINARY)
            mask = m.astype(np.uint8)
        if self.min_area > 1:
            return clean_mask(mask, open_radius=0, close_radius=0, min_area=self.min_area)
        return mask.astype(bool)

    __call__ = segment
