"""Task I, tip control: whip a 50 cm cable so that its tip hits a 5 cm spherical target (implicit task)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim import CableParams, PhysicsOptions, Scene, SceneConfig
from dyndlo_vision.tasks.base import EpisodeMonitor, Task
from dyndlo_vision.tasks.rewards import GOAL_TOLERANCE_M, TABLE_V, RewardCoefficients, implicit_reward
from dyndlo_vision.trajectory import ActionSpec

TARGET_DIAMETER_M = 0.05  # section III-A, task I
TARGET_RANGE_M = 0.20  # section V-A: target randomised in a 20 cm range
TCP_HOME_M = (0.45, 0.0, 0.60)
# Centre of the target range: in front of and below the TCP, 0.35-0.55 m away from it, out of reach of the
# hanging cable without a dynamic motion.
TARGET_CENTRE_M = (0.80, 0.0, 0.40)


class TipControl(Task):
    """Hit the target with the free tip (P_DLO is the tip).

    Success: at some instant the tip is within eps_goal (1 cm) of the target's surface, i.e. its distance
    to the target centre is below D_target/2 + eps_goal. Checked every 2 ms on the segment the tip swept,
    so a fast tip cannot jump over the target between samples. The multi-step episode ends at the hit.
    """

    kind = "implicit"
    settle_s = 0.5
    episode_s = 1.6
    swept_goal_check = True

    def __init__(self, planar: bool = True, multi_step: bool = False, cable: CableParams | None = None,
                 physics: PhysicsOptions | None = None, distance_reward: str = "indicator") -> None:
        super().__init__(planar=planar, multi_step=multi_step)
        if distance_reward not in ("indicator", "linear"):
            raise ValueError(f"distance_reward={distance_reward!r}; expected 'indicator' or 'linear'")
        self.cable = cable or CableParams()
        self.physics = physics or PhysicsOptions()
        self.distance_reward = distance_reward
        self.success_radius_m = TARGET_DIAMETER_M / 2 + GOAL_TOLERANCE_M

    def scene_config(self) -> SceneConfig:
        return SceneConfig(cable=self.cable, grippers_m=(TCP_HOME_M,), target_radius_m=TARGET_DIAMETER_M / 2,
                           physics=self.physics, settle_s=1.0)

    def action_spec(self) -> ActionSpec:
        return ActionSpec(num_points=3, planar=self.planar, dx_m=(-0.25, 0.25), dy_m=(-0.25, 0.25),
                          dz_m=(-0.25, 0.25), dt_s=(0.1, 0.5))

    def coefficients(self) -> RewardCoefficients:
        return TABLE_V["tip_control_multi_step" if self.multi_step else "tip_control"]

    def p_dlo_node(self, scene: Scene) -> int:
        return scene.config.cable.num_nodes - 1

    def sample_goal(self, rng: np.random.Generator) -> NDArray[np.float64]:
        offset = rng.uniform(-TARGET_RANGE_M / 2, TARGET_RANGE_M / 2, size=3)
        if self.planar:
            offset[1] = 0.0
        return np.asarray(TARGET_CENTRE_M) + offset

    def is_done_early(self, scene: Scene, goal: NDArray[np.float64], monitor: EpisodeMonitor) -> bool:
        return monitor.min_goal_distance_m < self.success_radius_m

    def evaluate(self, scene: Scene, goal: NDArray[np.float64], monitor: EpisodeMonitor,
                 final: bool) -> tuple[dict[str, float], bool, dict[str, Any]]:
        hit = monitor.min_goal_distance_m < self.success_radius_m and not monitor.diverged
        info = {"min_distance_m": monitor.min_goal_distance_m, "max_tcp_speed_m_s": monitor.max_tcp_speed_m_s}
        if not final:
            return {"r_avoid": 0.0, "r_distance": 0.0, "r_success": 0.0, "r_dyn": 0.0}, False, info
        terms = implicit_reward(self.coefficients(), monitor.any_avoid, hit, not hit,
                                monitor.max_mean_height_m)
        if self.distance_reward == "linear":
            # Shaped variant (not the paper's): lambda_2 per 10 cm of closest approach beyond the target.
            gap = max(0.0, monitor.min_goal_distance_m - self.success_radius_m)
            terms["r_distance"] = self.coefficients().distance * gap / 0.1
        return terms, hit, info
