"""``dyndlo-vision calib``: the calibration JSON of a simulated camera, in the format ``track --calib`` reads.

The task's scene is built as the other commands build it, and the named MuJoCo camera's pinhole model is taken
from :attr:`dyndlo_vision.cameras.MujocoCamera.calibration` (the model the demo's tracker uses):
``width``, ``height``, ``K`` (``fx = fy`` from the vertical field of view, principal point at the image
centre), ``dist`` (empty: MuJoCo renders without lens distortion), ``R`` and ``t`` with
``x_cam = R @ x_world + t`` in OpenCV's camera axes (x right, y down, z forward), and ``fps``.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

HELP = "write the calibration JSON of a simulated camera (for track --calib)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``calib``."""
    from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
    from dyndlo_vision.tasks.registry import TASKS

    default_fps = 1.0 / CONTROL_PERIOD_S  # the demo renders its camera once per control period
    p.add_argument(
        "--camera",
        default="tracking",
        help="MuJoCo camera of the task's scene (default: tracking, the demo's)",
    )
    p.add_argument(
        "--task", choices=sorted(TASKS), default="tip-control", help="whose scene (default: tip-control)"
    )
    p.add_argument("--width", type=int, default=640, help="image width in pixels (default 640, as the demo)")
    p.add_argument(
        "--height", type=int, default=480, help="image height in pixels (default 480, as the demo)"
    )
    p.add_argument(
        "--fps",
        type=float,
        default=default_fps,
        help=f"frame rate written to the file (default {default_fps:g}: one frame per control period)",
    )
    p.add_argument(
        "--out", required=True, metavar="CAMERA.json", help="file to write (its folder must exist)"
    )


@dataclass(frozen=True)
class _Settings:
    camera: str
    task: str
    width: int
    height: int
    fps: float
    out: Path


def _settings(args: argparse.Namespace) -> _Settings:
    """Validates every argument that needs no scene (raises ValueError naming the bad one)."""
    from dyndlo_vision.tasks.registry import TASKS

    if args.task not in TASKS:
        raise ValueError(f"--task {args.task!r} is not a task; expected one of {sorted(TASKS)}")
    for option, value in (("--width", args.width), ("--height", args.height)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ValueError(f"{option} must be a positive number of pixels, got {value!r}")
    if not (isinstance(args.fps, int | float) and math.isfinite(args.fps) and args.fps > 0):
        raise ValueError(f"--fps must be a positive finite number, got {args.fps!r}")
    from dyndlo_vision._atomic import check_output_file

    out = check_output_file(Path(args.out), "--out", "camera.json")
    return _Settings(str(args.camera), str(args.task), args.width, args.height, float(args.fps), out)


def run(args: argparse.Namespace) -> int:
    """Build the task's scene, take the camera's calibration and write it."""
    cfg = _settings(args)

    import mujoco

    from dyndlo_vision._atomic import write_atomic
    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.tasks.registry import make_env

    env = make_env(cfg.task)
    try:
        model, data = env.unwrapped.model, env.unwrapped.data
        names = [model.camera(i).name for i in range(model.ncam)]
        if cfg.camera not in names:
            raise ValueError(
                f"--camera {cfg.camera!r} is not a camera of the {cfg.task} scene; its cameras: {names}"
            )
        cam_id = int(model.camera(cfg.camera).id)
        # One file holds one pose: a camera that tracks a body, or rides on a moving one, has none.
        fixed = int(model.cam_mode[cam_id]) == int(mujoco.mjtCamLight.mjCAMLIGHT_FIXED)
        body = int(model.cam_bodyid[cam_id])
        if not fixed or int(model.body_weldid[body]) != 0:
            raise ValueError(
                f"--camera {cfg.camera!r} moves with the scene (body {model.body(body).name!r}, mode "
                f"{int(model.cam_mode[cam_id])}); a calibration file describes a camera fixed to the world"
            )
        # The file is for images the scene can render (MujocoCamera's limit too, with advice about the model
        # file that a user of a task cannot follow).
        largest = (int(model.vis.global_.offwidth), int(model.vis.global_.offheight))
        if cfg.width > largest[0] or cfg.height > largest[1]:
            raise ValueError(
                f"--width {cfg.width} --height {cfg.height} is larger than the {cfg.task} scene renders "
                f"(at most {largest[0]}x{largest[1]})"
            )
        mujoco.mj_forward(model, data)
        camera = MujocoCamera(model, data, cfg.camera, width=cfg.width, height=cfg.height, fps=cfg.fps)
        try:
            calib = camera.calibration
        finally:
            camera.close()
    finally:
        env.close()
    text = json.dumps(calib.to_dict(), indent=2) + "\n"
    write_atomic(cfg.out, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
    fx, cx, cy = calib.K[0, 0], calib.K[0, 2], calib.K[1, 2]
    centre = ", ".join(f"{c:.3f}" for c in calib.center)
    print(
        f"wrote {cfg.out}: camera {cfg.camera!r} of {cfg.task}, {cfg.width}x{cfg.height} px, "
        f"fx = fy = {fx:.2f} px, principal point ({cx:.1f}, {cy:.1f}), centre ({centre}) m, {cfg.fps:g} fps"
    )
    return 0
