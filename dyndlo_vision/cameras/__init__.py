"""Frame sources behind the :class:`Camera` protocol: MuJoCo off-screen renders, video files and image
folders, live OpenCV devices and (optional, untested) Intel RealSense RGB-D cameras.

Every source is a context manager and an iterator over its :class:`Frame` objects. Frames are RGB uint8;
OpenCV's BGR is converted once, at this edge. Capture times are seconds on the source's own clock, named in
its ``clock`` attribute (:data:`CAMERA_CLOCKS`):

* :class:`MujocoCamera`: the simulator's time, ``data.time``;
* :class:`VideoFileCamera`: the video's own time stamps when they are sane, else ``index / fps``;
* :class:`OpenCVDeviceCamera` and :class:`RealSenseCamera`: ``time.monotonic()`` when the frame arrived.

:class:`DelayedCamera` wraps any of them and hands frames over a fixed time after their capture.
"""

from dyndlo_vision.cameras._base import average_frames
from dyndlo_vision.cameras.devices import OpenCVDeviceCamera, RealSenseCamera
from dyndlo_vision.cameras.files import (
    DEFAULT_FOLDER_FPS,
    IMAGE_SUFFIXES,
    TruncatedVideoError,
    VideoFileCamera,
)
from dyndlo_vision.cameras.protocol import CAMERA_CLOCKS, Camera, Frame
from dyndlo_vision.cameras.simulated import DelayedCamera, MujocoCamera

__all__ = [
    "CAMERA_CLOCKS",
    "DEFAULT_FOLDER_FPS",
    "IMAGE_SUFFIXES",
    "Camera",
    "DelayedCamera",
    "Frame",
    "MujocoCamera",
    "OpenCVDeviceCamera",
    "RealSenseCamera",
    "TruncatedVideoError",
    "VideoFileCamera",
    "average_frames",
]
