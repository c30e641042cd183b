"""Frame sources for the control loop and the tracker: MuJoCo off-screen cameras, video files and image
folders, live OpenCV devices, and (optional, untested) Intel RealSense RGB-D cameras.

Every source implements the :class:`~dyndlo_vision.control.protocols.Camera` protocol (``read() -> Frame |
None``, ``close()``), is a context manager and an iterator over its frames. Frames are RGB uint8; OpenCV's BGR
is converted once, here, at the edge. Capture times are seconds on the source's own clock:

* :class:`MujocoCamera`: the simulator's time, ``data.time``.
* :class:`VideoFileCamera`: the video's own time stamps when they are sane, else ``index / fps``.
* :class:`OpenCVDeviceCamera` and :class:`RealSenseCamera`: ``time.monotonic()`` when the frame arrived.

Each says so in its ``clock`` attribute; :class:`~dyndlo_vision.control.state_sources.TrackedState` maps a
``"monotonic"`` camera's times onto the robot's clock (:mod:`dyndlo_vision.control.clocks`).

:class:`DelayedCamera` wraps any of them and hands frames over a fixed time after their capture, as a real
pipeline does (exposure, transfer, decoding), so the loop can be run in simulation with a camera's latency.
"""

from __future__ import annotations

import math
import os
import re
import time
import warnings
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import cv2
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.control.protocols import Frame
from dyndlo_vision.tracking.camera_model import PinholeCamera

__all__ = [
    "IMAGE_SUFFIXES",
    "DEFAULT_FOLDER_FPS",
    "TruncatedVideoError",
    "average_frames",
    "MujocoCamera",
    "DelayedCamera",
    "VideoFileCamera",
    "OpenCVDeviceCamera",
    "RealSenseCamera",
]

#: File name endings (lower case) that an image folder's frames may have; other files are ignored.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pbm")
#: Frame rate assumed for an image folder when none is given (with a warning).
DEFAULT_FOLDER_FPS = 25.0
#: Header frame rates outside (0, this] are treated as unknown.
_MAX_SANE_FPS = 10_000.0


class TruncatedVideoError(ValueError):
    """A video file ended before the number of frames its header promises (a cut or damaged file)."""


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


# ---------------------------------------------------------------------------------------------- MuJoCo


class MujocoCamera(_FrameSource):
    """Off-screen RGB (and optional depth) images of a named camera of a MuJoCo model.

    ``read()`` renders the current state of ``data`` (it never steps the physics) and stamps the frame with
    ``data.time``, so a frame is captured at the simulator's time. Depth is metres along the optical axis
    (MuJoCo's linearised depth buffer); pixels that see nothing (at the far clipping plane) are NaN.

    Example::

        with MujocoCamera(env.unwrapped.model, env.unwrapped.data, "front", depth=True) as cam:
            frame = cam.read()
            tracker = CableTracker(cam.calibration)
    """

    #: Frames are stamped with the simulator's time (see :mod:`dyndlo_vision.control.clocks`).
    clock = "simulation"

    def __init__(
        self,
        model: Any,
        data: Any,
        camera_name: str,
        width: int = 640,
        height: int = 480,
        depth: bool = False,
        fps: float | None = None,
    ) -> None:
        """Creates the renderer.

        Args:
            model: The ``mujoco.MjModel``.
            data: The ``mujoco.MjData`` whose state is rendered.
            camera_name: Name of a camera defined in the model.
            width: Image width in pixels (at most the model's ``<global offwidth>``).
            height: Image height in pixels (at most the model's ``<global offheight>``).
            depth: Also render a depth image into ``Frame.depth``.
            fps: Frame rate recorded in :attr:`calibration` (information only).

        Raises:
            ValueError: Unknown camera, a camera without a vertical field of view, or a size that does not
                fit the model's off-screen framebuffer.
        """
        import mujoco

        from dyndlo_vision.sim.rendering import make_renderer

        names = [model.camera(i).name for i in range(model.ncam)]
        if camera_name not in names:
            raise ValueError(f"camera {camera_name!r} is not in the model; its cameras are {names}")
        self.camera_id = int(model.camera(camera_name).id)
        if np.any(np.asarray(model.cam_sensorsize[self.camera_id]) > 0):
            raise ValueError(
                f"camera {camera_name!r} is defined by focal length and sensor size; only fovy cameras are "
                "supported (PinholeCamera.from_mujoco)"
            )
        if int(model.cam_projection[self.camera_id]) != int(mujoco.mjtProjection.mjPROJ_PERSPECTIVE):
            raise ValueError(f"camera {camera_name!r} is orthographic; expected a perspective camera")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        offwidth, offheight = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
        if width > offwidth or height > offheight:
            raise ValueError(
                f"image size {width}x{height} exceeds the model's off-screen framebuffer "
                f"{offwidth}x{offheight}; raise <visual><global offwidth offheight> in the model"
            )
        self.model = model
        self.data = data
        self.camera_name = camera_name
        self.width = int(width)
        self.height = int(height)
        self.depth = bool(depth)
        self.fps = fps
        self._far_m = float(model.stat.extent * model.vis.map.zfar)
        self._renderer: Any = make_renderer(model, self.height, self.width)
        self._index = 0

    @property
    def calibration(self) -> PinholeCamera:
        """The camera's pinhole model at the current state of ``data`` (cameras may move with bodies).

        Raises:
            ValueError: If ``data`` has no camera pose yet (run ``mujoco.mj_forward`` first).
        """
        xmat = np.asarray(self.data.cam_xmat[self.camera_id], dtype=np.float64)
        if not np.any(xmat):
            raise ValueError(
                f"camera {self.camera_name!r} has no pose in data yet (cam_xmat is zero): "
                "call mujoco.mj_forward first"
            )
        return PinholeCamera.from_mujoco(
            float(self.model.cam_fovy[self.camera_id]),
            self.width,
            self.height,
            self.data.cam_xpos[self.camera_id],
            xmat,
            fps=self.fps,
        )

    def read(self) -> Frame:
        """Renders the current simulation state; never None (a simulator does not run out of frames)."""
        if self._renderer is None:
            raise ValueError(f"MujocoCamera {self.camera_name!r} is closed")
        self._renderer.update_scene(self.data, camera=self.camera_id)
        rgb = np.array(self._renderer.render(), dtype=np.uint8)
        depth = None
        if self.depth:
            self._renderer.enable_depth_rendering()
            try:
                depth = np.array(self._renderer.render(), dtype=np.float32)
            finally:
                self._renderer.disable_depth_rendering()
            # The far clipping plane means "nothing here", not a surface 50 m away.
            depth[depth >= self._far_m * (1.0 - 1e-3)] = np.nan
        frame = Frame(rgb=rgb, t_capture=float(self.data.time), index=self._index, depth=depth)
        self._index += 1
        return frame

    def close(self) -> None:
        """Releases the GL context; safe to call twice."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def checked_latency_s(latency_s: Any) -> float:
    """``latency_s`` as a float, or a ValueError naming it unless it is a finite number >= 0 (seconds)."""
    if isinstance(latency_s, bool) or not isinstance(latency_s, int | float) or not (
        math.isfinite(latency_s) and latency_s >= 0
    ):
        raise ValueError(f"latency_s must be a finite number >= 0 (seconds), got {latency_s!r}")
    return float(latency_s)


class DelayedCamera(_FrameSource):
    """Frames that arrive ``latency_s`` after they were captured: a camera pipeline's latency.

    Every ``read()`` reads the wrapped camera (a :class:`MujocoCamera` renders the simulator's present) into a
    buffer and hands over the newest frame captured at least ``latency_s`` before the newest capture, each
    frame at most once and with its own capture time, so a filter that predicts from ``t_capture`` to the
    controller's time compensates the delay. Until a frame is old enough ``read()`` returns None (a frame
    that has not arrived yet); the very first read hands over the first frame at once, so a loop starts with
    an estimate (in simulation the cable rests before an episode). Read at a fixed period, a frame's delay is
    ``latency_s`` rounded up to a whole number of periods.

    Args:
        camera: The camera whose frames are delayed (its ``calibration``, if any, is passed through).
        latency_s: Delay from capture to hand-over in seconds, >= 0 (0: every frame at once).

    Raises:
        ValueError: A latency that is negative, not finite or not a number.
    """

    def __init__(self, camera: Any, latency_s: float) -> None:
        self.camera = camera
        self.latency_s = checked_latency_s(latency_s)
        self._buffer: list[Frame] = []
        self._started = False

    @property
    def calibration(self) -> Any:
        """The wrapped camera's calibration."""
        return self.camera.calibration

    @property
    def clock(self) -> str | None:
        """The wrapped camera's clock (capture times are passed through unchanged)."""
        return getattr(self.camera, "clock", None)

    def read(self) -> Frame | None:
        """Reads the wrapped camera; the newest frame that is ``latency_s`` old, or None if none has arrived.

        None also when the wrapped camera has run out and every buffered frame has been handed over.
        """
        frame = self.camera.read()
        if frame is not None:
            self._buffer.append(frame)
        if not self._buffer:
            return None
        if not self._started:
            self._started = True
            return self._buffer.pop(0)
        now = self._buffer[-1].t_capture if frame is not None else math.inf
        due = [i for i, f in enumerate(self._buffer) if now - f.t_capture >= self.latency_s - 1e-9]
        if not due:
            return None
        newest = due[-1]
        out = self._buffer[newest]
        del self._buffer[: newest + 1]  # older frames than the one handed over are never wanted again
        return out

    def __iter__(self) -> Iterator[Frame]:
        raise TypeError(
            "a DelayedCamera is read at the loop's period (None means 'not arrived yet', not 'no more'); "
            "iterate over the wrapped camera instead"
        )

    def close(self) -> None:
        """Closes the wrapped camera and drops the buffer."""
        self._buffer.clear()
        self.camera.close()


# ---------------------------------------------------------------------------------------------- files


def _natural_key(name: str) -> list[Any]:
    """Sort key that orders ``frame2`` before ``frame10``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def _check_fps(fps: float | None) -> float | None:
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


# ---------------------------------------------------------------------------------------------- devices


class OpenCVDeviceCamera(_FrameSource):
    """A live camera through ``cv2.VideoCapture``: a device index (``0`` = ``/dev/video0``) or a stream URL.

    ``t_capture`` is ``time.monotonic()`` right after the frame arrived (``grab`` returned), so frames share a
    clock with the rest of the process; the driver's own time stamps are not used because their clock differs
    between backends. ``read()`` returns None when the device stops delivering frames (unplugged, stream
    ended); the caller decides whether that is the end or a fault.
    """

    #: Frames are stamped with ``time.monotonic()``.
    clock = "monotonic"

    def __init__(
        self,
        index_or_url: int | str,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
    ) -> None:
        """Opens the device and applies the requested mode (the driver may choose a different one).

        Args:
            index_or_url: Device index or URL/path understood by ``cv2.VideoCapture``.
            width: Requested frame width in pixels.
            height: Requested frame height in pixels.
            fps: Requested frame rate.

        Raises:
            ValueError: If the device cannot be opened.
        """
        self.source = index_or_url
        cap = cv2.VideoCapture(index_or_url)
        if not cap.isOpened():
            cap.release()
            kind = "camera device" if isinstance(index_or_url, int) else "video stream"
            raise ValueError(
                f"cannot open {kind} {index_or_url!r} with OpenCV (missing, busy, or no permission; "
                "list devices with `v4l2-ctl --list-devices` on Linux)"
            )
        for prop, value in ((cv2.CAP_PROP_FRAME_WIDTH, width), (cv2.CAP_PROP_FRAME_HEIGHT, height)):
            if value is not None:
                cap.set(prop, int(value))
        if fps is not None:
            cap.set(cv2.CAP_PROP_FPS, float(_check_fps(fps) or 0.0))
        self._cap: cv2.VideoCapture | None = cap
        self._index = 0

    def read(self) -> Frame | None:
        """The next frame from the device, or None when it delivers none."""
        if self._cap is None:
            raise ValueError(f"OpenCVDeviceCamera {self.source!r} is closed")
        if not self._cap.grab():
            return None
        t = time.monotonic()
        ok, bgr = self._cap.retrieve()
        if not ok or bgr is None:
            return None
        frame = Frame(rgb=_bgr_to_rgb(bgr), t_capture=t, index=self._index)
        self._index += 1
        return frame

    def close(self) -> None:
        """Releases the device; safe to call twice."""
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class RealSenseCamera(_FrameSource):
    """Intel RealSense RGB-D camera: colour frames with depth aligned to them, in metres.

    UNTESTED HARDWARE CODE: written against the ``pyrealsense2`` API documentation without a device; only the
    missing-package error is exercised by the tests. ``t_capture`` is ``time.monotonic()`` when the frame set
    arrived. The camera's frame is the world frame of :attr:`calibration` (R = I, t = 0).
    """

    #: Frames are stamped with ``time.monotonic()``.
    clock = "monotonic"

    def __init__(self, width: int = 640, height: int = 480, fps: int = 30, serial: str | None = None) -> None:
        """Starts colour and depth streams.

        Args:
            width: Colour and depth width in pixels.
            height: Colour and depth height in pixels.
            fps: Stream rate (a mode the device supports, e.g. 30).
            serial: Serial number of the device to use when several are connected.

        Raises:
            ImportError: If ``pyrealsense2`` is not installed (the message says how to install it).
        """
        try:
            import pyrealsense2 as rs
        except ImportError as exc:
            raise ImportError(
                "RealSenseCamera needs the Intel RealSense SDK's Python package: pip install pyrealsense2"
            ) from exc
        self._rs = rs
        config = rs.config()
        if serial is not None:
            config.enable_device(serial)
        config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
        self._pipeline = rs.pipeline()
        profile = self._pipeline.start(config)
        self._depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        self._align = rs.align(rs.stream.color)
        intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        coeffs = np.asarray(intr.coeffs, dtype=np.float64)
        if np.any(coeffs) and intr.model != rs.distortion.brown_conrady:
            self.close()
            raise ValueError(
                f"RealSense colour distortion model {intr.model} is not OpenCV's (brown_conrady)"
            )
        K = np.array([[intr.fx, 0.0, intr.ppx], [0.0, intr.fy, intr.ppy], [0.0, 0.0, 1.0]])
        self.calibration = PinholeCamera(
            int(intr.width), int(intr.height), K, coeffs[:5], np.eye(3), np.zeros(3), fps=float(fps)
        )
        self._index = 0

    def read(self) -> Frame | None:
        """The next colour frame with aligned depth (NaN where the sensor has no depth), or None."""
        if self._pipeline is None:
            raise ValueError("RealSenseCamera is closed")
        ok, frames = self._pipeline.try_wait_for_frames(1000)
        if not ok:
            return None
        t = time.monotonic()
        frames = self._align.process(frames)
        color, depth_frame = frames.get_color_frame(), frames.get_depth_frame()
        if not color or not depth_frame:
            return None
        rgb = np.array(color.get_data(), dtype=np.uint8)
        depth = np.asarray(depth_frame.get_data(), dtype=np.float32) * self._depth_scale
        depth[depth <= 0] = np.nan
        frame = Frame(rgb=rgb, t_capture=t, index=self._index, depth=depth)
        self._index += 1
        return frame

    def close(self) -> None:
        """Stops the streams; safe to call twice."""
        if getattr(self, "_pipeline", None) is not None:
            self._pipeline.stop()
            self._pipeline = None
