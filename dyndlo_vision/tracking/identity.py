"""Which end of a cable seen in a frame is the held one: continuity, registration of the last frame's nodes,
and where the robot says the gripper is.

A cable's two ends look alike on an image; a tip taken for the held end is the worst answer a tracker can
give (it reports the gripper as the tip, as measured). So the held end's identity is carried from frame to
frame and re-checked in every frame, and a frame where the two ends cannot be told apart is not measured.

Evidence, per frame:

* **continuity** (:class:`HeldEnd`): the held end moves like a robot's gripper, smoothly, at a bounded
  acceleration and speed, while a whipped tip accelerates several times harder. A constant-velocity Kalman
  filter on its pixel, driven by the gripper's acceleration, predicts it; its gate is three standard
  deviations of the prediction, at most ``max_speed_m_s * dt`` wider than at the last identification and at
  most a share of the cable's length. The end in the gate is the held end when the other end is clearly
  farther (a Gaussian likelihood ratio of at least 1000 with the gate at three sigma);
* **gravity**: a cable that hangs still hangs below its held end. While the cable is still, a held end found
  below the other end makes the frame ambiguous, and a lost held end is found again as the upper end;
* **registration** (:func:`order_correlation`): the last frame's nodes, ordered from the held end, are
  registered to the new centreline (each to its nearest point there, after moving them with the held end);
  the order in which they land along it says which way the centreline runs. It decides when both ends are
  near the held end's prediction (a tip passing the gripper), and a strong disagreement with continuity
  makes the frame ambiguous;
* **the robot's pose**, where it is known (the loop, ``track --tcp-log``): the held end's pixel is the
  gripper's projection, its gate the gripper's size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["HeldEnd", "IdentityParams", "order_correlation", "orient"]


@dataclass(frozen=True)
class IdentityParams:
    """Tuning of the held end's identification (lengths in pixels unless named otherwise).

    Attributes:
        max_accel_m_s2: The largest acceleration of the held end (the gripper): its gate grows by
            ``max_accel * dt^2 / 2`` with the time since it was last seen. The generated whip videos' grippers
            reach 48 m/s^2 (p99, at the frame rate), a whipped tip 160 m/s^2.
        max_speed_m_s: ... but by at most ``max_speed * dt``: the generated grippers move at up to 2.3 m/s
            (p99), 4.1 m/s at most.
        min_gate_px: The held end's gate is at least this wide (and at least three cable widths).
        separation: Continuity decides when the other end is farther from the held end's prediction than
            ``sqrt(d_near^2 + separation * gate^2)``: with the gate at three sigma, 1.5 is a Gaussian
            likelihood ratio of 1000. Nearer, the registration (or the gripper's blob) decides.
        min_order: Registration decides (or vetoes continuity) when the rank correlation of the registered
            nodes is at least this strong ...
        min_registered: ... and at least this many nodes registered.
        register_widths: A node registers to the new centreline when it lies within this many cable widths of
            it (at least ``min_gate_px``), after the held end's motion is taken out.
        lost_s: After this long without an identification the held end's track is lost; it is found again
            only where the cable hangs still (its upper end), or at the robot's reported pose.
        max_gate_share: The held end's gate is at most this share of the cable's length on the image.
        coast_s: An unseen held end is predicted on its last velocity for at most this long (a gripper that
            whipped stops), and held there after.
    """

    max_accel_m_s2: float = 60.0
    max_speed_m_s: float = 4.0
    min_gate_px: float = 10.0
    separation: float = 1.5
    min_order: float = 0.6
    min_registered: int = 4
    register_widths: float = 4.0
    lost_s: float = 0.4
    max_gate_share: float = 0.5
    coast_s: float = 0.06

    def __post_init__(self) -> None:
        for name in (
            "max_accel_m_s2",
            "max_speed_m_s",
            "min_gate_px",
            "separation",
            "min_order",
            "register_widths",
            "lost_s",
            "max_gate_share",
            "coast_s",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if self.min_order > 1:
            raise ValueError(f"min_order must be at most 1, got {self.min_order!r}")
        if not isinstance(self.min_registered, int) or self.min_registered < 2:
            raise ValueError(f"min_registered must be an int >= 2, got {self.min_registered!r}")


def _ranks(x: NDArray[np.float64]) -> NDArray[np.float64]:
    order = np.argsort(x, kind="stable")
    ranks = np.empty(len(x))
    ranks[order] = np.arange(len(x), dtype=np.float64)
    # ties share their mean rank
    values, inverse = np.unique(x, return_inverse=True)
    if len(values) < len(x):
        sums = np.bincount(inverse, weights=ranks)
        counts = np.bincount(inverse)
        ranks = (sums / counts)[inverse]
    return ranks


def order_correlation(
    prev_nodes: NDArray[np.float64], path_uv: NDArray[np.float64], max_dist_px: float
) -> tuple[float, int]:
    """How the last frame's nodes (ordered from the held end) lie along a new centreline path.

    Each finite node registers to its nearest point of ``path_uv`` when it lies within ``max_dist_px`` of it;
    the result is the rank correlation (Spearman) between the nodes' order and their arc positions along the
    path: +1 when the path runs from the held end the same way, -1 when it runs from the other end.

    Returns:
        (correlation, number of registered nodes); (0, n) when fewer than two registered or all at one place.
    """
    nodes = np.asarray(prev_nodes, dtype=np.float64).reshape(-1, 2)
    path = np.asarray(path_uv, dtype=np.float64).reshape(-1, 2)
    index = np.flatnonzero(np.all(np.isfinite(nodes), axis=1))
    if index.size < 2 or len(path) < 2:
        return 0.0, 0
    d2 = np.sum((nodes[index, None, :] - path[None, :, :]) ** 2, axis=2)
    nearest = np.argmin(d2, axis=1)
    close = d2[np.arange(index.size), nearest] <= max_dist_px**2
    if np.count_nonzero(close) < 2:
        return 0.0, int(np.count_nonzero(close))
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))))[nearest[close]]
    i = index[close].astype(np.float64)
    ri, rs = _ranks(i), _ranks(s)
    if np.ptp(rs) == 0:
        return 0.0, int(close.sum())
    return float(np.corrcoef(ri, rs)[0, 1]), int(close.sum())


class HeldEnd:
    """The held end's track in one view: a constant-velocity Kalman filter on its pixel.

    Args:
        params: The tuning.
        px_per_m: The image scale near the cable (pixels per metre), which turns the gripper's acceleration
        and
            speed into pixels.
    """

    def __init__(self, params: IdentityParams, px_per_m: float) -> None:
        self.params = params
        self.px_per_m = float(px_per_m)
        #: Spectral density of the white acceleration (px^2/s^3): the gripper's largest acceleration per 40
        #: ms.
        self.q = (params.max_accel_m_s2 * self.px_per_m) ** 2 * 0.04
        self.reset()

    def reset(self) -> None:
        """Forgets the track."""
        self.x = np.zeros(4)
        self.P = np.eye(4)
        self.t: float = -math.inf
        self.known = False

    @property
    def uv(self) -> NDArray[np.float64] | None:
        """The held end's pixel at its last identification (None before the first)."""
        return self.x[:2].copy() if self.known else None

    def lost_at(self, t: float) -> bool:
        """Whether the track is lost at ``t`` (never identified, or not for longer than ``lost_s``)."""
        return not self.known or abs(t - self.t) > self.params.lost_s

    def _predicted(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        dt = t - self.t
        F = np.eye(4)
        F[0, 2] = F[1, 3] = math.copysign(min(abs(dt), self.params.coast_s), dt)
        a = abs(dt)
        Q = np.zeros((4, 4))
        for i in (0, 1):
            Q[i, i] = self.q * a**3 / 3
            Q[i, i + 2] = Q[i + 2, i] = self.q * a**2 / 2
            Q[i + 2, i + 2] = self.q * a
        return F @ self.x, F @ self.P @ F.T + Q

    def predict(self, t: float) -> NDArray[np.float64] | None:
        """The held end's pixel predicted at ``t``, None before the first identification."""
        if not self.known:
            return None
        return self._predicted(t)[0][:2]

    def gate(self, t: float, width_px: float, cable_px: float, noise_px: float = 2.0) -> float:
        """The radius (px) within which the held end is expected at ``t``: three standard deviations of the
        prediction plus the measurement, widened to at least the base (``min_gate_px``, three widths), at most
        ``max_speed_m_s * dt`` beyond the base and at most ``max_gate_share`` of the cable (``cable_px``)."""
        p = self.params
        base = max(p.min_gate_px, 3.0 * width_px, 3.0 * noise_px)
        if not self.known:
            return base
        _, P = self._predicted(t)
        sigma = math.sqrt(float(np.linalg.eigvalsh(P[:2, :2])[-1]) + noise_px**2)
        dt = abs(t - self.t)
        return float(
            min(
                max(3.0 * sigma, base),
                base + p.max_speed_m_s * dt * self.px_per_m,
                max(base, p.max_gate_share * cable_px),
            )
        )

    def update(self, uv: NDArray[np.float64], t: float, noise_px: float = 2.0) -> None:
        """The held end identified at ``uv`` at ``t`` (a lost track starts again there, at rest)."""
        z = np.asarray(uv, dtype=np.float64).reshape(2)
        if self.lost_at(t):
            self.x = np.array([z[0], z[1], 0.0, 0.0])
            speed = self.params.max_speed_m_s * self.px_per_m / 3.0
            self.P = np.diag([noise_px**2, noise_px**2, speed**2, speed**2])
        else:
            x, P = self._predicted(t)
            S = P[:2, :2] + np.eye(2) * noise_px**2
            K = P[:, :2] @ np.linalg.inv(S)
            self.x = x + K @ (z - x[:2])
            self.P = (np.eye(4) - K[:, :2] @ np.eye(2, 4)) @ P
        self.t = float(t)
        self.known = True


@dataclass(frozen=True)
class Orientation:
    """The outcome of :func:`orient`: ``held_at_start`` (True: the path runs from the held end; False: from
    the other end; None: cannot tell) and why."""

    held_at_start: bool | None
    reason: str
    registered: int = 0
    correlation: float = 0.0


def orient(
    path_uv: NDArray[np.float64],
    held_uv: NDArray[np.float64] | None,
    gate_px: float,
    prev_nodes: NDArray[np.float64] | None,
    register_px: float,
    params: IdentityParams,
    held_shift: NDArray[np.float64] | None = None,
) -> Orientation:
    """Which end of ``path_uv`` is the held one.

    Args:
        path_uv: The centreline's dense path.
        held_uv: Where the held end is expected (None: nowhere known).
        gate_px: How far from ``held_uv`` it may be.
        prev_nodes: The last frame's nodes, held end first (None: none recent).
        register_px: A node registers within this distance of the path.
        params: The tuning.
        held_shift: The held end's motion since ``prev_nodes``, added to them before they are registered.
    """
    path = np.asarray(path_uv, dtype=np.float64).reshape(-1, 2)
    rho, n = 0.0, 0
    if prev_nodes is not None:
        nodes = np.asarray(prev_nodes, dtype=np.float64).reshape(-1, 2)
        if held_shift is not None:
            nodes = nodes + held_shift
        rho, n = order_correlation(nodes, path, register_px)
    decisive = n >= params.min_registered and abs(rho) >= params.min_order
    if held_uv is None:
        if decisive:
            return Orientation(rho > 0, "registration", n, rho)
        return Orientation(None, "no held end to follow", n, rho)
    d = (float(np.hypot(*(path[0] - held_uv))), float(np.hypot(*(path[-1] - held_uv))))
    near = 0 if d[0] <= d[1] else 1
    if d[near] > gate_px:
        return Orientation(None, "held end not seen", n, rho)
    if d[1 - near] ** 2 >= d[near] ** 2 + params.separation * gate_px**2:
        if decisive and (rho > 0) != (near == 0):
            return Orientation(None, "continuity and registration disagree", n, rho)
        return Orientation(near == 0, "continuity", n, rho)
    # Both ends near where the held end should be (a tip passing the gripper): the registration decides, and
    # the end it names must be in the gate.
    if decisive:
        at = 0 if rho > 0 else 1
        if d[at] <= gate_px:
            return Orientation(at == 0, "registration", n, rho)
    return Orientation(None, "ends too close to tell apart", n, rho)


class GripperTemplate:
    """The gripper's appearance, followed from frame to frame: where the held end is, whatever the cable's
    segmentation does near it.

    The gripper is rigid and moves smoothly; around the pixel the user clicked in the first frame (the held
    end, on the gripper) a square patch is its template, found again in each frame by normalised
    cross-correlation (``cv2.matchTemplate``) within a window around its constant-velocity prediction. A match
    below ``min_score`` (motion blur, an occluder, the gripper leaving the image) is no match. The template
    follows slow changes (light) by blending in patches that match well. A patch that is not distinctive in
    its first frame (it matches its surroundings nearly as well as itself: a plain wall, a stretch of cable)
    is no template at all (:attr:`usable`).

    Args:
        rgb: The first frame.
        uv: The clicked pixel.
        size_px: The patch's side (odd).
        min_score: The least correlation of a match ...
        min_margin: ... by at least this much above any other place in the search window.
        max_other_score: In the first frame, a template that matches anywhere else near it above this is not
            distinctive.
    """

    def __init__(
        self,
        rgb: NDArray[np.uint8],
        uv: NDArray[np.float64],
        size_px: int,
        min_score: float = 0.8,
        max_other_score: float = 0.6,
        min_margin: float = 0.1,
    ) -> None:
        import cv2

        self.size = int(size_px) | 1
        self.min_score = float(min_score)
        self.min_margin = float(min_margin)
        self.template = self._patch(rgb, np.asarray(uv, dtype=np.float64))
        self.uv = np.asarray(uv, dtype=np.float64).reshape(2)
        self.velocity = np.zeros(2)
        self.t = -math.inf
        self.score = 0.0
        if self.template is not None:
            # Distinctive: away from its own place (a third of its size) nothing within three sizes matches it
            # above ``max_other_score``.
            r, s = self.size // 2, 3 * self.size
            h, w = rgb.shape[:2]
            u, v = int(round(self.uv[0])), int(round(self.uv[1]))
            u0, v0, u1, v1 = max(0, u - s), max(0, v - s), min(w, u + s + 1), min(h, v + s + 1)
            scores = cv2.matchTemplate(
                rgb[v0:v1, u0:u1].astype(np.float32), self.template, cv2.TM_CCOEFF_NORMED
            )
            vv, uu = np.mgrid[0 : scores.shape[0], 0 : scores.shape[1]]
            away = np.hypot(uu + u0 + r - u, vv + v0 + r - v) > self.size / 3
            if away.any() and float(scores[away].max()) > max_other_score:
                self.template = None

    @property
    def usable(self) -> bool:
        """Whether the template is distinctive enough to follow."""
        return self.template is not None

    def _patch(self, rgb: NDArray[np.uint8], uv: NDArray[np.float64]) -> NDArray[np.float32] | None:
        h, w = rgb.shape[:2]
        r = self.size // 2
        u, v = int(round(uv[0])), int(round(uv[1]))
        if u - r < 0 or v - r < 0 or u + r + 1 > w or v + r + 1 > h:
            return None
        return rgb[v - r : v + r + 1, u - r : u + r + 1].astype(np.float32)

    def _window_scores(
        self, rgb: NDArray[np.uint8], centre: NDArray[np.float64], radius_px: float
    ) -> tuple[NDArray[np.float32], int, int] | None:
        """The template's correlation at every place within ``radius_px`` of ``centre`` (and the window's
        corner, u0 and v0); None where the window is smaller than the template."""
        import cv2

        h, w = rgb.shape[:2]
        s = int(math.ceil(radius_px)) + self.size // 2
        u0, v0 = max(0, int(centre[0]) - s), max(0, int(centre[1]) - s)
        u1, v1 = min(w, int(centre[0]) + s + 1), min(h, int(centre[1]) + s + 1)
        if u1 - u0 < self.size or v1 - v0 < self.size:
            return None
        window = rgb[v0:v1, u0:u1].astype(np.float32)
        return cv2.matchTemplate(window, self.template, cv2.TM_CCOEFF_NORMED), u0, v0

    def seen_near(self, rgb: NDArray[np.uint8], uv: NDArray[np.float64], radius_px: float) -> bool:
        """Whether the gripper's template matches (at least ``min_score``) somewhere within ``radius_px`` of
        ``uv``: a check, which changes nothing of the template's state."""
        if self.template is None or not np.all(np.isfinite(uv)):
            return False
        found = self._window_scores(rgb, np.round(np.asarray(uv, dtype=np.float64)), radius_px)  # nearest px
        return found is not None and bool(float(found[0].max()) >= self.min_score)

    def locate(self, rgb: NDArray[np.uint8], t: float, search_px: float) -> NDArray[np.float64] | None:
        """The gripper's pixel in ``rgb`` (taken at ``t``), searched within ``search_px`` of its prediction;
        None when it matches nowhere well enough."""
        import cv2

        if self.template is None:
            return None
        dt = 0.0 if not math.isfinite(self.t) else min(t - self.t, 0.06)
        found = self._window_scores(rgb, self.uv + self.velocity * dt, search_px)
        if found is None:
            return None
        scores, u0, v0 = found
        r = self.size // 2
        _, best, _, (bu, bv) = cv2.minMaxLoc(scores)
        self.score = float(best)
        if not best >= self.min_score:
            return None
        # Unique: nothing away from the peak (half the template's size) matches nearly as well.
        vv, uu = np.mgrid[0 : scores.shape[0], 0 : scores.shape[1]]
        away = np.hypot(uu - bu, vv - bv) > self.size / 2
        if away.any() and float(scores[away].max()) > best - self.min_margin:
            return None
        # sub-pixel peak: a parabola through the neighbours on each axis
        du = dv = 0.0
        if 0 < bu < scores.shape[1] - 1:
            a, b, c = scores[bv, bu - 1], scores[bv, bu], scores[bv, bu + 1]
            du = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) < 0 else 0.0
        if 0 < bv < scores.shape[0] - 1:
            a, b, c = scores[bv - 1, bu], scores[bv, bu], scores[bv + 1, bu]
            dv = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) < 0 else 0.0
        uv = np.array([u0 + bu + r + du, v0 + bv + r + dv])
        if math.isfinite(self.t) and 0 < t - self.t <= 0.1:
            self.velocity = (uv - self.uv) / (t - self.t)
        else:
            self.velocity = np.zeros(2)
        self.uv, self.t = uv, float(t)
        if best >= 0.9:  # follow slow changes of light and shading
            patch = self._patch(rgb, uv)
            if patch is not None:
                self.template = 0.9 * self.template + 0.1 * patch
        return uv
