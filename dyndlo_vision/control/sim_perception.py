"""Camera-based state estimation in simulation: the perception pipeline set up on the MuJoCo cameras of a
DynDLO scene.

What a real set-up knows and uses, reproduced here: the camera calibration, the plane the planar trajectories
move in, the cable's length, the robot's own pose (the gripper is masked out of the segmentation by its
projected position, and the projected TCP marks the held end of the cable), and for the classical segmenter an
image of the scene without the cable. :func:`loop_pipeline_config` says what the loop's
:class:`~dyndlo_vision.tracking.pipeline.CablePipeline` does; ``run`` builds the same for a real camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.cameras.simulated import DelayedCamera, MujocoCamera, checked_latency_s
from dyndlo_vision.control.sim_env import as_sim_env
from dyndlo_vision.control.state_sources import TrackedState
from dyndlo_vision.sim.cable_look import CableLook
from dyndlo_vision.sim.scene import SECOND_TRACKING_CAMERA_NAME
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
from dyndlo_vision.tracking.params import LATENT_LOOP_FILTER, LOOP_FILTER, FilterParams
from dyndlo_vision.tracking.pipeline import CablePipeline, PipelineConfig
from dyndlo_vision.tracking.segmenters import SegmenterConfig, build_segmenter, build_view_segmenter
from dyndlo_vision.tracking.tracker import Plane

#: The planar tasks move in the x-z plane through the origin.
MOTION_PLANE = Plane(np.array([0.0, 1.0, 0.0]), 0.0)
GRIPPER_MASK_RADIUS_M = 0.03  # the 2 cm gripper sphere plus a margin
#: The learned segmenter looks within the cable's length plus this of the gripper (tracking.masks.
#: CableReachSegmenter): the chain is inextensible and its first node is the TCP (measured: the farthest node
#: is the cable's length away, to 1e-15 m, under the policy and random actions), so this covers the cable's
#: drawn thickness and the gripper sphere.
CABLE_REACH_MARGIN_M = 0.03
#: The loop's learned segmenter sees the frame enlarged this many times (a 640x480 frame as 960x720), its
#: logits resized back, at the network's own threshold (logit 0). At the frame's own size the loop camera's
#: 1.6 px red cable is faint to a network where it crosses the grey floor: the mask is cut there and the
#: tracked cable ends early. At 1.5x it is 2.4 px wide. Chosen for ``cable-segmenter-loop`` on seeds
#: 200000-200019 among 1, 1.25, 1.5 and 2; on 100 fresh seeds its median estimate RMSE per episode fell from
#: 8.8 mm (1x) to 1.95 mm. On the cable's whole reach the learned tracker's time doubled (about 5.5 to 11 ms);
#: following the cable (LOOP_FOLLOW_PX) and resizing only its part bring it back to about 5 ms. The other
#: shipped networks gain as much in the loop.
LOOP_NETWORK_SCALE = 1.5
#: The loop's learned segmenter computes the box around the last frame's mask grown by this many pixels
#: (``CableReachSegmenter(follow_px=...)``), not the whole image of the cable's reach: about a fifth of it.
#: Chosen on seeds 200000-200019 between 48 and 80: at 80 the estimates match the whole reach's (median
#: 1.71 against 1.72 mm, p90 2.08 against 2.15 mm), at 48 the p90 rose to 3.3 mm.
LOOP_FOLLOW_PX = 80
#: Segmenters the loop can use: the shipped full-resolution CNN ``cable-segmenter-loop`` (no background
#: image needed, as with a real camera), or the classical background segmenter against the scene rendered
#: without the cable (a clean plate only a simulator or a fixed real camera has).
LOOP_SEGMENTERS = ("background", "learned")
#: The loop's segmenter when none is named, by the number of loop cameras the scene has
#: (:func:`scene_views`). One camera (tip control): the learned network, as ``run`` uses with a real camera:
#: 98 of 100 hits on fresh seeds, as with the classical one, at an estimate RMSE of 1.9 against 1.3 mm and
#: a controller p95 of 17 against 15 ms. Two cameras (vaulting): the classical one; there the
#: learned network loses the cable lying on the light floor beyond the obstacle (estimates 71-148 mm) and two
#: renders plus two networks overrun the 40 ms cycle.
DEFAULT_LOOP_SEGMENTER = {1: "learned", 2: "background"}
#: Longest simulated camera latency (s): beyond a quarter second the loop re-plans on a past the cable has
#: long left.
MAX_LATENCY_S = 0.25




@dataclass(frozen=True)
class LoopPerception:
    """How the simulated loop sees the cable, checked when made (ValueError naming the bad value).

    Attributes:
        segmenter: The segmenter (None: the scene's default, :func:`default_segmenter`).
        views: The cameras tracked, 1 or 2 (None: as many as the scene has, :func:`scene_views`).
        latency_s: The camera's delay (s), at most :data:`MAX_LATENCY_S`: each frame reaches the tracker that
            long after it was rendered, and the filter predicts across it.
        filter: The tip's filter (None: :data:`~dyndlo_vision.tracking.params.LOOP_FILTER`, or
            :data:`~dyndlo_vision.tracking.params.LATENT_LOOP_FILTER` behind a latency).
    """

    segmenter: SegmenterConfig | None = None
    views: int | None = None
    latency_s: float = 0.0
    filter: FilterParams | None = None

    def __post_init__(self) -> None:
        if self.segmenter is not None and not isinstance(self.segmenter, SegmenterConfig):
            raise ValueError(f"segmenter must be a SegmenterConfig (or None), got {self.segmenter!r}")
        if self.segmenter is not None and self.segmenter.kind not in LOOP_SEGMENTERS:
            raise ValueError(
                f"the loop's segmenter {self.segmenter.kind!r}; expected one of {list(LOOP_SEGMENTERS)}"
            )
        if self.views not in (None, 1, 2):
            raise ValueError(f"views={self.views!r}; expected 1 or 2 (or None)")
        if checked_latency_s(self.latency_s) > MAX_LATENCY_S:
            raise ValueError(f"latency_s must be at most {MAX_LATENCY_S} s, got {self.latency_s!r}")
        if self.filter is not None and not isinstance(self.filter, FilterParams):
            raise ValueError(f"filter must be a FilterParams (or None), got {self.filter!r}")


def loop_segmenter(kind: str, model: str | None = None, scale: float | None = None) -> SegmenterConfig:
    """The loop's segmenter of ``kind`` (one of :data:`LOOP_SEGMENTERS`): the learned one defaults to the
    loop's own network, ``cable-segmenter-loop``, seeing each frame enlarged :data:`LOOP_NETWORK_SCALE` times;
    the classical one to the scene rendered without the cable as its background."""
    from dyndlo_vision.tracking.networks import LOOP_NAME

    if kind not in LOOP_SEGMENTERS:
        raise ValueError(f"segmenter={kind!r}; expected one of {list(LOOP_SEGMENTERS)}")
    if kind == "learned":
        return SegmenterConfig(
            "learned", model=model or LOOP_NAME, scale=LOOP_NETWORK_SCALE if scale is None else scale
        )
    return SegmenterConfig("background", model=model, scale=scale)


def render_without_cable(camera: MujocoCamera) -> NDArray[np.uint8]:
    """The camera's view with the cable and the grippers made transparent (the segmentation's background).

    The grippers are hidden too: they move, and a gripper drawn at its start position would leave a "ghost"
    blob there once it has moved (the live gripper is masked by its projected position instead).
    """
    model = camera.model
    cable = CableLook.of(model)
    geoms = [g for g in range(model.ngeom) if model.geom(g).name.startswith("tcp_")]
    sites = [k for k in range(model.nsite) if model.site(k).name.startswith("tcp_")]
    saved = (cable.alphas(model), model.geom_rgba[geoms, 3].copy(), model.site_rgba[sites, 3].copy())
    cable.set_alphas(model, 0.0)
    model.geom_rgba[geoms, 3] = 0.0
    model.site_rgba[sites, 3] = 0.0
    try:
        return camera.read().rgb
    finally:
        cable.set_alphas(model, saved[0])
        model.geom_rgba[geoms, 3], model.site_rgba[sites, 3] = saved[1], saved[2]


def default_segmenter(env: Any) -> str:
    """The loop's segmenter for ``env``'s scene when none is named (:data:`DEFAULT_LOOP_SEGMENTER`)."""
    return DEFAULT_LOOP_SEGMENTER[scene_views(env)]


def scene_views(env: Any) -> int:
    """The loop cameras ``env``'s scene has: 2 with a second tracking camera (vaulting), else 1."""
    model = as_sim_env(env).model
    return 2 if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, SECOND_TRACKING_CAMERA_NAME) >= 0 else 1


def loop_pipeline_config(
    scene: Any,
    point: float,
    segmenter: SegmenterConfig,
    filter_params: FilterParams,
) -> PipelineConfig:
    """What the loop's pipeline does in ``scene`` (a :class:`~dyndlo_vision.sim.Scene`): the cable's length
    and nodes, the motion plane and the floor (raised by the cable's radius: where the cable lies on it, off
    the motion plane, a lift onto the plane would put it under the floor), the gripper masked around the TCP,
    the learned segmenter looking only within the cable's reach, and no shape test (the gripper is masked)."""
    cable = scene.config.cable
    learned = segmenter.kind == "learned"
    return PipelineConfig(
        segmenter=segmenter,
        nodes=cable.num_nodes,
        point=point,
        cable_length_m=cable.length_m,
        plane=MOTION_PLANE,
        floor=Plane(np.array([0.0, 0.0, 1.0]), -cable.radius_m),
        filter=filter_params,
        gripper_radius_m=GRIPPER_MASK_RADIUS_M,
        max_width_share=None,
        max_width_ratio=None,
        reach_margin_m=CABLE_REACH_MARGIN_M if learned else None,
        follow_px=LOOP_FOLLOW_PX if learned else None,
    )


def view_segmenter(
    config: PipelineConfig,
    camera: Any,
    calibration: Any,
    background: Any = None,
    held_world: NDArray[np.float64] | None = None,
) -> Any:
    """One view's segmenter stack for the loop's pipeline (``background``: the scene without the cable, for
    the classical segmenter).

    The learned one is warmed up here, before the loop's first cycle, as the classical one is by that
    render: a camera's first render and a process's first network pass at the frame's size take 3-5x their
    usual time, up to 52 ms together, which would overrun cycle 0's deadline. With ``held_world`` (the TCP
    now) the warm-up frame also goes through the cable's reach, so that the first cycle already follows the
    cable's box (:class:`~dyndlo_vision.tracking.masks.CableReachSegmenter`) instead of computing the whole
    ball: the scene is at rest until the loop starts, so the first cycle sees this frame's cable."""
    seg = config.segmenter
    base, _ = build_segmenter(
        seg, frame_size=(calibration.width, calibration.height), background_image=background
    )
    first = camera.read().rgb if seg.kind == "learned" else None
    if first is not None:
        base.segment(first)
    reach = None if config.reach_margin_m is None else config.cable_length_m + config.reach_margin_m
    stack = build_view_segmenter(
        base,
        camera=calibration,
        reach_m=reach,
        follow_px=config.follow_px,
        gripper_radius_px=0.0,
        max_width_share=config.max_width_share,
        max_width_ratio=config.max_width_ratio,
    )
    if first is not None and held_world is not None and stack.reach is not None:
        stack.hold(np.asarray(held_world, dtype=np.float64), None)
        stack(first)
    return stack


def tracked_state(
    env: Any,
    camera_name: str = "tracking",
    perception: LoopPerception | None = None,
    width: int = 640,
    height: int = 480,
) -> tuple[TrackedState, MujocoCamera]:
    """A :class:`TrackedState` on the MuJoCo cameras of ``env`` (call after ``env.reset``).

    ``perception`` (default :class:`LoopPerception()`) names the segmenter, the views, the camera's latency
    and the filter. With one view the cable is lifted onto the motion plane from ``camera_name``; with two it
    is also tracked in the scene's second tracking camera and triangulated. The classical segmenter's
    background is rendered now, with the cable hidden, so call it at the start of an episode. The camera
    returned renders the present (for videos).

    P_DLO's node: the free tip, or an inner node (vaulting's middle): with one view the same fraction along
    the observed centreline as along the cable, with two the point that far along the triangulated cable
    from the gripper.
    """
    perception = perception or LoopPerception()
    available = scene_views(env)
    views = available if perception.views is None else perception.views
    if views > available:
        raise ValueError(
            f"views=2 needs a scene with a {SECOND_TRACKING_CAMERA_NAME!r} camera; this one has "
            "only one loop camera"
        )
    segmenter = perception.segmenter or loop_segmenter(DEFAULT_LOOP_SEGMENTER[available])
    latency_s = perception.latency_s
    base = as_sim_env(env)
    mujoco.mj_forward(base.model, base.data)
    # The newest measurement is always at least the latency old, so the filter's coasting limit and the
    # frames the camera may miss in a row (the first ones have not arrived yet) grow with it.
    params = perception.filter or (LOOP_FILTER if latency_s == 0 else LATENT_LOOP_FILTER)
    params = replace(params, max_coast_s=params.max_coast_s + latency_s)
    node = base.task.p_dlo_node(base.scene)
    point = node / (base.scene.config.cable.num_nodes - 1)
    config = loop_pipeline_config(base.scene, point, segmenter, params)
    names = ["tracking" if camera_name is None else camera_name, SECOND_TRACKING_CAMERA_NAME][:views]
    cameras = [MujocoCamera(base.model, base.data, name, width=width, height=height) for name in names]
    calibrations = [c.calibration for c in cameras]
    held = base.scene.tcp_positions()[0]
    segmenters = [
        view_segmenter(
            config, cam, calib, None if segmenter.kind == "learned" else render_without_cable(cam), held
        )
        for cam, calib in zip(cameras, calibrations, strict=True)
    ]
    pipeline = CablePipeline(config, calibrations, segmenters)
    frames = [DelayedCamera(c, latency_s) if latency_s > 0 else c for c in cameras]
    not_yet_arrived = math.ceil(latency_s / CONTROL_PERIOD_S - 1e-9)
    source = TrackedState(frames, pipeline, max_missing_frames=3 + not_yet_arrived)
    return source, cameras[0]
