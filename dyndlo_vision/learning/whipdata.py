"""Whip videos with known truth: a gripper whips a cable in front of a static camera, with rests in between.

What a user films and hands to ``dyndlo-vision track``: a static camera at 25-60 fps, a cable held by a
gripper that whips it, lets it hang still, drags it, whirls it so that the tip passes the gripper and the
cable crosses itself, sometimes behind a post or a board that enters and leaves the view. Every factor of a
video is drawn from its seed (:func:`sample_spec`):

* background: a plain wall, a textured one (wood, brick, fabric, noise), or a cluttered one (shelves,
  posters, lines that look like cables, patches in the cable's own colour);
* cable: length, width on the image (1.5-12 px), colour (black, white, grey, saturated colours), stiffness;
* gripper: sphere, block, two fingers or a flange, any colour, as dark as the cable among them, on an arm
  link that leaves the image or alone;
* camera: distance, oblique angles (up to 35 degrees off the plane's normal), field of view, image size;
* light: direction, strength, shadows on the wall, exposure gain, gamma;
* camera effects: motion blur (an exposure of up to 90 % of the frame period, averaged over sub-frames),
  defocus, sensor noise, JPEG compression, then the MP4 encoder's own;
* motion: rests where the cable hangs still, swings, flicks, whirls, drags to a new place;
* occluders: a post in front of the swing, or a board that enters and leaves.

The cable is a planar chain of capsules on hinge joints about the plane's normal: it moves in the plane
``y = 0`` (the plane ``track --plane 0,1,0,0`` names), so a single calibrated camera can place it exactly and
every world error is the tracker's. The wall behind it is a textured MuJoCo box, lit with the cable, so its
shadow falls on it.

Truth is taken at each frame's time stamp, the middle of its exposure (what a camera's time stamp marks): the
tip, the gripper (TCP) and every node in the world and in pixels, whether the tip is in view, and how far the
tip moved on the image during the exposure (its blur).

Seeds: :data:`DEV_SEEDS` for development and tuning; :data:`SEALED_SEEDS` are kept for one final check
(``benchmarks/track_videos.py --sealed``).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["DEV_SEEDS", "SEALED_SEEDS", "Segment", "WhipSpec", "WhipTruth", "sample_spec", "render_video",
           "load_truth", "write_video"]

#: Development seeds: tune and look at these.
DEV_SEEDS = range(0, 100_000)
#: The sealed test range: evaluated once, at the end, and reported beside the development figures.
SEALED_SEEDS = range(900_000, 1_000_000)

#: Physics step (s).
_DT = 0.001

_PALETTE = {
    "black": (0.04, 0.04, 0.05), "dark-grey": (0.18, 0.18, 0.2), "grey": (0.5, 0.5, 0.52),
    "white": (0.92, 0.92, 0.9), "red": (0.8, 0.1, 0.08), "orange": (0.95, 0.45, 0.08),
    "yellow": (0.95, 0.85, 0.15), "green": (0.15, 0.6, 0.2), "blue": (0.12, 0.3, 0.8),
    "brown": (0.45, 0.28, 0.15), "purple": (0.45, 0.2, 0.6),
}


@dataclass(frozen=True)
class Segment:
    """One piece of the gripper's motion program (in the plane, relative to where the piece starts).

    kinds: ``rest`` (hold still), ``swing`` (out along ``angle_deg`` by ``amplitude_m`` and back, ``cycles``
    times), ``flick`` (a fast there-and-back stroke of one cycle, sharper than a swing), ``whirl`` (circles of
    radius ``amplitude_m``: the cable whips round, its tip passes the gripper and it crosses itself), ``drag``
    (a smooth move by ``amplitude_m`` along ``angle_deg`` to a new place).
    """

    kind: str
    duration_s: float
    amplitude_m: float = 0.0
    angle_deg: float = 0.0
    cycles: float = 1.0

    def offset(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        """(K, 2) offset in the plane (x, z) at times ``tau`` (s) since the piece began."""
        s = np.clip(tau / self.duration_s, 0.0, 1.0)
        a = math.radians(self.angle_deg)
        direction = np.array([math.cos(a), math.sin(a)])
        if self.kind == "rest":
            return np.zeros((s.size, 2))
        if self.kind == "drag":
            smooth = s * s * s * (10 - 15 * s + 6 * s * s)  # minimum-jerk
            return self.amplitude_m * smooth[:, None] * direction
        if self.kind in ("swing", "flick"):
            envelope = np.sin(math.pi * s) ** (1 if self.kind == "swing" else 2)
            wave = np.sin(2 * math.pi * self.cycles * s)
            return self.amplitude_m * (envelope * wave)[:, None] * direction
        if self.kind == "whirl":
            envelope = np.sin(math.pi * s) ** 2
            phase = 2 * math.pi * self.cycles * s
            circle = np.column_stack((np.sin(phase), 1.0 - np.cos(phase)))  # starts at the piece's start
            rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
            return self.amplitude_m * envelope[:, None] * (circle @ rot.T)
        raise ValueError(f"unknown motion segment kind {self.kind!r}")

    @property
    def net_m(self) -> NDArray[np.float64]:
        """Where the piece ends, relative to where it starts."""
        return self.offset(np.array([self.duration_s]))[0]


@dataclass(frozen=True)
class WhipSpec:
    """Every factor of one whip video (drawn by :func:`sample_spec`; JSON in ``spec.json``)."""

    seed: int
    fps: float
    width: int
    height: int
    camera_distance_m: float
    camera_yaw_deg: float
    camera_pitch_deg: float
    fovy_deg: float
    look_at_m: tuple[float, float, float]
    wall_kind: str
    wall_distance_m: float
    wall_rgb: tuple[float, float, float]
    cable_length_m: float
    cable_radius_m: float
    cable_segments: int
    cable_rgb: tuple[float, float, float]
    cable_colour: str
    cable_specular: float
    cable_stiffness: float
    cable_damping: float
    gripper_shape: str
    gripper_size_m: float
    gripper_rgb: tuple[float, float, float]
    arm: bool
    home_m: tuple[float, float]
    light_dir: tuple[float, float, float]
    light_diffuse: float
    ambient: float
    shadows: bool
    exposure_fraction: float
    gain: float
    gamma: float
    noise_sigma: float
    defocus_px: float
    jpeg_quality: int
    occluder: str
    occluder_x_m: float
    occluder_width_m: float
    occluder_rgb: tuple[float, float, float]
    occluder_window_s: tuple[float, float]
    motion: tuple[Segment, ...] = field(default_factory=tuple)

    @property
    def duration_s(self) -> float:
        return float(sum(s.duration_s for s in self.motion))

    @property
    def blurred(self) -> bool:
        """Whether frames average several instants (motion blur)."""
        return self.exposure_fraction > 0

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["motion"] = [asdict(s) for s in self.motion]
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> WhipSpec:
        d = dict(d)
        d["motion"] = tuple(Segment(**s) for s in d["motion"])
        for k, v in list(d.items()):
            if isinstance(v, list):
                d[k] = tuple(v)
        return cls(**d)


def _choice(rng: np.random.Generator, options: list[Any], p: list[float] | None = None) -> Any:
    return options[int(rng.choice(len(options), p=p))]


def _motion(rng: np.random.Generator, duration_s: float, length_m: float) -> tuple[Segment, ...]:
    """Rests and whips in turn, starting and ending at rest, summing to ``duration_s``."""
    pieces: list[Segment] = [Segment("rest", float(rng.uniform(0.4, 1.0)))]
    offset = np.zeros(2)
    total = pieces[0].duration_s
    while total < duration_s - 0.6:
        kind = _choice(rng, ["swing", "flick", "whirl", "drag"], [0.35, 0.3, 0.2, 0.15])
        scale = math.sqrt(length_m / 0.5)
        if kind == "swing":
            seg = Segment("swing", float(rng.uniform(0.5, 1.4)) * scale, float(rng.uniform(0.06, 0.25)),
                          float(rng.uniform(-30, 30) + _choice(rng, [0.0, 180.0])), float(rng.integers(1, 3)))
        elif kind == "flick":
            seg = Segment("flick", float(rng.uniform(0.25, 0.6)), float(rng.uniform(0.05, 0.2)),
                          float(rng.uniform(0, 360)), 1.0)
        elif kind == "whirl":
            seg = Segment("whirl", float(rng.uniform(0.8, 1.8)), float(rng.uniform(0.04, 0.12)),
                          float(rng.uniform(0, 360)), float(rng.integers(2, 5)))
        else:
            seg = Segment("drag", float(rng.uniform(0.6, 1.2)), float(rng.uniform(0.05, 0.2)),
                          float(rng.uniform(0, 360)))
        end = offset + seg.net_m
        if np.any(np.abs(end) > (0.25, 0.15)):  # keep the gripper near home: drag back instead
            seg = Segment("drag", float(rng.uniform(0.6, 1.0)), float(np.linalg.norm(offset)),
                          math.degrees(math.atan2(-offset[1], -offset[0])))
            end = offset + seg.net_m
        pieces.append(seg)
        offset = end
        total += seg.duration_s
        rest = Segment("rest", float(rng.uniform(0.4, 1.5)))  # the cable hangs (nearly) still
        pieces.append(rest)
        total += rest.duration_s
    return tuple(pieces)


def sample_spec(seed: int, duration_s: float = 6.0) -> WhipSpec:
    """The factors of video ``seed`` (deterministic)."""
    rng = np.random.default_rng([seed, 7349])
    fps = float(_choice(rng, [25.0, 30.0, 50.0, 60.0], [0.35, 0.3, 0.15, 0.2]))
    width, height = _choice(rng, [(640, 480), (800, 600), (960, 540)], [0.6, 0.2, 0.2])
    length = float(rng.uniform(0.3, 0.9))
    home = (float(rng.uniform(-0.1, 0.1)), float(0.55 + length * rng.uniform(0.55, 0.8)))
    fovy = float(rng.uniform(38, 62))
    # The camera frames the gripper's reach and the hanging cable: the view's half-height on the plane covers
    # most of the swing (a whipped tip may leave the image: users' videos do that too).
    half_h = float(rng.uniform(0.55, 0.85)) * (length + 0.25)
    distance = half_h / math.tan(math.radians(fovy / 2))
    look_at = (home[0] + float(rng.uniform(-0.05, 0.05)), 0.0, home[1] - 0.55 * length)
    cable_colour = _choice(rng, list(_PALETTE))
    shade = rng.uniform(0.85, 1.1)
    cable_rgb = tuple(float(c) for c in np.clip(np.array(_PALETTE[cable_colour]) * shade, 0, 1))
    f_px = 0.5 * height / math.tan(math.radians(fovy / 2))
    width_px = float(np.exp(rng.uniform(math.log(1.5), math.log(12.0))))
    radius = width_px * distance / (2 * f_px)
    gripper_colour = _choice(
        rng, ["same-as-cable", "black", "dark-grey", "grey", "white", "orange", "blue", "metal"]
    )
    gripper_rgb = (
        cable_rgb
        if gripper_colour == "same-as-cable"
        else (0.6, 0.62, 0.65)
        if gripper_colour == "metal"
        else _PALETTE[gripper_colour]
    )
    wall_kind = _choice(rng, ["plain", "textured", "cluttered"], [0.3, 0.35, 0.35])
    wall_rgb = tuple(float(c) for c in rng.uniform(0.25, 0.9, 3))
    if rng.random() < 0.15:  # a wall in the cable's own colour
        wall_rgb = tuple(float(min(1.0, c * rng.uniform(0.9, 1.3) + 0.05)) for c in cable_rgb)
    exposure = 0.0 if rng.random() < 0.4 else float(rng.uniform(0.2, 0.9))
    occluder = _choice(rng, ["none", "post", "board"], [0.5, 0.3, 0.2])
    motion = _motion(rng, duration_s, length)
    total = sum(s.duration_s for s in motion)
    t_in = float(rng.uniform(0.1, 0.5)) * total
    light = rng.normal(size=3)
    light[1] = abs(light[1]) + 0.5  # from the camera's side towards the wall
    light[2] = -abs(light[2]) - 0.3  # from above
    light /= np.linalg.norm(light)
    return WhipSpec(
        seed=int(seed),
        fps=fps,
        width=int(width),
        height=int(height),
        camera_distance_m=float(distance),
        camera_yaw_deg=float(rng.uniform(-35, 35) if rng.random() < 0.6 else rng.uniform(-8, 8)),
        camera_pitch_deg=float(rng.uniform(-20, 20) if rng.random() < 0.5 else rng.uniform(-5, 5)),
        fovy_deg=fovy,
        look_at_m=look_at,
        wall_kind=wall_kind,
        wall_distance_m=float(rng.uniform(0.25, 1.2)),
        wall_rgb=wall_rgb,
        cable_length_m=length,
        cable_radius_m=float(radius),
        cable_segments=int(rng.integers(16, 31)),
        cable_rgb=cable_rgb,
        cable_colour=cable_colour,
        cable_specular=float(rng.uniform(0.0, 0.8)),
        cable_stiffness=float(np.exp(rng.uniform(-1.5, 1.5))),
        cable_damping=float(np.exp(rng.uniform(math.log(0.004), math.log(0.04)))),
        gripper_shape=_choice(rng, ["sphere", "block", "fingers", "flange"]),
        gripper_size_m=float(rng.uniform(0.02, 0.05)),
        gripper_rgb=tuple(float(c) for c in gripper_rgb),
        arm=bool(rng.random() < 0.5),
        home_m=home,
        light_dir=tuple(float(c) for c in light),
        light_diffuse=float(rng.uniform(0.4, 1.0)),
        ambient=float(rng.uniform(0.15, 0.5)),
        shadows=bool(rng.random() < 0.7),
        exposure_fraction=exposure,
        gain=float(rng.uniform(0.75, 1.3)),
        gamma=float(rng.uniform(0.8, 1.25)),
        noise_sigma=float(rng.uniform(0.0, 6.0)),
        defocus_px=float(0.0 if rng.random() < 0.6 else rng.uniform(0.5, 1.5)),
        jpeg_quality=int(rng.integers(35, 96)),
        occluder=occluder,
        occluder_x_m=float(home[0] + rng.uniform(-0.6, 0.6) * length),
        occluder_width_m=float(rng.uniform(0.02, 0.08) if occluder == "post" else rng.uniform(0.1, 0.25)),
        occluder_rgb=tuple(float(c) for c in rng.uniform(0.1, 0.9, 3)),
        occluder_window_s=(t_in, t_in + float(rng.uniform(0.2, 0.5)) * total),
        motion=motion,
    )


# ------------------------------------------------------------------------------------------- the wall


def _wall_texture(spec: WhipSpec, rng: np.random.Generator, size: int = 1024) -> NDArray[np.uint8]:
    """The wall's texture image (RGB uint8), of ``spec.wall_kind``."""
    base = np.array(spec.wall_rgb, dtype=np.float32) * 255
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    img = np.empty((size, size, 3), np.float32)
    img[:] = base
    img *= (1.0 - 0.15 * yy / size)[..., None]  # a soft gradient, as light falls off
    if spec.wall_kind in ("textured", "cluttered"):
        texture = _choice(rng, ["wood", "brick", "fabric", "noise"])
        if texture == "wood":
            grain = 0.5 + 0.5 * np.sin(
                xx / rng.uniform(3, 9) + rng.uniform(2, 5) * np.sin(yy / rng.uniform(30, 90))
            )
            planks = ((xx // rng.uniform(90, 200)) % 2).astype(np.float32)
            img *= (0.75 + 0.25 * grain + 0.08 * planks)[..., None]
        elif texture == "brick":
            bh, bw = rng.uniform(30, 60), rng.uniform(70, 140)
            row = (yy // bh).astype(int)
            shifted = xx + (row % 2) * bw / 2
            mortar = (np.mod(yy, bh) < 4) | (np.mod(shifted, bw) < 4)
            tint = rng.uniform(0.85, 1.1, (int(size / bh) + 2, int(size / bw) + 3)).astype(np.float32)
            img *= tint[row, (shifted // bw).astype(int)][..., None]
            img[mortar] = 0.5 * img[mortar] + 0.5 * 200
        elif texture == "fabric":
            weave = (
                0.5 + 0.25 * np.sin(xx * rng.uniform(0.8, 1.6)) + 0.25 * np.sin(yy * rng.uniform(0.8, 1.6))
            )
            img *= (0.8 + 0.25 * weave)[..., None]
        else:
            noise = cv2.resize(
                rng.uniform(0.7, 1.2, (size // 16, size // 16)).astype(np.float32),
                (size, size),
                interpolation=cv2.INTER_CUBIC,
            )
            img *= noise[..., None]
    if spec.wall_kind == "cluttered":
        for _ in range(int(rng.integers(8, 30))):
            colour = (
                rng.uniform(0, 255, 3) if rng.random() < 0.8 else np.array(spec.cable_rgb) * 255
            ).tolist()
            x0, y0 = (float(v) for v in rng.uniform(0, size, 2))
            shape = _choice(rng, ["rect", "circle", "line", "shelf", "poster"])
            if shape == "rect":
                w, h = rng.uniform(20, 200, 2)
                cv2.rectangle(img, (int(x0), int(y0)), (int(x0 + w), int(y0 + h)), colour, -1)
            elif shape == "circle":
                cv2.circle(img, (int(x0), int(y0)), int(rng.uniform(8, 80)), colour, -1, cv2.LINE_AA)
            elif shape == "line":  # a thin curve: a cable-like distractor on the wall
                pts = np.cumsum(rng.normal(0, 25, (8, 2)), axis=0) + (x0, y0)
                cv2.polylines(
                    img, [pts.astype(np.int32)], False, colour, int(rng.integers(1, 6)), cv2.LINE_AA
                )
            elif shape == "shelf":
                cv2.rectangle(img, (0, int(y0)), (size, int(y0 + rng.uniform(6, 20))), colour, -1)
            else:
                w, h = rng.uniform(80, 260), rng.uniform(100, 300)
                poster = rng.uniform(0, 255, (4, 4, 3)).astype(np.float32)
                patch = cv2.resize(poster, (int(w), int(h)), interpolation=cv2.INTER_NEAREST)
                ys, xs = int(y0), int(x0)
                ph, pw = img[ys : ys + patch.shape[0], xs : xs + patch.shape[1]].shape[:2]
                img[ys : ys + ph, xs : xs + pw] = patch[:ph, :pw]
    return np.clip(img, 0, 255).astype(np.uint8)


# ------------------------------------------------------------------------------------------- the scene


def _fmt(v: Any) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.ravel(v))


def _camera_pose(spec: WhipSpec) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Camera position and MuJoCo ``xyaxes`` (looking at ``look_at`` from the -y side, yawed and pitched)."""
    yaw, pitch = math.radians(spec.camera_yaw_deg), math.radians(spec.camera_pitch_deg)
    forward = np.array([math.sin(yaw) * math.cos(pitch), math.cos(yaw) * math.cos(pitch), math.sin(pitch)])
    target = np.array(spec.look_at_m)
    pos = target - spec.camera_distance_m * forward
    x_axis = np.cross(forward, [0.0, 0.0, 1.0])
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(x_axis, forward)
    return pos, np.concatenate([x_axis, y_axis])


def _gripper_geoms(spec: WhipSpec) -> str:
    s = spec.gripper_size_m
    common = 'material="gripper" contype="0" conaffinity="0" group="0"'
    if spec.gripper_shape == "sphere":
        geoms = f'<geom name="grip_0" type="sphere" size="{s:.5g}" {common}/>'
    elif spec.gripper_shape == "block":
        size = _fmt([s, s * 0.8, s * 1.2])
        geoms = f'<geom name="grip_0" type="box" size="{size}" pos="0 0 {s * 0.6:.5g}" {common}/>'
    elif spec.gripper_shape == "fingers":
        geoms = (
            f'<geom name="grip_0" type="box" size="{_fmt([s * 1.3, s * 0.7, s * 0.5])}" pos="0 0 {s:.5g}" '
            f"{common}/>"
            f'<geom name="grip_1" type="box" size="{_fmt([s * 0.25, s * 0.5, s * 0.9])}" '
            f'pos="{_fmt([-s * 0.6, 0, 0])}" {common}/>'
            f'<geom name="grip_2" type="box" size="{_fmt([s * 0.25, s * 0.5, s * 0.9])}" '
            f'pos="{_fmt([s * 0.6, 0, 0])}" {common}/>'
        )
    else:  # a flange: a short thick cylinder across the view
        geoms = (
            f'<geom name="grip_0" type="cylinder" size="{_fmt([s * 1.1, s * 0.5])}" pos="0 0 {s * 0.5:.5g}" '
            f"{common}/>"
        )
    if spec.arm:
        geoms += (
            f'<geom name="grip_arm" type="capsule" fromto="0 0 {s:.5g} {_fmt([0.25, 0.05, 1.2])}" '
            f'size="{s * 0.9:.5g}" {common}/>'
        )
    return geoms


def _chain(spec: WhipSpec) -> tuple[str, float]:
    """MJCF of the planar chain (first capsule rigid with the gripper) and its segment length."""
    n = spec.cable_segments
    seg = spec.cable_length_m / n
    r = spec.cable_radius_m
    # A cable of 5-40 g per metre; bending stiffness about that of a 2-6 mm cable, times the spec's factor.
    mass = 0.02 * spec.cable_length_m / n
    ei = 2e-3 * spec.cable_stiffness * (spec.cable_length_m / 0.5) ** 2
    k = ei / seg
    damping = spec.cable_damping * k + 2e-5
    geom = (
        f'type="capsule" fromto="0 0 0 0 0 {-seg:.6g}" size="{r:.6g}" mass="{mass:.6g}" material="cable" '
        'contype="0" conaffinity="0" group="0"'
    )
    opening, closing = [], []
    for i in range(n):
        pos = f'pos="0 0 {-seg:.6g}"' if i else 'pos="0 0 0"'
        joint = (
            f'<joint name="hinge_{i}" type="hinge" axis="0 1 0" stiffness="{k:.6g}" damping="{damping:.6g}" '
            f'armature="1e-7"/>'
            if i
            else ""
        )
        opening.append(f'<body name="cable_{i}" {pos}>{joint}<geom name="cable_{i}" {geom}/>')
        closing.append("</body>")
    opening.append(f'<body name="tip" pos="0 0 {-seg:.6g}"><site name="tip"/></body>')
    return "".join(opening) + "".join(closing), seg


def build_model(spec: WhipSpec) -> Any:
    """The compiled MuJoCo model of ``spec``'s scene (the wall's texture drawn from its seed)."""
    import mujoco

    rng = np.random.default_rng([spec.seed, 11])
    cam_pos, xyaxes = _camera_pose(spec)
    chain, _ = _chain(spec)
    hx, hz = spec.home_m
    light = np.array(spec.light_dir)
    occ = ""
    if spec.occluder == "post":
        occ = (
            f'<geom name="occ" type="capsule" fromto="{_fmt([spec.occluder_x_m, -0.12, -1])} '
            f'{_fmt([spec.occluder_x_m + 0.1, -0.12, 3])}" size="{spec.occluder_width_m / 2:.5g}" '
            f'rgba="{_fmt((*spec.occluder_rgb, 1))}" contype="0" conaffinity="0" group="0"/>'
        )
    elif spec.occluder == "board":
        occ = (
            f'<body name="board" mocap="true" pos="-9 -0.15 {hz:.4g}"><geom name="occ" type="box" '
            f'size="{_fmt([spec.occluder_width_m / 2, 0.01, 1.5])}" rgba="{_fmt((*spec.occluder_rgb, 1))}" '
            f'contype="0" conaffinity="0" group="0"/></body>'
        )
    xml = f"""<mujoco model="whip">
  <option timestep="{_DT}" integrator="implicitfast" gravity="0 0 -9.81"><flag contact="disable"/></option>
  <asset>
    <material name="cable" rgba="{_fmt((*spec.cable_rgb, 1))}" specular="{spec.cable_specular:.3g}"
              shininess="0.7"/>
    <material name="gripper" rgba="{_fmt((*spec.gripper_rgb, 1))}" specular="0.6" shininess="0.6"/>
  </asset>
  <visual><global offwidth="{spec.width}" offheight="{spec.height}"/><quality shadowsize="1024"/>
    <headlight ambient="{_fmt([spec.ambient] * 3)}" diffuse="0.15 0.15 0.15" specular="0 0 0"/></visual>
  <worldbody>
    <light name="key" directional="true" dir="{_fmt(light)}" diffuse="{_fmt([spec.light_diffuse] * 3)}"
           specular="0.3 0.3 0.3" castshadow="{"true" if spec.shadows else "false"}"/>
    <camera name="cam" pos="{_fmt(cam_pos)}" xyaxes="{_fmt(xyaxes)}" fovy="{spec.fovy_deg:.6g}"/>
    <geom name="wall" type="box" size="4 0.01 3" pos="0 {spec.wall_distance_m:.4g} 0.6" material="wall"
          contype="0" conaffinity="0"/>
    {occ}
    <body name="gripper" pos="{hx:.6g} 0 {hz:.6g}">
      <joint name="gx" type="slide" axis="1 0 0"/>
      <joint name="gz" type="slide" axis="0 0 1"/>
      <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
      {_gripper_geoms(spec)}
      {chain}
    </body>
  </worldbody>
  <actuator>
    <general name="ax" joint="gx" gainprm="400" biastype="affine" biasprm="0 -24000 -400"/>
    <general name="az" joint="gz" gainprm="400" biastype="affine" biasprm="0 -24000 -400"/>
  </actuator>
</mujoco>"""
    mspec = mujoco.MjSpec.from_string(xml)
    tex_img = _wall_texture(spec, rng)
    tex = mspec.add_texture(
        name="wall",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        width=tex_img.shape[1],
        height=tex_img.shape[0],
        nchannel=3,
    )
    tex.data = np.ascontiguousarray(tex_img[::-1]).tobytes()
    mat = mspec.add_material(name="wall")
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "wall"
    mat.specular = 0.1
    return mspec.compile()  # names resolve on compile: the wall's material may be added after the XML


# ------------------------------------------------------------------------------------------- rendering


@dataclass(frozen=True)
class WhipTruth:
    """Per-frame truth of a whip video (``truth.npz``), at each frame's time stamp (mid-exposure).

    Attributes:
        t: (F,) frame times (s): frame k at k / fps.
        tip, tcp: (F, 3) world positions (m) of the free tip and the held end (the gripper's TCP).
        nodes: (F, N+1, 3) the cable's nodes from the held end to the tip.
        tip_uv, tcp_uv: (F, 2) their pixels.
        tip_in_view: (F,) the tip's pixel lies in the image and the tip is not hidden behind an occluder.
        blur_px: (F,) how far the tip's pixel moved during the exposure (0 without motion blur).
        cable_mask: (F, H, W) bool: the cable's pixels at the time stamp (where no occluder hides it).
    """

    t: NDArray[np.float64]
    tip: NDArray[np.float64]
    tcp: NDArray[np.float64]
    nodes: NDArray[np.float64]
    tip_uv: NDArray[np.float64]
    tcp_uv: NDArray[np.float64]
    tip_in_view: NDArray[np.bool_]
    blur_px: NDArray[np.float64]
    cable_mask: NDArray[np.bool_] | None = None


def _reference_position(spec: WhipSpec, t: NDArray[np.float64]) -> NDArray[np.float64]:
    """The gripper's reference offset from home (K, 2) in the plane (x, z) at times ``t``."""
    pos = np.zeros((t.size, 2))
    start, base = 0.0, np.zeros(2)
    for seg in spec.motion:
        inside = (t >= start) & (t < start + seg.duration_s)
        pos[inside] = base + seg.offset(t[inside] - start)
        base = base + seg.net_m
        start += seg.duration_s
    pos[t >= start] = base
    return pos


def _reference(spec: WhipSpec, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The gripper's reference offset from home and its velocity (central difference) at time ``t``."""
    eps = 1e-4
    p = _reference_position(spec, np.array([t - eps, t, t + eps]))
    return p[1], (p[2] - p[0]) / (2 * eps)


class _Sim:
    """The scene stepped along the motion program (settled first, hanging at home)."""

    def __init__(self, spec: WhipSpec) -> None:
        import mujoco

        self.mj = mujoco
        self.spec = spec
        self.model = build_model(spec)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.cable_bodies = [m.body(f"cable_{i}").id for i in range(spec.cable_segments)] + [m.body("tip").id]
        self.board = m.body("board").mocapid[0] if spec.occluder == "board" else -1
        # Settle: the cable hangs still before the video starts.
        for _ in range(int(2.0 / _DT)):
            self._control(0.0)
            mujoco.mj_step(m, self.data)
        self.t0 = float(self.data.time)

    @property
    def t(self) -> float:
        return float(self.data.time) - self.t0

    def _control(self, t: float) -> None:
        p, v = (np.zeros(2), np.zeros(2)) if t <= 0 else _reference(self.spec, t)
        # u = v_ref + kp * p_ref: the joints measure the displacement from the gripper's home position.
        self.data.ctrl[:] = v + 60.0 * p
        if self.board >= 0:
            t_in, t_out = self.spec.occluder_window_s
            # The board slides in from the left, stands in front of the cable, and slides out to the right.
            span = 0.35
            x_stop = self.spec.occluder_x_m
            if t < t_in:
                x = x_stop - 3.0
            elif t < t_in + span:
                x = x_stop - 3.0 * (1 - (t - t_in) / span)
            elif t < t_out:
                x = x_stop
            elif t < t_out + span:
                x = x_stop + 3.0 * (t - t_out) / span
            else:
                x = x_stop + 3.0
            self.data.mocap_pos[self.board] = (x, -0.15, self.spec.home_m[1])

    def step_to(self, t: float) -> None:
        while self.t < t - 1e-9:
            self._control(self.t)
            self.mj.mj_step(self.model, self.data)

    def save(self) -> NDArray[np.float64]:
        state = np.empty(self.mj.mj_stateSize(self.model, self.mj.mjtState.mjSTATE_INTEGRATION))
        self.mj.mj_getState(self.model, self.data, state, self.mj.mjtState.mjSTATE_INTEGRATION)
        return state

    def restore(self, state: NDArray[np.float64]) -> None:
        self.mj.mj_setState(self.model, self.data, state, self.mj.mjtState.mjSTATE_INTEGRATION)
        self.mj.mj_forward(self.model, self.data)

    def nodes(self) -> NDArray[np.float64]:
        """The cable's nodes, held end to tip (the xpos after the last step's forward pass)."""
        return self.data.xpos[self.cable_bodies].copy()

    def tcp(self) -> NDArray[np.float64]:
        return self.data.xpos[self.model.body("gripper").id].copy()


def _camera_effects(spec: WhipSpec, img: NDArray[np.float32], rng: np.random.Generator) -> NDArray[np.uint8]:
    if spec.defocus_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), spec.defocus_px)
    img = 255.0 * np.power(np.clip(img * spec.gain / 255.0, 0, 1), spec.gamma)
    if spec.noise_sigma > 0:
        img = img + rng.normal(0, spec.noise_sigma, img.shape).astype(np.float32)
    out = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, spec.jpeg_quality])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy() if ok else out


def render_video(
    spec: WhipSpec, max_frames: int | None = None
) -> tuple[list[NDArray[np.uint8]], WhipTruth, Any]:
    """Simulates and renders ``spec``: the frames (RGB uint8), their truth, and the camera's
    :class:`~dyndlo_vision.tracking.camera_model.PinholeCamera`."""
    import mujoco

    from dyndlo_vision.tracking.camera_model import PinholeCamera

    sim = _Sim(spec)
    m, d = sim.model, sim.data
    renderer = mujoco.Renderer(m, spec.height, spec.width)
    seg_renderer = mujoco.Renderer(m, spec.height, spec.width)
    seg_renderer.enable_segmentation_rendering()
    cam_id = m.camera("cam").id
    mujoco.mj_forward(m, d)
    calib = PinholeCamera.from_mujoco(
        spec.fovy_deg, spec.width, spec.height, d.cam_xpos[cam_id], d.cam_xmat[cam_id], fps=spec.fps
    )
    rng = np.random.default_rng([spec.seed, 23])
    period = 1.0 / spec.fps
    exposure = spec.exposure_fraction * period
    n_frames = int(math.floor(spec.duration_s * spec.fps))
    if max_frames is not None:
        n_frames = min(n_frames, max_frames)
    occ_geoms = {m.geom(i).id for i in range(m.ngeom) if m.geom(i).name == "occ"}
    cable_geoms = np.array([m.geom(f"cable_{i}").id for i in range(spec.cable_segments)])
    frames, rows = [], []
    for k in range(n_frames):
        t_mid = k * period
        times, blur = [t_mid], 0.0
        if exposure > 0:
            # The tip's path on the image during the exposure, every physics step, sets how many instants the
            # frame averages: about one per 3 px of travel (odd, so that the middle one is the time stamp), so
            # a fast tip leaves a continuous smear rather than separate copies.
            sim.step_to(max(0.0, t_mid - exposure / 2))
            state = sim.save()
            path = [calib.project(sim.nodes()[-1][None])[0]]
            while sim.t < t_mid + exposure / 2 - 1e-9:
                sim.step_to(sim.t + _DT)
                path.append(calib.project(sim.nodes()[-1][None])[0])
            sim.restore(state)
            blur = float(np.linalg.norm(np.diff(np.array(path), axis=0), axis=1).sum())
            n = int(np.clip(math.ceil(blur / 3.0), 3, 15)) | 1
            times = list(np.linspace(t_mid - exposure / 2, t_mid + exposure / 2, n))
        acc = np.zeros((spec.height, spec.width, 3), np.float32)
        truth_row = None
        for j, t in enumerate(times):
            sim.step_to(max(0.0, t))
            mujoco.mj_forward(m, d)
            renderer.update_scene(d, camera=cam_id)
            acc += renderer.render()
            if j == len(times) // 2:
                truth_row = _truth_row(sim, calib, seg_renderer, cam_id, spec, occ_geoms, cable_geoms, t_mid)
        rows.append((*truth_row[:7], blur, truth_row[7]))
        frames.append(_camera_effects(spec, acc / len(times), rng))
    renderer.close()
    seg_renderer.close()
    truth = WhipTruth(
        t=np.array([r[0] for r in rows]),
        tip=np.array([r[1] for r in rows]),
        tcp=np.array([r[2] for r in rows]),
        nodes=np.array([r[3] for r in rows]),
        tip_uv=np.array([r[4] for r in rows]),
        tcp_uv=np.array([r[5] for r in rows]),
        tip_in_view=np.array([r[6] for r in rows], dtype=bool),
        blur_px=np.array([r[7] for r in rows]),
        cable_mask=np.array([r[8] for r in rows], dtype=bool),
    )
    return frames, truth, calib


def _truth_row(
    sim: _Sim,
    calib: Any,
    seg_renderer: Any,
    cam_id: int,
    spec: WhipSpec,
    occ_geoms: set[int],
    cable_geoms: NDArray[np.int64],
    t: float,
) -> tuple[Any, ...]:
    import mujoco

    nodes = sim.nodes()
    tcp = sim.tcp()
    tip_uv = calib.project(nodes[-1][None])[0]
    tcp_uv = calib.project(tcp[None])[0]
    in_image = bool(0 <= tip_uv[0] <= spec.width - 1 and 0 <= tip_uv[1] <= spec.height - 1)
    seg_renderer.update_scene(sim.data, camera=cam_id)
    seg = seg_renderer.render()
    is_geom = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
    cable = is_geom & np.isin(seg[..., 0], cable_geoms)
    visible = in_image
    if in_image and occ_geoms:  # hidden where an occluder covers the tip's pixel
        u, v = int(round(tip_uv[0])), int(round(tip_uv[1]))
        visible = not (is_geom[v, u] and int(seg[v, u, 0]) in occ_geoms)
    return t, nodes[-1].copy(), tcp, nodes, tip_uv, tcp_uv, visible, cable


# ------------------------------------------------------------------------------------------- files


def write_video(spec: WhipSpec, out_dir: Path, max_frames: int | None = None) -> dict[str, Path]:
    """Renders ``spec`` into ``out_dir``: ``video.mp4``, ``camera.json``, ``tcp.csv`` (``time_s,x,y,z`` at the
    frame times), ``truth.npz`` (:class:`WhipTruth`), ``spec.json``, and ``frame0.png``. Returns their
    paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames, truth, calib = render_video(spec, max_frames)
    paths = {
        name: out_dir / name
        for name in ("video.mp4", "camera.json", "tcp.csv", "truth.npz", "spec.json", "frame0.png")
    }
    writer = cv2.VideoWriter(
        str(paths["video.mp4"]), cv2.VideoWriter.fourcc(*"mp4v"), spec.fps, (spec.width, spec.height)
    )
    if not writer.isOpened():
        raise OSError(f"OpenCV cannot write {paths['video.mp4']}")
    try:
        for rgb in frames:
            writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    cv2.imwrite(str(paths["frame0.png"]), cv2.cvtColor(frames[0], cv2.COLOR_RGB2BGR))
    calib.to_json(paths["camera.json"])
    with open(paths["tcp.csv"], "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "x", "y", "z"])
        for t, p in zip(truth.t, truth.tcp, strict=True):
            w.writerow([f"{t:.6f}", *(f"{c:.6f}" for c in p)])
    arrays = {k: v for k, v in asdict(truth).items() if k != "cable_mask"}
    assert truth.cable_mask is not None
    arrays["cable_mask_bits"] = np.packbits(truth.cable_mask, axis=-1)
    arrays["mask_width"] = np.array(truth.cable_mask.shape[-1])
    np.savez_compressed(paths["truth.npz"], **arrays)
    paths["spec.json"].write_text(json.dumps(spec.to_json(), indent=1))
    return paths


def load_truth(path: Path) -> WhipTruth:
    """A ``truth.npz`` written by :func:`write_video`."""
    with np.load(path) as z:
        fields = {k: z[k] for k in WhipTruth.__dataclass_fields__ if k in z}
        if "cable_mask_bits" in z:
            fields["cable_mask"] = np.unpackbits(
                z["cable_mask_bits"], axis=-1, count=int(z["mask_width"])
            ).astype(bool)
        return WhipTruth(**fields)


# ------------------------------------------------------------------------------------------- scoring

#: A reported tip farther than this from the true tip is wrong (m).
WRONG_M = 0.05
#: A reported tip this close to the gripper (m), while the true tip is at least :data:`FAR_FROM_GRIPPER_M`
#: away from it, is the gripper reported as the tip.
ON_GRIPPER_M = 0.04
FAR_FROM_GRIPPER_M = 0.10
#: A frame whose tip moved farther than this on the image during the exposure is blurred (px).
BLURRED_PX = 3.0


def motion_kind(spec: WhipSpec, t: NDArray[np.float64]) -> NDArray[np.str_]:
    """The motion segment's kind at each time (``rest``, ``swing``, ...), the last one after the program."""
    kinds = np.full(t.shape, spec.motion[-1].kind, dtype=object)
    start = 0.0
    for seg in spec.motion:
        kinds[(t >= start) & (t < start + seg.duration_s)] = seg.kind
        start += seg.duration_s
    return kinds.astype(str)


def score_frames(
    truth: WhipTruth, calib: Any, reported_xyz: NDArray[np.float64], measured: NDArray[np.bool_]
) -> dict[str, NDArray[Any]]:
    """Per-frame scores of a tracked tip against the truth.

    Args:
        truth: The video's truth.
        calib: The camera (to judge pixel errors).
        reported_xyz: (F, 3) the tip the tracker reported for each frame (NaN where none).
        measured: (F,) the tracker's claim that the frame's point is this frame's measurement (or its
            continuation): ``visible=1`` in ``track``'s CSV.

    Returns:
        Arrays of length F: ``err_m`` (world error, NaN where nothing was reported), ``err_px`` (the reported
        point's pixel against the true tip's), ``measured``, ``wrong`` (measured and farther than
        :data:`WRONG_M`), ``gripper`` (measured, on the gripper, the tip away from it), ``blurred``,
        ``in_view``.
    """
    xyz = np.asarray(reported_xyz, dtype=np.float64).reshape(-1, 3)
    measured = np.asarray(measured, dtype=bool)
    finite = np.all(np.isfinite(xyz), axis=1)
    err = np.full(len(xyz), np.nan)
    err[finite] = np.linalg.norm(xyz[finite] - truth.tip[finite], axis=1)
    err_px = np.full(len(xyz), np.nan)
    if finite.any():
        err_px[finite] = np.linalg.norm(calib.project(xyz[finite]) - truth.tip_uv[finite], axis=1)
    to_gripper = np.full(len(xyz), np.inf)
    to_gripper[finite] = np.linalg.norm(xyz[finite] - truth.tcp[finite], axis=1)
    tip_far = np.linalg.norm(truth.tip - truth.tcp, axis=1) >= FAR_FROM_GRIPPER_M
    ok = measured & finite
    return {
        "err_m": err,
        "err_px": err_px,
        "measured": ok,
        "wrong": ok & (err > WRONG_M),
        "gripper": ok & (to_gripper < ON_GRIPPER_M) & tip_far,
        "blurred": truth.blur_px > BLURRED_PX,
        "in_view": truth.tip_in_view.copy(),
    }


def summarise(frames: dict[str, NDArray[Any]]) -> dict[str, float | int | None]:
    """Pooled figures of :func:`score_frames` arrays (concatenated over videos)."""
    measured, blurred = frames["measured"], frames["blurred"]

    def median_mm(sel: NDArray[np.bool_]) -> float | None:
        return round(1e3 * float(np.median(frames["err_m"][sel])), 1) if sel.any() else None

    def p90_mm(sel: NDArray[np.bool_]) -> float | None:
        return round(1e3 * float(np.percentile(frames["err_m"][sel], 90)), 1) if sel.any() else None

    n = int(measured.size)
    in_view = frames["in_view"]
    return {
        "frames": n,
        "measured_share": round(float(measured.mean()), 4) if n else None,
        "measured_share_tip_in_view": round(float(measured[in_view].mean()), 4) if in_view.any() else None,
        "wrong_frames": int(frames["wrong"].sum()),
        "wrong_share": round(float(frames["wrong"].mean()), 4) if n else None,
        "gripper_frames": int(frames["gripper"].sum()),
        "median_mm_sharp": median_mm(measured & ~blurred),
        "median_mm_blurred": median_mm(measured & blurred),
        "p90_mm_sharp": p90_mm(measured & ~blurred),
        "p90_mm_blurred": p90_mm(measured & blurred),
        "median_px_measured": (
            round(float(np.median(frames["err_px"][measured])), 2) if measured.any() else None
        ),
    }
