"""ABB Externally Guided Motion (EGM) driver: joint targets streamed over UDP to an ABB controller (the GoFa).

EGM is UDP with Google protobuf messages. The controller is the one that starts talking: once RAPID runs
``EGMRunJoint``, it sends an ``EgmRobot`` message (measured joints in degrees, its clock) every cycle, up to
250 Hz, to the sensor port configured on the controller (``UCdevice`` in sio.cfg, usually 6510), and takes the
``EgmSensor`` answer (``planned.joints`` in degrees, ``speedRef.joints`` in deg/s) as its next target. This
driver is that sensor: it binds the port, answers every message, and does IK and the joint-limit check itself
(joint mode, no Cartesian EGM), so nothing outside the limits is ever sent.

The protobuf messages and the UDP endpoint come from ``abb-robot-client`` (``abb_robot_client.egm``, the EGM
class and its compiled ``egm.proto``), imported when the driver connects (``pip install
dyndlo_vision[robot]``).

Controller side (RAPID, sketch): ``EGMGetId``, ``EGMSetupUC ROB_1, egm_id, "default", "UCdevice" \\Joint``,
``EGMActJoint egm_id \\J1:=... \\SampleRate:=4``,
``EGMRunJoint egm_id, EGM_STOP_HOLD \\J1 ... \\J6 \\CondTime:=...``.
The controller stops EGM by itself when this driver stops answering (``\\CommTimeout``).
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from dyndlo_vision.robots._streaming import FloatArray, JointSample, JointStreamingDriver
from dyndlo_vision.robots.kinematics import ArmKinematics, abb_gofa_crb15000

__all__ = ["EGM_DEFAULT_PORT", "EgmRobot", "load_egm_module"]

logger = logging.getLogger(__name__)

EGM_DEFAULT_PORT = 6510  # ABB's default UCdevice port
EGM_PERIOD_S = 0.004  # 250 Hz, the fastest EGM rate


def load_egm_module() -> Any:
    """``abb_robot_client.egm`` (EGM endpoint and protobuf messages), with an install hint when missing."""
    try:
        from abb_robot_client import egm
    except ImportError as exc:
        raise ModuleNotFoundError(
            "the EGM driver needs abb-robot-client: pip install 'dyndlo_vision[robot]'"
        ) from exc
    return egm


class EgmRobot(JointStreamingDriver):
    """ABB EGM joint-streaming driver implementing the ``Robot`` protocol for one TCP.

    Args:
        kinematics: Arm, base placement and tool orientation; the GoFa CRB 15000 at the world origin with the
            tool pointing down when None.
        port: UDP port to listen on, all interfaces (the controller's UCdevice remote port); 0 lets the OS
            choose (tests).
        period_s: The controller's EGM sample time (``\\SampleRate``), 4 ms = 250 Hz by default.
        **kwargs: Passed to :class:`JointStreamingDriver` (``answer_timeout_s``, ``connect_timeout_s``, ...).
    """

    protocol_name = "EGM"

    def __init__(
        self,
        kinematics: ArmKinematics | None = None,
        port: int = EGM_DEFAULT_PORT,
        period_s: float = EGM_PERIOD_S,
        **kwargs: Any,
    ) -> None:
        super().__init__(kinematics or ArmKinematics(abb_gofa_crb15000()), period_s, **kwargs)
        if not 0 <= port <= 65535:
            raise ValueError(f"port must be in 0..65535, got {port}")
        self._requested_port = int(port)
        self._egm: Any = None

    def bind(self) -> int:
        """Open the UDP port now (``connect`` does it otherwise) and return its number."""
        if self._egm is None:
            module = load_egm_module()
            self._egm = module.EGM(port=self._requested_port)  # binds ('', port); port 0: the OS chooses
        return int(self._egm.socket.getsockname()[1])

    @property
    def port(self) -> int:
        """The bound UDP port (binds it if needed)."""
        return self.bind()

    def _open(self) -> None:
        self.bind()

    def _receive(self, timeout_s: float) -> JointSample | None:
        deadline = time.monotonic() + timeout_s
        while True:
            # abb_robot_client also answers "nothing" at once when recvfrom fails (e.g. an ICMP error from a
            # closed controller port): keep listening until the timeout really is over.
            ok, state = self._egm.receive_from_robot(max(0.0, deadline - time.monotonic()))
            if ok:
                break
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.001)
        while True:  # answer the newest message only: older ones queued while we were busy are stale
            more, newer = self._egm.receive_from_robot(0.0)
            if not more:
                break
            state = newer
        return self._sample(state)

    def _sample(self, state: Any) -> JointSample:
        msg = state.robot_message
        if state.joint_angles is None or len(state.joint_angles) < 6:
            raise ValueError(f"EGM message without 6 measured joints: {state.joint_angles!r}")
        q = np.deg2rad(np.asarray(state.joint_angles[:6], dtype=float))
        if msg.feedBack.HasField("time"):
            t = msg.feedBack.time.sec + 1e-6 * msg.feedBack.time.usec
        else:
            t = 1e-3 * msg.header.tm
        fault = None
        if msg.HasField("motorState") and not state.motors_on:
            fault = "the controller reports motors off"
        elif msg.HasField("rapidExecState") and not state.rapid_running:
            fault = "the controller reports the RAPID program stopped"
        return JointSample(t=float(t), q=q, qd=None, fault=fault)

    def _send_target(self, q: FloatArray, qd: FloatArray, active: bool) -> None:
        # EGM must be answered every cycle, so before the first plan the answer is the position held.
        if not self._egm.send_to_robot(np.rad2deg(q), speed_ref=np.rad2deg(qd)):
            raise ConnectionError("EGM: could not send the joint target to the controller")

    def _close_transport(self) -> None:
        if self._egm is not None:
            self._egm.close()
            self._egm = None
