"""Cartesian TCP trajectories and the agent-action parametrisation (DynDLO paper, Sec. III-C)."""

from dyndlo_vision.trajectory.actions import ActionSpec
from dyndlo_vision.trajectory.bspline import BSplineTrajectory
from dyndlo_vision.trajectory.replanner import Replanner

__all__ = ["ActionSpec", "BSplineTrajectory", "Replanner"]
