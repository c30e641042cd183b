"""Cable scenes composited in 2-D: many cables at once on the surfaces real photos show, with exact labels.

The MuJoCo styles of :mod:`dyndlo_vision.learning.segdata` render one simulated cable among a few props. Real
photos hold bundles of wires, parallel runs, crossings, branched harnesses with ties and connectors, on
keyboards, machines, floors, painted posters and glossy mats. This module draws such scenes directly: every
cable is a smooth centreline drawn as a shaded tube (a cylinder's diffuse fall-off towards its rims, a
specular stripe whose strength is the insulation's gloss, sometimes a tracer stripe), with a soft shadow on
the surface beneath it, in the order they lie on each other. Cable coverage is drawn at twice the output
size and area-averaged, so thin wires are anti-aliased like a photo's and their label is exact. Then come
global light (a gradient, a vignette, soft shadows of things out of view), and the camera effects the MuJoCo
styles use (motion blur, defocus, colour gains, gamma, noise, JPEG).

Scene kinds (:data:`COMPOSITE_STYLES`), each a recipe of cable layouts and surfaces:

* ``wires``: 1-6 separate wires crossing each other on plain surfaces, wood, fabric, metal, floors, painted
  clutter and industrial panels, most of them running out of the image at both ends;
* ``bundles``: bundles of 2-10 coloured wires side by side (parallel runs, loosely twisted, fanning out at
  their ends), often on keyboards, machines and floors;
* ``harness``: a branched wire harness (a trunk of wires splitting into branches) held by cable ties, with
  plastic connectors at the branch ends, on glossy mats;
* ``busy``: several cables on busy surfaces: colour mosaics, dense paint splatter, natural-looking textures;
* ``own-colour``: cables on a surface in their own colour, set apart only by shading, texture and edges.

The label holds every cable pixel (cable ties included: they are part of the bundle), and nothing else:
connectors, objects lying on a cable and the surface's own lines and edges are not cable.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["COMPOSITE_STYLES", "CompositeSampler", "surface"]

#: The composited scene kinds (see the module docstring).
COMPOSITE_STYLES = ("wires", "bundles", "harness", "busy", "own-colour")

#: Surfaces :func:`surface` draws.
SURFACES = ("plain", "wood", "fabric", "metal", "keyboard", "machine", "glossy-mat", "splatter", "mosaic",
            "natural", "clutter", "floor", "paper")

#: Which surfaces each kind draws from (with weights).
_KIND_SURFACES: dict[str, dict[str, float]] = {
    "wires": {"plain": 2, "wood": 2, "fabric": 2, "metal": 2, "floor": 2, "splatter": 1.5, "clutter": 1.5,
              "machine": 1.5, "paper": 1, "keyboard": 0.5, "glossy-mat": 0.5},
    "bundles": {"keyboard": 3, "machine": 3, "floor": 2, "metal": 1.5, "wood": 1, "plain": 1, "fabric": 1,
                "clutter": 1},
    "harness": {"glossy-mat": 6, "plain": 1, "metal": 1, "floor": 1},
    "busy": {"mosaic": 3, "splatter": 3, "natural": 3, "clutter": 1.5, "keyboard": 0.5},
    "own-colour": {"plain": 1, "wood": 1, "fabric": 2, "floor": 1, "glossy-mat": 1, "natural": 1, "metal": 1},
}


# ----------------------------------------------------------------------------- colours and noise
def _noise(rng: np.random.Generator, h: int, w: int, cells: int, octaves: int = 3,
           persistence: float = 0.5) -> NDArray[np.float32]:
    """Multi-octave value noise in [0, 1] starting at ``cells`` cells across."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for _ in range(octaves):
        small = rng.random((max(2, cells * h // max(h, w) + 1), max(2, cells * w // max(h, w) + 1)))
        out += amp * cv2.resize(small.astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= persistence
        cells *= 2
    out /= total
    lo, hi = float(out.min()), float(out.max())
    return (out - lo) / max(hi - lo, 1e-6)


def _hsv_colour(rng: np.random.Generator, s: tuple[float, float] = (0.0, 1.0),
                v: tuple[float, float] = (0.0, 1.0)) -> NDArray[np.float32]:
    """An RGB colour (0-255) of random hue with saturation and value drawn in the given ranges."""
    hsv = np.uint8([[[rng.integers(0, 180), int(255 * rng.uniform(*s)), int(255 * rng.uniform(*v))]]])
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def _wire_colour(rng: np.random.Generator) -> NDArray[np.float32]:
    """Insulation colours: saturated (red, blue, yellow, green...), black, white, greys, browns, pastels."""
    kind = rng.choice(["hue", "black", "white", "grey", "brown", "pastel"],
                      p=[0.45, 0.18, 0.12, 0.12, 0.06, 0.07])
    if kind == "black":
        return np.full(3, rng.uniform(8, 40), np.float32) + rng.uniform(0, 8, 3).astype(np.float32)
    if kind == "white":
        return np.full(3, rng.uniform(200, 250), np.float32) - rng.uniform(0, 15, 3).astype(np.float32)
    if kind == "grey":
        return np.full(3, rng.uniform(60, 180), np.float32)
    if kind == "brown":
        return (np.array([115, 77, 38], np.float32) * rng.uniform(0.5, 1.4)).clip(0, 255)
    if kind == "pastel":
        return _hsv_colour(rng, (0.2, 0.45), (0.75, 1.0))
    return _hsv_colour(rng, (0.55, 1.0), (0.45, 1.0))


def _rgb(colour: NDArray[np.floating]) -> tuple[float, ...]:
    """A colour as the tuple OpenCV's drawing functions take."""
    return tuple(float(v) for v in colour)


def _mix(a: NDArray[np.float32], b: NDArray[np.float32], t: NDArray[np.float32]) -> NDArray[np.float32]:
    return a[None, None, :] * (1 - t[..., None]) + b[None, None, :] * t[..., None]


# ----------------------------------------------------------------------------- surfaces
def _splatter_strokes(rng: np.random.Generator, img: NDArray[np.float32], count: int,
                      max_thick: int) -> None:
    """Paint drips: jagged strokes of varying width and dots in a few paint colours."""
    h, w = img.shape[:2]
    palette = [_hsv_colour(rng) for _ in range(int(rng.integers(2, 7)))]
    for _ in range(count):
        col = tuple(float(c) for c in palette[int(rng.integers(len(palette)))])
        p = np.array([rng.uniform(0, w), rng.uniform(0, h)])
        heading = float(rng.uniform(0, 2 * math.pi))
        th = int(rng.integers(1, max_thick + 1))
        for _ in range(int(rng.integers(2, 30))):
            heading += float(rng.normal(0, 0.6))
            q = p + float(rng.uniform(2, 14)) * np.array([math.cos(heading), math.sin(heading)])
            th = int(np.clip(th + rng.integers(-1, 2), 1, max_thick))
            cv2.line(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), col, th, cv2.LINE_AA)
            if rng.random() < 0.1:
                cv2.circle(img, (int(q[0]), int(q[1])), int(rng.integers(1, 2 + max_thick)), col, -1,
                           cv2.LINE_AA)
            p = q


def _keyboard(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    case = _wire_colour(rng) if rng.random() < 0.3 else np.full(3, rng.uniform(15, 220), np.float32)
    cap = np.clip(case + rng.normal(0, 40, 3).astype(np.float32) * (rng.random() < 0.5), 0, 255)
    if rng.random() < 0.5:
        cap = np.full(3, rng.uniform(10, 240), np.float32)
    img = np.empty((h, w, 3), np.float32)
    img[:] = case * 0.7
    pitch = float(rng.uniform(14, 60))
    gap = max(1, int(pitch * rng.uniform(0.08, 0.2)))
    ang = float(rng.normal(0, 0.15))
    legend = np.full(3, 255.0 if float(cap.mean()) < 128 else 20.0, np.float32)
    rows = int(h / pitch * 1.6) + 3
    for r in range(-1, rows):
        x = -float(rng.uniform(0, pitch))
        y = r * pitch
        while x < w * 1.4:
            kw = pitch * float(rng.choice([1, 1, 1, 1.25, 1.5, 2, 6]))
            x0, y0 = x + gap, y + gap
            x1, y1 = x + kw - gap, y + pitch - gap
            pts = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float32)
            c, s = math.cos(ang), math.sin(ang)
            pts = pts @ np.array([[c, s], [-s, c]], np.float32) + np.array([0, -0.2 * h], np.float32)
            shade = float(rng.uniform(0.9, 1.1))
            cv2.fillConvexPoly(img, np.round(pts * 4).astype(np.int32), tuple(float(v) for v in cap * shade),
                               cv2.LINE_AA, 2)
            inner = pts.mean(axis=0) + (pts - pts.mean(axis=0)) * 0.7
            cv2.fillConvexPoly(img, np.round(inner * 4).astype(np.int32),
                               _rgb(np.clip(cap * shade * 1.08 + 6, 0, 255)), cv2.LINE_AA, 2)
            if rng.random() < 0.8:  # a legend: a few short strokes
                cx, cy = inner.mean(axis=0)
                for _ in range(int(rng.integers(1, 4))):
                    d = rng.uniform(-0.15, 0.15, 4) * pitch
                    cv2.line(img, (int(cx + d[0]), int(cy + d[1])), (int(cx + d[2]), int(cy + d[3])),
                             tuple(float(v) for v in legend), 1, cv2.LINE_AA)
            x += kw
    return img


def _machine(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    base = np.full(3, rng.uniform(40, 200), np.float32) * rng.uniform(0.85, 1.15, 3).astype(np.float32)
    img = _mix(base * 0.8, base * 1.1, _noise(rng, h, w, 3))
    for _ in range(int(rng.integers(3, 14))):  # panels with bevels
        x0, y0 = int(rng.integers(-w // 4, w)), int(rng.integers(-h // 4, h))
        x1, y1 = x0 + int(rng.integers(w // 10, w // 2)), y0 + int(rng.integers(h // 10, h // 2))
        col = (base * float(rng.uniform(0.6, 1.3)) if rng.random() < 0.7
               else _hsv_colour(rng, (0.4, 1), (0.3, 1)))
        col = np.clip(col, 0, 255)
        cv2.rectangle(img, (x0, y0), (x1, y1), tuple(float(v) for v in col), -1)
        cv2.line(img, (x0, y0), (x1, y0), tuple(float(v) for v in np.clip(col * 1.3 + 20, 0, 255)), 2)
        cv2.line(img, (x0, y1), (x1, y1), tuple(float(v) for v in col * 0.5), 2)
        if rng.random() < 0.4:  # a vent grille
            pitch = int(rng.integers(3, 9))
            for yy in range(y0 + pitch, y1 - 1, pitch):
                cv2.line(img, (x0 + 3, yy), (x1 - 3, yy), _rgb(col * 0.3), max(1, pitch // 3))
        for _ in range(int(rng.integers(0, 5))):  # screws
            cx, cy = int(rng.integers(x0, x1 + 1)), int(rng.integers(y0, y1 + 1))
            r = int(rng.integers(2, 6))
            cv2.circle(img, (cx, cy), r, tuple(float(v) for v in np.clip(col * 1.4, 0, 255)), -1, cv2.LINE_AA)
            cv2.line(img, (cx - r, cy), (cx + r, cy), tuple(float(v) for v in col * 0.4), 1, cv2.LINE_AA)
    for _ in range(int(rng.integers(0, 3))):  # rods and pipes: straight, shaded, with flanges
        p0 = rng.uniform(0, 1, 2) * (w, h)
        ang = float(rng.uniform(0, math.pi))
        d = np.array([math.cos(ang), math.sin(ang)]) * max(h, w) * 2
        rw = int(rng.integers(12, 60))
        col = np.clip(base * float(rng.uniform(0.5, 1.5)), 0, 255)
        a, b = tuple(map(int, (p0 - d).astype(int))), tuple(map(int, (p0 + d).astype(int)))
        cv2.line(img, a, b, _rgb(col * 0.6), rw, cv2.LINE_AA)
        cv2.line(img, a, b, _rgb(col), max(1, rw // 2), cv2.LINE_AA)
        cv2.line(img, a, b, _rgb(np.clip(col * 1.5, 0, 255)), max(1, rw // 6), cv2.LINE_AA)
        unit = d / np.linalg.norm(d)
        normal = np.array([-unit[1], unit[0]])
        for k in range(-6, 7):  # flanges and clamps across the pipe
            c = p0 + unit * k * float(rng.uniform(40, 120))
            e0, e1 = c - normal * rw * 0.8, c + normal * rw * 0.8
            cv2.line(img, tuple(map(int, e0)), tuple(map(int, e1)), tuple(float(v) for v in col * 0.8),
                     int(rng.integers(3, 10)))
    return img


def _wood(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    c1 = np.array([rng.uniform(90, 220), rng.uniform(50, 150), rng.uniform(20, 90)], np.float32)
    if rng.random() < 0.3:
        c1 = _hsv_colour(rng, (0.1, 0.6), (0.3, 0.95))
    c2 = c1 * float(rng.uniform(0.5, 0.85))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    ang = float(rng.uniform(0, math.pi))
    proj = xx * math.cos(ang) + yy * math.sin(ang)
    across = -xx * math.sin(ang) + yy * math.cos(ang)
    warp = _noise(rng, h, w, 3) * float(rng.uniform(5, 50))
    t = 0.5 + 0.5 * np.sin(2 * math.pi * (across + warp) / float(rng.uniform(3, 25)))
    t = t ** float(rng.uniform(0.5, 3.0))
    img = _mix(c1, c2, t * float(rng.uniform(0.4, 1.0)))
    plank = float(rng.uniform(40, 200))
    seams = (np.abs(((across + 1000) % plank) - 0.5) < 1.0).astype(np.float32)
    img *= 1 - 0.5 * seams[..., None] * (rng.random() < 0.6)
    del proj
    return img


def _fabric(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    c1 = _hsv_colour(rng, (0.0, 0.9), (0.1, 0.95))
    c2 = np.clip(c1 * float(rng.uniform(0.6, 0.95)) + rng.normal(0, 20, 3).astype(np.float32), 0, 255)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    p = float(rng.uniform(1.5, 6))
    ang = float(rng.uniform(0, math.pi))
    u, v = xx * math.cos(ang) + yy * math.sin(ang), -xx * math.sin(ang) + yy * math.cos(ang)
    weave = 0.5 + 0.25 * np.sin(2 * math.pi * u / p) + 0.25 * np.sin(2 * math.pi * v / p)
    if rng.random() < 0.3:  # a check or stripe pattern woven in
        big = float(rng.uniform(10, 60))
        weave = 0.5 * weave + 0.5 * ((np.floor(u / big) + np.floor(v / big * (rng.random() < 0.5))) % 2)
    img = _mix(c1, c2, weave.astype(np.float32))
    folds = _noise(rng, h, w, 2, 2)
    return img * (0.7 + 0.5 * folds[..., None])


def _metal(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    base = np.full(3, rng.uniform(90, 220), np.float32) * rng.uniform(0.9, 1.1, 3).astype(np.float32)
    grain = rng.normal(0, 1, (h, w)).astype(np.float32)
    k = int(rng.integers(9, 41))
    kernel = np.zeros((k, k), np.float32)
    kernel[k // 2, :] = 1.0 / k
    rot = cv2.getRotationMatrix2D((k / 2 - 0.5, k / 2 - 0.5), float(rng.uniform(0, 180)), 1.0)
    kernel = cv2.warpAffine(kernel, rot, (k, k))
    kernel /= max(float(kernel.sum()), 1e-6)
    grain = cv2.filter2D(grain, -1, kernel)
    grain /= max(float(grain.std()), 1e-6)
    sheen = _noise(rng, h, w, 2, 2)
    img = base[None, None, :] * (0.75 + 0.45 * sheen[..., None]) + 8 * grain[..., None]
    if rng.random() < 0.5:  # holes or rivets in rows (perforated plate, a rail)
        pitch = int(rng.integers(10, 40))
        r = int(rng.integers(1, max(2, pitch // 3)))
        dark = tuple(float(v) for v in base * 0.2)
        for y in range(pitch // 2, h, pitch):
            for x in range(pitch // 2 + (y // pitch % 2) * pitch // 2 * (rng.random() < 0.5), w, pitch):
                cv2.circle(img, (x, y), r, dark, -1, cv2.LINE_AA)
    return img


def _glossy_mat(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    col = rng.choice(["green", "blue", "grey", "black", "any"], p=[0.45, 0.15, 0.15, 0.1, 0.15])
    if col == "green":
        c = np.array([rng.uniform(10, 80), rng.uniform(90, 180), rng.uniform(40, 110)], np.float32)
    elif col == "blue":
        c = np.array([rng.uniform(10, 60), rng.uniform(60, 130), rng.uniform(120, 200)], np.float32)
    elif col == "grey":
        c = np.full(3, rng.uniform(60, 180), np.float32)
    elif col == "black":
        c = np.full(3, rng.uniform(10, 40), np.float32)
    else:
        c = _hsv_colour(rng, (0.3, 1.0), (0.3, 0.9))
    img = np.empty((h, w, 3), np.float32)
    img[:] = c
    img *= (0.9 + 0.2 * _noise(rng, h, w, 2, 2))[..., None]
    if rng.random() < 0.8:  # the cutting mat's grid and rulers: thin light straight lines
        pitch = float(rng.uniform(8, 45))
        line = tuple(float(v) for v in np.clip(c * 0.5 + rng.uniform(80, 140), 0, 255))
        ang = float(rng.normal(0, 0.1))
        rot = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
        off = rng.uniform(0, pitch, 2)
        for k in range(-int(2 * max(h, w) / pitch), int(2 * max(h, w) / pitch)):
            th = 2 if k % 5 == 0 and rng.random() < 0.7 else 1
            for d in (0, 1):
                a = (np.array([k * pitch + off[0], -max(h, w)]) if d == 0
                     else np.array([-max(h, w), k * pitch + off[1]]))
                b = a + (np.array([0, 3 * max(h, w)]) if d == 0 else np.array([3 * max(h, w), 0]))
                a, b = rot @ a, rot @ b
                cv2.line(img, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), line, th, cv2.LINE_AA)
    # a broad specular reflection of a lamp or a window
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    cx, cy = rng.uniform(-0.2, 1.2) * w, rng.uniform(-0.2, 1.2) * h
    sx, sy = rng.uniform(0.1, 0.6) * w, rng.uniform(0.1, 0.6) * h
    spec = np.exp(-(((xx - cx) / sx) ** 2 + ((yy - cy) / sy) ** 2)) * float(rng.uniform(0, 140))
    return img + spec[..., None]


def _mosaic(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    tile = float(rng.uniform(12, 70))
    ang = float(rng.normal(0, 0.1))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    u = (xx * math.cos(ang) + yy * math.sin(ang)) / tile
    v = (-xx * math.sin(ang) + yy * math.cos(ang)) / tile
    iu, iv = np.floor(u).astype(np.int32), np.floor(v).astype(np.int32)
    nu, nv = int(iu.max() - iu.min() + 1), int(iv.max() - iv.min() + 1)
    # hue drifts smoothly over the poster (a rainbow gradient), value varies tile by tile
    hue0 = float(rng.uniform(0, 180))
    drift = np.linspace(0, float(rng.uniform(60, 200)), nu)[:, None]
    hue = (hue0 + drift + rng.normal(0, 10, (nu, nv))) % 180
    sat = rng.uniform(0.5, 1.0, (nu, nv)) * 255
    val = rng.uniform(0.35, 1.0, (nu, nv)) * 255
    hsv = np.stack([hue, sat, val], -1).astype(np.uint8)
    cols = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB).astype(np.float32)
    img = cols[iu - iu.min(), iv - iv.min()]
    fu, fv = u - iu, v - iv
    bevel = np.minimum(np.minimum(fu, 1 - fu), np.minimum(fv, 1 - fv))
    shade = 0.75 + 0.35 * fu * (1 - fv) + 0.0 * bevel
    img = img * shade[..., None]
    img *= np.clip(bevel * 12, 0.4, 1.0)[..., None]
    return img


def _natural(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    """Leaves, bark, gravel: speckled colour at several scales (a photo print of a forest floor)."""
    img = np.zeros((h, w, 3), np.float32)
    palette = [_hsv_colour(rng, (0.2, 0.9), (0.15, 0.9)) for _ in range(int(rng.integers(3, 7)))]
    for k, col in enumerate(palette):
        t = _noise(rng, h, w, int(rng.integers(4, 40)), 3, 0.7)
        weight = np.clip((t - float(rng.uniform(0.3, 0.7))) * 6, 0, 1) if k else np.ones((h, w), np.float32)
        img = img * (1 - weight[..., None]) + col * weight[..., None]
    for _ in range(int(rng.integers(20, 200))):  # leaves and pebbles
        col = tuple(float(v) for v in palette[int(rng.integers(len(palette)))] * rng.uniform(0.5, 1.4))
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        ax = (int(rng.integers(2, 14)), int(rng.integers(1, 6)))
        cv2.ellipse(img, c, ax, float(rng.uniform(0, 180)), 0, 360, col, -1, cv2.LINE_AA)
    for _ in range(int(rng.integers(0, 25))):  # twigs: thin, dark, jagged
        p = rng.uniform(0, 1, 2) * (w, h)
        ang = float(rng.uniform(0, 2 * math.pi))
        col = tuple(float(v) for v in np.full(3, rng.uniform(10, 90)))
        for _ in range(int(rng.integers(2, 8))):
            ang += float(rng.normal(0, 0.5))
            q = p + rng.uniform(4, 20) * np.array([math.cos(ang), math.sin(ang)])
            cv2.line(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), col, int(rng.integers(1, 3)),
                     cv2.LINE_AA)
            p = q
    grain = rng.normal(0, float(rng.uniform(5, 25)), (h, w, 1)).astype(np.float32)
    return img + grain


def _floor(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    c = np.full(3, rng.uniform(70, 200), np.float32) * rng.uniform(0.85, 1.15, 3).astype(np.float32)
    if rng.random() < 0.3:
        c = _hsv_colour(rng, (0.1, 0.6), (0.3, 0.9))
    img = c[None, None, :] * (0.8 + 0.3 * _noise(rng, h, w, 8, 4, 0.6))[..., None]
    img += rng.normal(0, float(rng.uniform(2, 14)), (h, w, 1)).astype(np.float32)
    if rng.random() < 0.6:  # tiles with grout lines
        pitch = float(rng.uniform(40, 200))
        grout = tuple(float(v) for v in c * float(rng.uniform(0.4, 1.3)))
        th = int(rng.integers(1, 5))
        x0, y0 = rng.uniform(0, pitch, 2)
        for x in np.arange(x0, w, pitch):
            cv2.line(img, (int(x), 0), (int(x), h), grout, th)
        for y in np.arange(y0, h, pitch):
            cv2.line(img, (0, int(y)), (w, int(y)), grout, th)
    if rng.random() < 0.4:  # painted safety line
        col = tuple(float(v) for v in rng.choice([np.array([230, 200, 30]), np.array([240, 240, 240]),
                                                  np.array([200, 40, 30])]))
        p0 = rng.uniform(0, 1, 2) * (w, h)
        ang = float(rng.uniform(0, math.pi))
        d = np.array([math.cos(ang), math.sin(ang)]) * 2 * max(h, w)
        cv2.line(img, tuple(map(int, p0 - d)), tuple(map(int, p0 + d)), col, int(rng.integers(8, 50)))
    return img


def _paper(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    img = np.full((h, w, 3), rng.uniform(200, 250), np.float32)
    img += rng.normal(0, 2, (h, w, 1)).astype(np.float32)
    ink = tuple(float(v) for v in np.full(3, rng.uniform(10, 80)))
    for _ in range(int(rng.integers(5, 60))):  # printed text lines and sketches
        y = int(rng.integers(0, h))
        x0 = int(rng.integers(0, w))
        cv2.line(img, (x0, y), (x0 + int(rng.integers(10, w // 2)), y), ink, 1, cv2.LINE_AA)
    return img


def _plain(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    c = _hsv_colour(rng, (0, 0.8), (0.05, 1.0))
    t = _noise(rng, h, w, 2, 2) * float(rng.uniform(0, 0.3))
    return _mix(c, c * 0.6, t)


def _clutter(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    img = _plain(rng, h, w)
    draw_shapes(rng, img, int(rng.integers(5, 40)), _hsv_colour, tools=True)
    return img


def draw_shapes(rng: np.random.Generator, img: NDArray[np.float32], count: int,
                colour: Any, tools: bool = False) -> None:
    """Draw ``count`` filled rectangles, discs and ellipses of random ``colour(rng)`` on ``img``, and with
    ``tools`` also straight thick lines (a tool or a pen: elongated, but straight and with ends)."""
    h, w = img.shape[:2]
    for _ in range(count):
        col = tuple(float(v) for v in colour(rng))
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        s = int(rng.integers(4, max(6, min(h, w) // 3)))
        shape = rng.integers(0, 4 if tools else 3)
        if shape == 0:
            cv2.rectangle(img, (cx - s, cy - s // 2), (cx + s, cy + s // 2), col, -1)
        elif shape == 1:
            cv2.circle(img, (cx, cy), s // 2, col, -1, cv2.LINE_AA)
        elif shape == 2:
            cv2.ellipse(img, (cx, cy), (s, max(3, s // 3)), float(rng.uniform(0, 180)), 0, 360, col, -1,
                        cv2.LINE_AA)
        else:  # a straight tool or pen: elongated, but straight and with ends
            ang = float(rng.uniform(0, math.pi))
            d = np.array([math.cos(ang), math.sin(ang)]) * s * 1.5
            cv2.line(img, (int(cx - d[0]), int(cy - d[1])), (int(cx + d[0]), int(cy + d[1])), col,
                     int(rng.integers(3, 12)), cv2.LINE_AA)


_SURFACE_FUNCS = {"plain": _plain, "wood": _wood, "fabric": _fabric, "metal": _metal, "keyboard": _keyboard,
                  "machine": _machine, "glossy-mat": _glossy_mat, "mosaic": _mosaic, "natural": _natural,
                  "clutter": _clutter, "floor": _floor, "paper": _paper}


def surface(rng: np.random.Generator, kind: str, h: int, w: int) -> NDArray[np.float32]:
    """A surface of ``kind`` (:data:`SURFACES`) as float RGB (H, W, 3), roughly 0-255."""
    if kind == "splatter":
        img = _plain(rng, h, w) if rng.random() < 0.6 else _natural(rng, h, w)
        _splatter_strokes(rng, img, int(rng.integers(150, 700)), int(rng.integers(2, 6)))
        return img
    if kind not in _SURFACE_FUNCS:
        raise ValueError(f"surface kind must be one of {SURFACES}, got {kind!r}")
    return _SURFACE_FUNCS[kind](rng, h, w)


# ----------------------------------------------------------------------------- cable shapes
def _spline(ctrl: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """A Catmull-Rom curve through the control points, sampled about every ``step`` pixels."""
    p = np.vstack([2 * ctrl[0] - ctrl[1], ctrl, 2 * ctrl[-1] - ctrl[-2]])
    out = []
    for i in range(1, len(p) - 2):
        p0, p1, p2, p3 = p[i - 1], p[i], p[i + 1], p[i + 2]
        n = max(2, int(np.linalg.norm(p2 - p1) / step))
        t = np.linspace(0, 1, n, endpoint=False)[:, None]
        out.append(0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                          + (-p0 + 3 * p1 - 3 * p2 + p3) * t**3))
    out.append(ctrl[-1:])
    return np.vstack(out)


def _border_point(rng: np.random.Generator, h: int, w: int, margin: float) -> NDArray[np.float64]:
    side = int(rng.integers(4))
    t = float(rng.uniform(0, 1))
    return np.array([[t * w, -margin], [w + margin, t * h], [t * w, h + margin], [-margin, t * h]][side])


def _path(rng: np.random.Generator, h: int, w: int, margin: float, leave_share: float = 0.7,
          start: NDArray[np.float64] | None = None, end: NDArray[np.float64] | None = None,
          wiggle: float = 1.0) -> NDArray[np.float64]:
    """A smooth centreline: from and to the image's border (leaving it) or free ends inside, through a few
    random points, sampled every pixel or so."""
    def end_point() -> NDArray[np.float64]:
        if rng.random() < leave_share:
            return _border_point(rng, h, w, margin)
        return rng.uniform(0.1, 0.9, 2) * (w, h)
    a = end_point() if start is None else start
    b = end_point() if end is None else end
    n_mid = int(rng.integers(1, 5))
    mids = []
    for k in range(n_mid):
        t = (k + 1) / (n_mid + 1)
        base = a + (b - a) * t
        mids.append(base + rng.normal(0, 0.25 * wiggle, 2) * (w, h))
    ctrl = np.vstack([a, *mids, b])
    if rng.random() < 0.15 * wiggle:  # a loop
        k = int(rng.integers(1, len(ctrl)))
        c = ctrl[k - 1] + (ctrl[k] - ctrl[k - 1]) * 0.5
        r = float(rng.uniform(0.05, 0.15)) * min(h, w)
        loop = c + r * np.array([[math.cos(t), math.sin(t)] for t in np.linspace(0, 2 * math.pi, 6)])
        ctrl = np.vstack([ctrl[:k], loop, ctrl[k:]])
    return _spline(ctrl, 1.0)


def _normals(path: NDArray[np.float64]) -> NDArray[np.float64]:
    d = np.gradient(path, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    return np.column_stack([-d[:, 1], d[:, 0]])


def _arc_length(path: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])


class _Wire:
    """One cable to draw: centreline (pixels), width, colour, gloss, optional tracer stripe."""

    def __init__(self, path: NDArray[np.float64], width: float, colour: NDArray[np.float32], gloss: float,
                 tracer: NDArray[np.float32] | None = None) -> None:
        self.path, self.width, self.colour, self.gloss, self.tracer = path, width, colour, gloss, tracer


def _bundle_paths(rng: np.random.Generator, centre: NDArray[np.float64], n: int, width: float,
                  spread_ends: bool) -> list[NDArray[np.float64]]:
    """``n`` wires side by side along ``centre``: touching or with small gaps, loosely twisted in places,
    fanning out towards the ends."""
    normal = _normals(centre)
    s = _arc_length(centre)
    total = max(float(s[-1]), 1.0)
    pitch = width * float(rng.uniform(0.9, 1.4))
    twist = rng.random() < 0.4
    period = float(rng.uniform(40, 200))
    paths = []
    for k in range(n):
        off = (k - (n - 1) / 2) * pitch * np.ones_like(s)
        if twist:
            off = off * np.cos(2 * math.pi * s / period + k * math.pi / n)
        if spread_ends:
            fan = float(rng.uniform(0, 4)) * pitch
            off = off + np.sign(off + 1e-6) * fan * (np.clip(1 - s / (0.15 * total), 0, 1) ** 2
                                                     + np.clip(1 - (total - s) / (0.15 * total), 0, 1) ** 2)
        off = off + rng.normal(0, 0.08 * pitch) * np.sin(s / float(rng.uniform(20, 80)) + rng.uniform(0, 6))
        paths.append(centre + normal * off[:, None])
    return paths


# ----------------------------------------------------------------------------- drawing
def _coverage(paths: list[NDArray[np.float64]], width: float, shape: tuple[int, int],
              origin: tuple[float, float] = (0.0, 0.0), scale: float = 2.0) -> NDArray[np.float32]:
    """Coverage of polylines ``width`` wide (paths in 1x pixels) on a canvas of ``shape`` at ``scale`` times
    the output size whose top-left pixel is ``origin`` (in canvas pixels)."""
    layer = np.zeros(shape, np.uint8)
    th = max(1, int(round(scale * width)) - 2)  # OpenCV's anti-aliased thick line is about 2 px wider
    for p in paths:
        pts = np.round((p * scale - origin) * 16).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(layer, [pts], False, 255, th, cv2.LINE_AA, 4)
    return layer.astype(np.float32) / 255.0


def _box(paths: list[NDArray[np.float64]], pad: float, h2: int, w2: int) -> tuple[int, int, int, int] | None:
    """The 2x canvas box (x0, y0, x1, y1) around the paths, grown by ``pad``; None when it misses."""
    pts = np.vstack(paths) * 2
    x0, y0 = np.floor(pts.min(axis=0) - pad).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0) + pad).astype(int)
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w2, x1), min(h2, y1)
    return None if x0 >= x1 or y0 >= y1 else (int(x0), int(y0), int(x1), int(y1))


def _draw_wire(canvas: NDArray[np.float32], label: NDArray[np.float32], wire: _Wire,
               light: NDArray[np.float64], rng: np.random.Generator) -> None:
    """Draws a shaded tube on the 2x ``canvas`` and its coverage into the 2x ``label`` (max)."""
    h2, w2 = label.shape
    box = _box([wire.path], 2 * wire.width + 4, h2, w2)
    ambient = float(rng.uniform(0.25, 0.95))  # from strongly shaded to flatly lit insulation
    shininess = float(rng.uniform(8, 60))
    if box is None:
        return
    x0, y0, x1, y1 = box
    cov_c = _coverage([wire.path], wire.width, (y1 - y0, x1 - x0), (x0, y0))
    on = np.nonzero(cov_c > 0)
    if len(on[0]) == 0:
        return
    a = cov_c[on]
    # Distance from the centreline (2x pixels) gives the cylinder's cross-section.
    centre = np.full((y1 - y0, x1 - x0), 255, np.uint8)
    pts = np.round((wire.path * 2 - (x0, y0)) * 16).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(centre, [pts], False, 0, 1, cv2.LINE_8, 4)
    dist_full = cv2.distanceTransform(centre, cv2.DIST_L2, 3)
    dist = dist_full[on]
    r2 = max(wire.width, 0.5)  # the radius in 2x pixels is the width in 1x pixels
    t = np.clip(dist / r2, 0, 1)
    # Which side of the centre: the distance grows away from the centreline, towards the light or not.
    ys, xs = on
    hh, ww = dist_full.shape
    gx = dist_full[ys, np.minimum(xs + 1, ww - 1)] - dist_full[ys, np.maximum(xs - 1, 0)]
    gy = dist_full[np.minimum(ys + 1, hh - 1), xs] - dist_full[np.maximum(ys - 1, 0), xs]
    side = np.where(gx * light[0] + gy * light[1] >= 0, 1.0, -1.0).astype(np.float32)
    n_z = np.sqrt(np.clip(1 - t**2, 0, 1))  # the surface normal's component towards the camera
    n_x = t * side  # towards the light's side in the image
    lz = float(light[2])
    lxy = float(math.sqrt(max(0.0, 1 - lz * lz)))
    diffuse = np.clip(n_z * lz + n_x * lxy, 0, 1)
    colour = np.empty((len(t), 3), np.float32)
    colour[:] = wire.colour
    if wire.tracer is not None:  # a stripe along one side (earth wire, marked insulation)
        stripe = (np.abs(t * side - 0.35) < 0.3)
        colour[stripe] = wire.tracer
    body = colour * (ambient + (1 - ambient) * diffuse)[:, None]
    if wire.gloss > 0:  # a specular stripe where the normal halves the light and the view
        hz, hx = lz + 1.0, lxy
        cos_h = np.clip((n_z * hz + n_x * hx) / math.hypot(hz, hx), 0, 1)
        body += (wire.gloss * 255 * cos_h**shininess)[:, None]
    region = canvas[y0:y1, x0:x1]
    region[on] = region[on] * (1 - a[:, None]) + a[:, None] * body
    lab = label[y0:y1, x0:x1]
    lab[on] = np.maximum(lab[on], a)


def _shadow(canvas: NDArray[np.float32], paths: list[NDArray[np.float64]], width: float,
            offset: NDArray[np.float64], strength: float) -> None:
    """A soft shadow of the wires on the surface (drawn before them), computed at half the output size."""
    h2, w2 = canvas.shape[:2]
    small = (h2 // 4, w2 // 4)
    cov = _coverage([p + offset for p in paths], width, small, scale=0.5)
    sigma = max(0.5, (1.5 * width + float(np.linalg.norm(offset)) * 0.5) / 4)
    cov = cv2.GaussianBlur(cov, (0, 0), sigma)
    cov = cv2.resize(cov, (w2, h2), interpolation=cv2.INTER_LINEAR)
    canvas *= (1 - strength * np.clip(cov * 1.5, 0, 1))[..., None]


def _connector(canvas: NDArray[np.float32], label: NDArray[np.float32], end: NDArray[np.float64],
               direction: NDArray[np.float64], size: float, rng: np.random.Generator) -> None:
    """A plastic connector housing over a wire end (2x canvas; not cable: it clears the label)."""
    d = direction / max(float(np.linalg.norm(direction)), 1e-9)
    n = np.array([-d[1], d[0]])
    length, half = size * float(rng.uniform(1.0, 2.5)), size * float(rng.uniform(0.5, 1.0))
    c = end * 2
    pts = np.array([c - n * half * 2, c + n * half * 2, c + d * length * 2 + n * half * 2,
                    c + d * length * 2 - n * half * 2])
    col = rng.choice([np.array([235, 235, 225]), np.array([25, 25, 25]), np.array([200, 200, 200]),
                      np.array([60, 60, 160]), np.array([200, 170, 60])]).astype(np.float32)
    col = col * float(rng.uniform(0.8, 1.1))
    box = _box([pts / 2], 4, *label.shape)
    if box is None:
        return
    x0, y0, x1, y1 = box
    poly = np.round((pts - (x0, y0)) * 16).astype(np.int32)
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillConvexPoly(mask, poly, 255, cv2.LINE_AA, 4)
    a = (mask.astype(np.float32) / 255)[..., None]
    region = canvas[y0:y1, x0:x1]
    region *= 1 - a
    region += a * col
    edge = np.zeros(mask.shape, np.uint8)
    cv2.polylines(edge, [poly], True, 255, 2, cv2.LINE_AA, 4)
    region *= (1 - 0.4 * edge.astype(np.float32) / 255)[..., None]
    label[y0:y1, x0:x1] *= 1 - a[..., 0]


def _tie(canvas: NDArray[np.float32], label: NDArray[np.float32], centre: NDArray[np.float64],
         direction: NDArray[np.float64], half_width: float, colour: NDArray[np.float32]) -> None:
    """A cable tie around a bundle: a short band across it (2x canvas; part of the bundle: labelled)."""
    d = direction / max(float(np.linalg.norm(direction)), 1e-9)
    n = np.array([-d[1], d[0]])
    a, b = (centre - n * half_width * 1.15) * 2, (centre + n * half_width * 1.15) * 2
    th = max(2, int(round(half_width * 0.5)))
    box = _box([a[None] / 2, b[None] / 2], th + 2, *label.shape)
    if box is None:
        return
    x0, y0, x1, y1 = box
    layer = np.zeros((y1 - y0, x1 - x0), np.uint8)
    o = np.array([x0, y0])
    cv2.line(layer, tuple(np.round((a - o) * 16).astype(int)), tuple(np.round((b - o) * 16).astype(int)), 255,
             th, cv2.LINE_AA, 4)
    cov = layer.astype(np.float32) / 255
    region = canvas[y0:y1, x0:x1]
    region *= 1 - cov[..., None]
    region += cov[..., None] * colour
    np.maximum(label[y0:y1, x0:x1], cov, out=label[y0:y1, x0:x1])


class CompositeSampler:
    """Draws samples of one composited scene kind (:data:`COMPOSITE_STYLES`); every draw comes from
    ``numpy.random.default_rng((seed, group))``, so a group's samples are reproducible."""

    def __init__(self, kind: str, width: int, height: int, min_width_px: float, max_width_px: float,
                 seed: int, group: int) -> None:
        if kind not in COMPOSITE_STYLES:
            raise ValueError(f"kind must be one of {COMPOSITE_STYLES}, got {kind!r}")
        self.kind, self.w, self.h = kind, int(width), int(height)
        self.min_w, self.max_w = float(min_width_px), float(max_width_px)
        self.rng = np.random.default_rng((int(seed), int(group)))

    def close(self) -> None:  # the samplers' common interface (nothing to free here)
        pass

    def _width(self, lo: float | None = None, hi: float | None = None) -> float:
        lo = self.min_w if lo is None else max(self.min_w, lo)
        hi = self.max_w if hi is None else min(self.max_w, hi)
        return float(np.exp(self.rng.uniform(math.log(lo), math.log(max(lo, hi)))))

    def _gloss(self) -> float:
        r = self.rng.random()
        return 0.0 if r < 0.25 else float(self.rng.uniform(0.1, 0.5)) if r < 0.7 else float(
            self.rng.uniform(0.5, 1.0))

    def _wire(self, path: NDArray[np.float64], width: float,
              colour: NDArray[np.float32] | None = None) -> _Wire:
        rng = self.rng
        colour = _wire_colour(rng) if colour is None else colour
        tracer = _wire_colour(rng) if rng.random() < 0.08 and width >= 3 else None
        return _Wire(path, width, colour, self._gloss(), tracer)

    def _layout(self) -> tuple[list[list[_Wire]], list[tuple[str, Any]]]:
        """Groups of wires (each group shares a shadow and lies together) and extra parts (ties,
        connectors) to draw after them."""
        rng, h, w, kind = self.rng, self.h, self.w, self.kind
        groups: list[list[_Wire]] = []
        extras: list[tuple[str, Any]] = []
        scale = min(h, w)
        if kind in ("wires", "busy", "own-colour"):
            n = int(rng.integers(1, 7)) if kind == "wires" else int(rng.integers(2, 7))
            base_w = self._width()
            for _ in range(n):
                width = base_w * float(rng.uniform(0.7, 1.4)) if rng.random() < 0.7 else self._width()
                width = float(np.clip(width, self.min_w, self.max_w))
                groups.append([self._wire(_path(rng, h, w, margin=width * 2 + 5), width)])
            if kind == "wires" and rng.random() < 0.25:  # a parallel run: a few wires along one route
                width = self._width(hi=12)
                centre = _path(rng, h, w, margin=40)
                count = int(rng.integers(2, 5))
                paths = _bundle_paths(rng, centre, count, width * float(rng.uniform(1.5, 4)), False)
                groups.append([self._wire(p, width) for p in paths])
        elif kind == "bundles":
            for _ in range(int(rng.integers(1, 4))):
                n = int(rng.integers(2, 11))
                width = self._width(hi=16)
                centre = _path(rng, h, w, margin=n * width + 10, wiggle=0.7)
                same = rng.random() < 0.3
                colour = _wire_colour(rng) if same else None
                paths = _bundle_paths(rng, centre, n, width, spread_ends=rng.random() < 0.5)
                groups.append([self._wire(p, width, colour) for p in paths])
            for _ in range(int(rng.integers(0, 3))):  # loose single wires too
                width = self._width()
                groups.append([self._wire(_path(rng, h, w, margin=width * 2 + 5), width)])
        else:  # harness: a trunk of wires splitting into branches, ties along it, connectors at branch ends
            width = self._width(lo=1.5, hi=10)
            n = int(rng.integers(4, 13))
            palette = [_wire_colour(rng) for _ in range(int(rng.integers(2, 6)))]
            colours = [palette[int(rng.integers(len(palette)))] for _ in range(n)]
            start = (_border_point(rng, h, w, 10.0) if rng.random() < 0.7
                     else rng.uniform(0.1, 0.3, 2) * (w, h))
            end = rng.uniform(0.5, 0.9, 2) * (w, h) if rng.random() < 0.5 else _border_point(rng, h, w, 10.0)
            if np.linalg.norm(end - start) < 0.6 * scale:  # a trunk across the picture
                end = np.array([w, h], float) - start
            trunk = _path(rng, h, w, margin=10.0, start=start, end=end, wiggle=0.4)
            s = _arc_length(trunk)
            paths = _bundle_paths(rng, trunk, n, width, spread_ends=False)
            wires_left = list(range(n))
            ends: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
            cut = len(trunk) - 1
            for _ in range(int(rng.integers(1, 4))):  # branches split off the trunk
                if len(wires_left) < 2:
                    break
                k = int(rng.integers(max(1, len(trunk) // 4), max(2, len(trunk) - 5)))
                take = int(rng.integers(1, max(2, len(wires_left) // 2 + 1)))
                chosen = [wires_left.pop(int(rng.integers(len(wires_left)))) for _ in range(take)]
                direction = trunk[min(k + 3, len(trunk) - 1)] - trunk[max(k - 3, 0)]
                branch_normal = _normals(trunk)[k] * rng.choice([-1, 1])
                along = direction / max(float(np.linalg.norm(direction)), 1e-9)
                toward = branch_normal * float(rng.uniform(0.7, 1.2)) + along * float(rng.uniform(-0.3, 0.6))
                end = trunk[k] + toward * float(rng.uniform(0.3, 0.7)) * scale
                mid = (trunk[k] + end) / 2 + rng.normal(0, 0.05, 2) * scale
                branch = _spline(np.vstack([trunk[max(k - 8, 0)], trunk[k], mid, end]), 1.0)
                bpaths = _bundle_paths(rng, branch, take, width, spread_ends=False)
                for i, bp in zip(chosen, bpaths, strict=True):
                    joined = np.vstack([paths[i][: max(k - 8, 1)], bp])
                    paths[i] = joined
                ends.append((branch[-1], branch[-1] - branch[-4]))
                extras.append(("tie", (branch[len(branch) // 3], branch[len(branch) // 3 + 2]
                                       - branch[len(branch) // 3], take * width / 2)))
            ends.append((trunk[cut], trunk[cut] - trunk[cut - 3]))
            groups.append([self._wire(p, width, c) for p, c in zip(paths, colours, strict=True)])
            tie_colour = rng.choice([np.array([20, 20, 20]), np.array([230, 230, 220])]).astype(np.float32)
            for k in range(int(rng.integers(1, 6))):  # ties along the trunk
                j = int(np.searchsorted(s, s[-1] * (k + 1) / 7 + rng.uniform(-10, 10)))
                j = int(np.clip(j, 1, len(trunk) - 2))
                extras.append(("tie", (trunk[j], trunk[j + 1] - trunk[j - 1], n * width / 2)))
            for e, d in ends:
                if rng.random() < 0.8:
                    extras.append(("connector", (e, d, max(6.0, width * math.sqrt(n) * 1.6))))
            extras = [(name, (*args, tie_colour)) if name == "tie" else (name, args) for name, args in extras]
            for _ in range(int(rng.integers(0, 3))):  # loose single wires
                width2 = self._width(hi=12)
                groups.append([self._wire(_path(rng, h, w, margin=width2 * 2 + 5), width2)])
        order = rng.permutation(len(groups))
        return [groups[i] for i in order], extras

    def _surface(self, cable_colour: NDArray[np.float32]) -> tuple[NDArray[np.float32], str]:
        rng, h, w = self.rng, self.h, self.w
        table = _KIND_SURFACES[self.kind]
        names = list(table)
        weights = np.array([table[n] for n in names], float)
        name = str(rng.choice(names, p=weights / weights.sum()))
        img = surface(rng, name, h, w)
        if self.kind != "own-colour" and rng.random() < 0.2:  # a dark surface (black cloth, a dim bench)
            img = img * float(rng.uniform(0.04, 0.35))
        if self.kind == "own-colour":  # the surface in the cable's colour: its texture kept, its hue changed
            lum = img.mean(axis=2, keepdims=True) / max(float(img.mean()), 1.0)
            target = cable_colour * float(rng.uniform(0.7, 1.3))
            img = lum * target[None, None, :] * float(rng.uniform(0.8, 1.2))
        return img, name

    def sample(self) -> tuple[NDArray[np.uint8], NDArray[np.uint8], dict[str, Any]]:
        """One (RGB (H, W, 3) uint8, mask (H, W) uint8 0/255, metadata) sample."""
        from dyndlo_vision.learning.segdata import camera_effects

        rng, h, w = self.rng, self.h, self.w
        groups, extras = self._layout()
        first = groups[0][0].colour if groups and groups[0] else _wire_colour(rng)
        bg, surface_name = self._surface(first)
        canvas = cv2.resize(bg, (2 * w, 2 * h), interpolation=cv2.INTER_LINEAR)
        label = np.zeros((2 * h, 2 * w), np.float32)
        elev = float(rng.uniform(0.35, 0.95))
        az = float(rng.uniform(0, 2 * math.pi))
        light = np.array([math.cos(az) * math.sqrt(1 - elev**2), math.sin(az) * math.sqrt(1 - elev**2), elev])
        shadow_dir = -light[:2] / max(float(np.linalg.norm(light[:2])), 1e-6)
        shadow_strength = float(rng.uniform(0.0, 0.6))
        if shadow_strength > 0.05:  # on the surface only (one pass for all wires)
            lift = float(rng.uniform(0.2, 2.0)) * float(np.median([w_.width for g in groups for w_ in g]))
            _shadow(canvas, [wire.path for g in groups for wire in g],
                    float(np.median([w_.width for g in groups for w_ in g])), shadow_dir * lift * (1 - elev),
                    shadow_strength)
        for group in groups:
            for wire in group:
                _draw_wire(canvas, label, wire, light, rng)
        for name, args in extras:
            if name == "tie":
                _tie(canvas, label, *args)
            else:
                _connector(canvas, label, *args, rng)
        for _ in range(int(rng.integers(0, 3)) if rng.random() < 0.3 else 0):  # objects lying on the cables
            col = tuple(float(v) for v in _hsv_colour(rng))
            c = (int(rng.integers(0, 2 * w)), int(rng.integers(0, 2 * h)))
            ax = (int(rng.integers(10, max(12, w // 3))), int(rng.integers(6, max(8, h // 5))))
            occ = np.zeros(label.shape, np.uint8)
            cv2.ellipse(occ, c, ax, float(rng.uniform(0, 180)), 0, 360, 255, -1, cv2.LINE_AA)
            a = occ.astype(np.float32) / 255
            canvas *= 1 - a[..., None]
            canvas += a[..., None] * np.asarray(col, np.float32)
            label *= 1 - a
        img = cv2.resize(canvas, (w, h), interpolation=cv2.INTER_AREA)
        cov = cv2.resize(label, (w, h), interpolation=cv2.INTER_AREA)
        # Light over the whole scene: a gradient, a vignette, soft shadows of things out of view.
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        ang = float(rng.uniform(0, 2 * math.pi))
        grad = ((xx / w - 0.5) * math.cos(ang) + (yy / h - 0.5) * math.sin(ang)) * float(rng.uniform(0, 0.8))
        gain = 1 + grad
        if rng.random() < 0.5:
            r2 = ((xx / w - 0.5) ** 2 + (yy / h - 0.5) ** 2) * 2
            gain *= 1 - float(rng.uniform(0, 0.5)) * r2
        if rng.random() < 0.35:
            blob = np.zeros((h, w), np.float32)
            pts = (rng.uniform(-0.2, 1.2, (int(rng.integers(3, 7)), 2)) * (w, h)).astype(np.int32)
            cv2.fillConvexPoly(blob, cv2.convexHull(pts), 1.0)
            blob = cv2.GaussianBlur(blob, (0, 0), float(rng.uniform(2, 20)))
            gain *= 1 - float(rng.uniform(0.2, 0.7)) * blob
        img = img * np.clip(gain, 0.15, 2.0)[..., None]
        cover_u8 = np.clip(cov * 255 + 0.5, 0, 255).astype(np.uint8)
        rgb, mask = camera_effects(rng, img, cover_u8)
        widths = [wire.width for g in groups for wire in g]
        meta = {"style": self.kind, "surface": surface_name, "wires": len(widths),
                "width_px": [round(min(widths), 2), round(max(widths), 2)]}
        return rgb, mask, meta
