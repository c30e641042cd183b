"""Perception in the loop: the control loop, the Camera/Robot protocols and their implementations.

* protocols: :class:`Camera`, :class:`Robot` and the records they exchange;
* sources of frames (:mod:`~dyndlo_vision.control.cameras`) and of P_DLO (:mod:`~.state_sources`);
* the loop (:class:`ControlLoop`) and the simulated robot (:class:`SimRobot`);
* for hardware: arm kinematics and joint-limit checks (:mod:`~.kinematics`), safety clamps and a watchdog
  (:mod:`~.safety`), and drivers for ABB EGM and UR RTDE in :mod:`dyndlo_vision.control.robots`.
"""

from dyndlo_vision.control.cameras import (
    DelayedCamera,
    MujocoCamera,
    OpenCVDeviceCamera,
    RealSenseCamera,
    TruncatedVideoError,
    VideoFileCamera,
    average_frames,
)
from dyndlo_vision.control.clocks import ClockSync
from dyndlo_vision.control.kinematics import (
    TOOL_DOWN,
    ArmKinematics,
    ArmModel,
    IKError,
    JointLimitError,
    abb_gofa_crb15000,
    check_joint_limits,
    ur5e,
)
from dyndlo_vision.control.loop import ControlLoop, CycleRecord, LoopReport
from dyndlo_vision.control.noise_model import ObservationNoiseModel, packaged_noise_model_path
from dyndlo_vision.control.protocols import Camera, Frame, Robot, Setpoints, TcpState
from dyndlo_vision.control.safety import ClampedRobot, Watchdog, WorkspaceBox, clamp_setpoints
from dyndlo_vision.control.sim_robot import SimRobot
from dyndlo_vision.control.state_sources import NoisyState, PDloReading, TrackedState, TrueState
from dyndlo_vision.control.wrappers import CableRandomization, NoisyObservation

__all__ = [
    "TOOL_DOWN",
    "ArmKinematics",
    "ArmModel",
    "CableRandomization",
    "Camera",
    "ClampedRobot",
    "ClockSync",
    "ControlLoop",
    "CycleRecord",
    "Frame",
    "IKError",
    "JointLimitError",
    "LoopReport",
    "DelayedCamera",
    "MujocoCamera",
    "NoisyObservation",
    "NoisyState",
    "ObservationNoiseModel",
    "OpenCVDeviceCamera",
    "PDloReading",
    "RealSenseCamera",
    "Robot",
    "Setpoints",
    "SimRobot",
    "TcpState",
    "TrackedState",
    "TrueState",
    "TruncatedVideoError",
    "VideoFileCamera",
    "Watchdog",
    "WorkspaceBox",
    "abb_gofa_crb15000",
    "average_frames",
    "check_joint_limits",
    "clamp_setpoints",
    "packaged_noise_model_path",
    "ur5e",
]
