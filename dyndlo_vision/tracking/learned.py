"""The learned cable segmenter at run time: a small CNN (ONNX) evaluated with OpenCV's ``cv2.dnn``.

Pure computation on arrays: the network arrives as ONNX bytes (the shipped one from
:func:`dyndlo_vision.policies.segmenter.onnx_bytes`). The frame is resized so that its shorter side is
``short_side`` pixels (the scale the network was trained at; 640x480 -> 320x240), rounded to a multiple of 8,
fed as ``RGB / 255 - 0.5``; the logits (at half that size) are resized bilinearly to the frame and
thresholded, so the mask has the frame's size. cv2.dnn runs the network 3-4x faster than torch on one core
(docs/RESULTS.md, "Learned segmenter"), and torch is not needed at run time.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["LearnedSegmenter"]


class LearnedSegmenter:
    """Segments cables with a CNN; ``segmenter(rgb) -> (H, W) bool mask``.

    Args:
        onnx: The network as ONNX bytes (input ``rgb`` N x 3 x H x W float32, output one logit per pixel at
            half the input size).
        short_side: The frame's shorter side is resized to this many pixels before the network (None: the
            frame's own size).
        threshold: Logit above which a pixel is cable (0: probability 0.5).
        min_area: Connected components of the mask smaller than this many pixels are dropped (0: off).

    Raises:
        ValueError: ONNX bytes OpenCV cannot read, or bad settings.
    """

    def __init__(
        self, onnx: bytes, *, short_side: int | None = 240, threshold: float = 0.0, min_area: int = 0
    ) -> None:
        if not isinstance(onnx, bytes | bytearray) or not onnx:
            raise ValueError(f"onnx must be non-empty bytes, got {type(onnx).__name__}")
        if short_side is not None and (
            isinstance(short_side, bool) or not isinstance(short_side, int) or short_side < 16
        ):
            raise ValueError(f"short_side must be None or an int >= 16, got {short_side!r}")
        if not np.isfinite(threshold):
            raise ValueError(f"threshold must be finite, got {threshold!r}")
        try:
            self._net = cv2.dnn.readNetFromONNX(np.frombuffer(bytes(onnx), np.uint8))
        except cv2.error as exc:
            raise ValueError(f"OpenCV cannot read the segmenter's ONNX bytes: {exc}") from exc
        self.short_side = short_side
        self.threshold = float(threshold)
        self.min_area = int(min_area)

    def input_size(self, height: int, width: int) -> tuple[int, int]:
        """(w, h) of the network input for a frame of ``height`` x ``width`` (multiples of 8)."""
        s = 1.0 if self.short_side is None else self.short_side / min(height, width)
        return max(8, int(round(width * s / 8)) * 8), max(8, int(round(height * s / 8)) * 8)

    def logits(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """The network's logits (h, w) at half the input size (see :meth:`input_size`)."""
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"rgb must be an (H, W, 3) uint8 RGB image, got {rgb.dtype} {rgb.shape}")
        h, w = rgb.shape[:2]
        size = self.input_size(h, w)
        interp = cv2.INTER_AREA if size[0] < w else cv2.INTER_LINEAR
        small = rgb if size == (w, h) else cv2.resize(rgb, size, interpolation=interp)
        blob = cv2.dnn.blobFromImage(small, 1.0 / 255.0, mean=(127.5, 127.5, 127.5), swapRB=False)
        self._net.setInput(blob)
        return np.asarray(self._net.forward()[0, 0], dtype=np.float32)

    def logits_full(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """The logits resized bilinearly to the frame (H, W)."""
        lg = self.logits(rgb)
        h, w = rgb.shape[:2]
        return cv2.resize(lg, (w, h), interpolation=cv2.INTER_LINEAR)

    def probability(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Per-pixel cable probability (H, W) in [0, 1]."""
        return (1.0 / (1.0 + np.exp(-self.logits_full(rgb)))).astype(np.float32)

    def segment(self, rgb: NDArray[np.uint8]) -> NDArray[np.bool_]:
        """The (H, W) bool cable mask of one RGB frame."""
        _, m = cv2.threshold(self.logits_full(rgb), self.threshold, 1, cv2.THRESH_BINARY)
        mask = m.astype(np.uint8)
        if self.min_area > 1:
            n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
            small = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] < self.min_area) + 1
            for i in small:
                x, y, bw, bh = stats[i, :4]
                roi = mask[y : y + bh, x : x + bw]
                roi[labels[y : y + bh, x : x + bw] == i] = 0
        return mask.astype(bool)

    __call__ = segment
