"""What every frame source shares: the iterator and context-manager plumbing, OpenCV's BGR to RGB at the edge,
and the exposure average that gives simulated frames their motion blur."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from types import TracebackType
from typing import Any, Self

import cv2
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.cameras.protocol import Frame


def _bgr_to_rgb(image: NDArray[Any]) -> NDArray[np.uint8]:
    """RGB uint8 (H, W, 3) from what OpenCV decoded (BGR, BGRA or grey)."""
    if image.ndim == 2:
        code = cv2.COLOR_GRAY2RGB
    elif image.shape[2] == 4:
        code = cv2.COLOR_BGRA2RGB
    else:
        code = cv2.COLOR_BGR2RGB
    return np.asarray(cv2.cvtColor(image, code), dtype=np.uint8)


def average_frames(exposure_frames: Sequence[NDArray[np.uint8]]) -> NDArray[np.uint8]:
    """Motion blur: the mean of sub-frames rendered during one exposure, as uint8.

    The simulation loop renders several frames while the physics advances through one exposure time and
    averages them here, which is what a camera's sensor does with a moving cable.

    Args:
        exposure_frames: Non-empty sequence of equally shaped uint8 images (H, W) or (H, W, C).

    Returns:
        The rounded per-pixel mean, same shape, uint8.

    Raises:
        ValueError: If the sequence is empty, an image is not uint8, or the shapes differ.
    """
    if len(exposure_frames) == 0:
        raise ValueError("average_frames needs at least one frame, got an empty sequence")
    first = np.asarray(exposure_frames[0])
    acc = np.zeros(first.shape, dtype=np.float64)
    for i, frame in enumerate(exposure_frames):
        img = np.asarray(frame)
        if img.dtype != np.uint8:
            raise ValueError(f"exposure frame {i} has dtype {img.dtype}, expected uint8")
        if img.shape != first.shape:
            raise ValueError(f"exposure frame {i} has shape {img.shape}, expected {first.shape} like frame 0")
        acc += img
    return np.rint(acc / len(exposure_frames)).astype(np.uint8)


class _FrameSource(ABC):
    """Context-manager and iterator plumbing shared by the cameras."""

    @abstractmethod
    def read(self) -> Frame | None:
        """The next frame, or None when the source has no more."""

    @abstractmethod
    def close(self) -> None:
        """Releases the source."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __iter__(self) -> Iterator[Frame]:
        while (frame := self.read()) is not None:
            yield frame


def _check_fps(fps: float | None) -> float | None:
    """A requested frame rate as float (None stays None); anything but a positive finite number is refused."""
    if fps is None:
        return None
    if (
        isinstance(fps, bool)
        or not isinstance(fps, int | float | np.number)
        or not math.isfinite(fps)
        or fps <= 0
    ):
        raise ValueError(f"fps must be a positive finite number, got {fps!r}")
    return float(fps)
