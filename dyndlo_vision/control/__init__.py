"""Perception in the loop: the control loop, the Camera/Robot protocols and their implementations."""

from dyndlo_vision.control.protocols import Camera, Frame, Robot, Setpoints, TcpState

__all__ = ["Camera", "Frame", "Robot", "Setpoints", "TcpState"]
