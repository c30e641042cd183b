"""What the EGM and RTDE drivers share: setpoints -> checked joint plan -> one joint target per robot cycle.

Both interfaces are clocked by the robot: it sends its state every cycle (EGM up to 250 Hz, RTDE 500 Hz on
e-Series) and the driver answers each state with the joint target for the next cycle. A background thread does
that; ``send`` only replaces the plan it reads from, and only after the whole plan has passed the joint-limit
check:

1. resample the setpoints onto the robot's cycle (cubic Hermite on positions and feed-forward velocities),
2. IK for every sample, seeded from the joints last commanded (``ArmKinematics.joint_trajectory``),
3. join it to the last two targets already sent and append a braking tail (the plan ends at rest even when the
   setpoints end moving and no more arrive),
4. check positions, velocities and accelerations of all of it (``check_joint_limits``); on any breach raise
   ``JointLimitError`` (a ``ValueError``) and keep following the old plan: not one sample of the new one is
   sent.

Between plan samples the target is interpolated linearly, so what is streamed stays within the checked limits.
``stop`` replaces the plan with a braking ramp from the current command (decelerations within the limits).
The thread stops the robot when the robot stops answering (no state for ``answer_timeout_s``: a log line, the
driver faults) and on any exception (log, fault, the transport's halt command).
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.robots.feasibility import braking_tail, join_plan
from dyndlo_vision.robots.kinematics import ArmKinematics, JointLimitError, check_joint_limits
from dyndlo_vision.robots.protocol import Setpoints, TcpState

__all__ = ["JointSample", "JointStreamingDriver", "braking_tail", "resample_setpoints"]

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class JointSample:
    """One state message from the robot.

    Attributes:
        t: Robot clock in seconds.
        q: Measured joint positions (6,) in radians.
        qd: Measured joint velocities (6,) in rad/s, or None when the interface does not report them.
        fault: Set by the transport when the robot reports a state it cannot follow targets in
            (motors off, program stopped); the driver then stops.
    """

    t: float
    q: FloatArray
    qd: FloatArray | None = None
    fault: str | None = None


def resample_setpoints(setpoints: Setpoints, period_s: float) -> tuple[FloatArray, FloatArray]:
    """Resample single-TCP setpoints onto an even grid of about ``period_s`` (cubic Hermite in time).

    Returns:
        Times (M,) from ``t[0]`` to ``t[-1]`` and TCP positions (M, 3).

    Raises:
        ValueError: When the setpoints are for more than one TCP.
    """
    t = np.asarray(setpoints.t, dtype=float)
    pos = np.asarray(setpoints.position, dtype=float)
    if pos.shape[1] != 1:
        raise ValueError(f"this driver moves one TCP (n_g = 1), got setpoints for n_g = {pos.shape[1]}")
    p, v = pos[:, 0, :], np.asarray(setpoints.velocity, dtype=float)[:, 0, :]
    if t.size == 1:
        return t.copy(), p.copy()
    n = max(1, round((t[-1] - t[0]) / period_s))
    grid = np.linspace(t[0], t[-1], n + 1)
    k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.size - 2)
    h = (t[k + 1] - t[k])[:, None]
    s = (grid - t[k])[:, None] / h
    s2, s3 = s * s, s * s * s
    out = (2 * s3 - 3 * s2 + 1) * p[k] + (s3 - 2 * s2 + s) * h * v[k] + (3 * s2 - 2 * s3) * p[k + 1]
    out += (s3 - s2) * h * v[k + 1]
    return grid, out


class JointStreamingDriver:
    """Base of the EGM and RTDE drivers: a :class:`~dyndlo_vision.robots.protocol.Robot` for one TCP.

    Subclasses provide the transport (``_open``, ``_receive``, ``_send_target``, ``_send_halt``,
    ``_close_transport``); everything about plans, limits, stopping and faults is here.

    Args:
        kinematics: The arm, its base placement in the task's world frame and the fixed tool orientation.
        period_s: The robot's cycle (seconds between its state messages).
        answer_timeout_s: Stop (fault) when no state arrives for this long.
        connect_timeout_s: How long ``connect`` waits for the first state.
        lookahead_s: The target answered to a state at robot time t is the plan at t + lookahead_s (default:
            one period, the time the target takes effect).
        braking_fraction: Fraction of the joint acceleration limits used by braking tails and ``stop``.
    """

    protocol_name: ClassVar[str] = "robot"

    def __init__(
        self,
        kinematics: ArmKinematics,
        period_s: float,
        *,
        answer_timeout_s: float = 0.5,
        connect_timeout_s: float = 10.0,
        lookahead_s: float | None = None,
        braking_fraction: float = 0.9,
    ) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        if not (answer_timeout_s > 0.0 and connect_timeout_s > 0.0):
            raise ValueError(
                f"timeouts must be > 0, got answer_timeout_s={answer_timeout_s}, "
                f"connect_timeout_s={connect_timeout_s}"
            )
        if not 0.0 < braking_fraction <= 1.0:
            raise ValueError(f"braking_fraction must be in (0, 1], got {braking_fraction}")
        self.kinematics = kinematics
        self.period_s = float(period_s)
        self.answer_timeout_s = float(answer_timeout_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.lookahead_s = self.period_s if lookahead_s is None else float(lookahead_s)
        self._braking_fraction = float(braking_fraction)
        self._braking_acc = braking_fraction * np.array(kinematics.arm.max_acceleration_rad_s2)
        self._lock = threading.Lock()
        self._cycle = threading.Condition(self._lock)
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self._connected = False
        self._fault: str | None = None
        self._measured: JointSample | None = None
        self._history: deque[tuple[float, FloatArray]] = deque(maxlen=2)  # last targets sent (t, q)
        self._plan: tuple[FloatArray, FloatArray] | None = None
        self._active = False  # a plan has been accepted since connect: the robot is being driven
        self.cycles = 0

    # ------------------------------------------------------------------------------------------- transport
    def _open(self) -> None:
        raise NotImplementedError

    def _receive(self, timeout_s: float) -> JointSample | None:
        """The next state from the robot, or None when none arrived within the timeout."""
        raise NotImplementedError

    def _send_target(self, q: FloatArray, qd: FloatArray, active: bool) -> None:
        """Answer the state just received with joint target q (rad) and velocity qd (rad/s).

        ``active`` is False until a plan has been accepted (the target is then the position held at connect).
        """
        raise NotImplementedError

    def _send_halt(self) -> None:
        """Best-effort command that makes the robot stop by itself (after a fault or on close)."""

    def _close_transport(self) -> None:
        raise NotImplementedError

    # -------------------------------------------------------------------------------------------- Robot API
    def connect(self) -> None:
        """Open the interface, wait for the robot's first state and start answering it every cycle.

        Raises:
            TimeoutError: When no state arrives within ``connect_timeout_s``.
        """
        if self._connected:
            return
        self._open()
        try:
            first = self._receive(self.connect_timeout_s)
        except BaseException:
            self._close_transport()
            raise
        if first is None:
            self._close_transport()
            raise TimeoutError(
                f"{self.protocol_name}: no state from the robot within {self.connect_timeout_s:.1f} s"
            )
        with self._lock:
            self._fault = None
            self._measured = first
            self._history.clear()
            self._history.append((first.t, first.q.copy()))
            self._plan = None
            self._active = False
            self._closing.clear()
            self._connected = True
        self._respond(first)
        self._thread = threading.Thread(target=self._run, name=f"{self.protocol_name}-stream", daemon=True)
        self._thread.start()
        logger.info("%s: connected, joints %s rad", self.protocol_name, np.round(first.q, 4).tolist())

    def state(self) -> TcpState:
        """Latest measured TCP state: FK of the measured joints, world frame, robot clock."""
        with self._lock:
            sample = self._require_connected()
        qd = np.zeros(6) if sample.qd is None else sample.qd
        position, _ = self.kinematics.fk(sample.q)
        velocity = self.kinematics.tcp_velocity(sample.q, qd)
        return TcpState(position=position[None, :], velocity=velocity[None, :], t=float(sample.t))

    def commanded_state(self) -> TcpState:
        """TCP state of the last target sent (ahead of the measured state by the robot's tracking lag).

        Re-plan from this rather than from :meth:`state`: a plan that starts where the robot *is* jumps back
        from where it was last *told* to be, which the limit check refuses at speed.
        """
        with self._lock:
            self._require_connected()
            hist = list(self._history)
        t, q = hist[-1]
        qd = (q - hist[0][1]) / (t - hist[0][0]) if len(hist) == 2 else np.zeros(6)
        position, _ = self.kinematics.fk(q)
        return TcpState(
            position=position[None, :], velocity=self.kinematics.tcp_velocity(q, qd)[None, :], t=t
        )

    def joints(self) -> JointSample:
        """Latest measured joint state."""
        with self._lock:
            return self._require_connected()

    @property
    def fault(self) -> str | None:
        """Why the driver stopped on its own (robot not answering, exception, robot state), or None."""
        return self._fault

    def send(self, setpoints: Setpoints) -> None:
        """Follow these setpoints from the next robot cycle on, replacing the current plan.

        Raises:
            ValueError: Setpoints for more than one TCP, or entirely in the past.
            IKError: A setpoint has no IK solution (a ``ValueError``).
            JointLimitError: The joint plan breaks a position, velocity or acceleration limit (a
                ``ValueError`` naming joint, time, value and limit). Nothing of this plan is sent.
            RuntimeError: Not connected, or stopped after a fault (close() and connect() again).
        """
        t_grid, p_grid = resample_setpoints(setpoints, self.period_s)
        with self._lock:
            self._require_ready()
            seed = self._history[-1][1].copy()
        traj = self.kinematics.joint_trajectory(t_grid, p_grid, seed)
        with self._lock:
            self._require_ready()
            hist_t = np.array([h[0] for h in self._history])
            hist_q = np.array([h[1] for h in self._history])
            try:
                plan = join_plan(self.kinematics.arm, traj.t, traj.q, hist_t, hist_q, self.period_s,
                                 self._braking_fraction)
            except ValueError as exc:
                raise ValueError(f"{self.protocol_name}: setpoints: {exc} (robot clock)") from exc
            t_all, q_all, report = plan.t, plan.q, plan.report
            if not report.ok:
                hint = ""
                if check_joint_limits(self.kinematics.arm, t_all[hist_t.size :], q_all[hist_t.size :]).ok:
                    hint = (
                        "\n  (broken where the setpoints join the targets already sent, up to "
                        f"t={hist_t[-1]:.4f} s: "
                        "start them from commanded_state(), after the time send() itself takes)"
                    )
                logger.error(
                    "%s: refusing setpoints, nothing of them sent: %s%s", self.protocol_name, report, hint
                )
                raise JointLimitError(report, hint, at_join=bool(hint))
            # The plan starts at the last target sent, so interpolation joins it without a jump.
            self._plan = (t_all[hist_t.size - 1 :], q_all[hist_t.size - 1 :])
            self._active = True

    def stop(self) -> None:
        """Brake to rest from the current command (joint accelerations within the limits) and hold there."""
        with self._lock:
            if not self._connected:
                return
            hist = list(self._history)
            t_last, q_last = hist[-1]
            qd = (q_last - hist[0][1]) / (t_last - hist[0][0]) if len(hist) == 2 else np.zeros(6)
            tail_t, tail_q = braking_tail(t_last, q_last, qd, self._braking_acc, self.period_s)
            lo, hi = self.kinematics.lower, self.kinematics.upper
            if tail_q.size and (np.any(tail_q < lo) or np.any(tail_q > hi)):
                logger.error(
                    "%s: braking ramp reaches a joint position limit; clipped to it", self.protocol_name
                )
                tail_q = np.clip(tail_q, lo, hi)
            self._plan = (np.concatenate([[t_last], tail_t]), np.concatenate([q_last[None], tail_q]))
        if tail_t.size:
            logger.info("%s: stop: braking to rest in %.3f s", self.protocol_name, tail_t[-1] - t_last)

    def close(self) -> None:
        """Stop, wait for the braking to end, halt the robot side and close the interface."""
        if not self._connected:
            return
        self.stop()
        with self._lock:
            end = self._plan[0][-1] if self._plan is not None else -math.inf
            while self._fault is None and self._thread is not None and self._thread.is_alive():
                t_now = self._measured.t if self._measured is not None else math.inf
                if t_now >= end or not self._cycle.wait(timeout=self.answer_timeout_s):
                    break
        self._closing.set()
        if self._thread is not None:  # first, so that no target is sent after the halt
            self._thread.join(timeout=self.answer_timeout_s + 2.0)
        try:
            self._send_halt()
        except Exception:  # closing anyway; the robot side has its own timeout
            logger.exception("%s: halt command on close failed", self.protocol_name)
        self._close_transport()
        self._connected = False
        logger.info("%s: closed", self.protocol_name)

    def __enter__(self) -> JointStreamingDriver:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def wait_cycles(self, n: int, timeout_s: float) -> bool:
        """Block until ``n`` more robot cycles have been answered (False on timeout or fault)."""
        with self._lock:
            target = self.cycles + n
            return self._cycle.wait_for(
                lambda: self.cycles >= target or self._fault is not None, timeout_s
            ) and (self._fault is None)

    # ------------------------------------------------------------------------------------------- internals
    def _require_connected(self) -> JointSample:
        if not self._connected or self._measured is None:
            raise RuntimeError(f"{self.protocol_name}: not connected; call connect() first")
        return self._measured

    def _require_ready(self) -> None:
        self._require_connected()
        if self._fault is not None:
            raise RuntimeError(
                f"{self.protocol_name}: stopped after a fault ({self._fault}); close() and connect() again"
            )

    def _target_at(self, t: float) -> FloatArray:
        if self._plan is None:
            return self._history[-1][1]
        pt, pq = self._plan
        if t <= pt[0]:
            return pq[0]
        if t >= pt[-1]:
            return pq[-1]
        k = int(np.searchsorted(pt, t, side="right")) - 1
        w = (t - pt[k]) / (pt[k + 1] - pt[k])
        return pq[k] + w * (pq[k + 1] - pq[k])

    def _respond(self, sample: JointSample) -> None:
        """Record a state and answer it with the target one lookahead ahead."""
        with self._lock:
            prev = self._measured
            if sample.qd is None and prev is not None and sample.t > prev.t:
                sample = JointSample(
                    sample.t, sample.q, (sample.q - prev.q) / (sample.t - prev.t), sample.fault
                )
            self._measured = sample
            t_last, q_last = self._history[-1]
            t_cmd = sample.t + self.lookahead_s
            if t_cmd > t_last:
                q_cmd = self._target_at(t_cmd)
                qd_cmd = (q_cmd - q_last) / (t_cmd - t_last)
                self._history.append((t_cmd, q_cmd))
            else:  # the robot clock did not advance (repeated message): repeat the last target
                q_cmd, qd_cmd = q_last, np.zeros(6)
            active = self._active
            self.cycles += 1
            self._cycle.notify_all()
        self._send_target(q_cmd, qd_cmd, active)

    def _set_fault(self, reason: str) -> None:
        with self._lock:
            if self._fault is None:
                self._fault = reason
                logger.error("%s: %s; streaming stopped", self.protocol_name, reason)
            self._cycle.notify_all()

    def _run(self) -> None:
        try:
            while not self._closing.is_set():
                sample = self._receive(self.answer_timeout_s)
                if self._closing.is_set():
                    break
                if sample is None:
                    self._set_fault(
                        f"watchdog: the robot stopped answering (no state for {self.answer_timeout_s:.3f} s)"
                    )
                    return
                if sample.fault is not None:
                    self._set_fault(sample.fault)
                    self._halt_quietly()
                    return
                self._respond(sample)
        except Exception as exc:
            logger.exception("%s: exception in the streaming thread", self.protocol_name)
            self._set_fault(f"exception in the streaming thread: {exc!r}")
            self._halt_quietly()

    def _halt_quietly(self) -> None:
        try:
            self._send_halt()
        except Exception:
            logger.exception("%s: halt command failed", self.protocol_name)
