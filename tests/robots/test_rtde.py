"""Tests for the UR RTDE driver and client against the fake UR controller on loopback (RTDE v2 over TCP)."""

from __future__ import annotations

import logging
import socket
import struct
import subprocess
import sys
import textwrap
from collections.abc import Iterator

import numpy as np
import pytest

from dyndlo_vision.robots import FakeRtdeController, RtdeRobot
from dyndlo_vision.robots.kinematics import ArmKinematics, JointLimitError, check_joint_limits, ur5e
from dyndlo_vision.robots.protocol import Robot
from dyndlo_vision.robots.rtde import (
    COMMAND_SERVO,
    DATA_PACKAGE,
    PackageStream,
    RegisterLayout,
    RtdeClient,
    pack_values,
    servo_script,
    unpack_values,
)
from dyndlo_vision.tasks.tip_control import TCP_HOME_M

from .robot_plans import GENTLE_ACTION, TIMEOUT_S, VIOLENT_ACTION, send_from_now, tip_control_setpoints


@pytest.fixture
def setup() -> Iterator[tuple[RtdeRobot, FakeRtdeController, ArmKinematics, np.ndarray]]:
    kin = ArmKinematics(ur5e())
    q_home = kin.ik(TCP_HOME_M).q
    fake = FakeRtdeController(kin.arm, q_home, reply_timeout_s=2.0).start()
    robot = RtdeRobot(
        "127.0.0.1", kin, rtde_port=fake.rtde_port, script_port=fake.script_port, answer_timeout_s=5.0,
        connect_timeout_s=TIMEOUT_S,
    )  # fmt: skip
    robot.connect()
    yield robot, fake, kin, q_home
    robot.close()
    fake.close()
    assert fake.error is None


def test_connect_uploads_the_servo_program(setup) -> None:
    robot, fake, _, _ = setup
    assert isinstance(robot, Robot)
    assert fake.program_running and len(fake.scripts) == 1
    script = fake.scripts[0]
    assert script == robot.script
    assert "servoj([read_input_float_register(24)" in script and "stopj(" in script
    assert RegisterLayout.from_script(script) == robot.layout
    np.testing.assert_allclose(robot.state().position[0], TCP_HOME_M, atol=1e-9)


def test_moves_the_fake_robot_along_a_tip_control_plan(setup) -> None:
    robot, fake, kin, _ = setup
    setpoints, end = send_from_now(robot, fake, GENTLE_ACTION)
    assert fake.wait_until(setpoints.t[-1] + 0.3, TIMEOUT_S)
    np.testing.assert_allclose(fake.q, kin.ik(end, fake.q).q, atol=1e-4)
    np.testing.assert_allclose(kin.fk(fake.q)[0], end, atol=1e-4)
    np.testing.assert_allclose(robot.state().position[0], end, atol=1e-4)
    received = fake.received
    t, q = np.array([r.t for r in received]), np.array([r.q for r in received])
    assert t.size > 0.9 * (setpoints.t[-1] - setpoints.t[0]) * robot.frequency_hz
    assert check_joint_limits(kin.arm, t, q).ok


def test_refuses_a_plan_that_breaks_a_joint_limit(setup, caplog: pytest.LogCaptureFixture) -> None:
    robot, fake, _, q_home = setup
    with (
        caplog.at_level(logging.ERROR),
        pytest.raises(JointLimitError, match=r"joint \w+ \w+ [+-][\d.]+") as err,
    ):
        send_from_now(robot, fake, VIOLENT_ACTION)
    assert any(v.quantity == "acceleration" for v in err.value.report.violations)
    assert "RTDE: refusing setpoints, nothing of them sent" in caplog.text
    assert robot.wait_cycles(50, TIMEOUT_S)
    assert fake.received == []  # not a single servo target reached the controller
    np.testing.assert_allclose(fake.q, q_home, atol=1e-12)
    assert robot.fault is None


def test_close_ends_the_servo_program(setup) -> None:
    robot, fake, _, _ = setup
    robot.close()
    assert fake.wait_for(lambda: not fake.program_running, TIMEOUT_S)
    assert fake.stop_commands == 1


def test_watchdog_stops_when_the_robot_stops_answering(caplog: pytest.LogCaptureFixture) -> None:
    kin = ArmKinematics(ur5e())
    with FakeRtdeController(kin.arm, kin.ik(TCP_HOME_M).q, reply_timeout_s=2.0) as fake:
        robot = RtdeRobot(
            "127.0.0.1", kin, rtde_port=fake.rtde_port, script_port=fake.script_port, answer_timeout_s=0.3,
            connect_timeout_s=TIMEOUT_S,
        )  # fmt: skip
        robot.connect()
        with caplog.at_level(logging.ERROR):
            fake.hang()
            assert not robot.wait_cycles(100_000, TIMEOUT_S)
        assert (
            "RTDE: watchdog: the robot stopped answering (no state for 0.300 s); streaming stopped"
            in caplog.text
        )
        with pytest.raises(RuntimeError, match="stopped after a fault"):
            robot.send(tip_control_setpoints(GENTLE_ACTION, robot.state().t + 0.1)[0])
        robot.close()


def test_an_exception_in_the_streaming_thread_halts_the_robot(
    setup, caplog: pytest.LogCaptureFixture
) -> None:
    robot, fake, _, _ = setup
    with caplog.at_level(logging.ERROR):
        fake.send_garbage()
        assert not robot.wait_cycles(100_000, TIMEOUT_S)
    assert robot.fault is not None and "data package for recipe 7" in robot.fault
    assert "RTDE: exception in the streaming thread" in caplog.text
    assert fake.wait_for(lambda: not fake.program_running, TIMEOUT_S)
    assert fake.stop_commands == 1  # the halt command reached the robot


def test_servo_program_stops_the_robot_when_targets_stop_coming() -> None:
    """The robot-side keep-alive: a PC that dies mid-motion does not leave the robot servoing."""
    arm = ur5e()
    layout = RegisterLayout(offset=0, keepalive_cycles=10)
    # Lockstep: a cycle waits up to 0.1 s for the client, so only a client that really stopped misses cycles.
    with FakeRtdeController(arm, arm.seed_rad, realtime=False, reply_timeout_s=0.1) as fake:
        client = RtdeClient("127.0.0.1", fake.rtde_port, timeout_s=TIMEOUT_S)
        client.connect()
        client.setup_outputs(["timestamp", "actual_q", layout.ready], 500.0)
        inputs = client.setup_inputs([layout.command, layout.keepalive, *layout.targets])
        client.start()
        with socket.create_connection(("127.0.0.1", fake.script_port)) as s:
            s.sendall(servo_script(layout, 0.002).encode())
        for seq in range(1, 200):
            data = client.receive_outputs(TIMEOUT_S)
            assert data is not None
            if data[layout.ready] == 1:
                break
            client.send_inputs(inputs, [0, seq, *arm.seed_rad])
        assert data[layout.ready] == 1
        for seq in range(200, 210):  # servo for a few cycles ...
            client.send_inputs(inputs, [COMMAND_SERVO, seq, *arm.seed_rad])
            client.receive_outputs(TIMEOUT_S)
        assert fake.program_running
        t_silent = fake.t
        # ... then go silent: the program ends on its own after 10 cycles without a new keep-alive value.
        assert fake.wait_until(t_silent + 0.05, TIMEOUT_S)
        assert not fake.program_running and fake.stop_commands == 0
        client.close()


def test_values_round_trip_and_bad_packages_raise() -> None:
    types = ["DOUBLE", "VECTOR6D", "INT32", "UINT32", "BOOL", "VECTOR3D"]
    values = [1.5, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], -7, 8, True, [0.1, 0.2, 0.3]]
    assert unpack_values(types, pack_values(types, values)) == values
    with pytest.raises(ValueError, match="too short"):
        unpack_values(types, pack_values(types, values)[:-1])
    with pytest.raises(ValueError, match="bytes more"):
        unpack_values(types[:2], pack_values(types, values))


def test_package_stream_reassembles_split_packages() -> None:
    a, b = socket.socketpair()
    with a, b:
        body = bytes([1]) + pack_values(["DOUBLE"], [2.5])
        wire = struct.pack(">HB", len(body) + 3, DATA_PACKAGE) + body
        stream = PackageStream(b)
        a.sendall(wire[:2])
        assert stream.receive(0.01) is None  # incomplete header
        a.sendall(wire[2:7])
        assert stream.receive(0.01) is None  # incomplete payload
        a.sendall(wire[7:] + wire)  # rest of the first package and all of a second one
        assert stream.receive(1.0) == (DATA_PACKAGE, body)
        assert stream.receive(1.0) == (DATA_PACKAGE, body)
        a.sendall(struct.pack(">HB", 2, DATA_PACKAGE))
        with pytest.raises(ValueError, match="announces 2 bytes"):
            stream.receive(1.0)
        a.close()
        with pytest.raises(ConnectionError):
            PackageStream(b).receive(1.0)


def test_register_layout_validation() -> None:
    with pytest.raises(ValueError, match="register offset"):
        RegisterLayout(offset=45)
    assert RegisterLayout.from_script("def other():\n  sync()\nend\n") is None


_UR_RTDE_SERVER = textwrap.dedent(
    """
    import sys
    from dyndlo_vision.robots.kinematics import ur5e
    from dyndlo_vision.robots import FakeRtdeController
    arm = ur5e()
    try:
        fake = FakeRtdeController(arm, arm.seed_rad, rtde_port=30004, reply_timeout_s=0.0).start()
    except OSError:
        print("busy", flush=True)
        sys.exit(0)
    print("ready", flush=True)
    sys.stdin.read()
    fake.close()
    """
)


def test_ur_rtde_reads_the_fake_controller() -> None:
    """Cross-check with an independent RTDE client: ur-rtde's receive interface (fixed port 30004)."""
    rtde_receive = pytest.importorskip("rtde_receive")
    # ur-rtde blocks with the GIL held while it connects, so the fake runs in its own process.
    server = subprocess.Popen(
        [sys.executable, "-c", _UR_RTDE_SERVER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        status = server.stdout.readline().strip() if server.stdout else ""
        if status != "ready":
            pytest.skip(f"port 30004 unavailable for the fake controller ({status or 'no answer'})")
        receiver = rtde_receive.RTDEReceiveInterface(
            "127.0.0.1", 500.0, ["timestamp", "actual_q", "actual_qd"]
        )
        try:
            np.testing.assert_allclose(receiver.getActualQ(), ur5e().seed_rad, atol=1e-12)
            assert receiver.getTimestamp() > 0.0
        finally:
            receiver.disconnect()
    finally:
        if server.stdin:
            server.stdin.close()
        server.wait(timeout=TIMEOUT_S)
