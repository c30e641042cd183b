"""Frames from the simulator: :class:`MujocoCamera` renders a MuJoCo scene off-screen and stamps frames with
the simulator's time; :class:`DelayedCamera` hands any camera's frames over a fixed time after capture, as a
real pipeline does (exposure, transfer, decoding), so the loop can be run in simulation with a camera's
latency."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from dyndlo_vision.cameras._base import _FrameSource
from dyndlo_vision.cameras.protocol import Frame
from dyndlo_vision.tracking.camera_model import PinholeCamera


class MujocoCamera(_FrameSource):
    """Off-screen RGB (and optional depth) images of a named camera of a MuJoCo model.

    ``read()`` renders the current state of ``data`` (it never steps the physics) and stamps the frame with
    ``data.time``, so a frame is captured at the simulator's time. Depth is metres along the optical axis
    (MuJoCo's linearised depth buffer); pixels that see nothing (at the far clipping plane) are NaN.

    Example::

        with MujocoCamera(env.unwrapped.model, env.unwrapped.data, "front", depth=True) as cam:
            frame = cam.read()
            calibration = cam.calibration   # for a CablePipeline (tracking.pipeline)
    """

    #: Frames are stamped with the simulator's time (see :mod:`dyndlo_vision.control.clocks`).
    clock = "simulation"

    def __init__(
        self,
        model: Any,
        data: Any,
        camera_name: str,
        width: int = 640,
        height: int = 480,
        depth: bool = False,
        fps: float | None = None,
    ) -> None:
        """Creates the renderer.

        Args:
            model: The ``mujoco.MjModel``.
            data: The ``mujoco.MjData`` whose state is rendered.
            camera_name: Name of a camera defined in the model.
            width: Image width in pixels (at most the model's ``<global offwidth>``).
            height: Image height in pixels (at most the model's ``<global offheight>``).
            depth: Also render a depth image into ``Frame.depth``.
            fps: Frame rate recorded in :attr:`calibration` (information only).

        Raises:
            ValueError: Unknown camera, a camera without a vertical field of view, or a size that does not
                fit the model's off-screen framebuffer.
        """
        import mujoco

        from dyndlo_vision.sim.rendering import make_renderer

        names = [model.camera(i).name for i in range(model.ncam)]
        if camera_name not in names:
            raise ValueError(f"camera {camera_name!r} is not in the model; its cameras are {names}")
        self.camera_id = int(model.camera(camera_name).id)
        if np.any(np.asarray(model.cam_sensorsize[self.camera_id]) > 0):
            raise ValueError(
                f"camera {camera_name!r} is defined by focal length and sensor size; only fovy cameras are "
                "supported (PinholeCamera.from_mujoco)"
            )
        if int(model.cam_projection[self.camera_id]) != int(mujoco.mjtProjection.mjPROJ_PERSPECTIVE):
            raise ValueError(f"camera {camera_name!r} is orthographic; expected a perspective camera")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        offwidth, offheight = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
        if width > offwidth or height > offheight:
            raise ValueError(
                f"image size {width}x{height} exceeds the model's off-screen framebuffer "
                f"{offwidth}x{offheight}; raise <visual><global offwidth offheight> in the model"
            )
        self.model = model
        self.data = data
        self.camera_name = camera_name
        self.width = int(width)
        self.height = int(height)
        self.depth = bool(depth)
        self.fps = fps
        self._far_m = float(model.stat.extent * model.vis.map.zfar)
        self._renderer: Any = make_renderer(model, self.height, self.width)
        self._index = 0

    @property
    def calibration(self) -> PinholeCamera:
        """The camera's pinhole model at the current state of ``data`` (cameras may move with bodies).

        Raises:
            ValueError: If ``data`` has no camera pose yet (run ``mujoco.mj_forward`` first).
        """
        xmat = np.asarray(self.data.cam_xmat[self.camera_id], dtype=np.float64)
        if not np.any(xmat):
            raise ValueError(
                f"camera {self.camera_name!r} has no pose in data yet (cam_xmat is zero): "
                "call mujoco.mj_forward first"
            )
        return PinholeCamera.from_mujoco(
            float(self.model.cam_fovy[self.camera_id]),
            self.width,
            self.height,
            self.data.cam_xpos[self.camera_id],
            xmat,
            fps=self.fps,
        )

    def read(self) -> Frame:
        """Renders the current simulation state; never None (a simulator does not run out of frames)."""
        if self._renderer is None:
            raise ValueError(f"MujocoCamera {self.camera_name!r} is closed")
        self._renderer.update_scene(self.data, camera=self.camera_id)
        rgb = np.array(self._renderer.render(), dtype=np.uint8)
        depth = None
        if self.depth:
            self._renderer.enable_depth_rendering()
            try:
                depth = np.array(self._renderer.render(), dtype=np.float32)
            finally:
                self._renderer.disable_depth_rendering()
            # The far clipping plane means "nothing here", not a surface 50 m away.
            depth[depth >= self._far_m * (1.0 - 1e-3)] = np.nan
        frame = Frame(rgb=rgb, t_capture=float(self.data.time), index=self._index, depth=depth)
        self._index += 1
        return frame

    def close(self) -> None:
        """Releases the GL context; safe to call twice."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def checked_latency_s(latency_s: Any) -> float:
    """``latency_s`` as a float, or a ValueError naming it unless it is a finite number >= 0 (seconds)."""
    if isinstance(latency_s, bool) or not isinstance(latency_s, int | float) or not (
        math.isfinite(latency_s) and latency_s >= 0
    ):
        raise ValueError(f"latency_s must be a finite number >= 0 (seconds), got {latency_s!r}")
    return float(latency_s)


class DelayedCamera(_FrameSource):
    """Frames that arrive ``latency_s`` after they were captured: a camera pipeline's latency.

    Every ``read()`` reads the wrapped camera (a :class:`MujocoCamera` renders the simulator's present) into a
    buffer and hands over the newest frame captured at least ``latency_s`` before the newest capture, each
    frame at most once and with its own capture time, so a filter that predicts from ``t_capture`` to the
    controller's time compensates the delay. Until a frame is old enough ``read()`` returns None (a frame
    that has not arrived yet); the very first read hands over the first frame at once, so a loop starts with
    an estimate (in simulation the cable rests before an episode). Read at a fixed period, a frame's delay is
    ``latency_s`` rounded up to a whole number of periods.

    Args:
        camera: The camera whose frames are delayed (its ``calibration``, if any, is passed through).
        latency_s: Delay from capture to hand-over in seconds, >= 0 (0: every frame at once).

    Raises:
        ValueError: A latency that is negative, not finite or not a number.
    """

    def __init__(self, camera: Any, latency_s: float) -> None:
        self.camera = camera
        self.latency_s = checked_latency_s(latency_s)
        self._buffer: list[Frame] = []
        self._started = False

    @property
    def calibration(self) -> Any:
        """The wrapped camera's calibration."""
        return self.camera.calibration

    @property
    def clock(self) -> str | None:
        """The wrapped camera's clock (capture times are passed through unchanged)."""
        return getattr(self.camera, "clock", None)

    def read(self) -> Frame | None:
        """Reads the wrapped camera; the newest frame that is ``latency_s`` old, or None if none has arrived.

        None also when the wrapped camera has run out and every buffered frame has been handed over.
        """
        frame = self.camera.read()
        if frame is not None:
            self._buffer.append(frame)
        if not self._buffer:
            return None
        if not self._started:
            self._started = True
            return self._buffer.pop(0)
        now = self._buffer[-1].t_capture if frame is not None else math.inf
        due = [i for i, f in enumerate(self._buffer) if now - f.t_capture >= self.latency_s - 1e-9]
        if not due:
            return None
        newest = due[-1]
        out = self._buffer[newest]
        del self._buffer[: newest + 1]  # older frames than the one handed over are never wanted again
        return out

    def __iter__(self) -> Iterator[Frame]:
        raise TypeError(
            "a DelayedCamera is read at the loop's period (None means 'not arrived yet', not 'no more'); "
            "iterate over the wrapped camera instead"
        )

    def close(self) -> None:
        """Closes the wrapped camera and drops the buffer."""
        self._buffer.clear()
        self.camera.close()
