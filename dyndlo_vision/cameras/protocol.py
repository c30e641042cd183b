"""The camera edge of the loop: a :class:`Camera` yields time-stamped :class:`Frame` objects.

Times are seconds on the source's own clock, named in the camera's ``clock`` attribute (one of
:data:`CAMERA_CLOCKS`); in simulation that clock is the simulator's time. The tracked state source maps a
``"monotonic"`` camera's frames onto the robot's clock (:mod:`dyndlo_vision.control.clocks`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

#: Values of a camera's ``clock`` attribute: ``"simulation"`` (the simulator's time, which is also the
#: simulated robot's clock), ``"video"`` (a file's own time line; no robot shares it) and ``"monotonic"``
#: (this process's ``time.monotonic()``, which a robot driver's clock must be mapped onto).
CAMERA_CLOCKS = ("simulation", "video", "monotonic")


@dataclass(frozen=True)
class Frame:
    """One camera image with the time it was captured.

    Attributes:
        rgb: (H, W, 3) uint8 image, RGB channel order.
        t_capture: Capture time in seconds (the simulator's time in simulation).
        index: Running frame number from the source, starting at 0.
        depth: Optional (H, W) float32 depth in metres along the optical axis (NaN or 0 where unknown).
    """

    rgb: NDArray[np.uint8]
    t_capture: float
    index: int = 0
    depth: NDArray[np.float32] | None = None


@runtime_checkable
class Camera(Protocol):
    """A source of time-stamped frames: MuJoCo off-screen camera, video file, OpenCV device, RGB-D sensor."""

    def read(self) -> Frame | None:
        """The next frame, or None when the source has no more frames (end of a video file)."""
        ...

    def close(self) -> None:
        """Release the device or file."""
        ...
