"""Atomic file writes: outputs appear whole or not at all, with the modes a plain ``open`` would give them."""

from __future__ import annotations

import os
import tempfile
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process' file mode creation mask, read without changing it where the OS allows.

    ``os.umask`` can only read the mask by setting another one, which would briefly change the mode of files
    that other threads create; Linux reports the mask in ``/proc/self/status``, so that is read first.
    """
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    # Elsewhere: set a placeholder and put the mask back. 0o077 is the safe placeholder (a file another thread
    # creates meanwhile is private, not public); the lock keeps two readers from restoring each other's.
    with _UMASK_LOCK:
        mask = os.umask(0o077)
        os.umask(mask)
    return mask


def write_atomic(path: Path, write: Callable[[str], Any]) -> None:
    """Write via a temporary file in the same folder, then rename: no partial outputs on failure.

    The file gets the mode a plain ``open(path, "w")`` would give a new file (``0o666`` less the umask):
    ``tempfile.mkstemp`` creates its files ``0o600``, private to the owner, which outputs are not meant to be.

    Args:
        path: The file to (over)write.
        write: Writes the content to the temporary path it is given.
    """
    path = Path(path)
    # A dot-name with the target's name in it: a partial file left by a killed process is hidden and says
    # what it was; the suffix is kept because some writers (OpenCV, matplotlib) choose the format by it.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~current_umask())
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
