"""Camera-based state estimation in simulation: the tracker set up on a MuJoCo camera of a DynDLO scene.

What a real set-up knows and uses, reproduced here: an image of the scene without the cable (the background
model of the automatic segmentation), the camera calibration, the plane the planar trajectories move in, the
cable's length in pixels on that plane, and the robot's own pose (the gripper is masked out of the
segmentation by its projected position, and the projected TCP marks the held end of the cable).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.cameras.simulated import DelayedCamera, MujocoCamera, checked_latency_s
from dyndlo_vision.control.sim_env import as_sim_env
from dyndlo_vision.control.state_sources import StereoTrackedState, TrackedState
from dyndlo_vision.sim.cable_look import CableLook
from dyndlo_vision.sim.scene import SECOND_TRACKING_CAMERA_NAME
from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
from dyndlo_vision.tracking import (
    LATENT_LOOP_FILTER,
    LOOP_FILTER,
    BackgroundSegmenter,
    CableTracker,
    Plane,
    PointFilter,
)
from dyndlo_vision.tracking.masks import CableReachSegmenter, GripperMaskedSegmenter

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
#: shipped networks gain as much in the loop (docs/RESULTS.md, "The loop network at 1.5x").
LOOP_NETWORK_SCALE = 1.5
#: The loop's learned segmenter computes the box around the last frame's mask grown by this many pixels
#: (``CableReachSegmenter(follow_px=...)``), not the whole image of the cable's reach: about a fifth of it.
#: Chosen on seeds 200000-200019 between 48 and 80: at 80 the estimates match the whole reach's (median
#: 1.71 against 1.72 mm, p90 2.08 against 2.15 mm), at 48 the p90 rose to 3.3 mm (docs/RESULTS.md, "The loop
#: network at 1.5x").
LOOP_FOLLOW_PX = 80
# The tip filter's tuned acceleration noise without and with a camera latency (why: tracking.params).
LOOP_SIGMA_ACCEL = LOOP_FILTER.sigma_accel
LATENT_LOOP_SIGMA_ACCEL = LATENT_LOOP_FILTER.sigma_accel
#: Segmenters the loop can use: the shipped full-resolution CNN ``cable-segmenter-loop`` (no background
#: image needed, as with a real camera), or the classical background segmenter against the scene rendered
#: without the cable (a clean plate only a simulator or a fixed real camera has).
LOOP_SEGMENTERS = ("background", "learned")
#: The loop's segmenter when none is named, by the number of loop cameras the scene has
#: (:func:`scene_views`). One camera (tip control): the learned network, as ``run`` uses with a real camera:
#: 98 of 100 hits on fresh seeds, as with the classical one, at an estimate RMSE of 1.9 against 1.3 mm and
#: a controller p95 of 17 against 15 ms. Two cameras (vaulting): the classical one; there the
#: learned network loses the cable lying on the light floor beyond the obstacle (estimates 71-148 mm) and two
#: renders plus two networks overrun the 40 ms cycle (docs/RESULTS.md, "The learned segmenter, the loop's
#: default (session 36)").
DEFAULT_LOOP_SEGMENTER = {1: "learned", 2: "background"}
#: Longest simulated camera latency (s): beyond a quarter second the loop re-plans on a past the cable has
#: long left.
MAX_LATENCY_S = 0.25
#: Range of the learned segmenter's enlargement in the loop: below 0.5 the 1.6 px cable is under a pixel;
#: above 3 a 640x480 frame is a 1920x1440 input, beyond any cycle budget.
MIN_SEGMENTER_SCALE, MAX_SEGMENTER_SCALE = 0.5, 3.0


def checked_segmenter_scale(scale: Any, name: str = "segmenter_scale") -> float:
    """``scale`` as a float, or ValueError naming it as ``name`` unless it is a number in
    [MIN_SEGMENTER_SCALE, MAX_SEGMENTER_SCALE]."""
    if isinstance(scale, bool) or not isinstance(scale, int | float) or not (
            MIN_SEGMENTER_SCALE <= scale <= MAX_SEGMENTER_SCALE):
        raise ValueError(f"{name} must be a number in [{MIN_SEGMENTER_SCALE:g}, "
                         f"{MAX_SEGMENTER_SCALE:g}], got {scale!r}")
    return float(scale)


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


def pixels_per_metre(camera: Any, point: NDArray[np.float64], plane: Plane = MOTION_PLANE) -> float:
    """Image scale on the motion plane near ``point`` (pixels per metre), from two projected points."""
    normal = np.asarray(plane.normal, dtype=float)
    along = np.cross(normal, [0.0, 0.0, 1.0])
    along = along / np.linalg.norm(along)
    uv = camera.project(np.stack([point, point + 0.1 * along]))
    return float(np.linalg.norm(uv[1] - uv[0]) / 0.1)


def _camera_tracker(base: Any, camera_name: str, width: int, height: int, segmenter: str,
                    segmenter_model: str | None = None,
                    segmenter_scale: float = LOOP_NETWORK_SCALE) -> tuple[MujocoCamera, CableTracker, Any]:
    """A loop camera of the scene, its 2D-and-plane tracker (gripper masked), and the map from a world point
    to its pixel that also moves the gripper mask there."""
    camera = MujocoCamera(base.model, base.data, camera_name, width=width, height=height)
    calib = camera.calibration
    home = base.scene.gripper_home[0]
    scale = pixels_per_metre(calib, home)
    if segmenter == "learned":
        from dyndlo_vision.tracking.learned import LearnedSegmenter
        from dyndlo_vision.tracking.networks import LOOP_NAME, onnx_bytes

        # By default the full-resolution network fine-tuned on the loop's own scenes (docs/RESULTS.md, "A
        # segmenter for the loop's own scenes"). The loop camera's cable is 1.6 px wide, so every network sees
        # the frame enlarged (LOOP_NETWORK_SCALE by default). It computes only the part of the frame the held
        # cable can reach (docs/RESULTS.md, "The cable's reach").
        network = LearnedSegmenter(onnx_bytes(segmenter_model or LOOP_NAME),
                                   short_side=round(segmenter_scale * min(width, height)))
        # Warmed up here, as the classical branch is by its background render: a camera's first render and a
        # process's first network pass at the frame's size take 3-5x their usual time (up to 52 ms together),
        # which would overrun cycle 0's deadline.
        network.segment(camera.read().rgb)
        reach_m = base.scene.config.cable.length_m + CABLE_REACH_MARGIN_M
        reach: Any = CableReachSegmenter(network, calib, reach_m, follow_px=LOOP_FOLLOW_PX)
        inner: Any = reach
    else:
        reach = None
        inner = BackgroundSegmenter(render_without_cable(camera), open_radius=0)
    masked = GripperMaskedSegmenter(inner, GRIPPER_MASK_RADIUS_M * scale)
    # Nodes are spread over the observed centreline (from the gripper mask's edge to the far end): the last
    # one is the tip whenever the tip is in view. (With ``cable_length_px`` the tracker would mark nodes past
    # the observed length invisible, but the rendered 2 mm cable measures a few pixels short: no tip.)
    # The floor, raised by the cable's radius: where the cable lies on it (vaulting's start, off the motion
    # plane), a lift onto the motion plane would put it under the floor.
    floor = Plane(np.array([0.0, 0.0, 1.0]), -base.scene.config.cable.radius_m)
    tracker = CableTracker(calib, segmenter=masked, n_nodes=base.scene.config.cable.num_nodes,
                           plane=MOTION_PLANE, floor=floor)

    def project(p: NDArray[np.float64]) -> NDArray[np.float64]:
        held = np.asarray(p, dtype=float)
        uv = calib.project(held[None])[0]
        masked.center_uv = uv
        if reach is not None:
            reach.held_world = held
        return uv

    return camera, tracker, project


def default_segmenter(env: Any) -> str:
    """The loop's segmenter for ``env``'s scene when none is named (:data:`DEFAULT_LOOP_SEGMENTER`)."""
    return DEFAULT_LOOP_SEGMENTER[scene_views(env)]


def scene_views(env: Any) -> int:
    """The loop cameras ``env``'s scene has: 2 with a second tracking camera (vaulting), else 1."""
    model = as_sim_env(env).model
    return 2 if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, SECOND_TRACKING_CAMERA_NAME) >= 0 else 1


def tracked_state(env: Any, camera_name: str = "tracking", point_filter: PointFilter | None = None,
                  width: int = 640, height: int = 480,
                  latency_s: float = 0.0, segmenter: str | None = None,
                  views: int | None = None,
                  segmenter_model: str | None = None,
                  segmenter_scale: float | None = None) -> tuple[TrackedState, MujocoCamera]:
    """A :class:`TrackedState` on a MuJoCo camera of ``env`` (call after ``env.reset``).

    The background image is rendered now, with the cable hidden, so call it at the start of an episode. With
    ``latency_s`` > 0 the tracker sees each frame that long after it was rendered (:class:`DelayedCamera`)
    and the filter predicts across the delay. The camera returned renders the present (for videos).
    ``segmenter`` is one of :data:`LOOP_SEGMENTERS` (None: the scene's default, :func:`default_segmenter`);
    either way the gripper is masked by its projected pose.
    ``segmenter_model``: the learned segmenter's network, a shipped name or an ONNX file (default
    ``cable-segmenter-loop``). ``segmenter_scale``: the learned segmenter's network sees the frame enlarged
    this many times (default :data:`LOOP_NETWORK_SCALE`; :func:`checked_segmenter_scale`).
    ``views``: 1 lifts the cable onto the motion plane from ``camera_name``; 2 also tracks it in the scene's
    second tracking camera and triangulates (:class:`StereoTrackedState`). None: as many as the scene has
    (:func:`scene_views`).
    """
    if segmenter is None:
        segmenter = default_segmenter(env)
    if segmenter not in LOOP_SEGMENTERS:
        raise ValueError(f"segmenter={segmenter!r}; expected one of {list(LOOP_SEGMENTERS)}")
    if segmenter_model is not None and segmenter != "learned":
        raise ValueError(f"segmenter_model={segmenter_model!r} is for the learned segmenter, not "
                         f"{segmenter!r}")
    if segmenter_scale is not None and segmenter != "learned":
        raise ValueError(f"segmenter_scale={segmenter_scale!r} is for the learned segmenter, not "
                         f"{segmenter!r}")
    scale = LOOP_NETWORK_SCALE if segmenter_scale is None else checked_segmenter_scale(segmenter_scale)
    available = scene_views(env)
    views = available if views is None else views
    if views not in (1, 2):
        raise ValueError(f"views={views!r}; expected 1 or 2")
    if views > available:
        raise ValueError(f"views=2 needs a scene with a {SECOND_TRACKING_CAMERA_NAME!r} camera; this one has "
                         "only one loop camera")
    if checked_latency_s(latency_s) > MAX_LATENCY_S:
        raise ValueError(f"latency_s must be at most {MAX_LATENCY_S} s, got {latency_s!r}")
    base = as_sim_env(env)
    mujoco.mj_forward(base.model, base.data)
    camera, tracker, project = _camera_tracker(base, camera_name, width, height, segmenter, segmenter_model,
                                               scale)

    # The newest measurement is always at least the latency old, so the filter's coasting limit and the
    # frames the camera may miss in a row (the first ones have not arrived yet) grow with it.
    params = LOOP_FILTER if latency_s == 0 else LATENT_LOOP_FILTER
    point_filter = point_filter or PointFilter(replace(params, max_coast_s=params.max_coast_s + latency_s))
    frames = DelayedCamera(camera, latency_s) if latency_s > 0 else camera
    not_yet_arrived = math.ceil(latency_s / CONTROL_PERIOD_S - 1e-9)
    # The known cable: a polyline shorter than it ends where the cable disappears (behind the target sphere,
    # say), so its end is not the tip; the tip is placed by continuing it (tracker.tip_from_polyline).
    # P_DLO's node: the free tip (-1, continued past where the tracked cable disappears), or an inner node
    # (vaulting's middle): with one view the same fraction along the observed centreline as along the cable,
    # with two the point that far along the triangulated cable from the gripper.
    node = base.task.p_dlo_node(base.scene)
    point_index = -1 if node == base.scene.config.cable.num_nodes - 1 else node
    missing = 3 + not_yet_arrived
    length = base.scene.config.cable.length_m
    if views == 1:
        source = TrackedState(frames, tracker, point_filter, point_index=point_index, project=project,
                              max_missing_frames=missing, cable_length_m=length)
        return source, camera
    camera2, tracker2, project2 = _camera_tracker(base, SECOND_TRACKING_CAMERA_NAME, width, height, segmenter,
                                                  segmenter_model, scale)
    frames2 = DelayedCamera(camera2, latency_s) if latency_s > 0 else camera2
    stereo = StereoTrackedState(frames, frames2, tracker, tracker2, point_filter, point_index=point_index,
                                project=project, second_project=project2, max_missing_frames=missing,
                                cable_length_m=length)
    return stereo, camera
