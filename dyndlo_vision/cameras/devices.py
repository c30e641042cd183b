"""Frames from live devices: OpenCV video devices and (optional, untested) Intel RealSense RGB-D cameras,
stamped with ``time.monotonic()`` when the frame arrived."""

from __future__ import annotations

import time

import cv2
import numpy as np

from dyndlo_vision.cameras._base import _bgr_to_rgb, _check_fps, _FrameSource
from dyndlo_vision.cameras.protocol import Frame
from dyndlo_vision.tracking.camera_model import PinholeCamera


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
