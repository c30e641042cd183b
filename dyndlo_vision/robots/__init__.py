"""Robots behind the :class:`Robot` protocol, and what keeps a real arm safe.

* :mod:`~.protocol`: :class:`Robot` and the records it exchanges (:class:`TcpState`, :class:`Setpoints`);
* :mod:`~.kinematics`: DH arm models (ABB GoFa CRB 15000, UR5e), seeded IK along a Cartesian plan and
  joint-limit checks;
* :mod:`~.safety`: workspace and TCP speed clamps (:class:`ClampedRobot`) and a :class:`Watchdog`;
* drivers that stream joint targets: ABB EGM (:class:`EgmRobot`) and UR RTDE (:class:`RtdeRobot`), and fake
  controllers that speak the same protocols on loopback for dry runs and tests.

The drivers' optional dependency (``abb-robot-client`` for EGM) is imported when a driver connects, so this
package imports without it: ``pip install 'dyndlo_vision[robot]'`` for hardware.
"""

from dyndlo_vision.robots._streaming import JointSample, JointStreamingDriver
from dyndlo_vision.robots.egm import EgmRobot
from dyndlo_vision.robots.fake_servers import FakeEgmController, FakeRtdeController, ReceivedTarget
from dyndlo_vision.robots.kinematics import (
    TOOL_DOWN,
    ArmKinematics,
    ArmModel,
    IKError,
    JointLimitError,
    abb_gofa_crb15000,
    check_joint_limits,
    ur5e,
)
from dyndlo_vision.robots.protocol import Robot, Setpoints, TcpState
from dyndlo_vision.robots.rtde import RtdeRobot
from dyndlo_vision.robots.safety import ClampedRobot, Watchdog, WorkspaceBox, clamp_setpoints

__all__ = [
    "TOOL_DOWN",
    "ArmKinematics",
    "ArmModel",
    "ClampedRobot",
    "EgmRobot",
    "FakeEgmController",
    "FakeRtdeController",
    "IKError",
    "JointLimitError",
    "JointSample",
    "JointStreamingDriver",
    "ReceivedTarget",
    "Robot",
    "RtdeRobot",
    "Setpoints",
    "TcpState",
    "Watchdog",
    "WorkspaceBox",
    "abb_gofa_crb15000",
    "check_joint_limits",
    "clamp_setpoints",
    "ur5e",
]
