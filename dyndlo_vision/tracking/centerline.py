"""Ordered cable centreline from a binary mask: thinning, skeleton graph, ordering, resampling.

Pipeline (all pure numpy/OpenCV, designed for < 2 ms on a 640x480 mask on one core):

1. :func:`thin` - Zhang-Suen thinning of the mask, evaluated sparsely on foreground pixels
   only (``cv2.ximgproc`` is not in the headless OpenCV wheel).
2. Skeleton graph with *m-adjacency* (a diagonal neighbour counts only when the two pixels
   share no 4-neighbour), so that staircase corners of a 1-px skeleton are not mistaken for
   junctions. Pixels with one neighbour are ends, with three or more junctions; chains of
   two-neighbour pixels between them are branches.
3. Clean-up: short spurs at junctions are pruned; junctions joined by a branch shorter than
   about the cable width are contracted into one node, because a crossing of two cable
   strands thins into two Y junctions joined by a short bar rather than an X.
4. Ordering: a walk starts at the free end nearest ``anchor_uv`` (the held end), or at the
   end nearest the previous frame's start, or (neither given) at the end whose walk is the
   longest. At a junction the walk takes the unused branch that continues the incoming
   direction most smoothly; it never takes a branch twice. Where the walk reaches a free end
   it may jump a gap (occlusion, segmentation hole) to an unused free end whose direction
   agrees with the gap and with the incoming direction. Where the walk ends in a short hook
   (a blob on the cable's side bent the skeleton's end) it may cut the hook off and jump
   from its knee instead.
5. The ordered pixel path is smoothed and resampled to N nodes equally spaced in arc length.
   Nodes on bridged gaps are invisible; with ``expected_length_px`` nodes beyond the observed
   length are invisible (NaN) rather than stretched over the visible part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "Centerline",
    "Measurement2D",
    "CenterlineParams",
    "thin",
    "thin_coords",
    "extract_centerline",
    "polyline_distance",
    "resample_polyline",
    "nodes_from_path",
    "empty_centerline",
]

# Neighbour order P2..P9 of Zhang & Suen: N, NE, E, SE, S, SW, W, NW (clockwise from north).
_OFFSETS = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))


def _zhang_suen_luts() -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Deletion tables of the two Zhang-Suen sub-iterations, indexed by 8-neighbour code."""
    lut1 = np.zeros(256, dtype=bool)
    lut2 = np.zeros(256, dtype=bool)
    for code in range(256):
        p = [(code >> k) & 1 for k in range(8)]
        n_fg = sum(p)
        transitions = sum(1 for k in range(8) if p[k] == 0 and p[(k + 1) % 8] == 1)
        if not (2 <= n_fg <= 6 and transitions == 1):
            continue
        p2, _, p4, _, p6, _, p8, _ = p
        lut1[code] = p2 * p4 * p6 == 0 and p4 * p6 * p8 == 0
        lut2[code] = p2 * p4 * p8 == 0 and p2 * p6 * p8 == 0
    return lut1, lut2


_LUT1, _LUT2 = _zhang_suen_luts()


def thin_coords(mask: NDArray[np.uint8]) -> NDArray[np.intp]:
    """Zhang-Suen thinning of a binary uint8 mask (non-zero = foreground); returns the (K, 2) (row, col)
    coordinates of the skeleton pixels (what :func:`extract_centerline` thins; :func:`thin` draws them)."""
    h, w = mask.shape
    wp = w + 2
    img = np.zeros((h + 2, wp), dtype=np.uint8)
    img[1:-1, 1:-1] = mask != 0
    flat = img.reshape(-1)
    idx = np.flatnonzero(flat)
    # Each foreground pixel's 8 neighbours, gathered at once and packed into its code (bit k: P(k+2)).
    nbrs = idx[:, None] + np.array([dy * wp + dx for dy, dx in _OFFSETS])
    quiet = 0
    while idx.size and quiet < 2:  # two sub-iterations in a row without change: converged
        for lut in (_LUT1, _LUT2):
            code = np.packbits(flat[nbrs], axis=1, bitorder="little").reshape(-1)
            delete = lut[code]
            if delete.any():
                flat[idx[delete]] = 0
                keep = ~delete
                idx, nbrs = idx[keep], nbrs[keep]
                quiet = 0
            else:
                quiet += 1
                if quiet == 2:
                    break
    rows, cols = np.divmod(idx, wp)
    return np.column_stack((rows - 1, cols - 1))


def thin(mask: ArrayLike) -> NDArray[np.uint8]:
    """Zhang-Suen thinning of a binary mask to a one-pixel-wide skeleton.

    Only foreground pixels are visited (gathered by flat index), so the cost scales with the
    cable area times half its width, not with the image size.

    Args:
        mask: (H, W) binary mask (non-zero = foreground).

    Returns:
        (H, W) uint8 skeleton, 1 on skeleton pixels.
    """
    m = np.asarray(mask)
    yx = thin_coords(m)
    out = np.zeros(m.shape, dtype=np.uint8)
    out[yx[:, 0], yx[:, 1]] = 1
    return out


@dataclass(frozen=True)
class CenterlineParams:
    """Tuning of :func:`extract_centerline`; lengths in pixels unless stated.

    Lengths that scale with the cable are given as multiples of the measured cable width
    (mask area / skeleton length), so one set of defaults serves thin and thick cables.
    """

    #: Spurs (end-to-junction branches) shorter than this many widths are pruned.
    spur_widths: float = 1.5
    #: Junctions joined by a branch shorter than this many widths are one crossing.
    merge_widths: float = 4.0
    #: Skeleton within this many widths of a junction is distorted; skipped for directions
    #: and replaced by a straight bridge through the junction.
    trim_widths: float = 1.0
    #: Length over which a branch direction is measured, in widths (at least 6 px).
    dir_widths: float = 2.5
    #: Largest turn (deg) accepted to continue through a junction.
    max_turn_deg: float = 80.0
    #: Largest gap bridged between two free ends.
    max_gap_px: float = 120.0
    #: Largest angle (deg) between the gap and either end's direction.
    max_gap_angle_deg: float = 50.0
    #: A walk that ends in a hook (its last this-many widths or fewer turning more than
    #: ``max_gap_angle_deg`` away) with no gap to bridge from its end tries the gaps from the hook's knee: a
    #: blob on the cable's side (a highlight on a sphere it passes, a floor edge it crosses) bent the
    #: skeleton's end into itself before a crack in the mask, and the cable goes on beyond the crack (a gap of
    #: at most this many widths too). The hook is cut off when the branch across the gap is longer than it.
    hook_widths: float = 6.0
    #: Bridged gaps longer than this many widths make their nodes invisible. Skeleton ends
    #: stop half a width short of a mask end, so a skeleton gap is the mask gap plus about
    #: one width: 1.75 keeps cracks under ~0.75 width visible, while an occluder about as
    #: wide as the cable (another cable crossing over it) makes the nodes invisible.
    invisible_gap_widths: float = 1.75
    #: Half window (px of path) of the moving average that smooths pixel jaggies.
    smooth_half_window: int = 3
    #: Branches shorter than this that touch nothing are noise.
    min_isolated_px: float = 6.0
    #: Path ends within this many px (plus half a width) of the image border are truncated.
    border_margin_px: float = 2.0
    #: Without a start hint, walks are tried from the ends of this many longest branches.
    max_start_candidates: int = 8
    #: With a start hint, free ends up to this many widths (at least 20 px) farther from it than the nearest
    #: end are start candidates too, and one whose walk is ``hint_longer_walk`` times longer than the nearest
    #: end's wins: a blob at the held end (a gripper) cut off from the cable by a pixel or two thins into a
    #: stub, whose end is nearest the hint but whose walk is a few pixels long.
    hint_radius_widths: float = 5.0
    hint_longer_walk: float = 1.5
    #: A path at least this share of ``expected_length_px`` short is still the whole cable (its nodes are
    #: spread over it): skeletons stop short of the mask ends, by a few pixels on a rendered 200 px cable.
    length_tolerance: float = 0.035
    #: A path shorter than this many widths is no cable: a blob (a gripper, a box, a knot of noise) thins into
    #: a skeleton about as long as it is wide, while a cable is many times longer than wide.
    min_length_widths: float = 2.5
    #: A skeleton with more end/junction pixels than this is clutter (noise, a big blob),
    #: not a cable: nothing is reported, and the cost stays bounded.
    max_graph_nodes: int = 300


@dataclass(frozen=True)
class Centerline:
    """Ordered centreline of one cable in one image (a 2D measurement).

    Attributes:
        nodes_uv: (N, 2) pixel coordinates of nodes equally spaced by arc length from the
            start (held) end. NaN where a node lies beyond the observed cable.
        visible: (N,) bool, False where the cable is not observed at that node (beyond the
            observed length, or on a bridged gap where the position is interpolated).
        length_px: Arc length of the observed path in pixels (bridged gaps included).
        path_uv: (M, 2) dense ordered, smoothed path the nodes were sampled from.
        path_visible: (M-1,) bool per path segment (False on bridged gaps).
        start_at_border: The start of the path touches the image border (end cut off).
        end_at_border: The end of the path touches the image border (cable leaves the image).
        width_px: Estimated cable width in pixels (mask area / skeleton length).
    """

    nodes_uv: NDArray[np.float64]
    visible: NDArray[np.bool_]
    length_px: float
    path_uv: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    path_visible: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    start_at_border: bool = False
    end_at_border: bool = False
    width_px: float = float("nan")

    @property
    def n_nodes(self) -> int:
        """Number of nodes N."""
        return int(self.nodes_uv.shape[0])

    @property
    def any_visible(self) -> bool:
        """Whether any node is visible."""
        return bool(np.any(self.visible))

    def reversed(
        self, expected_length_px: float | None = None, image_shape: tuple[int, ...] | None = None
    ) -> Centerline:
        """The same cable ordered from the other end, resampled from the dense path.

        Args:
            expected_length_px: As in :func:`extract_centerline` (None: spread over the path).
            image_shape: Image shape for the border flags (default: keep the flags swapped).
        """
        if self.path_uv.shape[0] < 2:
            return self
        out = nodes_from_path(
            self.path_uv[::-1],
            self.path_visible[::-1],
            self.n_nodes,
            expected_length_px,
            image_shape or (10**9, 10**9),
            self.width_px,
        )
        if image_shape is None:
            out = Centerline(
                out.nodes_uv,
                out.visible,
                out.length_px,
                out.path_uv,
                out.path_visible,
                self.end_at_border,
                self.start_at_border,
                self.width_px,
            )
        return out


#: Alias: a centreline is the 2D measurement of the tracker.
Measurement2D = Centerline


def empty_centerline(n_nodes: int) -> Centerline:
    """A centreline with no visible node (nothing segmented)."""
    return Centerline(
        nodes_uv=np.full((n_nodes, 2), np.nan),
        visible=np.zeros(n_nodes, dtype=bool),
        length_px=0.0,
    )


# ---------------------------------------------------------------------------- polyline tools


def _arclength(pts: NDArray[np.float64]) -> NDArray[np.float64]:
    if pts.shape[0] == 0:
        return np.zeros(0)
    seg = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
    return np.concatenate(([0.0], np.cumsum(seg)))


def resample_polyline(pts: ArrayLike, n: int) -> NDArray[np.float64]:
    """Resamples a polyline (M, 2) to ``n`` points equally spaced in arc length."""
    p = np.asarray(pts, dtype=np.float64)
    if p.shape[0] == 0:
        return np.full((n, p.shape[1] if p.ndim == 2 else 2), np.nan)
    s = _arclength(p)
    if s[-1] == 0:
        return np.repeat(p[:1], n, axis=0)
    t = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(t, s, p[:, j]) for j in range(p.shape[1])])


def _point_to_polyline(points: NDArray[np.float64], poly: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance of each point (K, 2) to the polyline (M, 2)."""
    a = poly[:-1]
    b = poly[1:]
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    denom[denom == 0] = 1.0
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("kij,ij->ki", ap, ab) / denom, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.sqrt(np.min(np.sum((points[:, None, :] - closest) ** 2, axis=2), axis=1))


def polyline_distance(poly_a: ArrayLike, poly_b: ArrayLike, n_samples: int = 200) -> float:
    """Symmetric mean point-to-polyline distance between two polylines (pixels).

    Each polyline is resampled to ``n_samples`` points; the result is the mean of the mean
    distance of A's samples to B and of B's samples to A.
    """
    a = np.asarray(poly_a, dtype=np.float64)
    b = np.asarray(poly_b, dtype=np.float64)
    a = a[np.all(np.isfinite(a), axis=1)]
    b = b[np.all(np.isfinite(b), axis=1)]
    if a.shape[0] < 2 or b.shape[0] < 2:
        return float("inf")
    sa = resample_polyline(a, n_samples)
    sb = resample_polyline(b, n_samples)
    return 0.5 * (float(np.mean(_point_to_polyline(sa, b))) + float(np.mean(_point_to_polyline(sb, a))))


def _smooth_path(pts: NDArray[np.float64], half: int) -> NDArray[np.float64]:
    """Moving average with a window that shrinks symmetrically at the ends.

    Symmetric shrinking keeps the end points fixed and leaves straight lines unbiased.
    """
    m = pts.shape[0]
    if m < 3 or half <= 0:
        return pts.copy()
    i = np.arange(m)
    h = np.minimum(np.minimum(i, m - 1 - i), half)
    c = np.vstack((np.zeros((1, 2)), np.cumsum(pts, axis=0)))
    return (c[i + h + 1] - c[i - h]) / (2 * h + 1)[:, None]


# ---------------------------------------------------------------------------- skeleton graph


@dataclass
class _Branch:
    pts: NDArray[np.float64]  # (L, 2) (u, v) pixel coordinates, ordered from end 0 to end 1
    nodes: list[int]  # node id at end 0 and end 1
    alive: bool = True
    _s: NDArray[np.float64] | None = None

    @property
    def s(self) -> NDArray[np.float64]:
        if self._s is None:
            self._s = _arclength(self.pts)
        return self._s

    @property
    def length(self) -> float:
        return float(self.s[-1]) if self.pts.shape[0] else 0.0

    def oriented(self, end: int) -> NDArray[np.float64]:
        """Points ordered leaving the node at ``end``."""
        return self.pts if end == 0 else self.pts[::-1]

    def oriented_s(self, end: int) -> NDArray[np.float64]:
        """Arc length of :meth:`oriented`'s points from the node at ``end``."""
        return self.s if end == 0 else (self.s[-1] - self.s[::-1])


class _Graph:
    """Branch/node graph of a skeleton; nodes are ends (degree 1) or junction clusters."""

    def __init__(self) -> None:
        self.branches: list[_Branch] = []
        self.node_pos: list[NDArray[np.float64]] = []
        self.node_kind: list[str] = []  # "end", "junction", "cycle"
        self.parent: list[int] = []  # union-find over nodes (junction contraction)

    def add_node(self, pos: NDArray[np.float64], kind: str) -> int:
        self.node_pos.append(pos)
        self.node_kind.append(kind)
        self.parent.append(len(self.parent))
        return len(self.parent) - 1

    def find(self, i: int) -> int:
        while self.parent[i] != i:
            self.parent[i] = self.parent[self.parent[i]]
            i = self.parent[i]
        return i

    def ports(self) -> dict[int, list[tuple[int, int]]]:
        """Node root id -> list of (branch id, end) of live branches."""
        out: dict[int, list[tuple[int, int]]] = {}
        for bi, b in enumerate(self.branches):
            if not b.alive:
                continue
            for end in (0, 1):
                out.setdefault(self.find(b.nodes[end]), []).append((bi, end))
        return out


def _skeleton_graph(
    skel_yx: NDArray[np.intp],
    shape: tuple[int, int],
    offset: NDArray[np.float64],
    max_nodes: int | None = None,
) -> _Graph | None:
    """Builds the branch graph of skeleton pixels (row, col) inside an ROI of ``shape``.

    Returns None when more than ``max_nodes`` pixels are ends or junctions (clutter).
    """
    g = _Graph()
    n_px = skel_yx.shape[0]
    if n_px == 0:
        return g
    h, w = shape
    lab = np.full((h + 2, w + 2), -1, dtype=np.int32)
    ys = skel_yx[:, 0] + 1
    xs = skel_yx[:, 1] + 1
    lab[ys, xs] = np.arange(n_px, dtype=np.int32)
    nb = np.empty((n_px, 8), dtype=np.int32)
    for k, (dy, dx) in enumerate(_OFFSETS):
        nb[:, k] = lab[ys + dy, xs + dx]
    present = nb >= 0
    adj = present.copy()
    # m-adjacency: drop a diagonal link when the two pixels share a 4-neighbour on the skeleton.
    for k in (1, 3, 5, 7):
        adj[:, k] &= ~(present[:, k - 1] | present[:, (k + 1) % 8])
    deg = adj.sum(axis=1)
    if max_nodes is not None and np.count_nonzero(deg != 2) > max_nodes:
        return None
    rows, cols = np.nonzero(adj)
    nbr_flat = nb[rows, cols].tolist()
    starts = np.concatenate(([0], np.cumsum(deg)[:-1])).tolist()
    degl = deg.tolist()
    uv = np.column_stack((xs - 1, ys - 1)).astype(np.float64) + offset

    # Node pixels: ends and junctions. Adjacent junction pixels form one junction node.
    node_of = [-1] * n_px
    junction_px = np.flatnonzero(deg >= 3).tolist()
    for p in junction_px:
        if node_of[p] >= 0:
            continue
        nid = g.add_node(uv[p], "junction")
        stack = [p]
        node_of[p] = nid
        members = []
        while stack:
            q = stack.pop()
            members.append(q)
            for r in nbr_flat[starts[q] : starts[q] + degl[q]]:
                if degl[r] >= 3 and node_of[r] < 0:
                    node_of[r] = nid
                    stack.append(r)
        g.node_pos[nid] = uv[members].mean(axis=0)
    for p in np.flatnonzero(deg == 1).tolist():
        node_of[p] = g.add_node(uv[p], "end")

    visited = bytearray(n_px)
    seen_direct: set[tuple[int, int]] = set()

    def trace(p0: int, p1: int) -> list[int]:
        path = [p0, p1]
        prev, cur = p0, p1
        while node_of[cur] < 0:
            visited[cur] = 1
            a = nbr_flat[starts[cur]]
            b = nbr_flat[starts[cur] + 1]
            nxt = b if a == prev else a
            path.append(nxt)
            if nxt == p0 and node_of[nxt] >= 0:
                break
            prev, cur = cur, nxt
            if visited[cur] and node_of[cur] < 0:  # closed cycle came back
                break
        return path

    for p in np.flatnonzero(deg != 2).tolist():
        if degl[p] == 0 or node_of[p] < 0:
            continue
        for q in nbr_flat[starts[p] : starts[p] + degl[p]]:
            if node_of[q] >= 0:
                a, b = node_of[p], node_of[q]
                if a == b:
                    continue
                key = (min(p, q), max(p, q))
                if key in seen_direct:
                    continue
                seen_direct.add(key)
                g.branches.append(_Branch(uv[[p, q]], [a, b]))
                continue
            if visited[q]:
                continue
            path = trace(p, q)
            g.branches.append(_Branch(uv[path], [node_of[path[0]], node_of[path[-1]]]))
    # Closed loops without any end or junction: cut each at an arbitrary pixel.
    rest = [p for p in np.flatnonzero(deg == 2).tolist() if not visited[p]]
    for p in rest:
        if visited[p]:
            continue
        nid = g.add_node(uv[p], "cycle")
        node_of[p] = nid
        visited[p] = 1
        path = trace(p, nbr_flat[starts[p]])
        if path[-1] != p:
            path.append(p)
        g.branches.append(_Branch(uv[path], [nid, nid]))
    return g


def _simplify(g: _Graph, width: float, prm: CenterlineParams) -> None:
    """Prunes spurs, contracts crossings into single nodes and merges pass-through nodes."""
    spur_len = max(3.0, prm.spur_widths * width)
    merge_len = max(4.0, prm.merge_widths * width)
    for _ in range(3):
        changed = False
        ports = g.ports()
        # 1. Spurs: end -- junction branches that are short, at junctions of degree >= 3.
        for bi, b in enumerate(g.branches):
            if not b.alive:
                continue
            ends = [g.find(n) for n in b.nodes]
            kinds = [g.node_kind[n] for n in ends]
            if b.length < spur_len and "end" in kinds and "junction" in kinds:
                j = ends[kinds.index("junction")]
                if len(ports.get(j, [])) >= 3:
                    b.alive = False
                    ports[j] = [pt for pt in ports[j] if pt[0] != bi]
                    changed = True
            elif kinds == ["end", "end"] and b.length < prm.min_isolated_px:
                b.alive = False
                changed = True
        # 2. Crossings: junction -- junction bars shorter than merge_len.
        for b in g.branches:
            if not b.alive:
                continue
            a, c = g.find(b.nodes[0]), g.find(b.nodes[1])
            if a == c:
                if b.length < merge_len:  # tiny loop inside a blob
                    b.alive = False
                    changed = True
                continue
            if g.node_kind[a] == "junction" and g.node_kind[c] == "junction" and b.length < merge_len:
                b.alive = False
                g.parent[c] = a
                g.node_pos[a] = 0.5 * (g.node_pos[a] + g.node_pos[c])
                changed = True
        # 3. Junctions left with exactly two branches are just part of a branch: merge.
        ports = g.ports()
        for nid, pl in ports.items():
            if g.node_kind[nid] != "junction" or len(pl) != 2:
                continue
            (b1, e1), (b2, e2) = pl
            if b1 == b2:
                g.node_kind[nid] = "cycle"
                continue
            br1, br2 = g.branches[b1], g.branches[b2]
            if not (br1.alive and br2.alive):
                continue
            p1 = br1.oriented(1 - e1)  # ... towards the junction
            p2 = br2.oriented(e2)  # leaving the junction
            new_nodes = [br1.nodes[1 - e1], br2.nodes[1 - e2]]
            br1.alive = br2.alive = False
            g.branches.append(_Branch(np.vstack((p1, p2)), new_nodes))
            g.node_kind[nid] = "merged"
            changed = True
        if not changed:
            break


def _direction(b: _Branch, end: int, skip: float, length: float) -> NDArray[np.float64]:
    """Unit direction of branch ``b`` leaving the node at ``end``, ignoring ``skip`` px."""
    s = b.oriented_s(end)
    pts = b.oriented(end)
    total = s[-1]
    if total <= 0:
        return np.zeros(2)
    s0 = min(skip, total / 3.0)
    s1 = min(s0 + length, total)
    du, dv = np.diff(np.interp((s0, s1), s, pts[:, 0])), np.diff(np.interp((s0, s1), s, pts[:, 1]))
    n = math.hypot(du[0], dv[0])
    return np.array([du[0] / n, dv[0] / n]) if n > 0 else np.zeros(2)


def _angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    na = math.hypot(a[0], a[1])
    nb = math.hypot(b[0], b[1])
    if na == 0 or nb == 0:
        return 180.0
    c = (a[0] * b[0] + a[1] * b[1]) / (na * nb)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def _perfect_matchings(items: list[int]) -> list[list[tuple[int, int]]]:
    if not items:
        return [[]]
    first, rest = items[0], items[1:]
    out = []
    for i, other in enumerate(rest):
        for m in _perfect_matchings(rest[:i] + rest[i + 1 :]):
            out.append([(first, other), *m])
    return out


def _pair_crossings(
    g: _Graph,
    ports: dict[int, list[tuple[int, int]]],
    skip: float,
    dlen: float,
    max_turn: float,
) -> dict[tuple[int, int], tuple[int, int]]:
    """Pairs the ports of 4- and 6-way junctions so that the total turn is least.

    Greedy choice at a crossing looks only at the arriving strand; pairing all strands at
    once resolves shallow crossings and loops that leave and re-enter the same crossing.
    Pairs turning more than ``max_turn`` are left unpaired (greedy choice decides there).
    """
    out: dict[tuple[int, int], tuple[int, int]] = {}
    for nid, pl in ports.items():
        if g.node_kind[nid] != "junction" or len(pl) not in (4, 6):
            continue
        dirs = [_direction(g.branches[bi], e, skip, dlen) for bi, e in pl]
        k = len(pl)
        turn = np.zeros((k, k))
        for i in range(k):
            for j in range(k):
                # Arriving through port i means travelling along -dirs[i].
                turn[i, j] = _angle_deg(-dirs[i], dirs[j])
        best_cost, best_m = math.inf, None
        for m in _perfect_matchings(list(range(k))):
            cost = sum(turn[i, j] for i, j in m)
            if cost < best_cost:
                best_cost, best_m = cost, m
        for i, j in best_m or []:
            if turn[i, j] <= max_turn and pl[i][0] != pl[j][0]:
                out[pl[i]] = pl[j]
                out[pl[j]] = pl[i]
    return out


@dataclass
class _Walk:
    steps: list[tuple[int, int, str]]  # (branch, start end, how we entered: start/junction/gap)
    length: float
    #: Step index -> arc length (from the step's start end) past which its branch is cut off (a hook).
    cuts: dict[int, float] = field(default_factory=dict)


def _walk(
    g: _Graph,
    ports: dict[int, list[tuple[int, int]]],
    start: tuple[int, int],
    width: float,
    prm: CenterlineParams,
) -> _Walk:
    """Greedy walk over branches from a start port, through junctions and across gaps."""
    skip = prm.trim_widths * width
    dlen = max(6.0, prm.dir_widths * width)
    used: set[int] = set()
    steps: list[tuple[int, int, str]] = []
    total = 0.0
    bi, end = start
    how = "start"
    pairing = _pair_crossings(g, ports, skip, dlen, prm.max_turn_deg)
    free_ends = [(bj, ej) for nid, pl in ports.items() if g.node_kind[nid] == "end" for (bj, ej) in pl]
    free_pos = np.array([g.branches[bj].oriented(ej)[0] for bj, ej in free_ends]).reshape(-1, 2)

    def bridge(end_pt: NDArray[np.float64], arrive: NDArray[np.float64],
               max_gap_px: float = prm.max_gap_px) -> tuple[int, int] | None:
        """The unused free end a gap from ``end_pt`` (travelling along ``arrive``) best leads to, or None."""
        best_score, found = math.inf, None
        near = np.flatnonzero(np.hypot(*(free_pos - end_pt).T) <= max_gap_px).tolist()
        for c in near:
            bj, ej = free_ends[c]
            if bj in used:
                continue
            cb = g.branches[bj]
            gap = free_pos[c] - end_pt
            dist = math.hypot(gap[0], gap[1])
            leave = _direction(cb, ej, 1.0, dlen)
            if dist < 0.5 * width:
                a1 = a2 = 0.0
                turn = _angle_deg(arrive, leave)
                if turn > prm.max_turn_deg:
                    continue
            else:
                a1 = _angle_deg(arrive, gap)
                a2 = _angle_deg(gap, leave)
                if a1 > prm.max_gap_angle_deg or a2 > prm.max_gap_angle_deg:
                    continue
            score = dist * (1.0 + (a1 + a2) / 45.0)
            if score < best_score:
                best_score, found = score, (bj, ej)
        return found

    def knee(b: _Branch, end: int) -> tuple[float, NDArray[np.float64], tuple[int, int]] | None:
        """Where to cut a hook off the end of branch ``b`` (walked from ``end``) to bridge a gap from its
        knee: (arc length kept, the knee's point, the free end across the gap), or None."""
        s = b.oriented_s(end)
        pts = b.oriented(end)
        total = float(s[-1])
        tail = _direction(b, 1 - end, 1.0, dlen)  # leaving the branch's far end, backwards
        step = max(1.0, 0.5 * width)
        back = step
        while back <= min(prm.hook_widths * width, total / 2.0):
            s_cut = total - back
            before, at = np.column_stack([np.interp((max(0.0, s_cut - dlen), s_cut), s, pts[:, j])
                                          for j in (0, 1)])
            heading = at - before
            if _angle_deg(heading, -tail) > prm.max_gap_angle_deg:  # the hook turns away from here on
                jump = bridge(at, heading, prm.hook_widths * width)  # a crack, not an occlusion
                if jump is not None and g.branches[jump[0]].length > back:
                    return s_cut, at, jump
            back += step
        return None

    cuts: dict[int, float] = {}
    while True:
        used.add(bi)
        steps.append((bi, end, how))
        b = g.branches[bi]
        total += b.length
        far = 1 - end
        node = g.find(b.nodes[far])
        arrive = -_direction(b, far, skip if g.node_kind[node] == "junction" else 1.0, dlen)
        nxt: tuple[int, int] | None = None
        if g.node_kind[node] in ("junction", "cycle"):
            # A crossing's strands pair up as a whole; follow the pairing when possible.
            partner = pairing.get((bi, far))
            if partner is not None and partner[0] not in used:
                bi, end = partner
                how = "junction"
                continue
            best = prm.max_turn_deg
            for bj, ej in ports.get(node, []):
                if bj in used:
                    continue
                ang = _angle_deg(arrive, _direction(g.branches[bj], ej, skip, dlen))
                if ang <= best:
                    best, nxt = ang, (bj, ej)
            if nxt is not None:
                bi, end = nxt
                how = "junction"
                continue
        # Dead end (free end, or no smooth continuation): try to bridge a gap.
        end_pt = b.oriented(end)[-1]
        nxt = bridge(end_pt, arrive)
        if nxt is None and (hooked := knee(b, end)) is not None:
            s_cut, end_pt, nxt = hooked
            cuts[len(steps) - 1] = s_cut
            total -= b.length - s_cut
        if nxt is None:
            break
        gp = g.branches[nxt[0]].oriented(nxt[1])[0]
        total += math.hypot(*(gp - end_pt))
        bi, end = nxt
        how = "gap"
    return _Walk(steps, total, cuts)


def _assemble(
    g: _Graph, walk: _Walk, width: float, prm: CenterlineParams
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Concatenates the walked branches into one path; returns points and segment visibility."""
    trim = prm.trim_widths * width
    invisible_gap = prm.invisible_gap_widths * width
    pieces: list[NDArray[np.float64]] = []
    seg_vis: list[NDArray[np.bool_]] = []
    n_steps = len(walk.steps)
    for i, (bi, end, how) in enumerate(walk.steps):
        b = g.branches[bi]
        pts = b.oriented(end)
        s = b.oriented_s(end)
        total = s[-1]
        lo, hi = 0.0, total
        # Cut the skeleton distorted by a junction on both sides; the straight join through
        # the junction is closer to a crossing strand than the skeleton's detour.
        if how == "junction":
            lo = min(trim, total / 3.0)
        if i + 1 < n_steps and walk.steps[i + 1][2] == "junction":
            hi = max(total - min(trim, total / 3.0), lo)
        if i in walk.cuts:  # a hook cut off before a gap
            hi = max(min(hi, walk.cuts[i]), lo)
        keep = (s >= lo) & (s <= hi)
        if not np.any(keep):
            keep[np.argmin(np.abs(s - 0.5 * (lo + hi)))] = True
        part = pts[keep]
        if pieces:
            gap = float(np.hypot(*(part[0] - pieces[-1][-1])))
            seg_vis.append(np.array([not (how == "gap" and gap > invisible_gap)]))
        pieces.append(part)
        if part.shape[0] > 1:
            seg_vis.append(np.ones(part.shape[0] - 1, dtype=bool))
    path = np.vstack(pieces)
    vis = np.concatenate(seg_vis) if seg_vis else np.zeros(0, dtype=bool)
    return path, vis


def _choose_start(
    g: _Graph,
    ports: dict[int, list[tuple[int, int]]],
    hint: NDArray[np.float64] | None,
    width: float,
    prm: CenterlineParams,
) -> tuple[_Walk | None, list[tuple[int, int]]]:
    end_ports = [(bi, e) for nid, pl in ports.items() if g.node_kind[nid] == "end" for (bi, e) in pl]
    if not end_ports:
        # Closed loop(s) only: start anywhere on a cycle or junction.
        end_ports = [pl[0] for nid, pl in ports.items() if pl]
    if not end_ports:
        return None, []
    if hint is not None:
        d = np.array([float(np.hypot(*(g.branches[bi].oriented(e)[0] - hint))) for bi, e in end_ports])
        nearest = int(np.argmin(d))
        chosen = _walk(g, ports, end_ports[nearest], width, prm)
        radius = d[nearest] + max(20.0, prm.hint_radius_widths * width)
        for i in np.argsort(d, kind="stable")[1 : prm.max_start_candidates]:
            if d[i] > radius:
                break
            w = _walk(g, ports, end_ports[int(i)], width, prm)
            if w.length > prm.hint_longer_walk * chosen.length:
                chosen = w
        return chosen, end_ports
    # The longest walk starts at an end of a long branch; trying a few keeps clutter cheap.
    end_ports.sort(key=lambda p: -g.branches[p[0]].length)
    best: _Walk | None = None
    for sp in end_ports[: prm.max_start_candidates]:
        w = _walk(g, ports, sp, width, prm)
        if best is None or w.length > best.length + 1e-9:
            best = w
    return best, end_ports


def extract_centerline(
    mask: ArrayLike,
    n_nodes: int = 20,
    anchor_uv: ArrayLike | None = None,
    expected_length_px: float | None = None,
    prev_nodes_uv: ArrayLike | None = None,
    params: CenterlineParams | None = None,
) -> Centerline:
    """Extracts the ordered centreline of the (single) cable in a binary mask.

    Args:
        mask: (H, W) bool/uint8 mask of the cable.
        n_nodes: Number N of output nodes (>= 2).
        anchor_uv: Pixel near the held end; the free end nearest it becomes node 0.
        expected_length_px: Full cable length in pixels, if known: nodes are spaced
            ``expected_length_px / (N - 1)`` apart and those beyond the observed length are
            invisible (NaN) instead of the nodes being stretched over the visible part.
        prev_nodes_uv: (N, 2) nodes of the previous frame; without an anchor, the free end
            nearest the previous node 0 becomes node 0 (no head/tail flips).
        params: Tuning, see :class:`CenterlineParams`.

    Returns:
        The :class:`Centerline`; all nodes invisible when nothing usable is in the mask.
    """
    if n_nodes < 2:
        raise ValueError(f"n_nodes must be >= 2, got {n_nodes}")
    prm = params or CenterlineParams()
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {m.shape}")
    m8 = m.astype(np.uint8) if m.dtype != np.uint8 else m
    x0, y0, bw, bh = cv2.boundingRect(m8)
    if bw == 0 or bh == 0:
        return empty_centerline(n_nodes)
    roi = m8[y0 : y0 + bh, x0 : x0 + bw]
    yx = thin_coords(roi)
    if yx.shape[0] < 2:
        return empty_centerline(n_nodes)
    area = float(cv2.countNonZero(roi))
    width = max(1.0, area / yx.shape[0])
    g = _skeleton_graph(yx, (bh, bw), np.array([x0, y0], dtype=np.float64), prm.max_graph_nodes)
    if g is None:
        return empty_centerline(n_nodes)
    _simplify(g, width, prm)
    ports = g.ports()

    hint: NDArray[np.float64] | None = None
    if anchor_uv is not None:
        hint = np.asarray(anchor_uv, dtype=np.float64).reshape(2)
    elif prev_nodes_uv is not None:
        prev = np.asarray(prev_nodes_uv, dtype=np.float64).reshape(-1, 2)
        finite = np.flatnonzero(np.all(np.isfinite(prev), axis=1))
        if finite.size:
            hint = prev[finite[0]]
    walk, _ = _choose_start(g, ports, hint, width, prm)
    if walk is None or not walk.steps:
        return empty_centerline(n_nodes)
    path, seg_vis = _assemble(g, walk, width, prm)
    if path.shape[0] < 2:
        return empty_centerline(n_nodes)
    if anchor_uv is not None and np.hypot(*(path[-1] - hint)) < np.hypot(*(path[0] - hint)):
        # No free end near the anchor to start from (a pinhole in the mask near the held end closes a small
        # loop there), so the walk started at the far end and ended at the held end: node 0 is the held end
        # all the same. Else the tip would be reported at the hand.
        path, seg_vis = path[::-1].copy(), seg_vis[::-1].copy()
    # Smooth each run of pixel steps separately: averaging across a long bridge (gap or
    # junction) would smear the bridge over its neighbours and shift node visibility.
    jumps = np.flatnonzero(np.hypot(*np.diff(path, axis=0).T) > 2.0) + 1
    path = np.vstack([_smooth_path(piece, prm.smooth_half_window) for piece in np.split(path, jumps)])
    if float(_arclength(path)[-1]) < prm.min_length_widths * width:
        return empty_centerline(n_nodes)
    return nodes_from_path(path, seg_vis, n_nodes, expected_length_px, m.shape, width, prm)


def nodes_from_path(
    path_uv: NDArray[np.float64],
    path_visible: NDArray[np.bool_],
    n_nodes: int,
    expected_length_px: float | None,
    image_shape: tuple[int, ...],
    width_px: float,
    params: CenterlineParams | None = None,
) -> Centerline:
    """Resamples a dense ordered path into a :class:`Centerline` of N nodes.

    Args:
        path_uv: (M, 2) ordered path from the held end.
        path_visible: (M-1,) visibility per path segment.
        n_nodes: Number of nodes N.
        expected_length_px: Full cable length in px, or None to spread the nodes over the path.
        image_shape: Shape of the image, for the border test.
        width_px: Cable width in px.
        params: Tuning (border margin).
    """
    prm = params or CenterlineParams()
    path = np.ascontiguousarray(path_uv, dtype=np.float64)
    seg_vis = np.ascontiguousarray(path_visible, dtype=bool)
    if path.shape[0] < 2:
        return empty_centerline(n_nodes)
    s = _arclength(path)
    length = float(s[-1])
    if length <= 0:
        return empty_centerline(n_nodes)
    h_img, w_img = image_shape[:2]
    margin = prm.border_margin_px + 0.5 * width_px

    def at_border(p: NDArray[np.float64]) -> bool:
        return bool(p[0] < margin or p[1] < margin or p[0] > w_img - 1 - margin or p[1] > h_img - 1 - margin)

    total = float(expected_length_px) if expected_length_px else length
    if expected_length_px and length >= (1.0 - prm.length_tolerance) * total:
        total = length
    s_nodes = np.linspace(0.0, total, n_nodes)
    inside = s_nodes <= length + 1e-6
    nodes = np.full((n_nodes, 2), np.nan)
    nodes[inside, 0] = np.interp(s_nodes[inside], s, path[:, 0])
    nodes[inside, 1] = np.interp(s_nodes[inside], s, path[:, 1])
    seg = np.clip(np.searchsorted(s, s_nodes[inside], side="right") - 1, 0, seg_vis.size - 1)
    visible = np.zeros(n_nodes, dtype=bool)
    visible[inside] = seg_vis[seg]
    return Centerline(
        nodes_uv=nodes,
        visible=visible,
        length_px=length,
        path_uv=path,
        path_visible=seg_vis,
        start_at_border=at_border(path[0]),
        end_at_border=at_border(path[-1]),
        width_px=width_px,
    )
