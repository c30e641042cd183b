"""Universal Robots RTDE driver: joint targets streamed to a UR controller through RTDE input registers.

A minimal RTDE client written from UR's published protocol ("Real-Time Data Exchange (RTDE) Guide"), protocol
version 2, over TCP (port 30004). Every package is ``uint16 size, uint8 type, payload``, big-endian:

* ``V`` request protocol version (uint16) -> accepted (uint8); ``v`` controller version -> 4 x uint32;
* ``O`` setup outputs (double frequency, comma-separated names) -> recipe id (uint8), comma-separated types;
* ``I`` setup inputs (names) -> recipe id, types (``NOT_FOUND`` or ``IN_USE`` mark a refused variable);
* ``S`` start / ``P`` pause -> accepted; ``U`` data package (recipe id, values); ``M`` text message.

Why not ``ur-rtde``: its ``RTDEControlInterface(hostname, frequency, flags, ur_cap_port, rt_priority)``
(1.6.5) takes no port numbers (RTDE 30004 is fixed), uploads its own control script and then drives it through
registers whose meaning is private to that script; a fake controller on OS-chosen loopback ports would have to
emulate ur-rtde's script rather than the robot, and ur-rtde holds the GIL while it connects, so it cannot talk
to a fake in the same process. Writing the few RTDE packages ourselves keeps the test honest: the fake speaks
RTDE itself (and ur-rtde's receive interface reads it, see tests/robots/test_rtde.py).

Robot side: :func:`servo_script` is a short URScript program, sent to the secondary interface (port 30002, the
robot must be in remote control on e-Series), that reads the target joints from input registers and
``servoj``-s to them every cycle, stops (``stopj``) on command 2 and stops by itself when the keep-alive
register stops changing (the PC died). Untested on hardware: a UR controller was not available here.
"""

from __future__ import annotations

import logging
import re
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from dyndlo_vision.robots._streaming import FloatArray, JointSample, JointStreamingDriver
from dyndlo_vision.robots.kinematics import ArmKinematics, ur5e

__all__ = [
    "COMMAND_IDLE",
    "COMMAND_SERVO",
    "COMMAND_STOP",
    "PackageStream",
    "Recipe",
    "RegisterLayout",
    "RtdeClient",
    "RtdeRobot",
    "servo_script",
]

logger = logging.getLogger(__name__)

RTDE_PORT = 30004
SCRIPT_PORT = 30002  # secondary interface: accepts URScript programs
PROTOCOL_VERSION = 2

# Package types (ASCII letters).
REQUEST_PROTOCOL_VERSION = 86  # 'V'
GET_URCONTROL_VERSION = 118  # 'v'
TEXT_MESSAGE = 77  # 'M'
DATA_PACKAGE = 85  # 'U'
CONTROL_PACKAGE_SETUP_OUTPUTS = 79  # 'O'
CONTROL_PACKAGE_SETUP_INPUTS = 73  # 'I'
CONTROL_PACKAGE_START = 83  # 'S'
CONTROL_PACKAGE_PAUSE = 80  # 'P'

# struct formats of the RTDE data types.
TYPE_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

_OUTPUT_TYPES = {
    "timestamp": "DOUBLE",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "target_q": "VECTOR6D",
    "robot_mode": "INT32",
    "safety_mode": "INT32",
    "runtime_state": "UINT32",
}
_REGISTER = re.compile(r"(input|output)_(int|double)_register_(\d+)$")

COMMAND_IDLE, COMMAND_SERVO, COMMAND_STOP = 0, 1, 2


def output_type(name: str) -> str | None:
    """RTDE type of an output variable this module knows (None when unknown)."""
    m = _REGISTER.match(name)
    if m and m.group(1) == "output" and int(m.group(3)) < 48:
        return "INT32" if m.group(2) == "int" else "DOUBLE"
    return _OUTPUT_TYPES.get(name)


def input_type(name: str) -> str | None:
    """RTDE type of an input register (None when unknown)."""
    m = _REGISTER.match(name)
    if m and m.group(1) == "input" and int(m.group(3)) < 48:
        return "INT32" if m.group(2) == "int" else "DOUBLE"
    return None


def pack_values(types: list[str], values: list[Any]) -> bytes:
    """Serialise data-package values of the given RTDE types (vectors as sequences)."""
    out = bytearray()
    for kind, value in zip(types, values, strict=True):
        fmt = ">" + TYPE_FORMATS[kind]
        out += struct.pack(fmt, *value) if kind.startswith("VECTOR") else struct.pack(fmt, value)
    return bytes(out)


def unpack_values(types: list[str], payload: bytes) -> list[Any]:
    """Parse data-package values (vectors as lists); raises ValueError when the payload does not fit."""
    out: list[Any] = []
    offset = 0
    for kind in types:
        if kind not in TYPE_FORMATS:
            raise ValueError(f"RTDE: unknown data type {kind!r}")
        fmt = ">" + TYPE_FORMATS[kind]
        size = struct.calcsize(fmt)
        if offset + size > len(payload):
            raise ValueError(f"RTDE: data package of {len(payload)} bytes too short for types {types}")
        value = struct.unpack_from(fmt, payload, offset)
        out.append(list(value) if kind.startswith("VECTOR") else value[0])
        offset += size
    if offset != len(payload):
        raise ValueError(f"RTDE: data package has {len(payload) - offset} bytes more than types {types}")
    return out


class PackageStream:
    """RTDE framing over a connected TCP socket: send whole packages (thread-safe), receive with a timeout."""

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock
        self._buffer = bytearray()
        self._send_lock = threading.Lock()

    def send(self, kind: int, payload: bytes = b"") -> None:
        """Send one package."""
        with self._send_lock:
            self._sock.sendall(struct.pack(">HB", len(payload) + 3, kind) + payload)

    def _complete(self) -> tuple[int, bytes] | None:
        if len(self._buffer) < 3:
            return None
        size, kind = struct.unpack_from(">HB", self._buffer)
        if size < 3:
            raise ValueError(f"RTDE: package header announces {size} bytes (minimum 3)")
        if len(self._buffer) < size:
            return None
        payload = bytes(self._buffer[3:size])
        del self._buffer[:size]
        return kind, payload

    def receive(self, timeout_s: float) -> tuple[int, bytes] | None:
        """The next package (type, payload), or None when none is complete within ``timeout_s``.

        Raises:
            ConnectionError: The peer closed the connection.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            package = self._complete()
            if package is not None:
                return package
            wait = max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([self._sock], [], [], wait)
            if not ready:
                return None
            data = self._sock.recv(65536)
            if not data:
                raise ConnectionError("RTDE: connection closed by the peer")
            self._buffer += data

    def pending(self) -> bool:
        """True when a complete package is buffered or bytes wait on the socket."""
        if self._complete_size() is not None:
            return True
        ready, _, _ = select.select([self._sock], [], [], 0.0)
        return bool(ready)

    def _complete_size(self) -> int | None:
        if len(self._buffer) >= 3:
            size = struct.unpack_from(">H", self._buffer)[0]
            if len(self._buffer) >= size:
                return size
        return None


@dataclass(frozen=True)
class Recipe:
    """An accepted RTDE recipe: its id, variable names and types."""

    id: int
    names: tuple[str, ...]
    types: tuple[str, ...]


class RtdeClient:
    """Minimal RTDE client (protocol version 2).

    Args:
        host: Controller address.
        port: RTDE port (30004 on a controller).
        timeout_s: Timeout of the setup requests.
    """

    def __init__(self, host: str, port: int = RTDE_PORT, timeout_s: float = 5.0) -> None:
        self.host, self.port, self.timeout_s = host, int(port), float(timeout_s)
        self._sock: socket.socket | None = None
        self._stream: PackageStream | None = None
        self.output_recipe: Recipe | None = None

    @property
    def stream(self) -> PackageStream:
        if self._stream is None:
            raise RuntimeError("RTDE: not connected")
        return self._stream

    def connect(self) -> None:
        """Open the TCP connection and negotiate protocol version 2."""
        self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._stream = PackageStream(self._sock)
        if not self._request(REQUEST_PROTOCOL_VERSION, struct.pack(">H", PROTOCOL_VERSION))[0]:
            raise ConnectionError(f"RTDE: the controller refused protocol version {PROTOCOL_VERSION}")

    def controller_version(self) -> tuple[int, int, int, int]:
        """(major, minor, bugfix, build) of the controller software."""
        major, minor, bugfix, build = struct.unpack(">IIII", self._request(GET_URCONTROL_VERSION))
        return major, minor, bugfix, build

    def setup_outputs(self, names: list[str], frequency_hz: float) -> Recipe:
        """Ask for these outputs at this rate; raises ConnectionError naming any variable refused."""
        reply = self._request(
            CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", frequency_hz) + ",".join(names).encode()
        )
        recipe = self._recipe(reply, names, "output")
        self.output_recipe = recipe
        return recipe

    def setup_inputs(self, names: list[str]) -> Recipe:
        """Register these inputs; raises ConnectionError naming any variable refused (unknown or in use)."""
        return self._recipe(
            self._request(CONTROL_PACKAGE_SETUP_INPUTS, ",".join(names).encode()), names, "input"
        )

    def start(self) -> None:
        """Start the data synchronisation."""
        if not self._request(CONTROL_PACKAGE_START)[0]:
            raise ConnectionError("RTDE: the controller refused to start the synchronisation")

    def pause(self) -> None:
        """Pause the data synchronisation."""
        self.stream.send(CONTROL_PACKAGE_PAUSE)

    def send_inputs(self, recipe: Recipe, values: list[Any]) -> None:
        """Send one input data package (values in the recipe's order)."""
        self.stream.send(DATA_PACKAGE, bytes([recipe.id]) + pack_values(list(recipe.types), values))

    def receive_outputs(self, timeout_s: float) -> dict[str, Any] | None:
        """The newest output data package as {name: value}, or None when none arrived within the timeout.

        Raises:
            ValueError: A malformed package or one for another recipe.
            ConnectionError: The controller closed the connection.
        """
        newest = None
        wait = timeout_s
        while True:
            package = self.stream.receive(wait)
            if package is None:
                return newest
            kind, payload = package
            if kind == DATA_PACKAGE:
                newest = self._parse_outputs(payload)
                wait = 0.0  # keep draining: only the newest state matters
                if not self.stream.pending():
                    return newest
            elif kind == TEXT_MESSAGE:
                self._log_text(payload)
            elif kind not in (CONTROL_PACKAGE_PAUSE, CONTROL_PACKAGE_START):
                raise ValueError(f"RTDE: unexpected package type {kind} while streaming")

    def close(self) -> None:
        """Close the connection."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            self._stream = None

    def _parse_outputs(self, payload: bytes) -> dict[str, Any]:
        recipe = self.output_recipe
        if recipe is None:
            raise ValueError("RTDE: data package before the output recipe was set up")
        if not payload or payload[0] != recipe.id:
            got = payload[0] if payload else None
            raise ValueError(f"RTDE: data package for recipe {got}, expected the output recipe {recipe.id}")
        return dict(zip(recipe.names, unpack_values(list(recipe.types), payload[1:]), strict=True))

    def _request(self, kind: int, payload: bytes = b"") -> bytes:
        self.stream.send(kind, payload)
        while True:
            package = self.stream.receive(self.timeout_s)
            if package is None:
                raise TimeoutError(f"RTDE: no answer to package type {kind} within {self.timeout_s} s")
            if package[0] == kind:
                return package[1]
            if package[0] == TEXT_MESSAGE:
                self._log_text(package[1])

    @staticmethod
    def _recipe(reply: bytes, names: list[str], what: str) -> Recipe:
        types = reply[1:].decode("ascii").split(",")
        refused = [f"{n} ({t})" for n, t in zip(names, types, strict=False) if t in ("NOT_FOUND", "IN_USE")]
        if reply[0] == 0 or refused or len(types) != len(names):
            raise ConnectionError(f"RTDE: the controller refused the {what} recipe: {refused or types}")
        return Recipe(reply[0], tuple(names), tuple(types))

    @staticmethod
    def _log_text(payload: bytes) -> None:
        try:
            n = payload[0]
            message = payload[1 : 1 + n].decode("utf-8", "replace")
            source = payload[2 + n : 2 + n + payload[1 + n]].decode("utf-8", "replace")
            logger.warning("RTDE message from %s: %s", source, message)
        except IndexError:
            logger.warning("RTDE text message: %r", payload)


@dataclass(frozen=True)
class RegisterLayout:
    """The registers the servo script and the driver share, from ``offset`` on (0 or 24 on a controller)."""

    offset: int = 24
    keepalive_cycles: int = 50

    def __post_init__(self) -> None:
        if not 0 <= self.offset <= 40:
            raise ValueError(
                f"register offset must be in 0..40 (registers offset..offset+7 < 48), got {self.offset}"
            )
        if self.keepalive_cycles < 1:
            raise ValueError(f"keepalive_cycles must be >= 1, got {self.keepalive_cycles}")

    @property
    def command(self) -> str:
        """Input int register: 0 idle, 1 servo to the targets, 2 stop and end the program."""
        return f"input_int_register_{self.offset}"

    @property
    def keepalive(self) -> str:
        """Input int register the driver increments every cycle."""
        return f"input_int_register_{self.offset + 1}"

    @property
    def targets(self) -> tuple[str, ...]:
        """Six input double registers: the target joints in radians."""
        return tuple(f"input_double_register_{self.offset + i}" for i in range(6))

    @property
    def ready(self) -> str:
        """Output int register the script sets to 1 while it runs."""
        return f"output_int_register_{self.offset}"

    @classmethod
    def from_script(cls, script: str) -> RegisterLayout | None:
        """The layout a :func:`servo_script` program was written for (None for any other program)."""
        m = re.search(
            r"# dyndlo_vision joint streaming: register_offset=(\d+) keepalive_cycles=(\d+)", script
        )
        return cls(int(m.group(1)), int(m.group(2))) if m else None


def servo_script(
    layout: RegisterLayout,
    period_s: float,
    servo_lookahead_s: float = 0.1,
    servo_gain: int = 300,
    stop_deceleration_rad_s2: float = 4.0,
) -> str:
    """URScript program that servoes to the joint targets in the input registers (see module docstring)."""
    b = layout.offset
    targets = ", ".join(f"read_input_float_register({b + i})" for i in range(6))
    return f"""def dyndlo_joint_streaming():
  # dyndlo_vision joint streaming: register_offset={b} keepalive_cycles={layout.keepalive_cycles}
  write_output_integer_register({b}, 1)
  last_seq = read_input_integer_register({b + 1})
  missed = 0
  while True:
    cmd = read_input_integer_register({b})
    seq = read_input_integer_register({b + 1})
    if cmd == {COMMAND_STOP}:
      break
    end
    if seq == last_seq:
      missed = missed + 1
      if missed > {layout.keepalive_cycles}:
        textmsg("dyndlo_vision: no targets from the PC, stopping")
        break
      end
    else:
      missed = 0
      last_seq = seq
    end
    if cmd == {COMMAND_SERVO}:
      servoj([{targets}], t={period_s:.6f}, lookahead_time={servo_lookahead_s:.4f}, gain={int(servo_gain)})
    else:
      sync()
    end
  end
  stopj({stop_deceleration_rad_s2:.3f})
  write_output_integer_register({b}, 0)
end
dyndlo_joint_streaming()
"""


class RtdeRobot(JointStreamingDriver):
    """UR RTDE joint-streaming driver implementing the ``Robot`` protocol for one TCP.

    Args:
        host: Controller address.
        kinematics: Arm, base placement and tool orientation; a UR5e at the world origin with the tool
            pointing down when None.
        rtde_port: RTDE port (30004).
        script_port: Port the servo script is sent to (30002, secondary interface).
        frequency_hz: RTDE output rate = streaming rate (500 Hz on e-Series, 125 Hz on CB3).
        register_offset: First of the 8 input registers (and the output int register) used.
        upload_script: Send :func:`servo_script` on connect (False: start it on the robot yourself).
        keepalive_timeout_s: The script stops the robot when no new target arrives for this long.
        servo_lookahead_s, servo_gain: servoj parameters.
        **kwargs: Passed to :class:`JointStreamingDriver` (``answer_timeout_s``, ``connect_timeout_s``, ...).
    """

    protocol_name = "RTDE"

    def __init__(
        self,
        host: str,
        kinematics: ArmKinematics | None = None,
        *,
        rtde_port: int = RTDE_PORT,
        script_port: int = SCRIPT_PORT,
        frequency_hz: float = 500.0,
        register_offset: int = 24,
        upload_script: bool = True,
        keepalive_timeout_s: float = 0.1,
        servo_lookahead_s: float = 0.1,
        servo_gain: int = 300,
        **kwargs: Any,
    ) -> None:
        if not 0.0 < frequency_hz <= 500.0:
            raise ValueError(f"frequency_hz must be in (0, 500], got {frequency_hz}")
        super().__init__(kinematics or ArmKinematics(ur5e()), 1.0 / frequency_hz, **kwargs)
        self.host = host
        self.rtde_port, self.script_port = int(rtde_port), int(script_port)
        self.frequency_hz = float(frequency_hz)
        self.upload_script = upload_script
        self.layout = RegisterLayout(register_offset, max(1, round(keepalive_timeout_s * 500.0)))
        stop_acc = 0.5 * min(self.kinematics.arm.max_acceleration_rad_s2)
        self.script = servo_script(self.layout, 1.0 / frequency_hz, servo_lookahead_s, servo_gain, stop_acc)
        self._client: RtdeClient | None = None
        self._inputs: Recipe | None = None
        self._seq = 0
        self._last_target = np.zeros(6)

    def _open(self) -> None:
        client = RtdeClient(self.host, self.rtde_port, timeout_s=self.connect_timeout_s)
        self._client = client
        try:
            client.connect()
            version = client.controller_version()
            logger.info("RTDE: controller software %s", ".".join(map(str, version)))
            client.setup_outputs(["timestamp", "actual_q", "actual_qd", self.layout.ready], self.frequency_hz)
            self._inputs = client.setup_inputs(
                [self.layout.command, self.layout.keepalive, *self.layout.targets]
            )
            self._write(COMMAND_IDLE, np.zeros(6))
            client.start()
            if self.upload_script:
                with socket.create_connection(
                    (self.host, self.script_port), timeout=self.connect_timeout_s
                ) as s:
                    s.sendall(self.script.encode("utf-8"))
            self._wait_for_program()
        except BaseException:
            client.close()
            self._client = None
            raise

    def _wait_for_program(self) -> None:
        deadline = time.monotonic() + self.connect_timeout_s
        assert self._client is not None
        while time.monotonic() < deadline:
            data = self._client.receive_outputs(max(0.0, deadline - time.monotonic()))
            if data is None:
                break
            self._write(COMMAND_IDLE, np.asarray(data["actual_q"], dtype=float))  # answer every state
            if data[self.layout.ready] == 1:
                self._last_target = np.asarray(data["actual_q"], dtype=float)
                return
        raise TimeoutError(
            f"RTDE: the servo program did not start within {self.connect_timeout_s:.1f} s "
            f"({self.layout.ready} stayed 0; is the robot in remote control?)"
        )

    def _write(self, command: int, q: FloatArray) -> None:
        assert self._client is not None and self._inputs is not None
        self._seq = (self._seq + 1) % 2**31
        self._client.send_inputs(self._inputs, [command, self._seq, *map(float, q)])

    def _receive(self, timeout_s: float) -> JointSample | None:
        assert self._client is not None
        data = self._client.receive_outputs(timeout_s)
        if data is None:
            return None
        fault = None if data[self.layout.ready] == 1 else "the servo program on the controller is not running"
        return JointSample(
            t=float(data["timestamp"]),
            q=np.asarray(data["actual_q"], dtype=float),
            qd=np.asarray(data["actual_qd"], dtype=float),
            fault=fault,
        )

    def _send_target(self, q: FloatArray, qd: FloatArray, active: bool) -> None:
        self._last_target = q
        self._write(COMMAND_SERVO if active else COMMAND_IDLE, q)

    def _send_halt(self) -> None:
        if self._client is not None and self._inputs is not None:
            self._write(COMMAND_STOP, self._last_target)

    def _close_transport(self) -> None:
        if self._client is not None:
            try:
                self._client.pause()
            except OSError:
                pass
            self._client.close()
            self._client = None
