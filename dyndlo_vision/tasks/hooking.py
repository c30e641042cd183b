"""Task III, hooking: two grippers swing a 50 cm cable onto a static hook (implicit, dual arm)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim import CableParams, CapsuleProp, PhysicsOptions, Scene, SceneConfig
from dyndlo_vision.tasks.base import EpisodeMonitor, Task
from dyndlo_vision.tasks.rewards import TABLE_V, RewardCoefficients, implicit_reward
from dyndlo_vision.trajectory import ActionSpec

GRIPPERS_M = ((0.40, -0.12, 0.25), (0.40, 0.12, 0.25))  # below M = 0.3 m (table V)
HOOK_RADIUS_M = 0.008
HOOK_POST = ((0.72, 0.0, 0.0), (0.72, 0.0, 0.20))
HOOK_PRONG = ((0.72, 0.0, 0.20), (0.60, 0.0, 0.23))  # points at the robot, tip slightly raised
HOOK_POINT_M = (0.63, 0.0, 0.225)  # P*: on the prong, near its tip


def _u_path(sag_length_m: float) -> tuple[tuple[float, float, float], ...]:
    """A U between the two grippers, made of straight pieces, of total length ``sag_length_m``."""
    (x, y0, z), (_, y1, _) = GRIPPERS_M
    drop = (sag_length_m - (y1 - y0)) / 2
    return ((x, y0, z), (x, y0, z - drop), (x, y1, z - drop), (x, y1, z))


def _segment_distance(p: NDArray[np.float64], a: tuple, b: tuple) -> float:
    a_, b_ = np.asarray(a), np.asarray(b)
    ab = b_ - a_
    s = float(np.clip((p - a_) @ ab / (ab @ ab), 0.0, 1.0))
    return float(np.linalg.norm(a_ + s * ab - p))


class Hooking(Task):
    """Leave the cable hanging on the hook's prong (P_DLO is the middle node, P* a point on the prong).

    Success at the end of the episode: some node of the cable's middle third rests on the prong (within
    cable radius + prong radius + 1 cm of its axis) and lies above the prong's axis, so the prong carries it.
    The grippers move symmetrically: the same x-z motion, mirrored lateral (y) motion.
    """

    kind = "implicit"
    settle_s = 1.0
    episode_s = 2.0

    def __init__(self, planar: bool = True, multi_step: bool = False, cable: CableParams | None = None,
                 physics: PhysicsOptions | None = None) -> None:
        super().__init__(planar=planar, multi_step=multi_step)
        self.cable = cable or CableParams()
        self.physics = physics or PhysicsOptions(integrator="discrete", timestep_s=0.001)

    def scene_config(self) -> SceneConfig:
        return SceneConfig(cable=self.cable, grippers_m=GRIPPERS_M, far_end="gripper",
                           initial_path_m=_u_path(self.cable.length_m), settle_s=1.5, physics=self.physics,
                           capsules=(CapsuleProp("hook_post", *HOOK_POST, HOOK_RADIUS_M),
                                     CapsuleProp("hook_prong", *HOOK_PRONG, HOOK_RADIUS_M)))

    def action_spec(self) -> ActionSpec:
        return ActionSpec(num_points=3, planar=self.planar, dx_m=(-0.2, 0.3), dy_m=(-0.05, 0.05),
                          dz_m=(-0.2, 0.4), dt_s=(0.1, 0.5))

    def coefficients(self) -> RewardCoefficients:
        return TABLE_V["hooking"]

    def p_dlo_node(self, scene: Scene) -> int:
        return scene.config.cable.num_segments // 2

    def sample_goal(self, rng: np.random.Generator) -> NDArray[np.float64]:
        return np.asarray(HOOK_POINT_M, dtype=float)

    def hooked(self, scene: Scene) -> bool:
        """Whether the prong carries the middle third of the cable."""
        nodes = scene.cable_nodes()
        n = len(nodes)
        reach = HOOK_RADIUS_M + self.cable.radius_m + 0.01
        for p in nodes[n // 3 : 2 * n // 3 + 1]:
            if _segment_distance(p, *HOOK_PRONG) < reach:
                (ax, _, az), (bx, _, bz) = HOOK_PRONG
                s = np.clip((p[0] - ax) / (bx - ax), 0.0, 1.0)
                if p[2] > az + s * (bz - az):
                    return True
        return False

    def evaluate(self, scene: Scene, goal: NDArray[np.float64], monitor: EpisodeMonitor,
                 final: bool) -> tuple[dict[str, float], bool, dict[str, Any]]:
        info = {"min_distance_m": monitor.min_goal_distance_m}
        if not final:
            return {"r_avoid": 0.0, "r_distance": 0.0, "r_success": 0.0, "r_dyn": 0.0}, False, info
        success = self.hooked(scene) and not monitor.diverged
        terms = implicit_reward(self.coefficients(), monitor.any_avoid, success, not success,
                                monitor.max_mean_height_m)
        return terms, success, info
