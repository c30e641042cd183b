"""Atomic file writes: outputs appear whole or not at all."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any


def write_atomic(path: Path, write: Callable[[str], Any]) -> None:
    """Write via a temporary file in the same folder, then rename: no partial outputs on failure."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_video_atomic(path: Path, frames: Sequence[Any], fps: float = 25.0, rgb: bool = True) -> None:
    """Write equally sized uint8 frames (RGB, or BGR with ``rgb=False``) to an MP4, atomically.

    Raises:
        ValueError: No frames.
        RuntimeError: OpenCV cannot write MP4 here.
    """
    import cv2

    if not frames:
        raise ValueError(f"no frames to write to {path}")
    h, w = frames[0].shape[:2]

    def write(tmp: str) -> None:
        writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
        if not writer.isOpened():
            raise RuntimeError(f"OpenCV cannot write MP4 to {tmp}")
        for frame in frames:
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR) if rgb else frame)
        writer.release()

    write_atomic(path, write)
