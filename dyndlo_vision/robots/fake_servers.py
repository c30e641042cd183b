"""Fake robot controllers on loopback that speak the real EGM and RTDE protocols, for tests and dry runs.

Each simulates a joint-space robot that tracks the joint targets it receives (first order, time constant
``tau_s``), reports its state every cycle on its own simulated clock, and records every target it received.

* :class:`FakeEgmController` plays the ABB controller: it sends ``EgmRobot`` protobuf messages over UDP to the
  driver's port and takes the ``EgmSensor`` answers as targets.
* :class:`FakeRtdeController` plays the UR controller: an RTDE server (protocol version 2: version
  negotiation, controller version, output/input recipes, start/pause, data packages) and a script port that
  accepts the driver's URScript; it then behaves as that script does (servo to the target registers while the
  command register is 1, stop on 2 or when the keep-alive counter stalls).

The simulated clock advances one period per cycle. A cycle waits for the driver's answer (up to
``reply_timeout_s``) before it integrates, so runs are repeatable on a loaded machine; with ``realtime`` the
cycles are also paced to the wall clock, as a real controller's are.

Dry run: ``FakeEgmController(arm, q0, ("127.0.0.1", 6510)).start()`` next to ``EgmRobot(port=6510)``.
"""

from __future__ import annotations

import logging
import math
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from dyndlo_vision.robots import rtde as rtde_protocol
from dyndlo_vision.robots._streaming import FloatArray
from dyndlo_vision.robots.kinematics import ArmModel

__all__ = ["FakeEgmController", "FakeRtdeController", "ReceivedTarget"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReceivedTarget:
    """A joint target the fake robot received: simulated time, joints (rad) and velocity (rad/s or None)."""

    t: float
    q: FloatArray
    qd: FloatArray | None


def _names(payload: bytes) -> list[str]:
    # ur-rtde ends its variable lists with a comma, which controllers accept.
    return payload.decode("ascii").rstrip(",").split(",")


class _JointRobotSim:
    """First-order joint tracking on a simulated clock, with the bookkeeping both fakes share."""

    def __init__(self, arm: ArmModel, q0: ArrayLike, period_s: float, tau_s: float) -> None:
        q = np.asarray(q0, dtype=float)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q0 must be 6 finite joint angles, got {np.asarray(q0).tolist()}")
        if not (period_s > 0.0 and tau_s > 0.0):
            raise ValueError(f"period_s and tau_s must be > 0, got {period_s} and {tau_s}")
        self.arm = arm
        self.period_s = float(period_s)
        self.gain = 1.0 - math.exp(-period_s / tau_s)
        self.q = q.copy()
        self.qd = np.zeros(6)
        self.target = q.copy()
        self.t = 0.0
        self.cycle = 0
        self.received: list[ReceivedTarget] = []
        self.lock = threading.Condition()

    def step(self, track: bool) -> None:
        q_new = self.q + self.gain * (self.target - self.q) if track else self.q
        with self.lock:
            self.qd = (q_new - self.q) / self.period_s
            self.q = q_new
            self.t += self.period_s
            self.cycle += 1
            self.lock.notify_all()


class _FakeController:
    """Thread plumbing shared by the two fakes: start/close, pacing, waiting for simulated time."""

    def __init__(self, sim: _JointRobotSim, realtime: bool, reply_timeout_s: float) -> None:
        self._sim = sim
        self.realtime = realtime
        self.reply_timeout_s = float(reply_timeout_s)
        self._stop = threading.Event()
        self._hang = threading.Event()
        self._thread: threading.Thread | None = None
        self._origin = time.monotonic()
        self.error: BaseException | None = None

    @property
    def clock_origin(self) -> float:
        """``time.monotonic()`` at the fake robot's time zero: its clock is ``monotonic() - clock_origin``."""
        return self._origin

    @property
    def q(self) -> FloatArray:
        """Simulated joint positions (rad)."""
        with self._sim.lock:
            return self._sim.q.copy()

    @property
    def t(self) -> float:
        """Simulated clock (s)."""
        with self._sim.lock:
            return self._sim.t

    @property
    def received(self) -> list[ReceivedTarget]:
        """Every joint target received so far."""
        with self._sim.lock:
            return list(self._sim.received)

    def hang(self) -> None:
        """Stop sending state and freeze the clock (a controller that stops answering); sockets stay open."""
        self._hang.set()

    def resume(self) -> None:
        """Carry on after :meth:`hang` (tests also use the pair to hold the clock while they plan)."""
        self._hang.clear()

    def wait_until(self, t_sim: float, timeout_s: float) -> bool:
        """Block until the simulated clock reaches ``t_sim`` (False on timeout)."""
        return self.wait_for(lambda: self._sim.t >= t_sim, timeout_s)

    def wait_for(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Block until ``condition()`` holds, checked after every cycle (False on timeout)."""
        with self._sim.lock:
            return self._sim.lock.wait_for(condition, timeout_s)

    def start(self) -> _FakeController:
        """Start the controller thread; returns self."""
        self._thread = threading.Thread(target=self._guarded, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and close the sockets."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._close_sockets()

    def __enter__(self) -> _FakeController:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _guarded(self) -> None:
        try:
            self._serve()
        except Exception as exc:  # kept for the test to inspect; the fake just stops like a dead controller
            if not self._stop.is_set():
                logger.exception("%s stopped", type(self).__name__)
                self.error = exc

    def _pace(self) -> None:
        if self.realtime:
            delay = self._origin + self._sim.cycle * self._sim.period_s - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)

    def _hung(self) -> bool:
        """While hung, idle a little and keep the pacing origin in step (no burst of cycles afterwards)."""
        if not self._hang.is_set():
            return False
        before = time.monotonic()
        time.sleep(0.005)
        self._origin += time.monotonic() - before
        return True

    def _wait_readable(self, sock: socket.socket) -> bool:
        """Wait up to reply_timeout_s for the driver's answer, in slices so that close() is quick."""
        deadline = time.monotonic() + self.reply_timeout_s
        while not self._stop.is_set():
            ready, _, _ = select.select([sock], [], [], max(0.0, min(0.05, deadline - time.monotonic())))
            if ready or time.monotonic() >= deadline:
                return bool(ready)
        return False

    def _serve(self) -> None:
        raise NotImplementedError

    def _close_sockets(self) -> None:
        raise NotImplementedError


class FakeEgmController(_FakeController):
    """An ABB controller running ``EGMRunJoint``, on loopback.

    Args:
        arm: Its joint limits (targets are clipped to them, as the controller would).
        q0: Initial joints (rad).
        driver_address: (host, port) of the EGM driver (the sensor).
        period_s: EGM cycle (4 ms = 250 Hz).
        tau_s: Time constant of the joint tracking.
        realtime: Pace the cycles to the wall clock.
        reply_timeout_s: How long a cycle waits for the driver's answer.
    """

    def __init__(
        self,
        arm: ArmModel,
        q0: ArrayLike,
        driver_address: tuple[str, int],
        period_s: float = 0.004,
        tau_s: float = 0.01,
        realtime: bool = True,
        reply_timeout_s: float = 0.05,
    ) -> None:
        from dyndlo_vision.robots.egm import load_egm_module

        super().__init__(_JointRobotSim(arm, q0, period_s, tau_s), realtime, reply_timeout_s)
        self._pb = load_egm_module().egm_pb2
        self._address = driver_address
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self.rapid_running = True
        self.motors_on = True
        self._garbage = threading.Event()

    def send_garbage(self) -> None:
        """Send one datagram that is not an EgmRobot message (to test the driver's exception handling)."""
        self._garbage.set()

    def _message(self) -> bytes:
        pb, sim = self._pb, self._sim
        msg = pb.EgmRobot()
        msg.header.seqno = sim.cycle
        msg.header.tm = int(round(sim.t * 1e3))
        msg.header.mtype = pb.EgmHeader.MSGTYPE_DATA
        msg.feedBack.joints.joints.extend(np.rad2deg(sim.q).tolist())
        msg.feedBack.time.sec = int(sim.t)
        msg.feedBack.time.usec = int(round((sim.t - int(sim.t)) * 1e6))
        msg.planned.joints.joints.extend(np.rad2deg(sim.target).tolist())
        motor = pb.EgmMotorState
        msg.motorState.state = motor.MOTORS_ON if self.motors_on else motor.MOTORS_OFF
        rapid = pb.EgmRapidCtrlExecState
        msg.rapidExecState.state = rapid.RAPID_RUNNING if self.rapid_running else rapid.RAPID_STOPPED
        return msg.SerializeToString()

    def _serve(self) -> None:
        self._origin = time.monotonic()
        lo, hi = np.array(self._sim.arm.lower_rad), np.array(self._sim.arm.upper_rad)
        while not self._stop.is_set():
            if self._hung():
                continue
            if self._garbage.is_set():
                self._garbage.clear()
                self._sock.sendto(b"\xff\xfe not an EgmRobot message", self._address)
            else:
                self._sock.sendto(self._message(), self._address)
            ready = self._wait_readable(self._sock)
            while ready:
                data = self._sock.recv(65536)
                sensor = self._pb.EgmSensor()
                sensor.ParseFromString(data)
                joints = list(sensor.planned.joints.joints)
                if len(joints) >= 6:
                    q = np.clip(np.deg2rad(joints[:6]), lo, hi)
                    speed = list(sensor.speedRef.joints.joints)
                    qd = np.deg2rad(speed[:6]) if len(speed) >= 6 else None
                    with self._sim.lock:
                        self._sim.target = q
                        self._sim.received.append(ReceivedTarget(self._sim.t, q, qd))
                ready = bool(select.select([self._sock], [], [], 0.0)[0])
            self._sim.step(track=self.motors_on and self.rapid_running)
            self._pace()

    def _close_sockets(self) -> None:
        self._sock.close()


class FakeRtdeController(_FakeController):
    """A UR controller on loopback: RTDE server plus a script port that accepts the driver's URScript.

    Args:
        arm: Its joint limits.
        q0: Initial joints (rad).
        period_s: Controller cycle (2 ms = 500 Hz on e-Series); the RTDE output rate must divide 1/period_s.
        tau_s: Time constant of the joint tracking (servoj).
        realtime: Pace the cycles to the wall clock.
        reply_timeout_s: How long a cycle waits for the client's input package after sending outputs.
        keepalive_cycles: The script stops the robot when the keep-alive register has not changed for this
            many cycles (None: the value written in the script).
        controller_version: Reported by RTDE_GET_URCONTROL_VERSION.
        rtde_port: Port of the RTDE server on 127.0.0.1; 0 lets the OS choose (30004 to serve ur-rtde).
    """

    def __init__(
        self,
        arm: ArmModel,
        q0: ArrayLike,
        period_s: float = 0.002,
        tau_s: float = 0.01,
        realtime: bool = True,
        reply_timeout_s: float = 0.05,
        keepalive_cycles: int | None = None,
        controller_version: tuple[int, int, int, int] = (5, 15, 0, 0),
        rtde_port: int = 0,
    ) -> None:
        super().__init__(_JointRobotSim(arm, q0, period_s, tau_s), realtime, reply_timeout_s)
        self.keepalive_cycles = keepalive_cycles
        self.controller_version = controller_version
        self._listener = socket.create_server(("127.0.0.1", rtde_port))
        self._script_listener = socket.create_server(("127.0.0.1", 0))
        self._conn: socket.socket | None = None
        self._stream: rtde_protocol.PackageStream | None = None
        self._streaming = False
        self.scripts: list[str] = []
        self.stop_commands = 0  # command register set to 2 (stop) by the client
        self.program_running = False
        self._registers: dict[str, Any] = {}
        self._layout = rtde_protocol.RegisterLayout()
        self._script_state = {"seq": 0, "missed": 0}
        self._outputs: tuple[list[str], float] | None = None
        self._inputs: dict[int, list[str]] = {}
        self._garbage = threading.Event()

    @property
    def rtde_port(self) -> int:
        """Port of the RTDE server (30004 on a real controller)."""
        return int(self._listener.getsockname()[1])

    @property
    def script_port(self) -> int:
        """Port that accepts URScript programs (30002, the secondary interface, on a real controller)."""
        return int(self._script_listener.getsockname()[1])

    def send_garbage(self) -> None:
        """Send one malformed RTDE package (to test the client's exception handling)."""
        self._garbage.set()

    # ------------------------------------------------------------------------------------- protocol side
    def _handle_control(self, kind: int, payload: bytes) -> bool:
        """Answer one setup package; True when it was START."""
        rt, stream = rtde_protocol, self._stream
        assert stream is not None
        if kind == rt.REQUEST_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload)
            stream.send(kind, bytes([1 if version == rt.PROTOCOL_VERSION else 0]))
        elif kind == rt.GET_URCONTROL_VERSION:
            stream.send(kind, struct.pack(">IIII", *self.controller_version))
        elif kind == rt.CONTROL_PACKAGE_SETUP_OUTPUTS:
            (frequency,) = struct.unpack(">d", payload[:8])
            names = _names(payload[8:])
            types = [rt.output_type(name) or "NOT_FOUND" for name in names]
            ok = "NOT_FOUND" not in types and 0.0 < frequency <= 1.0 / self._sim.period_s + 1e-9
            recipe = 1 if ok else 0
            if ok:
                self._outputs = (names, frequency)
            stream.send(kind, bytes([recipe]) + ",".join(types).encode("ascii"))
        elif kind == rt.CONTROL_PACKAGE_SETUP_INPUTS:
            names = _names(payload)
            types = [rt.input_type(name) or "NOT_FOUND" for name in names]
            recipe = 0 if "NOT_FOUND" in types else len(self._inputs) + 1
            if recipe:
                self._inputs[recipe] = names
            stream.send(kind, bytes([recipe]) + ",".join(types).encode("ascii"))
        elif kind == rt.CONTROL_PACKAGE_START:
            stream.send(kind, bytes([1 if self._outputs is not None else 0]))
            return self._outputs is not None
        elif kind == rt.CONTROL_PACKAGE_PAUSE:
            stream.send(kind, bytes([1]))
        elif kind == rt.DATA_PACKAGE:
            self._apply_inputs(payload)
        else:
            raise ValueError(f"fake RTDE server: unexpected package type {kind}")
        return False

    def _apply_inputs(self, payload: bytes) -> None:
        recipe = payload[0]
        names = self._inputs.get(recipe)
        if names is None:
            raise ValueError(f"fake RTDE server: data package for unknown input recipe {recipe}")
        values = rtde_protocol.unpack_values([rtde_protocol.input_type(n) or "" for n in names], payload[1:])
        self._registers.update(zip(names, values, strict=True))

    def _output_values(self) -> list[Any]:
        assert self._outputs is not None
        sim = self._sim
        value: dict[str, Callable[[], Any]] = {
            "timestamp": lambda: sim.t,
            "actual_q": lambda: sim.q.tolist(),
            "actual_qd": lambda: sim.qd.tolist(),
            "target_q": lambda: sim.target.tolist(),
            "robot_mode": lambda: 7,  # RUNNING
            "safety_mode": lambda: 1,  # NORMAL
            "runtime_state": lambda: 2 if self.program_running else 1,  # PLAYING / STOPPED
        }
        out = []
        for name in self._outputs[0]:
            if name in value:
                out.append(value[name]())
            else:
                out.append(self._registers.get(name, 0.0 if name.startswith("output_double") else 0))
        return out

    # ------------------------------------------------------------------------------------- robot side
    def _run_script_cycle(self, layout: rtde_protocol.RegisterLayout, state: dict[str, int]) -> bool:
        """One cycle of the driver's URScript; True while it servoes."""
        regs = self._registers
        command = int(regs.get(layout.command, 0))
        seq = int(regs.get(layout.keepalive, 0))
        if command == rtde_protocol.COMMAND_STOP:
            self.stop_commands += 1
            self._end_program("stop command")
            return False
        state["missed"] = state["missed"] + 1 if seq == state["seq"] else 0
        state["seq"] = seq
        limit = layout.keepalive_cycles if self.keepalive_cycles is None else self.keepalive_cycles
        if state["missed"] > limit:
            self._end_program("keep-alive stalled")
            return False
        if command == rtde_protocol.COMMAND_SERVO:
            lo, hi = np.array(self._sim.arm.lower_rad), np.array(self._sim.arm.upper_rad)
            q = np.clip([float(regs.get(name, 0.0)) for name in layout.targets], lo, hi)
            with self._sim.lock:
                self._sim.target = q
                self._sim.received.append(ReceivedTarget(self._sim.t, q, None))
            return True
        return False

    def _end_program(self, why: str) -> None:
        logger.info("fake UR controller: program ended (%s)", why)
        self.program_running = False
        self._registers[self._layout.ready] = 0

    def _accept_script(self) -> None:
        ready, _, _ = select.select([self._script_listener], [], [], 0.0)
        if not ready:
            return
        conn, _ = self._script_listener.accept()
        with conn:
            conn.settimeout(2.0)
            chunks = []
            while True:
                data = conn.recv(65536)
                if not data:
                    break
                chunks.append(data)
        script = b"".join(chunks).decode("utf-8")
        self.scripts.append(script)
        layout = rtde_protocol.RegisterLayout.from_script(script)
        if layout is not None:
            self._layout = layout
            self.program_running = True
            self._registers[layout.ready] = 1
            self._script_state = {"seq": int(self._registers.get(layout.keepalive, 0)), "missed": 0}

    def _serve(self) -> None:
        self._listener.setblocking(False)
        self._origin = time.monotonic()
        while not self._stop.is_set():
            self._accept_script()
            if self._hung():
                continue
            try:
                self._serve_client()
            except (OSError, ConnectionError) as exc:  # the client went away; the robot carries on
                logger.info("fake UR controller: RTDE client disconnected (%s)", exc)
                self._drop_client()
            servo = self.program_running and self._run_script_cycle(self._layout, self._script_state)
            self._sim.step(track=servo)
            self._pace()

    def _serve_client(self) -> None:
        """One cycle of the RTDE side: accept, answer setup packages, or stream outputs and read inputs."""
        if self._stream is None:
            try:
                self._conn, _ = self._listener.accept()
            except BlockingIOError:
                return
            self._conn.setblocking(True)
            self._stream = rtde_protocol.PackageStream(self._conn)
            self._streaming = False
        stream = self._stream
        if not self._streaming:
            package = stream.receive(0.0 if self._outputs is None else self.reply_timeout_s)
            while package is not None and not self._streaming:
                self._streaming = self._handle_control(*package)
                package = stream.receive(0.0) if not self._streaming else None
            return
        assert self._outputs is not None
        names, frequency = self._outputs
        if self._sim.cycle % max(1, round(1.0 / (frequency * self._sim.period_s))) != 0:
            return
        if self._garbage.is_set():
            self._garbage.clear()
            stream.send(rtde_protocol.DATA_PACKAGE, b"\x07garbage")  # unknown recipe, short payload
        else:
            types = [rtde_protocol.output_type(n) or "" for n in names]
            stream.send(
                rtde_protocol.DATA_PACKAGE,
                bytes([1]) + rtde_protocol.pack_values(types, self._output_values()),
            )
        package = stream.receive(0.0)
        if package is None and self._conn is not None and self._wait_readable(self._conn):
            package = stream.receive(self.reply_timeout_s)
        while package is not None:
            kind, payload = package
            if kind == rtde_protocol.CONTROL_PACKAGE_PAUSE:
                self._streaming = False
            self._handle_control(kind, payload)
            package = stream.receive(0.0)

    def _drop_client(self) -> None:
        if self._conn is not None:
            self._conn.close()
        self._conn, self._stream, self._streaming = None, None, False
        self._outputs, self._inputs = None, {}

    def _close_sockets(self) -> None:
        for sock in (self._conn, self._listener, self._script_listener):
            if sock is not None:
                sock.close()
