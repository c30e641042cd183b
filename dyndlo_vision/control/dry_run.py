"""What ``dyndlo-vision run --dry-run`` puts where the hardware would be.

* :func:`start_fake_controller`: the fake ABB or UR controller of :mod:`dyndlo_vision.robots.fake_servers`,
  speaking the real EGM or RTDE protocol on loopback, its arm at rest with the TCP at the task's home; the
  driver is pointed at it and cannot tell it from a robot.
* :class:`FollowingCamera`: a camera on a MuJoCo scene of the task whose TCP follows the robot's *measured*
  joints. Before each frame the scene is simulated up to the robot's present: the joint states the driver
  received (:class:`JointRecorder`) are turned into TCP positions and velocities by forward kinematics,
  resampled onto the physics timestep and followed (``DynDLOEnv.follow``). Frames are stamped on the robot's
  clock, so the tracker and filter run exactly as with a live camera beside the robot.
* :func:`place_scene_camera`: moves the scene's camera to the calibration's pose and field of view, so the
  simulated camera is the one the calibration JSON describes (a pinhole camera without distortion, principal
  point at the image centre, square pixels; anything else is refused with the reason).
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.cameras.protocol import Frame
from dyndlo_vision.robots._streaming import JointSample
from dyndlo_vision.tracking.camera_model import PinholeCamera

__all__ = ["FollowingCamera", "JointRecorder", "place_scene_camera", "start_fake_controller"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


class JointRecorder:
    """Mixin for a :class:`~dyndlo_vision.robots._streaming.JointStreamingDriver`: records every state the
    robot reported and every joint target answered, on the robot's clock.

    ``measured``: ``(t, q, qd)`` per robot cycle; ``targets``: ``(t, q, active)``, ``active`` once a plan has
    been accepted (before that the driver answers the position held).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.record_lock = threading.Lock()
        self.measured: list[tuple[float, FloatArray, FloatArray | None]] = []
        self.targets: list[tuple[float, FloatArray, bool]] = []

    def _respond(self, sample: JointSample) -> None:
        super()._respond(sample)  # type: ignore[misc]
        with self._lock:  # type: ignore[attr-defined]
            t_cmd, q_cmd = self._history[-1]  # type: ignore[attr-defined]
            active = bool(self._active)  # type: ignore[attr-defined]
            measured = self._measured  # type: ignore[attr-defined]
        with self.record_lock:
            self.measured.append((float(measured.t), measured.q.copy(),
                                  None if measured.qd is None else measured.qd.copy()))
            self.targets.append((float(t_cmd), np.array(q_cmd, dtype=float), active))

    def measured_since(self, t: float) -> list[tuple[float, FloatArray, FloatArray | None]]:
        """The recorded states later than ``t``."""
        with self.record_lock:
            k = len(self.measured)
            while k > 0 and self.measured[k - 1][0] > t:
                k -= 1
            return self.measured[k:]


def start_fake_controller(driver_name: str, arm: Any, q0: FloatArray, egm_port: int | None = None) -> Any:
    """Start the fake controller of ``driver_name`` (``egm``/``rtde``) with the arm at ``q0``, realtime.

    For EGM the fake sends to the driver's UDP port ``egm_port`` on loopback; for RTDE it listens on
    OS-chosen loopback ports (its ``rtde_port``, ``script_port``).
    """
    from dyndlo_vision.robots.fake_servers import FakeEgmController, FakeRtdeController

    # The driver may answer late on a loaded machine; the controller then waits (as a real one would not,
    # but a dry run is about the code path, not the machine's speed).
    if driver_name == "egm":
        assert egm_port is not None
        fake: Any = FakeEgmController(arm, q0, ("127.0.0.1", egm_port), reply_timeout_s=0.2)
    else:
        fake = FakeRtdeController(arm, q0, reply_timeout_s=0.2)
    return fake.start()


def place_scene_camera(model: Any, data: Any, camera_name: str, calib: PinholeCamera) -> None:
    """Move a fixed world camera of ``model`` to the calibration's pose and vertical field of view.

    Raises:
        ValueError: The camera is attached to a moving body, or the calibration is not a camera MuJoCo can
            render (lens distortion, principal point off the image centre, fx != fy), or its image is larger
            than the model's off-screen buffer.
    """
    cid = int(model.camera(camera_name).id)
    if int(model.cam_bodyid[cid]) != 0:
        raise ValueError(f"camera {camera_name!r} is attached to a body; expected a fixed world camera")
    K = calib.K
    problems = []
    if calib.has_distortion:
        problems.append(f"lens distortion {calib.dist.tolist()}")
    centre = ((calib.width - 1) / 2.0, (calib.height - 1) / 2.0)
    if abs(K[0, 2] - centre[0]) > 0.5 or abs(K[1, 2] - centre[1]) > 0.5:
        problems.append(f"principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) px, not the image centre "
                        f"({centre[0]:.1f}, {centre[1]:.1f})")
    if abs(K[0, 0] - K[1, 1]) > 1e-3 * K[1, 1]:
        problems.append(f"fx {K[0, 0]:.2f} != fy {K[1, 1]:.2f}")
    if calib.width > model.vis.global_.offwidth or calib.height > model.vis.global_.offheight:
        problems.append(f"image {calib.width}x{calib.height} larger than the scene's off-screen buffer "
                        f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
    if problems:
        raise ValueError("the simulated camera cannot reproduce this calibration: " + "; ".join(problems))
    # from_mujoco: R = diag(1, -1, -1) @ xmat.T and t = -R @ pos.
    xmat = calib.R.T @ np.diag([1.0, -1.0, -1.0])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(xmat).reshape(-1))
    model.cam_pos[cid] = calib.center
    model.cam_quat[cid] = quat
    model.cam_fovy[cid] = math.degrees(2.0 * math.atan(0.5 * calib.height / K[1, 1]))
    mujoco.mj_forward(model, data)


class FollowingCamera:
    """Frames of the task's scene, its TCP following the robot's measured joints (see the module docstring).

    Args:
        camera: A :class:`~dyndlo_vision.cameras.MujocoCamera` on the environment's scene.
        env: The task environment (its unwrapped ``DynDLOEnv`` is simulated).
        driver: A driver with :class:`JointRecorder` (``measured_since``, ``joints()``, ``kinematics``).
    """

    clock = "robot"

    def __init__(self, camera: Any, env: Any, driver: Any) -> None:
        self.camera = camera
        self.base = env.unwrapped
        self.driver = driver
        now = float(driver.joints().t)
        #: robot time = simulated time + offset
        self.offset = now - float(self.base.scene.time)
        self._last_t = now
        self._last_p, _ = driver.kinematics.fk(driver.joints().q)
        self._last_v = np.zeros(3)

    @property
    def calibration(self) -> PinholeCamera:
        """The camera's pinhole model."""
        return self.camera.calibration

    def advance(self) -> None:
        """Simulate the scene up to the robot's latest measured state (its TCP following the measurements)."""
        samples = self.driver.measured_since(self._last_t)
        if not samples:
            return
        kin = self.driver.kinematics
        t = np.array([self._last_t] + [s[0] for s in samples])
        q = np.array([s[1] for s in samples])
        p = np.vstack([self._last_p[None], kin.fk(q)[0]])
        v = [self._last_v]
        for s in samples:
            v.append(np.zeros(3) if s[2] is None else kin.tcp_velocity(s[1], s[2]))
        vel = np.array(v)
        scene = self.base.scene
        dt = scene.timestep
        n = int(math.floor((t[-1] - self.offset - scene.time) / dt + 1e-9))
        if n > 0:
            grid = scene.time + dt * np.arange(n) + self.offset  # robot times of the physics steps
            pos = np.stack([np.interp(grid, t, p[:, i]) for i in range(3)], axis=1)
            velo = np.stack([np.interp(grid, t, vel[:, i]) for i in range(3)], axis=1)
            self.base.follow(grid - self.offset, pos[:, None, :], velo[:, None, :])
        self._last_t, self._last_p, self._last_v = float(t[-1]), p[-1], vel[-1]

    def robot_time(self) -> float:
        """The simulated scene's time on the robot's clock."""
        return float(self.base.scene.time) + self.offset

    def read(self) -> Frame:
        """Simulate up to the robot's present and render; stamped with the robot's clock."""
        self.advance()
        frame = self.camera.read()
        return Frame(rgb=frame.rgb, t_capture=self.robot_time(), index=frame.index, depth=frame.depth)

    def close(self) -> None:
        """Close the renderer."""
        self.camera.close()
