"""Domain-randomised image/mask pairs of cables rendered from our own MuJoCo scenes (labels for free).

Each *scene group* builds one :class:`dyndlo_vision.sim.Scene` with a random cable (length, segments, radius),
a random initial path, random props (boxes and capsule bars near the cable) and a gripper of random size and
colour, lets it settle for a random (often too short) time and then moves the gripper at random between
samples, so the cable is caught hanging, swinging and whipping. Every sample of a group draws its own:

* camera pose (look-at from a random direction, distance and field of view) so the cable is 1-12 px wide,
* cable colour (saturated colours, black, white, greys, browns) and rendered radius,
* lighting (key light position and strength, head light ambient/diffuse),
* background: the rendered floor, or a procedural texture (value noise, stripes, checkers, wood grain,
  clutter of shapes, plain with a gradient) composited behind everything the scene rendered; in a share of
  the textured samples scaled to the cable's brightness, so that only colour sets the cable apart,
* distractors drawn in 2D: gripper-like blobs, boxes, bars, extra cables (these are labelled: a real photo's
  mask holds every cable), occluders in front of the cable (its label is removed under them),
* camera effects: motion blur, defocus, colour gains and gamma, Gaussian noise, JPEG compression.

The label is MuJoCo's segmentation render of the cable flex (plus the drawn cables), rendered at twice the
output size and area-averaged, so the image is anti-aliased like a photo. Everything a sample is made of
is drawn from ``numpy.random.default_rng((seed, group))``: a dataset is reproducible, and generation resumes
by regenerating the group of the first missing sample.

That is the ``random-scenes`` style (:class:`SceneSampler`). The ``task-scenes`` style
(:class:`TaskSceneSampler`) renders the control loop's own scenes instead, through their loop cameras, with
the same labels and camera effects: the data for fine-tuning a network to the scenes it will run in.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.learning.segcomposite import COMPOSITE_STYLES, CompositeSampler, draw_shapes

__all__ = ["DEFAULT_WIDTHS_PX", "MUJOCO_STYLES", "STYLES", "SceneSampler", "SegDataConfig",
           "TaskSceneSampler", "camera_effects", "enlarged", "make_sampler", "procedural_background",
           "sample_path", "write_dataset"]


#: Dataset styles: what :class:`SegDataConfig` renders. The MuJoCo styles (:class:`SceneSampler`,
#: :class:`TaskSceneSampler`) and the 2-D composited scene kinds of
#: :mod:`dyndlo_vision.learning.segcomposite`.
MUJOCO_STYLES = ("random-scenes", "task-scenes")
STYLES = MUJOCO_STYLES + COMPOSITE_STYLES

#: Least and most cable width in output pixels, per kind of style, where ``seg-data`` is not told.
DEFAULT_WIDTHS_PX = {"mujoco": (0.7, 12.0), "composite": (1.0, 40.0)}


@dataclass(frozen=True)
class SegDataConfig:
    """What a dataset is made of (stored in its ``dataset.json``)."""

    width: int = 320
    height: int = 240
    samples_per_scene: int = 4
    #: Share of samples whose background is replaced by a procedural texture (the rest keep the floor).
    texture_share: float = 0.8
    #: Least and most cable width in output pixels.
    min_width_px: float = 0.7
    max_width_px: float = 12.0
    #: Share of textured samples whose background is scaled to the cable's brightness (colour-only contrast).
    lum_match_share: float = 0.3
    #: Share of rendered-floor samples whose floor is a neutral grey (the task scenes' look: a grey checker
    #: floor, the black void beyond it); the others get a random colour. 0 draws nothing more (datasets made
    #: before this option are reproduced sample for sample).
    grey_floor_share: float = 0.0
    #: What is rendered (:data:`STYLES`): ``random-scenes``, random cables among random props seen from
    #: random cameras (:class:`SceneSampler`); ``task-scenes``, the control loop's own scenes through their
    #: loop cameras (:class:`TaskSceneSampler`); or one of the composited scene kinds of
    #: :mod:`~dyndlo_vision.learning.segcomposite` (many cables on real-looking surfaces, drawn in 2-D).
    style: str = "random-scenes"
    #: Every image and its label are enlarged this many times (bilinear) after rendering at ``width`` x
    #: ``height`` and the camera effects, as the loop enlarges its frames before its network
    #: (``control.sim_perception.LOOP_NETWORK_SCALE``): the network then trains on what it is given. 1: as
    #: rendered (datasets made before this option).
    upscale: float = 1.0

    def check(self) -> None:
        for name in ("width", "height", "samples_per_scene"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive int, got {v!r}")
        if self.width < 32 or self.height < 32:
            raise ValueError(f"image size must be at least 32x32, got {self.width}x{self.height}")
        for name in ("texture_share", "lum_match_share", "grey_floor_share"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")
        if isinstance(self.upscale, bool) or not isinstance(self.upscale, int | float) or not (
                1.0 <= self.upscale <= 4.0):
            raise ValueError(f"upscale must be a number in [1, 4], got {self.upscale!r}")
        if self.style not in STYLES:
            raise ValueError(f"style must be one of {list(STYLES)}, got {self.style!r}")
        if not 0.5 <= self.min_width_px <= self.max_width_px:
            raise ValueError(
                f"cable widths must satisfy 0.5 <= min_width_px <= max_width_px, got "
                f"{self.min_width_px!r}, {self.max_width_px!r}"
            )


# ----------------------------------------------------------------------------- 2D pieces (pure numpy/cv2)
def _value_noise(rng: np.random.Generator, h: int, w: int, octaves: int = 4) -> NDArray[np.float32]:
    """Multi-octave value noise in [0, 1]."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    cells = int(rng.integers(2, 6))
    for _ in range(octaves):
        small = rng.random((cells, cells)).astype(np.float32)
        out += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= float(rng.uniform(0.35, 0.65))
        cells *= 2
    out /= total
    lo, hi = float(out.min()), float(out.max())
    return (out - lo) / max(hi - lo, 1e-6)


def _luminance(rgb: NDArray[np.floating]) -> NDArray[np.floating]:
    """Rec. 601 luma of RGB values (last axis)."""
    return np.asarray(rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114)


def _random_colour(rng: np.random.Generator) -> NDArray[np.float32]:
    return rng.uniform(0, 255, 3).astype(np.float32)


def _splatter(rng: np.random.Generator, img: NDArray[np.float32]) -> None:
    """Paint drips and splashes: thin strokes of varying width, jagged turns and dots (not cables: a cable
    keeps its width and bends smoothly)."""
    h, w = img.shape[:2]
    palette = [_random_colour(rng) for _ in range(int(rng.integers(2, 6)))]
    for _ in range(int(rng.integers(30, 250))):
        col = tuple(float(c) for c in palette[int(rng.integers(len(palette)))])
        p = np.array([rng.uniform(0, w), rng.uniform(0, h)])
        heading = float(rng.uniform(0, 2 * math.pi))
        for _ in range(int(rng.integers(1, 25))):
            heading += float(rng.normal(0, 0.7))
            q = p + float(rng.uniform(1, 8)) * np.array([math.cos(heading), math.sin(heading)])
            th = int(rng.integers(1, 5))
            cv2.line(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), col, th, cv2.LINE_AA)
            if rng.random() < 0.15:
                cv2.circle(img, (int(q[0]), int(q[1])), int(rng.integers(1, 5)), col, -1, cv2.LINE_AA)
            p = q


def procedural_background(rng: np.random.Generator, h: int, w: int) -> NDArray[np.uint8]:
    """A random textured or cluttered background (H, W, 3) uint8 RGB."""
    kind = rng.choice(
        ["plain", "noise", "stripes", "checker", "wood", "clutter", "splatter"],
        p=[0.1, 0.16, 0.12, 0.1, 0.14, 0.2, 0.18],
    )
    c1, c2 = _random_colour(rng), _random_colour(rng)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    ang = float(rng.uniform(0, math.pi))
    proj = xx * math.cos(ang) + yy * math.sin(ang)
    if kind == "plain":
        t = (proj - proj.min()) / max(float(np.ptp(proj)), 1.0) * float(rng.uniform(0, 0.5))
    elif kind == "noise":
        t = _value_noise(rng, h, w, int(rng.integers(2, 6)))
    elif kind == "stripes":
        period = float(rng.uniform(4, 60))
        t = 0.5 + 0.5 * np.sin(2 * math.pi * proj / period)
        if rng.random() < 0.5:
            t = (t > 0.5).astype(np.float32)
    elif kind == "checker":
        period = float(rng.uniform(6, 80))
        proj2 = -xx * math.sin(ang) + yy * math.cos(ang)
        t = ((np.floor(proj / period) + np.floor(proj2 / period)) % 2).astype(np.float32)
    elif kind == "wood":
        warp = _value_noise(rng, h, w, 3) * float(rng.uniform(10, 60))
        t = 0.5 + 0.5 * np.sin(2 * math.pi * (proj + warp) / float(rng.uniform(5, 30)))
        t = t ** float(rng.uniform(0.5, 2.0))
    else:  # clutter (shapes) or splatter (paint drips) on noise
        t = _value_noise(rng, h, w, 3) * 0.4
    img = c1[None, None, :] * (1 - t[..., None]) + c2[None, None, :] * t[..., None]
    if kind == "clutter" or rng.random() < 0.3:
        draw_shapes(rng, img, int(rng.integers(3, 25)), _random_colour)
    if kind == "splatter" or rng.random() < 0.1:
        _splatter(rng, img)
    img += (
        rng.normal(0, float(rng.uniform(0, 10)), (h, w, 1)).astype(np.float32)
        * _value_noise(rng, h, w, 2)[..., None]
    )
    return np.clip(img, 0, 255).astype(np.uint8)


def sample_path(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float64]:
    """A smooth random pixel curve (K, 2) starting inside the image (for drawn extra cables)."""
    n = int(rng.integers(40, 160))
    step = float(rng.uniform(2.0, 5.0))
    heading = float(rng.uniform(0, 2 * math.pi))
    curv = np.cumsum(rng.normal(0, 0.08, n)) * float(rng.uniform(0.1, 1.0))
    turn = np.convolve(rng.normal(0, 0.15, n) + curv * 0.05, np.ones(7) / 7, mode="same")
    angles = heading + np.cumsum(turn)
    p0 = np.array([rng.uniform(0, w), rng.uniform(0, h)])
    steps = np.column_stack((np.cos(angles), np.sin(angles))) * step
    return p0 + np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])


def _draw_tube(
    img: NDArray[np.float32],
    cover: NDArray[np.uint8],
    pts: NDArray[np.float64],
    width: float,
    colour: NDArray[np.float32],
    rng: np.random.Generator,
) -> None:
    """Draws a shaded tube (dark rim, body, highlight) into ``img`` and its coverage into ``cover``."""
    shift = 4
    p = np.round(pts * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
    th = max(1, int(round(width)))
    layer = np.zeros(cover.shape, np.uint8)
    cv2.polylines(layer, [p], False, 255, th, cv2.LINE_AA, shift)
    a = (layer.astype(np.float32) / 255.0)[..., None]
    body = colour * float(rng.uniform(0.6, 1.0))
    img *= 1 - a
    img += a * body
    if th >= 3 and rng.random() < 0.8:
        hl = np.zeros(cover.shape, np.uint8)
        off = np.array([rng.uniform(-0.25, 0.25) * th] * 2)
        ph = np.round((pts + off) * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(hl, [ph], False, 255, max(1, th // 3), cv2.LINE_AA, shift)
        b = (hl.astype(np.float32) / 255.0)[..., None] * a * float(rng.uniform(0.2, 0.7))
        img *= 1 - b
        img += b * np.minimum(255.0, colour * 0.5 + 160.0)
    np.maximum(cover, layer, out=cover)


def _cable_colour(rng: np.random.Generator) -> NDArray[np.float64]:
    """RGB in [0, 1]: saturated colours, black, white, greys, browns."""
    kind = rng.choice(["hue", "black", "white", "grey", "brown"], p=[0.45, 0.2, 0.12, 0.13, 0.1])
    if kind == "black":
        return np.full(3, rng.uniform(0.02, 0.12)) + rng.uniform(0, 0.03, 3)
    if kind == "white":
        return np.full(3, rng.uniform(0.8, 1.0)) - rng.uniform(0, 0.05, 3)
    if kind == "grey":
        return np.full(3, rng.uniform(0.25, 0.7))
    if kind == "brown":
        return np.array([0.45, 0.3, 0.15]) * rng.uniform(0.5, 1.3)
    hsv = np.uint8([[[rng.integers(0, 180), rng.integers(120, 256), rng.integers(100, 256)]]])
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float64) / 255.0


def _motion_kernel(rng: np.random.Generator) -> NDArray[np.float32] | None:
    length = int(rng.integers(3, 12))
    k = np.zeros((length, length), np.float32)
    ang = float(rng.uniform(0, 180))
    c = (length - 1) / 2.0
    d = np.array([math.cos(math.radians(ang)), math.sin(math.radians(ang))]) * c
    cv2.line(
        k, (int(round(c - d[0])), int(round(c - d[1]))), (int(round(c + d[0])), int(round(c + d[1]))), 1.0, 1
    )
    s = float(k.sum())
    return k / s if s > 0 else None


def camera_effects(
    rng: np.random.Generator, img: NDArray[np.float32], cover_u8: NDArray[np.uint8]
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """A rendered image (float RGB) after random camera effects (motion blur, defocus, colour gains and
    gamma, noise, JPEG), and its label from the cable's coverage ``cover_u8`` (blurred with the image)."""
    cov = cover_u8.astype(np.float32) / 255.0
    if rng.random() < 0.35:
        k = _motion_kernel(rng)
        if k is not None:
            img = cv2.filter2D(img, -1, k)
            cov = cv2.filter2D(cov, -1, k)
    if rng.random() < 0.3:
        sigma = float(rng.uniform(0.3, 1.2))
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    img = img * rng.uniform(0.7, 1.3, 3).astype(np.float32) * float(rng.uniform(0.6, 1.3))
    img = 255.0 * (np.clip(img, 0, 255) / 255.0) ** float(rng.uniform(0.7, 1.4))
    img += rng.normal(0, float(rng.uniform(0, 8)), img.shape).astype(np.float32)
    rgb = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    if rng.random() < 0.7:
        ok, buf = cv2.imencode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(30, 96))])
        rgb = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    # A pixel is cable where it is at least 40 % covered, or, across a line thinner than a pixel (whose
    # coverage is split between neighbours), where it holds at least half of the local peak coverage.
    peak = cv2.dilate(cov, np.ones((3, 3), np.uint8))
    cable = (cov >= np.minimum(0.4, 0.5 * peak)) & (cov >= 0.12)
    return rgb, np.where(cable, 255, 0).astype(np.uint8)


def _render_with_segmentation(renderer: Any, data: Any, camera: int) -> tuple[NDArray[np.float32], Any]:
    """The camera's colour render (float RGB) and its segmentation render (object id, object type)."""
    renderer.update_scene(data, camera=camera)
    rgb = renderer.render().astype(np.float32)
    renderer.enable_segmentation_rendering()
    try:
        renderer.update_scene(data, camera=camera)
        seg = renderer.render()
    finally:
        renderer.disable_segmentation_rendering()
    return rgb, seg


def _look_at_quat(forward: NDArray[np.float64], roll: float) -> NDArray[np.float64]:
    import mujoco

    f = forward / np.linalg.norm(forward)
    up = np.array([0.0, 0.0, 1.0])
    if abs(f @ up) > 0.98:
        up = np.array([0.0, 1.0, 0.0])
    x = np.cross(f, up)
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    mat = np.column_stack((x, y, -f))  # MuJoCo cameras look along their -z axis
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, mat.reshape(-1))
    return q


# ----------------------------------------------------------------------------- MuJoCo scenes
def _build_scene(scene_cls: Any, config_cls: Any, rng: np.random.Generator, kwargs: dict[str, Any]) -> Any:
    """Builds the scene; a draw that does not settle (unstable) is retried with a stiffer, shorter settle."""
    for attempt in range(5):
        try:
            return scene_cls(config_cls(**kwargs))
        except ValueError:
            if attempt == 4:
                raise
            kwargs = {**kwargs, "settle_s": float(rng.uniform(0.02, 0.2))}
    raise AssertionError("unreachable")


class SceneSampler:
    """Renders randomised samples of one scene group (see the module docstring)."""

    def __init__(self, config: SegDataConfig, seed: int, group: int) -> None:
        from dyndlo_vision.sim import BoxProp, CableParams, CapsuleProp, Scene, SceneConfig
        from dyndlo_vision.sim.cable_look import CableLook
        from dyndlo_vision.sim.rendering import make_renderer

        config.check()
        self.config = config
        self.rng = np.random.default_rng((int(seed), int(group)))
        rng = self.rng
        length = float(rng.uniform(0.3, 1.0))
        radius = float(rng.uniform(0.0015, 0.006))
        segments = max(4, min(int(rng.integers(12, 31)), int(length / (2.6 * radius))))
        # The rod, as when the shipped segmenter's data were made (before the chain became the default): the
        # same seeds give the same samples. Only the drawn shape matters here, and both models draw a tube.
        cable = CableParams(
            length_m=length,
            num_segments=segments,
            radius_m=radius,
            young_pa=float(10 ** rng.uniform(5.5, 7.5)),
            model="rod",
        )
        tcp = np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.1, 0.1), rng.uniform(0.5, 1.0)])
        # Random initial path: a random walk from the TCP (the cable settles from there).
        n = 8
        dirs = rng.normal(0, 1, (n, 3)) * np.array([1.0, 0.5, 1.0]) + np.array([0, 0, -rng.uniform(0, 1.5)])
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        path = tcp + np.vstack([np.zeros(3), np.cumsum(dirs * 1.4 * length / n, axis=0)])
        path[:, 2] += max(0.0, 0.05 - float(path[:, 2].min()))  # lift it above the floor
        tcp = path[0]
        centre = path.mean(axis=0)
        boxes = tuple(
            BoxProp(
                f"box{i}",
                tuple(centre + rng.normal(0, 0.25, 3) * [1, 1, 0.5]),
                tuple(rng.uniform(0.02, 0.2, 3)),
                tuple(list(_cable_colour(rng)) + [1.0]),
            )
            for i in range(int(rng.integers(0, 3)))
        )
        capsules = tuple(
            CapsuleProp(
                f"bar{i}",
                tuple(a),
                tuple(a + rng.normal(0, 0.12, 3)),
                float(rng.uniform(0.012, 0.04)),
                tuple(list(_cable_colour(rng)) + [1.0]),
            )
            for i, a in enumerate(centre + rng.normal(0, 0.25, (int(rng.integers(0, 2)), 3)))
        )
        w2, h2 = 2 * config.width, 2 * config.height
        self.scene = _build_scene(
            Scene,
            SceneConfig,
            rng,
            dict(
                cable=cable,
                grippers_m=(tuple(tcp),),
                initial_path_m=tuple(map(tuple, path)),
                settle_s=float(rng.uniform(0.02, 0.6)),
                boxes=boxes,
                capsules=capsules,
                image_size=(w2, h2),
            ),
        )
        m = self.scene.model
        self.cam_id = int(m.camera("tracking").id)
        self.cable_look = CableLook.of(m)
        self.floor_geom = int(m.geom("floor").id)
        self.tcp_geom = int(m.geom("tcp_0_geom").id)
        self.renderer = make_renderer(m, h2, w2)
        self.scene.reset()
        self.scene_lights = (m.light_diffuse[0].copy(), m.light_pos[0].copy(),
                             m.vis.headlight.ambient.copy(), m.vis.headlight.diffuse.copy())

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None

    def _move(self) -> None:
        """Drives the gripper to a random nearby point for a random time (the cable swings)."""
        rng, sc = self.rng, self.scene
        home = sc.gripper_home[0]
        target = home + rng.normal(0, 0.12, 3) * np.array([1.0, 0.6, 0.8])
        vel = rng.normal(0, 1.0, 3)
        sc.set_tcp_reference(target[None, :], vel[None, :])
        sc.step(int(rng.integers(10, 150)))
        if not sc.is_finite():
            sc.reset()

    def sample(self) -> tuple[NDArray[np.uint8], NDArray[np.uint8], dict[str, Any]]:
        """One (RGB (H, W, 3) uint8, mask (H, W) uint8 0/255, metadata) sample."""
        import mujoco

        rng, cfg, m, d = self.rng, self.config, self.scene.model, self.scene.data
        self._move()
        w, h = cfg.width, cfg.height
        width_px, colour, fovy = self._randomise_look()
        mujoco.mj_forward(m, d)
        rgb2, seg = _render_with_segmentation(self.renderer, d, self.cam_id)
        ids, types = seg[..., 0], seg[..., 1]
        cable2 = self.cable_look.mask(seg).astype(np.float32)
        bg2 = (types == -1) | ((types == int(mujoco.mjtObj.mjOBJ_GEOM)) & (ids == self.floor_geom))
        textured = bool(rng.random() < cfg.texture_share)
        lum_matched = False
        if textured:
            bg = procedural_background(rng, h, w).astype(np.float32)
            on_cable = cable2 > 0.5
            if rng.random() < cfg.lum_match_share and on_cable.any():
                # Colour-only contrast: the background as bright as the cable, so that only hue and
                # saturation tell them apart (a red cable on a grey floor of the same brightness).
                cable_lum = float(np.mean(_luminance(rgb2[on_cable])))
                bg *= np.float32(cable_lum / max(float(np.mean(_luminance(bg))), 1.0))
                lum_matched = True
            bg2f = bg2.astype(np.float32)
            bg_big = cv2.resize(bg, (2 * w, 2 * h), interpolation=cv2.INTER_LINEAR)
            rgb2 = rgb2 * (1 - bg2f[..., None]) + bg_big * bg2f[..., None]
        img = cv2.resize(rgb2, (w, h), interpolation=cv2.INTER_AREA)
        cov = cv2.resize(cable2, (w, h), interpolation=cv2.INTER_AREA)
        cover_u8 = np.clip(cov * 255 + 0.5, 0, 255).astype(np.uint8)
        img, n_extra = _draw_distractors(rng, cfg, img, cover_u8)
        rgb, mask = camera_effects(rng, img, cover_u8)
        meta = {
            "width_px": round(width_px, 2),
            "textured": textured,
            "lum_matched": lum_matched,
            "extra_cables": n_extra,
            "colour": [round(float(c), 3) for c in colour],
            "fovy_deg": round(fovy, 1),
        }
        return rgb, mask, meta

    def _randomise_look(self) -> tuple[float, NDArray[np.float64], float]:
        """A random camera pose and field of view on the cable, cable width and colour, gripper, lights and
        floor; returns the cable's width in output pixels, its colour and the field of view (degrees)."""
        rng, cfg, m = self.rng, self.config, self.scene.model
        h = cfg.height
        nodes = self.scene.cable_nodes()
        centre = nodes.mean(axis=0)
        extent = float(np.linalg.norm(np.ptp(nodes, axis=0))) + 0.05
        fovy = float(rng.uniform(30, 70))
        f_px = 0.5 * h / math.tan(math.radians(fovy) / 2)
        cover = float(rng.uniform(0.25, 1.3))
        dist = max(0.15, extent * f_px / (cover * h))
        width_px = float(np.exp(rng.uniform(math.log(cfg.min_width_px), math.log(cfg.max_width_px))))
        radius = width_px * dist / (2 * f_px)
        view = rng.normal(0, 1, 3) * np.array([0.5, 1.0, 0.5]) + np.array([0, -1.5, 0])  # mostly from -y
        view /= np.linalg.norm(view)
        look = centre + rng.normal(0, 0.15, 3) * extent
        m.cam_pos[self.cam_id] = look + view * dist
        m.cam_quat[self.cam_id] = _look_at_quat(-view, float(rng.normal(0, 0.3)))
        m.cam_fovy[self.cam_id] = fovy
        self.cable_look.set_radius(m, radius)
        colour = _cable_colour(rng)
        self.cable_look.set_rgba(m, [*colour, 1.0])
        m.geom_size[self.tcp_geom, 0] = float(rng.uniform(0.3, 2.5)) * max(radius * 4, 0.008)
        grip = _cable_colour(rng) if rng.random() < 0.5 else np.full(3, rng.uniform(0.05, 0.3))
        m.geom_rgba[self.tcp_geom] = [*grip, 1.0]
        m.light_diffuse[0] = rng.uniform(0.1, 1.0, 3) * rng.uniform(0.6, 1.0)
        m.light_pos[0] = centre + rng.normal(0, 1.5, 3) + np.array([0, 0, 1.5])
        m.vis.headlight.ambient[:] = rng.uniform(0.05, 0.6)
        m.vis.headlight.diffuse[:] = rng.uniform(0.1, 0.7)
        m.geom_rgba[self.floor_geom] = [*rng.uniform(0.2, 1.0, 3), 1.0]
        if cfg.grey_floor_share > 0 and rng.random() < cfg.grey_floor_share:
            # The task scenes' look: their own lights (a little brighter or dimmer), a grey checker floor.
            m.geom_rgba[self.floor_geom, :3] = rng.uniform(0.4, 1.0)
            gain = float(rng.uniform(0.8, 1.2))
            m.light_diffuse[0] = self.scene_lights[0] * gain
            m.light_pos[0] = self.scene_lights[1]
            m.vis.headlight.ambient[:] = self.scene_lights[2] * gain
            m.vis.headlight.diffuse[:] = self.scene_lights[3] * gain
        return width_px, colour, fovy


def _draw_distractors(rng: np.random.Generator, cfg: SegDataConfig, img: NDArray[np.float32],
                      cover_u8: NDArray[np.uint8]) -> tuple[NDArray[np.float32], int]:
    """Extra cables, blobs and a pole drawn in 2D on ``img``; what hides the cable is taken out of its cover
    ``cover_u8`` (in place). Returns the image and the number of extra cables."""
    h, w = cover_u8.shape
    n_extra = int(rng.integers(1, 5)) if rng.random() < 0.35 else 0
    for _ in range(n_extra):
        _draw_tube(
            img,
            cover_u8,
            sample_path(rng, h, w),
            float(np.exp(rng.uniform(math.log(cfg.min_width_px), math.log(cfg.max_width_px)))),
            (_cable_colour(rng) * 255).astype(np.float32),
            rng,
        )
    for _ in range(int(rng.integers(0, 4))):  # blobs (grippers, parts), boxes: they hide what is behind
        col = tuple(float(c) for c in (_cable_colour(rng) * 255))
        cx, cy, s = int(rng.integers(0, w)), int(rng.integers(0, h)), int(rng.integers(6, max(8, h // 4)))
        occl = np.zeros((h, w), np.uint8)
        if rng.random() < 0.5:
            cv2.circle(occl, (cx, cy), s // 2, 255, -1, cv2.LINE_AA)
        else:
            cv2.rectangle(occl, (cx - s // 2, cy - s // 3), (cx + s // 2, cy + s // 3), 255, -1)
        a = (occl.astype(np.float32) / 255.0)[..., None]
        img = img * (1 - a) + a * np.asarray(col, np.float32)
        cover_u8[occl >= 128] = 0
    if rng.random() < 0.25:  # an occluder (a pole) in front of everything
        x0 = int(rng.integers(0, w))
        bw = int(rng.integers(6, max(8, w // 8)))
        col = tuple(float(c) for c in (_cable_colour(rng) * 255))
        if rng.random() < 0.5:
            cv2.rectangle(img, (x0, 0), (x0 + bw, h), col, -1)
            cover_u8[:, x0 : x0 + bw + 1] = 0
        else:
            y0 = int(rng.integers(0, h))
            cv2.rectangle(img, (0, y0), (w, y0 + bw), col, -1)
            cover_u8[y0 : y0 + bw + 1, :] = 0
    return img, n_extra


#: The tasks whose loop scenes the ``task-scenes`` style renders, and their loop cameras.
TASK_SCENE_CAMERAS = {"tip-control": ("tracking",), "vaulting": ("tracking", "tracking2")}


class TaskSceneSampler:
    """Renders the control loop's own scenes: tip control's and vaulting's, through their loop cameras
    (moved a little), the cable driven by random multi-step actions.

    Each sample draws its own camera pose (about 5 cm and 3 degrees off the loop camera's), field of view,
    cable colour (the scene's red or any of :func:`_cable_colour`'s) and drawn width (0.6-2.5x), floor shade
    (the scene's, a grey or a colour), lights, sometimes a procedural texture where the scene shows the black
    void, and the camera effects of :func:`camera_effects`. The gripper, the target and the obstacle stay
    in view, unlabelled: the distractors the loop's segmenter meets. A group is one environment (task drawn
    from the group's generator), reset from a seed drawn from it.
    """

    def __init__(self, config: SegDataConfig, seed: int, group: int) -> None:
        from dyndlo_vision.sim.cable_look import CableLook
        from dyndlo_vision.sim.rendering import make_renderer
        from dyndlo_vision.tasks.registry import make_env

        config.check()
        self.config = config
        self.rng = np.random.default_rng((int(seed), int(group)))
        self.task = str(self.rng.choice(sorted(TASK_SCENE_CAMERAS)))
        self.env = make_env(self.task, multi_step=True)
        self.base = self.env.unwrapped
        self._reset()
        m = self.base.model
        self.cable_look = CableLook.of(m)
        self.floor_geom = int(m.geom("floor").id)
        m.vis.global_.offwidth = max(int(m.vis.global_.offwidth), 2 * config.width)
        m.vis.global_.offheight = max(int(m.vis.global_.offheight), 2 * config.height)
        self.renderer: Any = make_renderer(m, 2 * config.height, 2 * config.width)
        # What a sample changes, to put back (the drawn radius is also the chain's collision radius).
        self.saved = {name: getattr(m, name).copy() for name in
                      ("cam_pos", "cam_quat", "cam_fovy", "geom_rgba", "geom_size", "geom_rbound",
                       "light_diffuse", "light_pos", "flex_rgba", "flex_radius")}
        self.headlight = (m.vis.headlight.ambient.copy(), m.vis.headlight.diffuse.copy())

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
        self.env.close()

    def _reset(self) -> None:
        self.env.reset(seed=int(self.rng.integers(2**31)))

    def _move(self) -> None:
        """A few random re-plans (40 ms each); a new episode where one ends. Sometimes none: the cable at
        rest, as every loop episode starts."""
        rng, env = self.rng, self.env
        if rng.random() < 0.1:
            self._reset()
            return
        for _ in range(int(rng.integers(1, 9))):
            _, _, terminated, truncated, _ = env.step(rng.uniform(-1.0, 1.0, env.action_space.shape))
            if terminated or truncated:
                self._reset()

    def _restore(self) -> None:
        m = self.base.model
        for name, value in self.saved.items():
            getattr(m, name)[:] = value
        m.vis.headlight.ambient[:], m.vis.headlight.diffuse[:] = self.headlight

    def sample(self) -> tuple[NDArray[np.uint8], NDArray[np.uint8], dict[str, Any]]:
        """One (RGB (H, W, 3) uint8, mask (H, W) uint8 0/255, metadata) sample."""
        import mujoco

        rng, cfg = self.rng, self.config
        m, d = self.base.model, self.base.data
        self._move()
        camera = str(rng.choice(TASK_SCENE_CAMERAS[self.task]))
        cam_id = int(m.camera(camera).id)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, m.cam_quat[cam_id])
        # The camera's frame is in its body's; the loop cameras hang on the world body.
        forward = -rot.reshape(3, 3)[:, 2] + rng.normal(0.0, 0.05, 3)
        roll = float(rng.normal(0.0, 0.05))
        m.cam_pos[cam_id] += rng.normal(0.0, 0.05, 3)
        m.cam_quat[cam_id] = _look_at_quat(forward, roll)
        m.cam_fovy[cam_id] *= float(rng.uniform(0.85, 1.15))
        radius_scale = float(np.exp(rng.uniform(math.log(0.6), math.log(2.5))))
        self.cable_look.set_radius(m, radius_scale * self.base.scene.config.cable.radius_m)
        own_colour = rng.random() < 0.4
        if own_colour:
            colour = np.clip(self.cable_look.rgba(m)[:3] * rng.uniform(0.8, 1.2, 3), 0.0, 1.0)
        else:
            colour = _cable_colour(rng)
        self.cable_look.set_rgba(m, [*colour, 1.0])
        floor = rng.choice(["scene", "grey", "colour"], p=[0.5, 0.35, 0.15])
        if floor == "grey":
            m.geom_rgba[self.floor_geom, :3] = rng.uniform(0.3, 1.0)
        elif floor == "colour":
            m.geom_rgba[self.floor_geom, :3] = rng.uniform(0.2, 1.0, 3)
        gain = float(rng.uniform(0.7, 1.3))
        m.light_diffuse[0] *= gain
        m.light_pos[0] += rng.normal(0.0, 0.3, 3)
        m.vis.headlight.ambient[:] *= gain
        m.vis.headlight.diffuse[:] *= gain
        try:
            mujoco.mj_forward(m, d)
            rgb2, seg = _render_with_segmentation(self.renderer, d, cam_id)
        finally:
            self._restore()
            mujoco.mj_forward(m, d)
        w, h = cfg.width, cfg.height
        textured = bool(rng.random() < cfg.texture_share)
        if textured:  # a wall where the scene shows the black void
            void = (seg[..., 1] == -1).astype(np.float32)[..., None]
            bg = cv2.resize(procedural_background(rng, h, w).astype(np.float32), (2 * w, 2 * h))
            rgb2 = rgb2 * (1 - void) + bg * void
        img = cv2.resize(rgb2, (w, h), interpolation=cv2.INTER_AREA)
        cov = cv2.resize(self.cable_look.mask(seg).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
        rgb, mask = camera_effects(rng, img, np.clip(cov * 255 + 0.5, 0, 255).astype(np.uint8))
        meta = {
            "task": self.task,
            "camera": camera,
            "radius_scale": round(radius_scale, 3),
            "textured": textured,
            "floor": str(floor),
            "colour": [round(float(c), 3) for c in colour],
            "own_colour": bool(own_colour),
        }
        return rgb, mask, meta


def make_sampler(config: SegDataConfig, seed: int,
                 group: int) -> SceneSampler | TaskSceneSampler | CompositeSampler:
    """The sampler of ``config.style`` for one scene group (``sample()`` gives the group's samples in turn;
    ``close()`` frees it)."""
    if config.style == "task-scenes":
        return TaskSceneSampler(config, seed, group)
    if config.style == "random-scenes":
        return SceneSampler(config, seed, group)
    config.check()
    return CompositeSampler(config.style, config.width, config.height, config.min_width_px,
                            config.max_width_px, seed, group)


def enlarged(rgb: NDArray[np.uint8], mask: NDArray[np.uint8],
             scale: float) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """A sample and its coverage label enlarged ``scale`` times, both bilinearly: the image as the loop's
    network is given its frames, the label as the cable's coverage of the enlarged pixels."""
    h, w = mask.shape[:2]
    size = (int(round(w * scale)), int(round(h * scale)))
    return (cv2.resize(rgb, size, interpolation=cv2.INTER_LINEAR),
            cv2.resize(mask, size, interpolation=cv2.INTER_LINEAR))


def _sample_names(index: int) -> tuple[str, str]:
    return f"{index:06d}.png", f"{index:06d}_mask.png"


def _write_png_atomic(path: Path, img: NDArray[np.uint8]) -> None:
    tmp = path.with_name(path.name + ".part.png")
    if not cv2.imwrite(str(tmp), img):
        raise OSError(f"could not write {tmp}")
    tmp.replace(path)


def write_dataset(out: Path, count: int, seed: int, config: SegDataConfig, progress: Any = None) -> int:
    """Writes samples ``0 .. count-1`` into ``out`` (``NNNNNN.png``, ``NNNNNN_mask.png``, ``meta.jsonl``).

    Resumes: samples whose mask exists are kept, and a group is regenerated from its start (deterministic) to
    reach the first missing one. ``out/dataset.json`` records the config and seed; resuming with another
    config or seed is refused. Returns the number of samples written by this call.
    """
    config.check()
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"count must be a positive int, got {count!r}")
    out = Path(out)
    manifest = out / "dataset.json"
    info = {"format": "dyndlo-segdata-1", "seed": int(seed), "config": asdict(config)}
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"--out {out} exists and is not a folder")
    if manifest.exists():
        old = json.loads(manifest.read_text())
        # A dataset made before an option existed was made with its default.
        old_config = {**asdict(SegDataConfig()), **old.get("config", {})}
        if old.get("seed") != info["seed"] or old_config != info["config"]:
            raise ValueError(
                f"{out} holds a dataset made with seed {old.get('seed')} and config {old.get('config')}; "
                f"asked for seed {seed} and config {info['config']}: use another --out"
            )
    elif out.exists() and any(out.iterdir()):
        raise FileExistsError(f"--out {out} is a non-empty folder that holds no dataset.json")
    out.mkdir(parents=True, exist_ok=True)
    manifest.write_text(json.dumps(info, indent=1))
    for p in out.glob("*.part.png"):
        p.unlink()
    per = config.samples_per_scene
    written = 0
    done = {i for i in range(count) if (out / _sample_names(i)[1]).exists()}
    if progress is not None:
        progress.update(len(done))
    group = 0
    with open(out / "meta.jsonl", "a") as meta_file:
        while group * per < count:
            idx = range(group * per, min(count, (group + 1) * per))
            if all(i in done for i in idx):
                group += 1
                continue
            sampler = make_sampler(config, seed, group)
            try:
                for i in idx:
                    rgb, mask, meta = sampler.sample()
                    if i in done:
                        continue
                    if config.upscale != 1.0:
                        rgb, mask = enlarged(rgb, mask, config.upscale)
                    img_name, mask_name = _sample_names(i)
                    _write_png_atomic(out / img_name, np.ascontiguousarray(rgb[..., ::-1]))
                    _write_png_atomic(out / mask_name, mask)
                    meta_file.write(json.dumps({"index": i, "group": group, **meta}) + "\n")
                    meta_file.flush()
                    written += 1
                    if progress is not None:
                        progress.update(1)
            finally:
                sampler.close()
            group += 1
    return written
