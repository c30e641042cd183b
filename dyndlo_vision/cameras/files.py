"""Frames from files: video files and folders of images, with the video's own time stamps when they are sane,
else ``index / fps``."""

from __future__ import annotations

import math
import os
import re
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.cameras._base import _bgr_to_rgb, _check_fps, _FrameSource
from dyndlo_vision.cameras.protocol import Frame

#: File name endings (lower case) that an image folder's frames may have; other files are ignored.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pbm")
#: Frame rate assumed for an image folder when none is given (with a warning).
DEFAULT_FOLDER_FPS = 25.0
#: Header frame rates outside (0, this] are treated as unknown.
_MAX_SANE_FPS = 10_000.0


def image_files(inputs: list[str]) -> list[Path]:
    """The image files named by ``inputs``: files as given, folders as their images (suffix in
    :data:`IMAGE_SUFFIXES`, sorted by name), in order.

    Raises:
        FileNotFoundError: An input that does not exist.
        ValueError: A folder that holds no images.
    """
    files: list[Path] = []
    for text in inputs:
        p = Path(text)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise ValueError(f"folder {p} holds no images (looked for {', '.join(IMAGE_SUFFIXES)})")
            files.extend(found)
        elif p.is_file():
            files.append(p)
        else:
            raise FileNotFoundError(f"input {p} does not exist")
    return files


class TruncatedVideoError(ValueError):
    """A video file ended before the number of frames its header promises (a cut or damaged file)."""


def _natural_key(name: str) -> list[Any]:
    """Sort key that orders ``frame2`` before ``frame10``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


class VideoFileCamera(_FrameSource):
    """Frames of a video file (anything OpenCV's FFmpeg reads) or of a folder of images.

    Time stamps:

    * ``fps`` given: ``t_capture = index / fps`` (it overrides the file's own time stamps).
    * A video without ``fps``: the decoder's time stamp of each frame (``CAP_PROP_POS_MSEC``), which follows
      variable frame rates, as long as it is finite, non-negative and strictly increasing; where it is not,
      the previous time plus one frame period of the header's frame rate.
    * A folder without ``fps``: ``index / 25`` and a ``UserWarning`` saying so.

    An image folder holds its frames as files ending in one of :data:`IMAGE_SUFFIXES` (other files are
    ignored), played in natural name order (``f2.png`` before ``f10.png``); all must have the same size.

    Truncated files: a video whose decoding stops before the frame count in its header raises
    :class:`TruncatedVideoError` from :meth:`read` (naming how many frames were read) when ``strict`` (the
    default): a tracker fed a damaged file should fail loudly rather than write a short result. With
    ``strict=False`` it warns and ends the stream instead. An MP4 cut short usually loses its index (the
    ``moov`` atom is written last) and then cannot be opened at all: that is a ``ValueError`` at construction.

    Attributes:
        path: The file or folder.
        fps: Frame rate used for time stamps (the argument, the header's, or the default).
        fps_source: ``"argument"``, ``"header"`` or ``"default"``.
        frame_count: Frames promised by the header (video) or image files found (folder); None if unknown.
        width, height: Frame size in pixels.
    """

    #: Frames are stamped on the video's own time line.
    clock = "video"

    def __init__(self, path: str | os.PathLike[str], fps: float | None = None, strict: bool = True) -> None:
        """Opens the video or lists the folder and reads its first frame's size.

        Args:
            path: Video file or folder of images.
            fps: Frame rate; overrides the video's time stamps; folders need it (else 25, with a warning).
            strict: Raise :class:`TruncatedVideoError` on a truncated video (else warn and stop).

        Raises:
            FileNotFoundError: If ``path`` does not exist.
            ValueError: If it is not a readable video, a folder without images, an unreadable first image,
                or ``fps`` is not a positive number.
        """
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"video or image folder not found: {self.path}")
        user_fps = _check_fps(fps)
        self.strict = bool(strict)
        self._index = 0
        self._t_prev = -math.inf
        self._cap: cv2.VideoCapture | None = None
        self._files: list[Path] | None = None
        self._closed = False
        if self.path.is_dir():
            self._files = sorted(
                (p for p in self.path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                key=lambda p: _natural_key(p.name),
            )
            if not self._files:
                raise ValueError(
                    f"image folder {self.path} contains no images (looked for files ending in "
                    f"{', '.join(IMAGE_SUFFIXES)})"
                )
            first = self._read_image(self._files[0])
            self.height, self.width = first.shape[:2]
            self.frame_count: int | None = len(self._files)
            if user_fps is None:
                warnings.warn(
                    f"image folder {self.path}: no frame rate given, assuming {DEFAULT_FOLDER_FPS:g} fps "
                    "for the time stamps (pass fps to set it)",
                    UserWarning,
                    stacklevel=2,
                )
                self.fps, self.fps_source = DEFAULT_FOLDER_FPS, "default"
            else:
                self.fps, self.fps_source = user_fps, "argument"
            return
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise ValueError(
                f"{self.path} cannot be opened as a video by OpenCV (not a video, an unsupported codec, or a "
                "damaged file, e.g. an MP4 cut short loses its index)"
            )
        self._cap = cap
        header_fps = float(cap.get(cv2.CAP_PROP_FPS))
        count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        self.frame_count = int(count) if math.isfinite(count) and count > 0 else None
        self.width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if self.width <= 0 or self.height <= 0:
            self.close()
            raise ValueError(
                f"{self.path} has no video stream OpenCV can decode (frame size {self.width}x{self.height})"
            )
        if user_fps is not None:
            self.fps, self.fps_source = user_fps, "argument"
        elif math.isfinite(header_fps) and 0 < header_fps <= _MAX_SANE_FPS:
            self.fps, self.fps_source = header_fps, "header"
        else:
            warnings.warn(
                f"video {self.path}: its header has no usable frame rate ({header_fps!r}); assuming "
                f"{DEFAULT_FOLDER_FPS:g} fps where its time stamps are missing (pass fps to set it)",
                UserWarning,
                stacklevel=2,
            )
            self.fps, self.fps_source = DEFAULT_FOLDER_FPS, "default"

    def _read_image(self, file: Path) -> NDArray[np.uint8]:
        image = cv2.imread(str(file), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"image {file} cannot be read by OpenCV (damaged or not an image)")
        return _bgr_to_rgb(image)

    def _timestamp(self, pos_msec: float | None) -> float:
        """Capture time of the frame just read (see the class docstring)."""
        if self.fps_source == "argument" or self._files is not None:
            return self._index / self.fps
        if (
            pos_msec is not None
            and math.isfinite(pos_msec)
            and pos_msec >= 0
            and pos_msec / 1e3 > self._t_prev
        ):
            return pos_msec / 1e3
        return 0.0 if self._index == 0 else self._t_prev + 1.0 / self.fps

    def read(self) -> Frame | None:
        """The next frame, or None at the end.

        Raises:
            TruncatedVideoError: ``strict`` and the video ended before its header's frame count.
            ValueError: An image of a folder cannot be read or has a different size than the first.
        """
        if self._closed:
            raise ValueError(f"VideoFileCamera {self.path} is closed")
        if self._files is not None:
            if self._index >= len(self._files):
                return None
            file = self._files[self._index]
            rgb = self._read_image(file)
            if rgb.shape[:2] != (self.height, self.width):
                raise ValueError(
                    f"image {file} is {rgb.shape[1]}x{rgb.shape[0]}, but the folder's first image is "
                    f"{self.width}x{self.height}"
                )
            pos = None
        else:
            assert self._cap is not None
            ok, bgr = self._cap.read()
            if not ok or bgr is None:
                self._check_complete()
                return None
            rgb = _bgr_to_rgb(bgr)
            pos = float(self._cap.get(cv2.CAP_PROP_POS_MSEC))
        t = self._timestamp(pos)
        frame = Frame(rgb=rgb, t_capture=t, index=self._index)
        self._t_prev = t
        self._index += 1
        return frame

    def _check_complete(self) -> None:
        """At the end of a video: raise or warn when fewer frames came than the header promised."""
        if self.frame_count is None or self._index >= self.frame_count:
            return
        message = (
            f"video {self.path} ended after {self._index} frames, but its header promises {self.frame_count} "
            "(truncated or damaged file)"
        )
        if self.strict:
            raise TruncatedVideoError(message)
        warnings.warn(message, UserWarning, stacklevel=3)
        self.frame_count = self._index  # warn once

    def close(self) -> None:
        """Releases the file; safe to call twice."""
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        self._closed = True
