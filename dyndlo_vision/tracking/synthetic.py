"""Synthetic cable images with known centrelines, for tests and benchmarks.

Curves are dense (K, 2) pixel polylines ordered from the held end to the free end. Images are
RGB uint8 drawn with anti-aliased ``cv2.polylines`` at sub-pixel precision.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "straight_curve",
    "arc_curve",
    "s_curve",
    "loop_curve",
    "render_cable",
    "draw_occluder",
]

_SHIFT = 4  # sub-pixel bits for cv2 drawing


def straight_curve(p0: ArrayLike, p1: ArrayLike, n: int = 200) -> NDArray[np.float64]:
    """Straight segment from ``p0`` to ``p1``."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) * np.asarray(p0, float) + t * np.asarray(p1, float)


def arc_curve(
    center: ArrayLike, radius: float, a0_deg: float, a1_deg: float, n: int = 300
) -> NDArray[np.float64]:
    """Circular arc from angle ``a0_deg`` to ``a1_deg`` (image axes: v down)."""
    a = np.radians(np.linspace(a0_deg, a1_deg, n))
    c = np.asarray(center, float)
    return np.column_stack((c[0] + radius * np.cos(a), c[1] + radius * np.sin(a)))


def s_curve(
    u0: float = 80,
    u1: float = 560,
    v0: float = 240,
    amp: float = 110,
    periods: float = 1.0,
    phase: float = 0.0,
    n: int = 400,
) -> NDArray[np.float64]:
    """Sinusoidal S-shaped curve across the image."""
    u = np.linspace(u0, u1, n)
    v = v0 + amp * np.sin(2 * np.pi * periods * (u - u0) / (u1 - u0) + phase)
    return np.column_stack((u, v))


def loop_curve(
    u0: float = 70, u1: float = 570, v0: float = 260, radius: float = 90, n: int = 600
) -> NDArray[np.float64]:
    """Cable running left to right that makes one self-crossing loop (a prolate cycloid)."""
    phi = np.linspace(-1.25 * np.pi, 1.25 * np.pi, n)
    a = radius / 2.5  # a < radius: the cycloid loops once around phi = 0
    x = a * phi - radius * np.sin(phi)
    y = radius * np.cos(phi)
    x = u0 + (x - x.min()) / (x.max() - x.min()) * (u1 - u0)
    return np.column_stack((x, v0 - y))


def render_cable(
    curve: ArrayLike,
    shape: tuple[int, int] = (480, 640),
    thickness: int = 6,
    color: tuple[int, int, int] = (230, 70, 40),
    background: tuple[int, int, int] | NDArray[np.uint8] = (40, 60, 50),
    noise_sigma: float = 4.0,
    seed: int | None = 0,
) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """Draws a cable polyline on a (noisy) background.

    Args:
        curve: (K, 2) pixel polyline.
        shape: (H, W) of the image.
        thickness: Line thickness in pixels.
        color: RGB colour of the cable.
        background: RGB colour or an (H, W, 3) uint8 background image.
        noise_sigma: Std of additive Gaussian pixel noise (grey levels).
        seed: Seed of the noise.

    Returns:
        ``(rgb, mask)``: the (H, W, 3) uint8 image and the (H, W) bool ground-truth mask.
    """
    h, w = shape
    if isinstance(background, np.ndarray) and background.ndim == 3:
        img = background.astype(np.float32).copy()
    else:
        img = np.empty((h, w, 3), np.float32)
        img[:] = np.asarray(background, np.float32)
    pts = np.round(np.asarray(curve, float) * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)
    cover = np.zeros((h, w), np.uint8)
    cv2.polylines(cover, [pts], False, 255, thickness, cv2.LINE_AA, _SHIFT)
    alpha = (cover.astype(np.float32) / 255.0)[..., None]
    img = img * (1 - alpha) + np.asarray(color, np.float32) * alpha
    if noise_sigma > 0:
        rng = np.random.default_rng(seed)
        img += rng.normal(0.0, noise_sigma, img.shape).astype(np.float32)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8), cover >= 128


def draw_occluder(
    rgb: NDArray[np.uint8],
    top_left: tuple[int, int],
    bottom_right: tuple[int, int],
    color: tuple[int, int, int] | None = None,
) -> NDArray[np.uint8]:
    """Returns a copy of ``rgb`` with a filled rectangle (an occluder) drawn on it.

    The default colour is the median image colour, i.e. the occluder looks like background.
    """
    out = rgb.copy()
    if color is None:
        color = tuple(int(c) for c in np.median(rgb.reshape(-1, 3), axis=0))
    cv2.rectangle(out, top_left, bottom_right, color, thickness=-1)
    return out


def render_checkerboard(
    camera_K: ArrayLike,
    camera_R: ArrayLike,
    camera_t: ArrayLike,
    size: tuple[int, int],
    cols: int,
    rows: int,
    square_m: float,
    board_rotation: ArrayLike,
    board_origin_m: ArrayLike,
    background: int = 110,
    supersample: int = 4,
    px_per_square: int = 40,
) -> NDArray[np.uint8]:
    """A grey image of a checkerboard (``cols`` x ``rows`` inner corners) seen by a pinhole camera.

    The board frame is :class:`~dyndlo_vision.tracking.calibration.Checkerboard`'s: origin at the first inner
    corner, x along a row of corners, y along a column; ``x_world = board_rotation @ x_board +
    board_origin_m`` and ``x_cam = camera_R @ x_world + camera_t``. The squares, with a white margin of one
    square around them, are warped into the image through their homography at ``supersample`` times the
    resolution and averaged down (anti-aliased edges), on a uniform ``background``.
    """
    p = px_per_square
    n_x, n_y = cols + 3, rows + 3  # squares: cols + 1 across, plus a white margin square on each side
    texture = np.full((n_y * p, n_x * p), 255, np.uint8)
    for j in range(1, n_y - 1):
        for i in range(1, n_x - 1):
            if (i + j) % 2 == 0:
                texture[j * p : (j + 1) * p, i * p : (i + 1) * p] = 0
    # Texture pixel (u, v) -> board (x, y): inner corner (0, 0) lies between texture pixels 2p - 1 and 2p.
    a = np.array([[square_m / p, 0.0, (0.5 / p - 2.0) * square_m],
                  [0.0, square_m / p, (0.5 / p - 2.0) * square_m],
                  [0.0, 0.0, 1.0]])
    return render_planar_texture(camera_K, camera_R, camera_t, size, texture, a, board_rotation,
                                 board_origin_m, background, supersample)


def render_charuco(
    camera_K: ArrayLike,
    camera_R: ArrayLike,
    camera_t: ArrayLike,
    size: tuple[int, int],
    board: Any,
    board_rotation: ArrayLike,
    board_origin_m: ArrayLike,
    background: int = 110,
    supersample: int = 4,
    px_per_square: int = 120,
) -> NDArray[np.uint8]:
    """A grey image of a ChArUco board (:class:`~dyndlo_vision.tracking.calibration.CharucoBoard`) seen by a
    pinhole camera, with a white margin of one square; frames and arguments as :func:`render_checkerboard`
    (the board frame is OpenCV's: origin at the board's outer corner by the first marker).

    The texture needs enough pixels per square that the markers' bits fall on whole texture pixels: at 60 the
    detected corners were up to 0.32 px off their projections, at 120 (default) 0.00 px (frontal views).
    """
    p = px_per_square
    inner = board.opencv_board().generateImage((board.squares_x * p, board.squares_y * p), marginSize=0)
    texture = np.full(((board.squares_y + 2) * p, (board.squares_x + 2) * p), 255, np.uint8)
    texture[p:-p, p:-p] = inner
    # Texture pixel centre (u, v) -> board (x, y) = ((u + 0.5) / p - 1, (v + 0.5) / p - 1) squares.
    sq = board.square_m
    a = np.array([[sq / p, 0.0, (0.5 / p - 1.0) * sq], [0.0, sq / p, (0.5 / p - 1.0) * sq], [0.0, 0.0, 1.0]])
    return render_planar_texture(camera_K, camera_R, camera_t, size, texture, a, board_rotation,
                                 board_origin_m, background, supersample)


def render_planar_texture(
    camera_K: ArrayLike,
    camera_R: ArrayLike,
    camera_t: ArrayLike,
    size: tuple[int, int],
    texture: NDArray[np.uint8],
    texture_to_board: NDArray[np.float64],
    board_rotation: ArrayLike,
    board_origin_m: ArrayLike,
    background: int = 110,
    supersample: int = 4,
) -> NDArray[np.uint8]:
    """A grey texture on a plane seen by a pinhole camera, anti-aliased, on a uniform ``background``.

    ``texture_to_board`` (3x3) maps texture pixel centres (u, v, 1) to board-frame (x, y, 1) in metres; the
    board frame sits at ``x_world = board_rotation @ x_board + board_origin_m``, the camera at ``x_cam =
    camera_R @ x_world + camera_t``. The texture is warped through the homography at ``supersample`` times
    the resolution and averaged down.
    """
    w, h = size
    k = np.asarray(camera_K, dtype=np.float64)
    r_cb = np.asarray(camera_R, dtype=np.float64) @ np.asarray(board_rotation, dtype=np.float64)
    t_cb = np.asarray(camera_R, dtype=np.float64) @ np.asarray(board_origin_m, dtype=np.float64) + np.asarray(
        camera_t, dtype=np.float64
    )
    s = float(supersample)
    # Image pixel centres at integers: a supersampled pixel (x, y) is image point ((x + 0.5) / s - 0.5, ...).
    up = np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0.0, 0.0, 1.0]])
    homography = up @ k @ np.column_stack([r_cb[:, 0], r_cb[:, 1], t_cb]) @ texture_to_board
    big = cv2.warpPerspective(texture, homography, (w * supersample, h * supersample), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=256)
    mask = cv2.warpPerspective(np.ones_like(texture), homography, (w * supersample, h * supersample),
                               flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    big = np.where(mask > 0, big, background).astype(np.uint8)
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
