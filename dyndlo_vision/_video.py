"""Every MP4 video the package writes (``demo``, ``run``, ``evaluate --video``, ``track --annotated``).

H.264 in yuv420p through PyAV (whose wheels bundle libx264), so that browsers, GitHub and editors play it.
MPEG-4 Part 2 (``mp4v``) through OpenCV is the fallback, for an install where PyAV cannot encode H.264; the
writer says which codec it used (:attr:`VideoWriter.codec`), and the commands record it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from dyndlo_vision._atomic import write_atomic

log = logging.getLogger(__name__)

#: The codecs tried in order: H.264 (PyAV, libx264) plays everywhere; MPEG-4 Part 2 (OpenCV) plays in VLC and
#: most desktop players but not in browsers.
VIDEO_CODECS = ("h264", "mp4v")
#: libx264's constant rate factor: 18 keeps a 1-2 px cable visible (23, its default, smears it).
H264_CRF = 18


class VideoWriter:
    """Writes equally sized uint8 BGR frames (OpenCV's order, as ``cv2.VideoWriter`` takes them) to an MP4.

    H.264 frames must have even sides: a frame of an odd width or height gets one more column or row, a copy
    of its last one, and the video is that much larger. Use as a context manager, or call :meth:`release`.

    Args:
        path: The file to write (its folder must exist).
        fps: Frames per second.
        size: ``(width, height)`` of every frame.
        codecs: The codecs to try, in order (see :data:`VIDEO_CODECS`).

    Raises:
        ValueError: A size or frame rate that is not positive, an unknown codec, or none of ``codecs`` can
            write here.
    """

    def __init__(self, path: str | Path, fps: float, size: tuple[int, int],
                 codecs: Sequence[str] = VIDEO_CODECS) -> None:
        width, height = (int(v) for v in size)
        if width < 1 or height < 1:
            raise ValueError(f"video size {size!r}; expected (width, height) of at least one pixel")
        if not (isinstance(fps, int | float) and 0 < fps < float("inf")):
            raise ValueError(f"video frame rate {fps!r}; expected a positive number of frames per second")
        unknown = [c for c in codecs if c not in VIDEO_CODECS]
        if unknown or not codecs:
            raise ValueError(f"video codecs {list(codecs)!r}; expected some of {list(VIDEO_CODECS)}")
        self.path, self.fps, self.size = Path(path), float(fps), (width, height)
        self.frames = 0
        self._container: Any = None
        self._stream: Any = None
        self._cv_writer: Any = None
        reasons = []
        for codec in codecs:
            try:
                (self._open_h264 if codec == "h264" else self._open_mp4v)()
            except Exception as err:  # noqa: BLE001  (PyAV and OpenCV fail in many ways; the next one is tried)
                reasons.append(f"{codec}: {err}")
                continue
            self.codec = codec
            break
        else:
            raise ValueError(f"cannot write an MP4 video to {self.path}: " + "; ".join(reasons))
        if reasons:
            log.info("%s: wrote %s (%s)", self.path, self.codec, "; ".join(reasons))

    def _open_h264(self) -> None:
        import av

        if "libx264" not in av.codecs_available:
            raise RuntimeError("this PyAV has no libx264 encoder")
        container = av.open(str(self.path), mode="w", format="mp4")
        try:
            stream = container.add_stream("libx264", rate=Fraction(self.fps).limit_denominator(1001))
            stream.width, stream.height = (v + v % 2 for v in self.size)
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(H264_CRF)}
        except BaseException:
            container.close()
            raise
        self._container, self._stream = container, stream

    def _open_mp4v(self) -> None:
        import cv2

        with _quiet_stderr():  # FFmpeg prints its complaints on stderr, several lines per try
            writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, self.size)
        if not writer.isOpened():
            raise RuntimeError("OpenCV cannot open an mp4v writer")
        self._cv_writer = writer

    def write(self, frame: np.ndarray) -> None:
        """Append one BGR frame of the writer's size.

        Raises:
            ValueError: A frame that is not ``(height, width, 3)`` uint8 (OpenCV would drop it silently).
        """
        width, height = self.size
        if frame.shape != (height, width, 3) or frame.dtype != np.uint8:
            raise ValueError(f"frame {self.frames} is {frame.shape} {frame.dtype}; "
                             f"expected ({height}, {width}, 3) uint8")
        if self._cv_writer is not None:
            self._cv_writer.write(frame)
        else:
            import av

            if width % 2 or height % 2:
                frame = np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")
            picture = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="bgr24")
            self._container.mux(self._stream.encode(picture))
        self.frames += 1

    def release(self) -> None:
        """Finish the file (idempotent)."""
        if self._cv_writer is not None:
            self._cv_writer.release()
            self._cv_writer = None
        if self._container is not None:
            try:
                self._container.mux(self._stream.encode(None))  # flush the encoder's delayed frames
            finally:
                self._container.close()
                self._container = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *_: Any) -> None:
        self.release()


def write_video_atomic(path: Path, frames: Sequence[Any], fps: float = 25.0, rgb: bool = True,
                       codecs: Sequence[str] = VIDEO_CODECS) -> str:
    """Write equally sized uint8 frames (RGB, or BGR with ``rgb=False``) to an MP4, atomically.

    Returns:
        The codec written (``"h264"`` or ``"mp4v"``).

    Raises:
        ValueError: No frames, frames that are not all (H, W, 3) uint8 of the first frame's size, or no codec
            can write here.
    """
    if not frames:
        raise ValueError(f"no frames to write to {path}")
    h, w = frames[0].shape[:2]
    for i, frame in enumerate(frames):
        if frame.shape != (h, w, 3) or frame.dtype != np.uint8:
            raise ValueError(
                f"frame {i} is {frame.shape} {frame.dtype}; expected ({h}, {w}, 3) uint8 like frame 0"
            )
    used: list[str] = []

    def write(tmp: str) -> None:
        with VideoWriter(tmp, fps, (w, h), codecs) as writer:
            for frame in frames:
                writer.write(np.ascontiguousarray(frame[..., ::-1]) if rgb else frame)
        used.append(writer.codec)

    write_atomic(Path(path), write)
    return used[-1]


@contextmanager
def _quiet_stderr() -> Iterator[None]:
    """Send file descriptor 2 to /dev/null for the block (C libraries write there, not to ``sys.stderr``).

    For a moment only (opening a writer): what other threads write to stderr meanwhile is lost too.
    """
    import sys

    try:
        sys.stderr.flush()
        saved: int | None = os.dup(2)
    except (OSError, ValueError):  # no usable stderr (closed or replaced): nothing to silence
        saved = None
    if saved is None:
        yield
        return
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
