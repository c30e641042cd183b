"""Putting a live camera's time stamps on the robot's clock.

On hardware the loop has two clocks. A live camera stamps its frames with this process's
``time.monotonic()`` (:class:`~dyndlo_vision.cameras.OpenCVDeviceCamera`,
:class:`~dyndlo_vision.cameras.RealSenseCamera`); a robot driver reports its state on the
controller's clock (EGM's header time, RTDE's ``timestamp``: seconds since the controller started). The
Kalman filter must update at a frame's capture time and predict to the controller's time on *one* clock;
left apart, the two differ by anything from seconds to days, and the filter either calls the estimate lost
at once or predicts across that gap.

:class:`ClockSync` estimates the offset between them from pairs the loop sees anyway: every cycle, the
robot's latest state time and the local time it was read at. A state is never younger than the moment it
is read, so ``robot_t - local_t`` is at most the true offset and falls short of it by the state's age (up to
one robot cycle plus transport). The largest difference over a sliding window is therefore the best estimate
(the freshest pair), the idea behind minimum-delay clock synchronisation; the window lets it follow a slow
drift.

Cameras say which clock they stamp with in their ``clock`` attribute
(:data:`dyndlo_vision.cameras.protocol.CAMERA_CLOCKS`).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable

__all__ = ["ClockSync"]



class ClockSync:
    """The offset from a local clock to the robot's clock, from (robot time, local time) pairs.

    Args:
        window: How many of the latest pairs the estimate uses (at the loop's 25 Hz, 250 are 10 s: a drift of
            100 ppm moves the clocks 1 ms apart in that time).
        clock: The local clock (``time.monotonic``, the clock the live cameras stamp with).

    Raises:
        ValueError: A window that is not a whole number >= 1.
    """

    def __init__(self, window: int = 250, clock: Callable[[], float] = time.monotonic) -> None:
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"window must be a whole number >= 1 (pairs), got {window!r}")
        self.window = window
        self.clock = clock
        self._offsets: deque[float] = deque(maxlen=window)
        self._last_robot_t = -math.inf

    def reset(self) -> None:
        """Forget every pair (the robot's clock restarted)."""
        self._offsets.clear()
        self._last_robot_t = -math.inf

    def observe(self, robot_t: float, local_t: float | None = None) -> None:
        """Record that a robot state stamped ``robot_t`` was read at ``local_t`` (default: now on ``clock``).

        A robot time earlier than the last one means the robot's clock restarted: the older pairs are dropped.

        Raises:
            ValueError: A time that is not a finite number.
        """
        local = self.clock() if local_t is None else local_t
        for name, value in (("robot_t", robot_t), ("local_t", local)):
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number of seconds, got {value!r}")
        if robot_t < self._last_robot_t:
            self._offsets.clear()
        self._last_robot_t = float(robot_t)
        self._offsets.append(float(robot_t) - float(local))

    @property
    def ready(self) -> bool:
        """Whether at least one pair has been observed."""
        return bool(self._offsets)

    @property
    def offset_s(self) -> float:
        """Robot time minus local time (seconds).

        Raises:
            RuntimeError: Before the first :meth:`observe`.
        """
        if not self._offsets:
            raise RuntimeError("ClockSync has no (robot time, local time) pair yet: call observe() first")
        return max(self._offsets)

    def to_robot(self, local_t: float) -> float:
        """``local_t`` on the robot's clock."""
        return float(local_t) + self.offset_s
