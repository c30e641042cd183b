"""Perception in the loop: the 25 Hz re-planning loop, where its P_DLO comes from, and its simulation
adapters.

* :mod:`~.loop`: :class:`ControlLoop`, which reads a state source, asks the policy, re-plans the B-spline from
  the TCP's current state and sends setpoints to a :class:`~dyndlo_vision.robots.Robot`;
* :mod:`~.state_sources`: P_DLO from the simulator's truth, through the fitted noise model, or tracked from
  a :class:`~dyndlo_vision.cameras.Camera`;
* :mod:`~.clocks`: mapping a live camera's clock onto the robot's;
* the simulation adapters: :class:`SimRobot` (the task's TCP behind the Robot protocol) and
  :mod:`~.sim_perception` (the tracker set up on the task's camera).

Cameras and robots live in :mod:`dyndlo_vision.cameras` and :mod:`dyndlo_vision.robots`.
"""

from dyndlo_vision.control.clocks import ClockSync
from dyndlo_vision.control.loop import ControlLoop, CycleRecord, LoopReport
from dyndlo_vision.control.sim_robot import SimRobot
from dyndlo_vision.control.state_sources import NoisyState, PDloReading, TrackedState, TrueState

__all__ = [
    "ClockSync",
    "ControlLoop",
    "CycleRecord",
    "LoopReport",
    "NoisyState",
    "PDloReading",
    "SimRobot",
    "TrackedState",
    "TrueState",
]
