"""MuJoCo simulation: the cable, the grippers (TCPs), task props and solver settings. No Gymnasium here."""

from dyndlo_vision.sim.cable import CableParams, paper_cable
from dyndlo_vision.sim.physics import PhysicsOptions
from dyndlo_vision.sim.scene import (
    BoxProp,
    CameraPose,
    CapsuleProp,
    GripperGains,
    Scene,
    SceneConfig,
    build_mjcf,
)

__all__ = [
    "BoxProp",
    "CableParams",
    "CameraPose",
    "CapsuleProp",
    "GripperGains",
    "PhysicsOptions",
    "Scene",
    "SceneConfig",
    "build_mjcf",
    "paper_cable",
]
