"""The real-robot loop's perception: P_DLO tracked from the configured camera.

* ``simulated`` (a dry run): the task's scene, its TCP following the robot's measured joints
  (:class:`~dyndlo_vision.control.dry_run.FollowingCamera`), through the loop's perception;
* ``video``: a recorded video, each frame stamped with the robot's time when it is read;
* ``device`` and ``realsense``: a live camera of the calibration's size.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from dyndlo_vision.control.run_config import RunConfig

__all__ = ["build_source", "camera_calibration"]


def build_source(cfg: RunConfig, env: Any, driver: Any, calib: Any) -> tuple[Any, Any]:
    """The P_DLO source and the camera the video is read from: the loop's perception pipeline on the
    configured camera (see the module docstring)."""
    from dyndlo_vision.control.sim_perception import LoopPerception, loop_segmenter

    base = env.unwrapped
    segmenter = loop_segmenter(cfg.camera.segmenter)
    if cfg.camera.source == "simulated":
        from dyndlo_vision.control.dry_run import FollowingCamera, place_scene_camera
        from dyndlo_vision.control.sim_perception import tracked_state

        place_scene_camera(base.model, base.data, "tracking", calib)
        source, camera = tracked_state(env, "tracking", LoopPerception(segmenter, views=1), width=calib.width,
                                       height=calib.height)
        following = FollowingCamera(camera, env, driver)
        source.camera = following
        return source, following
    from dyndlo_vision.control.sim_perception import loop_pipeline_config
    from dyndlo_vision.control.state_sources import TrackedState
    from dyndlo_vision.tracking.params import LOOP_FILTER
    from dyndlo_vision.tracking.pipeline import CablePipeline
    from dyndlo_vision.tracking.segmenters import background_from, build_segmenter, build_view_segmenter

    camera: Any
    if cfg.camera.source == "video":
        from dyndlo_vision.cameras.files import VideoFileCamera

        camera = _RobotClockCamera(VideoFileCamera(cfg.camera.path, fps=cfg.camera.fps), driver)
    elif cfg.camera.source == "device":
        from dyndlo_vision.cameras.devices import OpenCVDeviceCamera

        camera = OpenCVDeviceCamera(cfg.camera.device, width=calib.width, height=calib.height)
    else:
        from dyndlo_vision.cameras.devices import RealSenseCamera

        camera = RealSenseCamera(width=calib.width, height=calib.height)
    background = None
    if segmenter.kind == "background":
        try:
            background = background_from(cfg.camera.background)
        except ValueError as exc:
            raise ValueError(f"{cfg.path}: camera.background: {exc}") from None
    # A real camera's frames are the calibration's own size: the shipped network at its own input size.
    if segmenter.kind == "learned":
        segmenter = replace(segmenter, model=None, scale=None)
    config = loop_pipeline_config(base.scene, 1.0, segmenter, LOOP_FILTER)
    config = replace(config, reach_margin_m=None, follow_px=None, floor=None)
    base_segmenter, _ = build_segmenter(segmenter, frame_size=(calib.width, calib.height),
                                        background_image=background)
    view = build_view_segmenter(base_segmenter, camera=calib, gripper_radius_px=0.0)
    source = TrackedState(camera, CablePipeline(config, [calib], [view]))
    return source, camera


class _RobotClockCamera:
    """A replayed video, each frame stamped with the robot's time when it is read (as if live)."""

    clock = "robot"

    def __init__(self, camera: Any, driver: Any) -> None:
        self.camera, self.driver = camera, driver

    def read(self) -> Any:
        from dyndlo_vision.cameras.protocol import Frame

        frame = self.camera.read()
        if frame is None:
            return None
        return Frame(rgb=frame.rgb, t_capture=float(self.driver.joints().t), index=frame.index,
                     depth=frame.depth)

    def close(self) -> None:
        self.camera.close()


def camera_calibration(camera: Any, source: Any) -> Any:
    """The pinhole model the video overlay projects with (the tracker's)."""
    pipeline = getattr(source, "pipeline", None)
    return pipeline.views[0].camera if pipeline is not None else camera.calibration
