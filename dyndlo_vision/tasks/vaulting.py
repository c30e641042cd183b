"""Task II, vaulting: throw the middle of a 90 cm cable, whose far end is fixed, over a box (implicit)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim import (
    BoxProp,
    CableParams,
    CameraPose,
    PhysicsOptions,
    Scene,
    SceneConfig,
    paper_cable,
)
from dyndlo_vision.tasks.base import EpisodeMonitor, Task
from dyndlo_vision.tasks.rewards import TABLE_V, RewardCoefficients, implicit_reward
from dyndlo_vision.trajectory import ActionSpec

OBSTACLE_SIZE_M = (0.04, 0.08, 0.14)  # section III-A: a 4 x 8 x 14 cm box (x thickness, y width, height)
OBSTACLE_CENTRE_M = (0.55, 0.0, 0.07)
TCP_HOME_M = (0.40, 0.0, 0.20)  # below M = 0.3 m (table V), so the cable must be thrown, not carried
#: The fixed end, beyond the box: 0.45 m past the box's mid-plane, half the paper's 90 cm cable, so that a
#: cable drawn taut over the box has its middle just beyond it (the paper gives no layout; this one is ours).
SUPPORT_M = (1.00, 0.0, 0.01)
FLOOR_Z_M = 0.01
#: The loop's camera: raised and tilted down (16 deg) at the box, so that it sees the cable on the floor from
#: the TCP's foot to the support and the TCP up to 1 m (the planar tasks' camera looks level from 0.575 m and
#: loses the floor in front of the box).
TRACKING_CAMERA = CameraPose.looking_at((0.70, -1.7, 0.90), (0.70, 0.0, 0.40))
#: The loop's second camera, high and to the right of the first. The cable leaves the motion plane (the middle
#: swings sideways as it is thrown), so the loop triangulates it from the two views. Two views cannot place a
#: stretch of cable that lies in an epipolar plane (through both cameras): with the baseline in the y-z plane
#: (a camera straight above) that is the cable hanging vertically from the lifted TCP, just where the middle
#: is then. A baseline up and along +x leaves vertical and x-running cable well posed: on randomised cables
#: the middle's error is a tenth of what it is from straight above (docs/results.md, "Decided questions").
SECOND_TRACKING_CAMERA = CameraPose.looking_at((1.3, -0.9, 1.8), (0.70, 0.0, 0.35))
#: The cable passes the box's side at least this far from its mid-plane (half its 8 cm width plus 2 cm).
MIN_SIDE_OFFSET_M = 0.06


def _path_through(offset_m: float) -> tuple[tuple[float, float, float], ...]:
    x_box, half = OBSTACLE_CENTRE_M[0], OBSTACLE_SIZE_M[0] / 2
    return (TCP_HOME_M, (TCP_HOME_M[0], 0.0, FLOOR_Z_M), (x_box - half, -offset_m, FLOOR_Z_M),
            (x_box + half, -offset_m, FLOOR_Z_M), SUPPORT_M)


def _path_length(path: tuple[tuple[float, float, float], ...]) -> float:
    return float(np.linalg.norm(np.diff(np.asarray(path), axis=0), axis=1).sum())


def initial_path(length_m: float) -> tuple[tuple[float, float, float], ...]:
    """The cable hangs from the TCP to the floor and runs along the floor *past the side* of the obstacle to
    the support beyond it: from the foot below the TCP out to the box's side, along it, and in to the support,
    as far off the box's mid-plane as it must be for the path to be ``length_m`` long (16.4 cm for the paper's
    90 cm), so a cable of any length starts laid out and attached at the support, going around the box, not
    over it.

    Raises:
        ValueError: A cable too short to pass the box's side on the way to the support.
    """
    shortest = shortest_cable_m()
    if length_m < shortest - 1e-12:
        raise ValueError(
            f"a {length_m:.3f} m cable is too short for the vaulting scene (it must pass the box's side on "
            f"the floor on its way to the support; at least {shortest:.3f} m)"
        )
    low, high = MIN_SIDE_OFFSET_M, MIN_SIDE_OFFSET_M + length_m  # the length grows with the offset
    for _ in range(100):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if _path_length(_path_through(mid)) < length_m else (low, mid)
    return _path_through(0.5 * (low + high))


def shortest_cable_m() -> float:
    """The shortest cable the scene can lay out around the box's side to the support (0.807 m)."""
    return _path_length(_path_through(MIN_SIDE_OFFSET_M))


def check_cable_lengths(low_factor: float, what: str, nominal_m: float = 0.9) -> None:
    """Raise ValueError, naming ``what``, if cables down to ``low_factor`` x ``nominal_m`` do not fit.

    For a run that draws many cables: it fails before the first episode, not at the first short cable.
    """
    if low_factor * nominal_m < shortest_cable_m() - 1e-12:
        raise ValueError(
            f"{what} draws vaulting cables down to {low_factor:g} x {nominal_m:g} m = "
            f"{low_factor * nominal_m:.3f} m, but the vaulting scene needs at least "
            f"{shortest_cable_m():.3f} m (the cable passes the box's side on its way to the support)"
        )


def crosses_over_obstacle(nodes: NDArray[np.float64], tolerance_m: float = 0.01) -> bool:
    """Whether the cable crosses the obstacle's mid-plane (x = its centre), and only over the box.

    Every crossing must lie above the box's top face: no lower than the top, less ``tolerance_m``, and within
    the box's width (``|y - y_box| <= half its width``). A cable that went over the box rests on it or on the
    floor beyond; one dragged along the floor past the box's side face crosses it at floor height, and one
    pulled up against the side face crosses it beside the box at the top's height: neither is a vault. A
    cable that never crosses has not gone over.
    """
    top = OBSTACLE_CENTRE_M[2] + OBSTACLE_SIZE_M[2] / 2
    points = crossings(nodes)
    return bool(points) and all(z >= top - tolerance_m and within_box_width(y) for y, z in points)


def within_box_width(y: float) -> bool:
    """Whether a crossing of the box's mid-plane at ``y`` lies over the box's 8 cm width, not beside it."""
    return abs(y - OBSTACLE_CENTRE_M[1]) <= OBSTACLE_SIZE_M[1] / 2


def crossings(nodes: NDArray[np.float64]) -> list[tuple[float, float]]:
    """(y, z) where the node polyline crosses the obstacle's mid-plane (x = its centre), in order."""
    x_mid = OBSTACLE_CENTRE_M[0]
    p = np.asarray(nodes, dtype=float)
    side = np.sign(p[:, 0] - x_mid)
    points = []
    for i in np.flatnonzero(side[:-1] * side[1:] <= 0):
        a, b = p[i], p[i + 1]
        w = 0.0 if b[0] == a[0] else (x_mid - a[0]) / (b[0] - a[0])
        points.append((float(a[1] + w * (b[1] - a[1])), float(a[2] + w * (b[2] - a[2]))))
    return points


#: ``distance_reward="shaped"``: a failed episode's r_distance is lambda_2 times this times (1 - progress).
SHAPED_DISTANCE_SCALE = 5.0


def vault_progress(nodes: NDArray[np.float64], middle: int) -> float:
    """How close a cable state came to a vault, in [0, 1): a slope where the task's reward is flat.

    Half of it is how far the middle node got towards the box's far face, from below the TCP's home (the
    cable as laid starts with its middle beside the box, so this half is nearly full from the start); half is
    how high the cable's lowest crossing of the box's mid-plane lies, as a fraction of the box's height (0
    where it never crosses, or crosses beside the box). The task's reward is -1 to -3 for almost every
    failure, which gives a search or a learner nothing to climb.
    """
    far_face = OBSTACLE_CENTRE_M[0] + OBSTACLE_SIZE_M[0] / 2
    top = OBSTACLE_CENTRE_M[2] + OBSTACLE_SIZE_M[2] / 2
    home = TCP_HOME_M[0]
    reach = float(np.clip((nodes[middle, 0] - home) / (far_face - home), 0.0, 1.0))
    heights = [z if within_box_width(y) else 0.0 for y, z in crossings(nodes)]
    over = float(np.clip(min(heights) / top, 0.0, 1.0)) if heights else 0.0
    return 0.5 * reach + 0.5 * over * 0.999


def middle_landed_beyond(middle: NDArray[np.float64]) -> bool:
    """Whether a point lies beyond the obstacle's far face and below its top (landed on the far side)."""
    beyond = middle[0] > OBSTACLE_CENTRE_M[0] + OBSTACLE_SIZE_M[0] / 2
    below_top = middle[2] < OBSTACLE_CENTRE_M[2] + OBSTACLE_SIZE_M[2] / 2
    return bool(beyond and below_top)


def beyond_cable_reach(tcp_positions: NDArray[np.float64], length_m: float) -> bool:
    """Whether any TCP position, (..., 3), lies farther from the support than a ``length_m`` cable reaches.

    The cable's held end is the TCP and its far end is fixed at the support, so no TCP position farther from
    the support than the cable is long can be reached without tearing the cable or its support. In the
    simulation the support is a soft equality constraint, and a kinematic TCP simply drags the cable's end off
    it (by up to 0.56 m in random single-step plans, 2.1 m in multi-step ones, where the chain then blows up).
    """
    d = np.linalg.norm(np.asarray(tcp_positions, dtype=float) - np.asarray(SUPPORT_M), axis=-1)
    return bool(np.any(d > length_m))


class Vaulting(Task):
    """Make the cable's middle land beyond the obstacle (P_DLO is the middle node; P* the obstacle).

    The cable starts on the floor, from below the TCP past the box's side to a support beyond the box.
    Success at the end of the episode (:meth:`landed_beyond`): the middle node has landed beyond the far face
    of the box (below the box's top: resting there, not held up in the air by the TCP), and the cable crosses
    the box's mid-plane only over the box (:func:`crosses_over_obstacle`; around its side, as it starts, is
    not a vault). The cable rests on the floor by design, so cable-floor contact is not an avoid condition
    here.

    One avoid condition of this task's own (not the paper's), ``avoid["torn"]``: the TCP went farther from the
    support than the cable is long (:func:`beyond_cable_reach`), which a real cable survives only by tearing.
    The episode ends at the next decision (multi-step) and never counts as a success.
    """

    kind = "implicit"
    settle_s = 1.0
    episode_s = 2.0
    check_collision = False

    def __init__(self, planar: bool = True, multi_step: bool = False, cable: CableParams | None = None,
                 physics: PhysicsOptions | None = None, distance_reward: str = "indicator") -> None:
        """``distance_reward``: ``"indicator"`` (table V: lambda_2 when the episode fails) or ``"shaped"``
        (not the paper's: lambda_2 x :data:`SHAPED_DISTANCE_SCALE` x (1 - :func:`vault_progress`) when it
        fails)."""
        super().__init__(planar=planar, multi_step=multi_step)
        if distance_reward not in ("indicator", "shaped"):
            raise ValueError(f"distance_reward={distance_reward!r}; expected 'indicator' or 'shaped'")
        self.distance_reward = distance_reward
        self.cable = cable or paper_cable(0.9)
        self.physics = physics or PhysicsOptions(integrator="discrete", timestep_s=0.001)

    def scene_config(self) -> SceneConfig:
        return SceneConfig(cable=self.cable, grippers_m=(TCP_HOME_M,), far_end="support", support_m=SUPPORT_M,
                           initial_path_m=initial_path(self.cable.length_m), settle_s=1.5,
                           physics=self.physics, tracking_camera=TRACKING_CAMERA,
                           second_tracking_camera=SECOND_TRACKING_CAMERA,
                           boxes=(BoxProp("obstacle", OBSTACLE_CENTRE_M, OBSTACLE_SIZE_M),))

    def action_spec(self) -> ActionSpec:
        return ActionSpec(num_points=3, planar=self.planar, dx_m=(-0.25, 0.25), dy_m=(-0.25, 0.25),
                          dz_m=(-0.2, 0.4), dt_s=(0.1, 0.5))

    def coefficients(self) -> RewardCoefficients:
        return TABLE_V["vaulting"]

    def p_dlo_node(self, scene: Scene) -> int:
        return scene.config.cable.num_segments // 2

    def sample_goal(self, rng: np.random.Generator) -> NDArray[np.float64]:
        return np.asarray(OBSTACLE_CENTRE_M, dtype=float)

    def on_samples(self, times: NDArray[np.float64], tcp_positions: NDArray[np.float64],
                   tcp_velocities: NDArray[np.float64], p_dlo: NDArray[np.float64],
                   min_goal_distances: NDArray[np.float64], monitor: EpisodeMonitor) -> None:
        torn = beyond_cable_reach(tcp_positions[:, 0], self.cable.length_m)
        monitor.avoid["torn"] = monitor.avoid.get("torn", False) or torn

    def is_done_early(self, scene: Scene, goal: NDArray[np.float64], monitor: EpisodeMonitor) -> bool:
        return bool(monitor.avoid.get("torn", False))

    def landed_beyond(self, scene: Scene) -> bool:
        """Whether the middle node has landed past the far face of the obstacle, the cable over it."""
        nodes = scene.cable_nodes()
        return middle_landed_beyond(nodes[self.p_dlo_node(scene)]) and crosses_over_obstacle(nodes)

    def evaluate(self, scene: Scene, goal: NDArray[np.float64], monitor: EpisodeMonitor,
                 final: bool) -> tuple[dict[str, float], bool, dict[str, Any]]:
        middle = scene.cable_nodes()[self.p_dlo_node(scene)]
        info = {"middle_x_m": float(middle[0])}
        if not final:
            return {"r_avoid": 0.0, "r_distance": 0.0, "r_success": 0.0, "r_dyn": 0.0}, False, info
        success = self.landed_beyond(scene) and not (monitor.diverged or monitor.avoid.get("torn", False))
        terms = implicit_reward(self.coefficients(), monitor.any_avoid, success, not success,
                                monitor.max_mean_height_m)
        if self.distance_reward == "shaped" and not success:
            progress = vault_progress(scene.cable_nodes(), self.p_dlo_node(scene))
            terms["r_distance"] = self.coefficients().distance * SHAPED_DISTANCE_SCALE * (1.0 - progress)
            info["vault_progress"] = progress
        return terms, success, info
