"""Safety at the robot edge: workspace and TCP-speed clamps on setpoints, and a watchdog.

* :func:`clamp_setpoints` keeps every setpoint inside a workspace box and limits the TCP speed, both of the
  feed-forward velocities and of the motion between successive positions (a rate limiter, so a jump in the
  positions becomes a ramp at the speed limit). It logs one warning line per call when it changes anything.
  :class:`ClampedRobot` applies it in front of any :class:`~dyndlo_vision.robots.protocol.Robot`.
* :class:`Watchdog` watches named channels (camera frames, robot state) and calls a stop callback, once,
  with a log line, when one of them has not been fed within its timeout. Poll it from the control loop
  (``check``) or let it run its own thread (``start``).

These clamps are Cartesian; the drivers check the joint limits (``dyndlo_vision.robots.kinematics``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision.robots.protocol import Robot, Setpoints, TcpState

__all__ = ["ClampReport", "ClampedRobot", "Watchdog", "WorkspaceBox", "clamp_setpoints"]

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class WorkspaceBox:
    """Axis-aligned box in the task's world frame that the TCP must stay in.

    Attributes:
        lower_m: (x, y, z) minimum corner in metres.
        upper_m: (x, y, z) maximum corner in metres.
    """

    lower_m: tuple[float, float, float]
    upper_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lower_m, dtype=float), np.asarray(self.upper_m, dtype=float)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError(
                f"WorkspaceBox corners must be 3 finite numbers each, got {self.lower_m}, {self.upper_m}"
            )
        if not np.all(lo < hi):
            raise ValueError(
                "WorkspaceBox lower_m must be below upper_m on every axis, "
                f"got {self.lower_m} and {self.upper_m}"
            )
        object.__setattr__(self, "lower_m", tuple(float(v) for v in lo))
        object.__setattr__(self, "upper_m", tuple(float(v) for v in hi))

    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Whether each point (..., 3) lies inside the box (boundary included)."""
        p = np.asarray(points, dtype=float)
        return np.all((p >= np.asarray(self.lower_m)) & (p <= np.asarray(self.upper_m)), axis=-1)


@dataclass(frozen=True)
class ClampReport:
    """What :func:`clamp_setpoints` changed.

    Attributes:
        positions_moved_into_box: Setpoints (sample, gripper) that were outside the box.
        max_box_excess_m: Largest distance of a setpoint outside the box.
        steps_rate_limited: Setpoints moved because reaching them needed more than the speed limit.
        velocities_clipped: Feed-forward velocities above the speed limit.
        max_speed_m_s: Highest speed asked for (feed-forward or between positions), before clamping.
    """

    positions_moved_into_box: int = 0
    max_box_excess_m: float = 0.0
    steps_rate_limited: int = 0
    velocities_clipped: int = 0
    max_speed_m_s: float = 0.0

    @property
    def changed(self) -> bool:
        """True when any setpoint was changed."""
        return bool(self.positions_moved_into_box or self.steps_rate_limited or self.velocities_clipped)


def _clip_norm(v: FloatArray, limit: float) -> tuple[FloatArray, NDArray[np.bool_]]:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    over = norm[..., 0] > limit
    return np.where(norm > limit, v * (limit / np.maximum(norm, 1e-300)), v), over


def clamp_setpoints(
    setpoints: Setpoints, box: WorkspaceBox, max_speed_m_s: float, start: TcpState | None = None
) -> tuple[Setpoints, ClampReport]:
    """Setpoints moved into the box and slowed to the TCP speed limit.

    Positions are first clipped into the box; then, sample by sample, each position is moved towards the
    clipped one by at most ``max_speed_m_s * dt`` from the previous (clamped) position, starting from
    ``start`` when given (its position at its time ``t``) or from the first setpoint. Feed-forward velocities
    are clipped to the speed limit, and replaced by the finite-difference velocity where a position was moved.

    Args:
        setpoints: Setpoints for n_g grippers.
        box: The workspace.
        max_speed_m_s: TCP speed limit (e.g. the paper's v_max = 1.8 m/s).
        start: Current TCP state (n_g rows); limits the first step too.

    Returns:
        The clamped setpoints (the same object when nothing changed) and a report.
    """
    if not max_speed_m_s > 0.0:
        raise ValueError(f"max_speed_m_s must be > 0, got {max_speed_m_s}")
    t = np.asarray(setpoints.t, dtype=float)
    p = np.asarray(setpoints.position, dtype=float)
    v = np.asarray(setpoints.velocity, dtype=float)
    lo, hi = np.asarray(box.lower_m), np.asarray(box.upper_m)
    boxed = np.clip(p, lo, hi)
    excess = np.linalg.norm(p - boxed, axis=-1)
    out = boxed.copy()
    if start is not None:
        prev, t_prev = np.clip(np.asarray(start.position, dtype=float), lo, hi), float(start.t)
        if prev.shape != p.shape[1:]:
            raise ValueError(f"start.position must have shape {p.shape[1:]}, got {prev.shape}")
    else:
        prev, t_prev = boxed[0], float(t[0])
    step_speed = np.zeros(p.shape[:2])
    limited = np.zeros(p.shape[:2], dtype=bool)
    for k in range(t.size):
        dt = float(t[k]) - t_prev
        step = boxed[k] - prev
        dist = np.linalg.norm(step, axis=-1)
        allowed = max_speed_m_s * max(dt, 0.0)
        if dt > 0.0:
            step_speed[k] = dist / dt
        over = dist > allowed * (1.0 + 1e-9) + 1e-12
        if np.any(over):
            step = np.where(over[:, None], step * (allowed / np.maximum(dist, 1e-300))[:, None], step)
            limited[k] = over
        out[k] = prev + step
        prev, t_prev = out[k], float(t[k])
    vel, clipped = _clip_norm(v, max_speed_m_s)
    moved = limited | (excess > 0.0)
    if np.any(moved):
        fd = np.empty_like(out)
        fd[1:] = np.diff(out, axis=0) / np.diff(t)[:, None, None]
        fd[0] = (
            vel[0]
            if start is None or t[0] <= start.t
            else (out[0] - np.asarray(start.position)) / (t[0] - start.t)
        )
        fd, _ = _clip_norm(fd, max_speed_m_s)
        vel = np.where(moved[..., None], fd, vel)
    report = ClampReport(
        positions_moved_into_box=int(np.count_nonzero(excess > 0.0)),
        max_box_excess_m=float(excess.max(initial=0.0)),
        steps_rate_limited=int(np.count_nonzero(limited)),
        velocities_clipped=int(np.count_nonzero(clipped)),
        max_speed_m_s=float(max(np.linalg.norm(v, axis=-1).max(initial=0.0), step_speed.max(initial=0.0))),
    )
    if not report.changed:
        return setpoints, report
    logger.warning(
        "safety: clamped setpoints t=%.3f..%.3f s: %d outside the workspace box (up to %.3f m), %d steps and "
        "%d velocities over the TCP speed limit %.2f m/s (asked up to %.2f m/s)",
        t[0], t[-1], report.positions_moved_into_box, report.max_box_excess_m, report.steps_rate_limited,
        report.velocities_clipped, max_speed_m_s, report.max_speed_m_s,
    )  # fmt: skip
    return Setpoints(t=t.copy(), position=out, velocity=vel), report


class ClampedRobot:
    """A :class:`~dyndlo_vision.robots.protocol.Robot` that clamps setpoints before passing them on.

    Args:
        robot: The robot (simulated TCP or a driver).
        box: Workspace box.
        max_speed_m_s: TCP speed limit.
    """

    def __init__(self, robot: Robot, box: WorkspaceBox, max_speed_m_s: float) -> None:
        if not max_speed_m_s > 0.0:
            raise ValueError(f"max_speed_m_s must be > 0, got {max_speed_m_s}")
        self.robot, self.box, self.max_speed_m_s = robot, box, float(max_speed_m_s)
        self.last_report = ClampReport()

    def connect(self) -> None:
        """Connect the wrapped robot."""
        self.robot.connect()

    def state(self) -> TcpState:
        """The wrapped robot's state."""
        return self.robot.state()

    def send(self, setpoints: Setpoints) -> None:
        """Clamp (starting from the current state) and send."""
        clamped, self.last_report = clamp_setpoints(
            setpoints, self.box, self.max_speed_m_s, self.robot.state()
        )
        self.robot.send(clamped)

    def stop(self) -> None:
        """Stop the wrapped robot."""
        self.robot.stop()

    def close(self) -> None:
        """Close the wrapped robot."""
        self.robot.close()


class Watchdog:
    """Calls ``on_timeout`` once when a watched channel has not been fed within its timeout.

    Args:
        timeouts_s: Timeout per channel name, e.g. ``{"camera frames": 0.2, "robot state": 0.1}``.
        on_timeout: Stop callback; gets a sentence saying which channel went quiet and for how long.
        clock: Time source in seconds (``time.monotonic``; inject a fake one in tests).
        name: Prefix of the log line.

    The channels count from construction (or :meth:`reset`), so a channel that never delivers fires too.
    After firing, the watchdog stays fired (no second callback) until :meth:`reset`.
    """

    def __init__(
        self,
        timeouts_s: Mapping[str, float],
        on_timeout: Callable[[str], None],
        clock: Callable[[], float] = time.monotonic,
        name: str = "watchdog",
    ) -> None:
        if not timeouts_s:
            raise ValueError("Watchdog needs at least one channel")
        for channel, timeout in timeouts_s.items():
            if not timeout > 0.0:
                raise ValueError(f"Watchdog timeout for {channel!r} must be > 0, got {timeout}")
        self.timeouts_s = dict(timeouts_s)
        self.on_timeout = on_timeout
        self.clock = clock
        self.name = name
        self._lock = threading.Lock()
        self._fired: str | None = None
        self._thread: threading.Thread | None = None
        self._halt = threading.Event()
        now = clock()
        self._last = dict.fromkeys(self.timeouts_s, now)

    @property
    def fired(self) -> str | None:
        """The reason it fired, or None."""
        return self._fired

    def feed(self, channel: str, now: float | None = None) -> None:
        """Record that ``channel`` delivered (a frame, a robot state) at ``now`` (the clock when None)."""
        if channel not in self._last:
            raise ValueError(f"unknown watchdog channel {channel!r}; watched: {sorted(self._last)}")
        with self._lock:
            self._last[channel] = self.clock() if now is None else now

    def check(self, now: float | None = None) -> str | None:
        """Fire if a channel is overdue. Returns the reason when it fired (now or before), else None."""
        now = self.clock() if now is None else now
        with self._lock:
            if self._fired is not None:
                return self._fired
            overdue = [(now - last - self.timeouts_s[ch], ch) for ch, last in self._last.items()]
            late, channel = max(overdue)
            if late < 0.0:
                return None
            age = now - self._last[channel]
            self._fired = f"no {channel} for {age:.3f} s (timeout {self.timeouts_s[channel]:.3f} s)"
            reason = self._fired
        logger.error("%s: %s; stopping", self.name, reason)
        try:
            self.on_timeout(reason)
        except Exception:
            logger.exception("%s: the stop callback raised", self.name)
        return reason

    def reset(self, now: float | None = None) -> None:
        """Re-arm: every channel counts from now, and the watchdog may fire again."""
        now = self.clock() if now is None else now
        with self._lock:
            self._fired = None
            self._last = dict.fromkeys(self._last, now)

    def start(self, poll_s: float | None = None) -> Watchdog:
        """Check in a background thread every ``poll_s`` (a quarter of the shortest timeout by default)."""
        if self._thread is not None and self._thread.is_alive():
            return self
        period = min(self.timeouts_s.values()) / 4.0 if poll_s is None else float(poll_s)
        if not period > 0.0:
            raise ValueError(f"poll_s must be > 0, got {poll_s}")
        self._halt.clear()

        def run() -> None:
            while not self._halt.wait(period):
                self.check()

        self._thread = threading.Thread(target=run, name=self.name, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the background thread (if any)."""
        self._halt.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def __enter__(self) -> Watchdog:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
