"""The YAML configuration of ``dyndlo-vision run``: the robot, the camera, the task and the safety limits.

:func:`load_run_config` reads a YAML file and checks every key before anything connects or moves. An error
names the key (``robot.arm``), the value found and what was expected; unknown keys are errors too (a typo must
not silently fall back to a default). Paths in the file (the calibration, a video, a background image) are
relative to the file's folder.

Schema (``examples/run-gofa-dry.yaml`` documents it field by field)::

    robot:
      driver: egm | rtde          # ABB EGM (UDP) or UR RTDE (TCP)
      arm: gofa | ur5e            # must match the driver: gofa streams over egm, ur5e over rtde
      port: 6510                  # egm: local UDP port the controller sends to; rtde: RTDE port (30004)
      host: 192.168.125.1         # rtde only: the controller's address
      script_port: 30002          # rtde only: where the servo URScript is sent
      connect_timeout_s: 3.0      # fail if the robot does not answer within this long
      base_pose: [x, y, z, roll, pitch, yaw]   # arm base in the task's world (m, degrees); default per arm
      tool_offset: [x, y, z]      # TCP in the flange frame (m); default [0, 0, 0]
      home_tolerance_m: 0.01      # the TCP must start this close to the task's home
      plan_lead_s: 0.08           # re-plans start at least this long after the state they are made from
    camera:
      source: simulated | device | realsense | video
      calibration: camera.json    # PinholeCamera JSON (dyndlo-vision calibrate [--scene]); world = task world
      device: 0                   # device only: index or stream URL
      path: run.mp4               # video only
      fps: 25                     # video only (optional: the file's time stamps otherwise)
      segmenter: learned | background   # default: learned (the loop's tip-control default, sim or real)
      background: empty.png       # background segmenter with a real camera: the scene without the cable
    task: tip-control             # the only task run supports so far
    target: [x, y, z]             # P*, the target centre in the task's world (m)
    policy: NAME | FILE.zip | scripted:slow-reach
    fallback_policy: scripted:slow-reach   # optional: used only when `policy` is not installed
    safety:
      workspace: {min: [x, y, z], max: [x, y, z]}   # TCP box (m)
      max_tcp_speed: 1.5          # m/s
      joint_margin: 0.9           # scale on the arm's joint velocity and acceleration limits, in (0, 1]
      duration_s: 10.0            # longest run, robot time (s)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "CameraConfig",
    "ConfigError",
    "RobotConfig",
    "RunConfig",
    "SafetyConfig",
    "load_run_config",
    "parse_run_config",
]

DRIVERS = {"egm": "gofa", "rtde": "ur5e"}
CAMERA_SOURCES = ("simulated", "device", "realsense", "video")
SEGMENTERS = ("background", "learned")
TASKS = ("tip-control",)
SCRIPTED_PREFIX = "scripted:"


class ConfigError(ValueError):
    """A configuration file that cannot be run (the message names the file, the key and the problem)."""


@dataclass(frozen=True)
class RobotConfig:
    """``robot:`` (see the module docstring)."""

    driver: str
    arm: str
    port: int
    host: str | None
    script_port: int
    connect_timeout_s: float
    base_pose: tuple[float, ...] | None
    tool_offset: tuple[float, float, float]
    home_tolerance_m: float
    plan_lead_s: float


@dataclass(frozen=True)
class CameraConfig:
    """``camera:`` (paths resolved against the config file's folder)."""

    source: str
    calibration: Path
    device: int | str | None
    path: Path | None
    fps: float | None
    segmenter: str
    background: Path | None


@dataclass(frozen=True)
class SafetyConfig:
    """``safety:``."""

    workspace_min: tuple[float, float, float]
    workspace_max: tuple[float, float, float]
    max_tcp_speed: float
    joint_margin: float
    duration_s: float


@dataclass(frozen=True)
class RunConfig:
    """A checked ``run`` configuration."""

    path: Path
    robot: RobotConfig
    camera: CameraConfig
    task: str
    target: tuple[float, float, float]
    policy: str
    fallback_policy: str | None
    safety: SafetyConfig


class _Section:
    """Reads one mapping of the file, naming every key by its dotted path; refuses keys nobody read."""

    def __init__(self, source: str, data: Any, prefix: str, allowed: tuple[str, ...]) -> None:
        where = prefix or "the top level"
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: {where}: expected a mapping of keys, got {_show(data)}")
        unknown = sorted(str(k) for k in data if k not in allowed)
        if unknown:
            raise ConfigError(
                f"{source}: unknown key(s) {[self._key_name(prefix, k) for k in unknown]}; "
                f"{where} takes {list(allowed)}"
            )
        self.source, self.data, self.prefix = source, data, prefix

    @staticmethod
    def _key_name(prefix: str, key: str) -> str:
        return f"{prefix}.{key}" if prefix else key

    def key(self, name: str) -> str:
        return self._key_name(self.prefix, name)

    def fail(self, name: str, value: Any, expected: str) -> ConfigError:
        return ConfigError(f"{self.source}: {self.key(name)}: got {_show(value)}; expected {expected}")

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str, required: bool = True, default: Any = None) -> Any:
        if name not in self.data:
            if required:
                raise ConfigError(f"{self.source}: missing key {self.key(name)}")
            return default
        return self.data[name]

    def choice(self, name: str, choices: tuple[str, ...], default: str | None = None) -> str:
        value = self.raw(name, default is None, default)
        if value not in choices:
            raise self.fail(name, value, f"one of {list(choices)}")
        return str(value)

    def number(self, name: str, default: float | None = None, low: float | None = None,
               high: float | None = None, low_open: bool = False) -> float:
        value = self.raw(name, default is None, default)
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        span = f"a number in {'(' if low_open else '['}{lo}, {hi}]"
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(name, value, span)
        if (low is not None and (value < low or (low_open and value == low))) or (
            high is not None and value > high
        ):
            raise self.fail(name, value, span)
        return float(value)

    def integer(self, name: str, default: int | None, low: int, high: int) -> int:
        value = self.raw(name, default is None, default)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.fail(name, value, f"an integer in [{low}, {high}]")
        return int(value)

    def vector(self, name: str, size: int, default: Any = None, what: str = "") -> tuple[float, ...] | None:
        value = self.raw(name, default is None, default)
        if value is None:
            return None
        ok = (
            isinstance(value, list | tuple)
            and len(value) == size
            and all(not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v)
                    for v in value)
        )
        if not ok:
            raise self.fail(name, value, f"a list of {size} finite numbers{what}")
        return tuple(float(v) for v in value)

    def text(self, name: str, default: str | None = None, required: bool = True) -> str | None:
        value = self.raw(name, required and default is None, default)
        if value is None:
            return None
        if not isinstance(value, str) or not value.strip():
            raise self.fail(name, value, "a non-empty string")
        return value

    def section(self, name: str, allowed: tuple[str, ...]) -> _Section:
        return _Section(self.source, self.raw(name), self.key(name), allowed)


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _path(folder: Path, section: _Section, name: str, required: bool = True) -> Path | None:
    text = section.text(name, required=required)
    if text is None:
        return None
    path = Path(text).expanduser()
    path = path if path.is_absolute() else folder / path
    if not path.exists():
        raise FileNotFoundError(f"{section.source}: {section.key(name)}: file not found: {path}")
    return path


def load_run_config(path: str | Path) -> RunConfig:
    """Read and check a ``run`` configuration file.

    Raises:
        FileNotFoundError: The file, or a file it names, does not exist.
        ConfigError: (a ``ValueError``) Not YAML, a missing or unknown key, or a bad value.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    return parse_run_config(data, path)


def parse_run_config(data: Any, path: Path) -> RunConfig:
    """Check the parsed YAML ``data`` of the file ``path`` (paths in it are relative to its folder)."""
    source = str(path)
    folder = path.parent
    top = _Section(source, data, "", ("robot", "camera", "task", "target", "policy", "fallback_policy",
                                      "safety"))
    robot = _robot(top.section("robot", ("driver", "arm", "port", "host", "script_port", "connect_timeout_s",
                                          "base_pose", "tool_offset", "home_tolerance_m", "plan_lead_s")))
    camera = _camera(top.section("camera", ("source", "calibration", "device", "path", "fps", "segmenter",
                                            "background")), folder)
    task = top.choice("task", TASKS, default="tip-control")
    target = top.vector("target", 3, what=" (x, y, z in metres)")
    assert target is not None
    policy = top.text("policy")
    fallback = top.text("fallback_policy", required=False)
    for name, value in (("policy", policy), ("fallback_policy", fallback)):
        if value is not None and value.startswith(SCRIPTED_PREFIX):
            from dyndlo_vision.control.scripted import SCRIPTED_POLICIES

            if value[len(SCRIPTED_PREFIX):] not in SCRIPTED_POLICIES:
                raise top.fail(name, value, "a shipped policy name, a .zip file or one of "
                               f"{[SCRIPTED_PREFIX + n for n in SCRIPTED_POLICIES]}")
    if fallback is not None and policy == fallback:
        raise top.fail("fallback_policy", fallback, "a policy other than `policy`")
    safety = _safety(top.section("safety", ("workspace", "max_tcp_speed", "joint_margin", "duration_s")))
    assert policy is not None
    return RunConfig(path, robot, camera, task, (target[0], target[1], target[2]), policy, fallback, safety)


def _robot(s: _Section) -> RobotConfig:
    driver = s.choice("driver", tuple(DRIVERS))
    arm = s.choice("arm", tuple(DRIVERS.values()))
    if DRIVERS[driver] != arm:
        raise s.fail("arm", arm, f"{DRIVERS[driver]!r}: the {driver} driver streams to the {DRIVERS[driver]}")
    if driver == "egm":
        if s.has("host"):
            raise s.fail("host", s.raw("host"), "no host for egm: the controller sends to robot.port on this "
                         "machine (configure its UCdevice with this machine's address)")
        if s.has("script_port"):
            raise s.fail("script_port", s.raw("script_port"), "no script_port for egm (rtde only)")
        port = s.integer("port", 6510, 1, 65535)
        host = None
    else:
        host = s.text("host")
        port = s.integer("port", 30004, 1, 65535)
    script_port = s.integer("script_port", 30002, 1, 65535) if driver == "rtde" else 0
    base = s.vector("base_pose", 6, default=None, what=" (x, y, z in metres, roll, pitch, yaw in degrees)") \
        if s.has("base_pose") else None
    tool = s.vector("tool_offset", 3, default=[0.0, 0.0, 0.0], what=" (x, y, z in metres)")
    assert tool is not None
    return RobotConfig(
        driver, arm, port, host, script_port,
        s.number("connect_timeout_s", 3.0, 0.0, 60.0, low_open=True), base, (tool[0], tool[1], tool[2]),
        s.number("home_tolerance_m", 0.01, 0.0, 0.1, low_open=True),
        s.number("plan_lead_s", 0.08, 0.0, 0.5),
    )  # fmt: skip


def _camera(s: _Section, folder: Path) -> CameraConfig:
    source = s.choice("source", CAMERA_SOURCES)
    for name, wanted in (("device", "device"), ("path", "video"), ("fps", "video")):
        if s.has(name) and source != wanted:
            raise s.fail(name, s.raw(name), f"no camera.{name} with camera.source {source!r} "
                         f"(camera.{name} applies to source {wanted!r})")
    device: int | str | None = None
    if source == "device":
        device = s.raw("device", required=False, default=0)
        index_ok = isinstance(device, int) and not isinstance(device, bool) and device >= 0
        if not (index_ok or isinstance(device, str)):
            raise s.fail("device", device, "a device index (0, 1, ...) or a stream URL")
    video = _path(folder, s, "path") if source == "video" else None
    fps = s.number("fps", low=0.0, low_open=True) if s.has("fps") else None
    segmenter = s.choice("segmenter", SEGMENTERS, default="learned")
    background = None
    if s.has("background"):
        if source == "simulated" or segmenter != "background":
            raise s.fail("background", s.raw("background"), "no background image: it is for the background "
                         "segmenter with a real camera (a simulated one renders its own)")
        background = _path(folder, s, "background")
    elif segmenter == "background" and source != "simulated":
        raise ConfigError(f"{s.source}: missing key {s.key('background')} (an image of the scene without the "
                          "cable, for camera.segmenter 'background'; or use segmenter 'learned')")
    calibration = _path(folder, s, "calibration")
    assert calibration is not None
    return CameraConfig(source, calibration, device, video, fps, segmenter, background)


def _safety(s: _Section) -> SafetyConfig:
    box = s.section("workspace", ("min", "max"))
    lo = box.vector("min", 3, what=" (x, y, z in metres)")
    hi = box.vector("max", 3, what=" (x, y, z in metres)")
    assert lo is not None and hi is not None
    if not all(a < b for a, b in zip(lo, hi, strict=True)):
        raise box.fail("max", list(hi), f"above safety.workspace.min {list(lo)} on every axis")
    return SafetyConfig(
        (lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]),
        s.number("max_tcp_speed", low=0.0, high=5.0, low_open=True),
        s.number("joint_margin", 0.9, 0.0, 1.0, low_open=True),
        s.number("duration_s", low=0.0, high=600.0, low_open=True),
    )  # fmt: skip
