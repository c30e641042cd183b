"""How cable segmentation generalises to scenes it was not trained on, per kind of scene.

Every figure is per *kind*, never only pooled: a network that does well on average can fail a whole kind.

* ``external``: the labelled real photos of ``../shared/data/external``, per source (mBEST, cables_dataset)
  and per half of :func:`dyndlo_vision.learning.segtrain.external_split` (``heldout``: odd positions, never
  trained on; ``train``: what a fine-tuned network saw). Mean mask DICE, mean DICE within 1 px
  (:func:`~dyndlo_vision.tracking.segmentation.dice_within`: boundaries a pixel off forgiven; the
  cables_dataset labels sit about a pixel beside the cables in its photos) and the share of images whose mask
  is empty or near-empty (fewer cable pixels than a tenth of the truth's). Every kind also says where its
  DICE is lost (:func:`~dyndlo_vision.tracking.segmentation.dice_losses`, ``loss_mean``, adding up with the
  mean DICE to 1): cable missed, by the cable's width (1-2, 3-8, 9+ px), and mask beside a cable (within
  2 px) or away from any (other things taken for cable); and the share of cable pixels found per width.
* ``labels`` (not a default part): how well each external source's labels agree with the edges in its
  photos, from profiles across the cables (:func:`label_profiles`): the photo's and the label's cable widths,
  the offset of their centres, and the 1-D DICE of the two, the most a mask that follows the photo exactly
  can score in DICE against those labels; and, per half, the 1-D DICE of the segmenter's mask against the
  same photo edges, a figure the labels' errors do not enter.
* ``styles``: generated scenes of every ``seg-data`` style (:data:`dyndlo_vision.learning.segdata.STYLES`),
  drawn on the fly with a seed of their own (``--style-seed``: 1000 for development, 2000 for the sealed test
  range), or read from ``seg-data`` folders (``--sets``). Same figures per style; samples whose truth holds
  fewer than 20 cable pixels (a cable out of view) are counted apart.
* ``flat``: flat-coloured synthetic cables 1-11 px wide on plain walls (640x480): median DICE per width.
* ``phase``: a straight 1.6 px line at each of the four horizontal offsets within the 4x4 pixel blocks a block
  network reads: the share of lines found (median probability > 0.5) at the worst and the best offset.
* ``speed``: milliseconds per 640x480 frame of the segmenter (ONNX Runtime on ``learned.ENGINE_THREADS``
  threads) and, on one core, of the classical segmenter and the centreline.
* ``whip``: rendered whip videos of a dark 2.5 px cable in three styles no generator draws (plain wall,
  wood grain with motion blur, a pole in front): mask DICE and tip figures.
* ``loopcam``: the control loop's own camera (tip control, 640x480, a 1.6 px red cable): DICE and time at
  three network scales.

Every kind's mean DICE comes with its standard error (``dice_se``): over 50 generated scenes it is about
0.03, so one network's figures for a kind are known to about +-0.06. Two networks are compared on the same
images with ``--against OTHER.json`` (the other's report): ``paired`` holds, per kind, the mean per-image
difference and its standard error, a third to a tenth of that spread.

``--worst DIR`` writes, per kind, the worst images as PNG panels (photo, truth, mask) to look at.
``--quick`` runs a few images of every kind and no videos (what the test runs)::

    python benchmarks/segmentation_generalisation.py --out seg.json [--model NAME|FILE.onnx]
        [--short-side N] [--parts external,styles] [--style-seed 2000 --per-style 100] [--worst DIR]
        [--against OTHER.json]
    python benchmarks/segmentation_generalisation.py --model cable-segmenter-photo-wide --parts labels \
        --out labels.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from dyndlo_vision.learning.segdata import STYLES, SegDataConfig, make_sampler
from dyndlo_vision.learning.segtrain import external_source, external_split
from dyndlo_vision.sim.cable_look import CableLook
from dyndlo_vision.tracking import BackgroundSegmenter, cable_widths, dice, dice_losses, dice_within
from dyndlo_vision.tracking.centerline import extract_centerline
from dyndlo_vision.tracking.learned import LearnedSegmenter
from dyndlo_vision.tracking.networks import onnx_bytes
from dyndlo_vision.tracking.segmentation import WIDTH_BANDS
from dyndlo_vision.tracking.tracker import Measurement, Plane, lift_with_plane, tip_from_polyline

EXTERNAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "external"

#: A mask with fewer cable pixels than this share of the truth's counts as empty or near-empty.
NEAR_EMPTY = 0.1

#: Image size of the generated scenes per style (what ``seg-data`` was run with for training).
STYLE_SIZES = {"random-scenes": (320, 240), "task-scenes": (640, 480)}
COMPOSITE_SIZE = (384, 288)


def _read(path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"cannot read {path}")
    return np.ascontiguousarray(bgr[..., ::-1])


#: Per-image shares of ``|mask| + |truth|`` lost (:func:`~dyndlo_vision.tracking.segmentation.dice_losses`).
LOSSES = tuple(f"missed_{name}" for _, _, name in WIDTH_BANDS) + ("extra_near", "extra_away")


def _score(mask: np.ndarray, truth: np.ndarray) -> dict:
    widths = cable_widths(truth)
    losses = dice_losses(mask, truth, widths=widths)
    band = {name: truth & (widths >= lo) & (widths < hi) for lo, hi, name in WIDTH_BANDS}
    return {"dice": losses["dice"], "dice_1px": dice_within(mask, truth, 1.0),
            "near_empty": bool(mask.sum() < NEAR_EMPTY * truth.sum()),
            "mask_share": float(mask.sum() / max(1, truth.sum())),
            "losses": {k: losses[k] for k in LOSSES},
            "true_px": {name: int(m.sum()) for name, m in band.items()},
            "found_px": {name: int((m & mask).sum()) for name, m in band.items()}}


def _standard_error(values: list[float]) -> float | None:
    """The standard error of the values' mean (sample standard deviation over sqrt(n)); None under 2."""
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) >= 2 else None


def _rows_by_kind(report: dict) -> dict[str, dict[str, tuple[float, int | None]]]:
    """Per-image DICE and count of true cable pixels of a report, by kind (``source/split`` for the photos,
    the style or ``--sets`` folder's name for the rest)."""
    def entry(row: dict) -> tuple[float, int | None]:
        return row["dice"], (sum(row["true_px"].values()) if "true_px" in row else None)

    kinds: dict[str, dict[str, tuple[float, int | None]]] = {}
    for row in report.get("external", {}).get("rows", []):
        kinds.setdefault(f"{row['source']}/{row['split']}", {})[row["image"]] = entry(row)
    for style, value in report.get("styles", {}).items():
        kinds[style] = {row["image"]: entry(row) for row in value["rows"]}
    return kinds


def paired(report: dict, other: dict) -> dict:
    """This report's per-image DICE minus ``other``'s (the same benchmark, another network), per kind, over
    the images both scored: the mean difference, its standard error and n. Two networks scored on the same
    images differ far less from image to image than the images do among themselves, so this tells a real
    difference from the spread of a kind's scenes. Images are matched by kind and name, and must hold the same
    number of true cable pixels in both (a development and a test folder both named ``wires`` hold other
    scenes under the same names: an error, not a pairing). Kinds with no image in common are left out; none
    at all is an error."""
    mine, theirs = _rows_by_kind(report), _rows_by_kind(other)
    out = {}
    for kind, rows in mine.items():
        common = sorted(set(rows) & set(theirs.get(kind, {})))
        for name in common:
            a, b = rows[name][1], theirs[kind][name][1]
            if a is not None and b is not None and a != b:
                raise ValueError(f"{kind} {name}: {a} true cable pixels here and {b} in the other report; "
                                 f"not the same scenes")
        if common:
            diff = [rows[i][0] - theirs[kind][i][0] for i in common]
            out[kind] = {"n": len(common), "dice_diff_mean": float(np.mean(diff)),
                         "dice_diff_se": _standard_error(diff)}
    if not out:
        raise ValueError(f"no image scored in both reports: kinds {sorted(mine)} against {sorted(theirs)}")
    return out


def _summary(rows: list[dict]) -> dict:
    """Means over the kind's images (``loss_mean`` adds up with ``dice_mean`` to 1); ``found_share``: the
    share of the kind's true pixels found, pooled, per cable width (``None`` where it has none that wide)."""
    d = [r["dice"] for r in rows]
    true = {name: sum(r["true_px"][name] for r in rows) for _, _, name in WIDTH_BANDS}
    found = {name: sum(r["found_px"][name] for r in rows) for _, _, name in WIDTH_BANDS}
    return {"n": len(rows), "dice_mean": float(np.mean(d)), "dice_se": _standard_error(d),
            "dice_median": float(np.median(d)),
            "dice_1px_mean": float(np.mean([r["dice_1px"] for r in rows])),
            "dice_min": float(np.min(d)), "near_empty_share": float(np.mean([r["near_empty"] for r in rows])),
            "loss_mean": {k: float(np.mean([r["losses"][k] for r in rows])) for k in LOSSES},
            "true_px_share": {k: v / max(1, sum(true.values())) for k, v in true.items()},
            "found_share": {k: (found[k] / true[k] if true[k] else None) for k in true}}


def _panel(rgb: np.ndarray, truth: np.ndarray, mask: np.ndarray, title: str) -> np.ndarray:
    """Photo | truth | mask (green: right, red: extra, blue: missed), scaled to 320 px high."""
    s = 320 / rgb.shape[0]
    size = (int(round(rgb.shape[1] * s)), 320)
    over = (rgb * 0.45).astype(np.uint8)
    over[mask & truth] = (40, 220, 40)
    over[mask & ~truth] = (240, 40, 40)
    over[~mask & truth] = (60, 90, 255)
    tr = np.where(truth[..., None], 255, 0).astype(np.uint8).repeat(3, axis=2)
    out = np.hstack([cv2.resize(x, size, interpolation=cv2.INTER_AREA) for x in (rgb, tr, over)])
    cv2.putText(out, title, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1, cv2.LINE_AA)
    return out


def _write_worst(folder: Path, kind: str, items: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, str]],
                 k: int) -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    worst = sorted(items, key=lambda t: t[0])[:k]
    rows = [_panel(rgb, truth, mask, f"{kind} {name} DICE {d:.2f}") for d, rgb, truth, mask, name in worst]
    if not rows:
        return []
    width = max(r.shape[1] for r in rows)
    img = np.vstack([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows])
    path = folder / f"worst_{kind}.png"
    cv2.imwrite(str(path), img[..., ::-1])
    return [name for _, _, _, _, name in worst]


def _external_photos(root: Path, per_source: int | None = None):
    """(half, source, image path, label path) of the external photos, half by half
    (:func:`~dyndlo_vision.learning.segtrain.external_split`); at most ``per_source`` per source and half."""
    for part, pairs in external_split(root).items():
        counts: dict[str, int] = {}
        for img_path, lab_path in pairs:
            source = external_source(img_path)
            counts[source] = counts.get(source, 0) + 1
            if per_source is None or counts[source] <= per_source:
                yield part, source, img_path, lab_path


def part_external(seg, root: Path, per_source: int | None = None, worst: Path | None = None,
                  k_worst: int = 4) -> dict:
    """Mean DICE and near-empty share per source and half of the external photos."""
    rows, keep = [], {}
    for part, source, img_path, lab_path in _external_photos(root, per_source):
        rgb = _read(img_path)
        truth = cv2.imread(str(lab_path), cv2.IMREAD_GRAYSCALE) > 0
        mask = np.asarray(seg(rgb), bool)
        row = {"image": str(img_path.relative_to(root)), "source": source, "split": part,
               **_score(mask, truth)}
        rows.append(row)
        if worst is not None:
            keep.setdefault(f"{source}-{part}", []).append((row["dice"], rgb, truth, mask, row["image"]))
    summary = {}
    for source in sorted({r["source"] for r in rows}):
        for part in ("heldout", "train", "all"):
            sel = [r for r in rows if r["source"] == source and part in ("all", r["split"])]
            if sel:
                summary[f"{source}/{part}"] = _summary(sel)
    worst_names = ({kind: _write_worst(worst, kind, items, k_worst) for kind, items in keep.items()}
                   if worst else {})
    return {"summary": summary, "rows": rows, "worst": worst_names}


def _style_samples(style: str, seed: int, n: int):
    """``n`` samples of ``style`` with ``seed``: what ``seg-data --style STYLE --seed SEED`` writes first."""
    w, h = STYLE_SIZES.get(style, COMPOSITE_SIZE)
    lo, hi = (0.7, 12.0) if style in STYLE_SIZES else (1.0, 40.0)
    cfg = SegDataConfig(width=w, height=h, style=style, min_width_px=lo, max_width_px=hi)
    group, made = 0, 0
    while made < n:
        sampler = make_sampler(cfg, seed, group)
        try:
            for _ in range(cfg.samples_per_scene):
                if made >= n:
                    break
                rgb, mask, _ = sampler.sample()
                made += 1
                yield f"{seed}/{made - 1:06d}", rgb, mask > 0
        finally:
            sampler.close()
        group += 1


def _folder_samples(folder: Path):
    for mp in sorted(folder.glob("[0-9]*_mask.png")):
        yield mp.name.replace("_mask.png", ""), _read(mp.with_name(mp.name.replace("_mask", ""))), (
            cv2.imread(str(mp), cv2.IMREAD_GRAYSCALE) > 127)


def part_styles(seg, styles: list[str], seed: int, per_style: int, sets: list[Path] | None = None,
                worst: Path | None = None, k_worst: int = 4) -> dict:
    """Mean DICE and near-empty share per generated style (on the fly, or from ``seg-data`` folders)."""
    sources = []
    if sets:
        for folder in sets:
            style = json.loads((folder / "dataset.json").read_text())["config"]["style"]
            sources.append((style, folder.name, _folder_samples(folder)))
    else:
        sources = [(style, style, _style_samples(style, seed, per_style)) for style in styles]
    out = {}
    for style, label, samples in sources:
        rows, keep, no_cable = [], [], 0
        for name, rgb, truth in samples:
            if truth.sum() < 20:
                no_cable += 1
                continue
            mask = np.asarray(seg(rgb), bool)
            row = {"image": name, **_score(mask, truth)}
            rows.append(row)
            if worst is not None:
                keep.append((row["dice"], rgb, truth, mask, name))
        entry = {"style": style, "no_cable_samples": no_cable, **_summary(rows), "rows": rows}
        if worst is not None:
            entry["worst"] = _write_worst(worst, label, keep, k_worst)
        out[label] = entry
    return out


#: Labels-against-photo profiles: half-length (px) and step (px) of a profile across a cable, the part of it
#: read as the surface on either side, and what a profile needs to be read: the surface that far from the
#: label's centre differs from the cable's centre colour by this much (CIELAB, 0-255 scale) and is this
#: uniform, and no other cable lies this close.
PROFILE_HALF, PROFILE_STEP, SURFACE_FROM = 16.0, 0.25, 11.0
MIN_CONTRAST, MAX_SURFACE_SPREAD, OTHER_CABLE_PX = 50.0, 10.0, 22.0


def _cable_masks(lab_path: Path) -> list[np.ndarray]:
    """One bool mask per labelled cable: mBEST's label values, or cables_dataset's ``_mask_K`` files."""
    if lab_path.name.endswith("_labels.png"):
        lab = cv2.imread(str(lab_path), cv2.IMREAD_GRAYSCALE)
        return [lab == k for k in np.unique(lab) if k > 0]
    stem = lab_path.name[: -len("_mask_all.png")]
    files = sorted(lab_path.parent.glob(f"{stem}_mask_[0-9]*.png"),
                   key=lambda q: int(q.stem.rsplit("_", 1)[1]))
    return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) > 127 for f in files]


def _extent(inside: np.ndarray, t: np.ndarray, centre: float) -> tuple[float, float] | None:
    """The run of True samples of a profile that holds ``centre`` (or the nearest run within 2 px), as
    (start, end) in the profile's pixels; None for none."""
    idx = np.flatnonzero(inside)
    if len(idx) == 0:
        return None
    j = int(idx[np.argmin(np.abs(t[idx] - centre))])
    if abs(t[j] - centre) > 2.0:
        return None
    a = b = j
    while a > 0 and inside[a - 1]:
        a -= 1
    while b < len(t) - 1 and inside[b + 1]:
        b += 1
    return t[a] - PROFILE_STEP / 2, t[b] + PROFILE_STEP / 2


def _dice_1d(a: tuple[float, float] | None, b: tuple[float, float]) -> float:
    if a is None:
        return 0.0
    overlap = max(0.0, min(a[1], b[1]) - max(a[0], b[0]))
    return float(2 * overlap / max(1e-9, (a[1] - a[0]) + (b[1] - b[0])))


def label_profiles(rgb: np.ndarray, cables: list[np.ndarray], every: int = 4,
                   mask: np.ndarray | None = None) -> list[dict]:
    """Where each labelled cable's edges lie in the photo, against its label, across the cable.

    At every ``every``-th pixel of a cable's skeleton (away from its ends, crossings and other cables), a
    profile across it (the normal of the skeleton's local direction): the label's extent, and the photo's
    cable edges, where the colour, walking out from the label's centre, is first half-way from the cable's
    centre colour to the surface on that side. Only profiles with a contrasting, uniform surface on both sides
    are kept (:data:`MIN_CONTRAST`, :data:`MAX_SURFACE_SPREAD`). Each gives the photo's and the label's width,
    the offset of their centres and the 1-D DICE of the two extents: what a mask that followed the photo's
    edges exactly would score against the label there. With a segmenter's ``mask``, also the 1-D DICE of its
    extent on the same profile against the photo's edges and against the label's."""
    from dyndlo_vision.tracking.centerline import thin

    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    mask_f = None if mask is None else mask.astype(np.float32)
    h, w = rgb.shape[:2]
    t = np.arange(-PROFILE_HALF, PROFILE_HALF + 1e-9, PROFILE_STEP)
    out = []
    for k, cable in enumerate(cables):
        others = np.zeros((h, w), bool)
        for j, other in enumerate(cables):
            if j != k:
                others |= other
        far = cv2.distanceTransform((~others).astype(np.uint8), cv2.DIST_L2, 5) > OTHER_CABLE_PX
        skeleton = thin(cable)
        ys, xs = np.nonzero(skeleton)
        label = cable.astype(np.float32)
        for i in range(0, len(ys), every):
            y, x = ys[i], xs[i]
            near = (np.abs(ys - y) <= 6) & (np.abs(xs - x) <= 6)
            pts = np.column_stack([xs[near], ys[near]]).astype(np.float64)
            if len(pts) < 8 or not far[y, x]:
                continue
            evals, evecs = np.linalg.eigh(np.cov((pts - pts.mean(0)).T))
            if evals[0] > 0.1 * evals[1]:  # not a straight piece: an end, a crossing or a sharp bend
                continue
            nx, ny = evecs[:, 0]
            px, py = x + nx * t, y + ny * t
            if px.min() < 0 or py.min() < 0 or px.max() > w - 1 or py.max() > h - 1:
                continue
            mx, my = px[None].astype(np.float32), py[None].astype(np.float32)
            prof = np.stack([cv2.remap(lab[..., c], mx, my, cv2.INTER_LINEAR)[0] for c in range(3)], 1)
            inside = np.flatnonzero(cv2.remap(label, mx, my, cv2.INTER_LINEAR)[0] > 0.5)
            if len(inside) < 4:
                continue
            l0, l1 = t[inside[0]] - PROFILE_STEP / 2, t[inside[-1]] + PROFILE_STEP / 2
            lc = (l0 + l1) / 2
            centre = np.median(prof[np.abs(t - lc) < 1.0], 0)
            sides = [prof[(t >= lc - PROFILE_HALF) & (t <= lc - SURFACE_FROM)],
                     prof[(t >= lc + SURFACE_FROM) & (t <= lc + PROFILE_HALF)]]
            if min(len(sd) for sd in sides) < 4:
                continue
            contrast = [float(np.linalg.norm(np.median(sd, 0) - centre)) for sd in sides]
            spread = [float(np.linalg.norm(sd.std(0))) for sd in sides]
            if min(contrast) < MIN_CONTRAST or max(spread) > MAX_SURFACE_SPREAD:
                continue
            away = np.linalg.norm(prof - centre, axis=1)
            a = b = int(np.argmin(np.abs(t - lc)))
            while a > 0 and away[a] < 0.5 * contrast[0]:
                a -= 1
            while b < len(t) - 1 and away[b] < 0.5 * contrast[1]:
                b += 1
            e0, e1 = t[a] + PROFILE_STEP / 2, t[b] - PROFILE_STEP / 2
            row = {"photo_width": float(e1 - e0), "label_width": float(l1 - l0),
                   "centre_offset": float((e0 + e1) / 2 - lc), "dice_1d": _dice_1d((l0, l1), (e0, e1))}
            if mask is not None:
                along = cv2.remap(mask_f, mx, my, cv2.INTER_LINEAR)[0] > 0.5
                found = _extent(along, t, lc)
                row["mask_dice_1d"] = _dice_1d(found, (e0, e1))
                row["mask_label_dice_1d"] = _dice_1d(found, (l0, l1))
            out.append(row)
    return out


def part_labels(root: Path, per_source: int | None = None, seg=None) -> dict:
    """How well each external source's labels agree with the edges in its photos (:func:`label_profiles`),
    per source: the ceiling a mask that follows the photo exactly would reach in mask DICE against them. With
    a segmenter, how well its masks agree with the same edges, per source and half (``mask_vs_photo``): a
    figure the labels' own errors do not enter."""
    halves: dict[str, dict[str, list[dict]]] = {}
    for part, source, img_path, lab_path in _external_photos(root, per_source):
        rgb = _read(img_path)
        mask = np.asarray(seg(rgb), bool) if seg is not None else None
        profiles = label_profiles(rgb, _cable_masks(lab_path), mask=mask)
        halves.setdefault(source, {}).setdefault(part, []).extend(profiles)
    out = {}
    for source, by_half in sorted(halves.items()):
        profiles = [p for sel in by_half.values() for p in sel]
        if not profiles:
            out[source] = {"profiles": 0}
            continue
        col = {k: np.array([p[k] for p in profiles]) for k in profiles[0]}

        def pct(values: np.ndarray, qs: list[int]) -> list[float]:
            return [round(float(v), 2) for v in np.percentile(values, qs)]

        out[source] = {
            "profiles": len(profiles),
            "photo_width_px_p10_p50_p90": pct(col["photo_width"], [10, 50, 90]),
            "label_width_px_p10_p50_p90": pct(col["label_width"], [10, 50, 90]),
            "centre_offset_px_abs_p50_p90": pct(np.abs(col["centre_offset"]), [50, 90]),
            "dice_1d_mean": float(col["dice_1d"].mean()),
        }
        if seg is not None:
            out[source]["mask_vs_photo"] = {
                part: {"profiles": len(sel),
                       "mask_dice_1d_mean": float(np.mean([p["mask_dice_1d"] for p in sel])),
                       "mask_vs_label_dice_1d_mean": float(np.mean([p["mask_label_dice_1d"] for p in sel]))}
                for part, sel in sorted(by_half.items()) if sel}
    return out


def part_flat(seg) -> dict:
    """Flat-coloured synthetic cables (``render_cable``, an S curve, 640x480) of widths 1-11 px, five
    colours on three plain walls: median mask DICE per width."""
    from dyndlo_vision.tracking.synthetic import render_cable, s_curve

    colours = [(230, 70, 40), (40, 80, 220), (60, 200, 60), (20, 20, 20), (240, 240, 240)]
    walls = [(150, 150, 150), (200, 190, 170), (40, 40, 40)]
    out = {}
    for width in (1, 2, 3, 7, 11):
        scores = []
        for wall in walls:
            for colour in colours:
                rgb, truth = render_cable(s_curve(80, 560, 240, amp=90), (480, 640), width, colour, wall)
                scores.append(dice(seg(rgb), truth))
        out[f"{width}px"] = {"median": float(np.median(scores)), "min": float(np.min(scores))}
    return out


def part_phase(seg) -> dict:
    colours = [(220, 40, 30), (30, 30, 30), (240, 240, 240), (40, 200, 40), (40, 60, 220)]
    walls = [40, 90, 150, 210]
    found = {offset: [] for offset in range(4)}
    median_p: dict = {}
    for wall in walls:
        for colour in colours:
            for offset in range(4):
                img = np.full((480, 640, 3), wall, np.float32)
                cover = np.zeros((480 * 4, 640 * 4), np.uint8)
                # x from 320 + offset to 326 + offset over 300 rows: a slant of 1 px per 50 rows, so every
                # row is anti-aliased alike; 16x supersampled coverage, area-averaged.
                x0 = 4 * (320 + offset)
                cv2.line(cover, (x0, 4 * 100), (x0 + 4 * 6, 4 * 400), 255, 6, cv2.LINE_AA)
                c = cv2.resize(cover.astype(np.float32) / 255.0, (640, 480), interpolation=cv2.INTER_AREA)
                img = img * (1 - c[..., None]) + np.asarray(colour, np.float32) * c[..., None]
                rgb = np.clip(img + 0.5, 0, 255).astype(np.uint8)
                p = float(np.median(seg.probability(rgb)[c > 0.4]))
                median_p[f"{wall}/{colour}/{offset}"] = round(p, 3)
                found[offset].append(p > 0.5)
    shares = {offset: float(np.mean(v)) for offset, v in found.items()}
    return {"found_share_by_offset": shares, "worst": min(shares.values()), "best": max(shares.values()),
            "median_probability": median_p}


#: ``whip_video(..., views=2)``: the second camera, right of the first and higher, aimed at the hanging
#: cable. Its baseline with the first camera is not in the plane of the whip, so the cable seldom lies in an
#: epipolar plane (docs/RESULTS.md, session 18). Adding it to the model changes neither the physics nor the
#: first camera's frames.
WHIP_SECOND_CAMERA = ((1.55, -1.2, 1.1), (0.65, 0.0, 0.3))


def whip_video(style: str, seed: int, seconds: float = 3.0, views: int = 1):
    """Frames, true masks, true tips and TCPs (world), and the calibration of a whip video in ``style``; with
    ``views=2`` also the second camera's frames and calibration (same styles, same instants)."""
    import mujoco

    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.sim import CableParams, CapsuleProp, Scene, SceneConfig
    from dyndlo_vision.sim.scene import SECOND_TRACKING_CAMERA_NAME, CameraPose

    rng = np.random.default_rng(seed)
    f_px = 240 / math.tan(math.radians(22.5))
    width_px = 2.5
    radius = width_px * 1.45 / (2 * f_px)  # the tracking camera looks at y = 0 from 1.45 m
    rgba = (0.9, 0.45, 0.1, 1.0) if style == "textured-blur" else (0.08, 0.08, 0.08, 1.0)
    caps = ()
    if style == "occluded":
        caps = (CapsuleProp("pole", (0.42, -0.25, 0.0), (0.42, -0.25, 1.2), 0.02, (0.5, 0.5, 0.5, 1.0)),)
    second = CameraPose.looking_at(*WHIP_SECOND_CAMERA) if views == 2 else None
    sc = Scene(SceneConfig(cable=CableParams(radius_m=radius, rgba=rgba), capsules=caps, settle_s=0.5,
                           second_tracking_camera=second))
    m, d = sc.model, sc.data
    tcp_geom = int(m.geom("tcp_0_geom").id)
    m.geom_size[tcp_geom, 0] = 0.03
    m.geom_rgba[tcp_geom] = (0.12, 0.12, 0.12, 1.0)
    floor = int(m.geom("floor").id)
    names = ["tracking", SECOND_TRACKING_CAMERA_NAME][:views]
    cams = [MujocoCamera(m, d, name, 640, 480) for name in names]
    yy, xx = np.mgrid[0:480, 0:640].astype(np.float32)
    if style == "textured-blur":  # a wood-like grain, which the generator draws with other statistics
        grain = 0.5 + 0.5 * np.sin(xx / 7.0 + 3 * np.sin(yy / 40.0))
        wall = (np.array([150, 110, 70], np.float32) * (0.7 + 0.3 * grain[..., None])).astype(np.uint8)
    else:  # a plain light wall with a soft vertical gradient
        wall = np.repeat((200 - 30 * yy / 480)[..., None], 3, -1).astype(np.uint8)
    home = sc.gripper_home[0]
    frames, truths, tips, tcps = [], [], [], []
    frames2 = []
    steps_per_frame = int(round(0.04 / m.opt.timestep))
    sub = 8 if style == "textured-blur" else 1
    from dyndlo_vision.sim.rendering import make_renderer

    seg_r = make_renderer(m, 480, 640)
    seg_r.enable_segmentation_rendering()
    phase = float(rng.uniform(0, 2 * math.pi))
    for _ in range(int(seconds * 25)):
        acc: list = [None] * views
        for _ in range(sub):
            n = steps_per_frame // sub
            for _ in range(n):
                t = d.time
                w1 = 2 * math.pi * 1.3
                pos = home + np.array([0.18 * math.sin(w1 * t + phase), 0.0, 0.08 * math.sin(2 * w1 * t)])
                vel = np.array([0.18 * w1 * math.cos(w1 * t + phase), 0.0, 0.16 * w1 * math.cos(2 * w1 * t)])
                sc.set_tcp_reference(pos[None], vel[None])
                sc.step(1)
            for v, (cam, name) in enumerate(zip(cams, names, strict=True)):
                img = cam.read().rgb.astype(np.float32)
                seg_r.update_scene(d, camera=name)
                s = seg_r.render()
                bg = (s[..., 1] == -1) | ((s[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (s[..., 0] == floor))
                img[bg] = wall[bg]
                acc[v] = img if acc[v] is None else acc[v] + img
        rgb = np.clip(acc[0] / sub + 0.5, 0, 255).astype(np.uint8)
        if views == 2:
            frames2.append(np.clip(acc[1] / sub + 0.5, 0, 255).astype(np.uint8))
        seg_r.update_scene(d, camera="tracking")
        s = seg_r.render()
        truth = CableLook.of(sc.model).mask(s)
        frames.append(rgb)
        truths.append(truth)
        tips.append(sc.cable_nodes()[-1].copy())
        tcps.append(sc.tcp_positions()[0].copy())
    calibs = [cam.calibration for cam in cams]
    for cam in cams:
        cam.close()
    seg_r.close()
    out = (frames, truths, np.array(tips), np.array(tcps), calibs[0], sc.config.cable.length_m)
    return out + (frames2, calibs[1]) if views == 2 else out


def part_whip(seg, seed: int) -> dict:
    plane = Plane(np.array([0.0, 1.0, 0.0]), 0.0)
    out = {}
    for style in ("plain", "textured-blur", "occluded"):
        frames, truths, tips, tcps, calib, length_m = whip_video(style, seed)
        median_bg = np.median(np.stack(frames[:: max(1, len(frames) // 25)]), axis=0).astype(np.uint8)
        methods = {
            "learned": seg,
            "classical": BackgroundSegmenter(open_radius=0),
            "classical-median": BackgroundSegmenter(median_bg, open_radius=0),
        }
        res = {}
        for name, s in methods.items():
            dices = []
            # Two tip rules: "pixel length" spreads the nodes over the cable's expected length in pixels (a
            # node past the observed end is invisible: the tip is not measured); "known length" spreads them
            # over the observed polyline and places the tip with tip_from_polyline from the gripper, as the
            # loop does.
            tips_by_rule: dict[str, list] = {"pixel length": [], "known length": []}
            for rgb, truth, tip, tcp in zip(frames, truths, tips, tcps, strict=True):
                mask = s(rgb)
                dices.append(dice(mask, truth))
                anchor = calib.project(tcp)[0]
                depth = float(calib.world_to_camera(tcp)[0, 2])
                exp_px = length_m * calib.K[0, 0] / depth
                c = extract_centerline(mask, n_nodes=20, anchor_uv=anchor, expected_length_px=exp_px)
                p = lift_with_plane(c.nodes_uv[-1:], calib, plane)[0] if c.visible[-1] else None
                tips_by_rule["pixel length"].append((p, tip, tcp))
                c2 = extract_centerline(mask, n_nodes=20, anchor_uv=anchor)
                p2 = None
                if c2.any_visible:
                    xyz = lift_with_plane(c2.nodes_uv, calib, plane, c2.visible)
                    ok = c2.visible & np.all(np.isfinite(xyz), axis=1)
                    p2 = tip_from_polyline(Measurement(xyz, c2.nodes_uv, ok, 0.0), tcp, length_m)
                tips_by_rule["known length"].append((p2, tip, tcp))
            n = len(frames)
            entry: dict = {"frames": n, "dice": float(np.mean(dices))}
            for rule, found in tips_by_rule.items():
                seen = [(p, t, g) for p, t, g in found if p is not None and np.all(np.isfinite(p))]
                errs = [float(np.linalg.norm(p - t)) for p, t, _ in seen]
                gripper = [float(np.linalg.norm(p - g)) < 0.04 for p, _, g in seen]
                entry[rule] = {
                    "measured_share": len(errs) / n,
                    "tip_rmse_mm_measured": (
                        float(1e3 * math.sqrt(np.mean(np.square(errs)))) if errs else None
                    ),
                    "wrong_measured_share": sum(e > 0.05 for e in errs) / n,
                    "gripper_as_tip_share": sum(gripper) / n,
                }
            res[name] = entry
        out[style] = res
    return out


def part_speed(seg, seed: int, repeats: int = 200, seconds: float = 1.0) -> dict:
    """Median ms per 640x480 frame: the learned segmenter (ONNX Runtime, ``learned.ENGINE_THREADS`` threads),
    and on one core the classical segmenter and the centreline on the learned mask, on the last frames of the
    plain whip video."""
    frames, _, _, tcps, calib, length_m = whip_video("plain", seed, seconds=seconds)
    frames = frames[-10:]
    tcps = tcps[-10:]
    classical = BackgroundSegmenter(open_radius=0)

    def med(fn) -> float:
        fn(0)
        ts = []
        for k in range(repeats):
            t = time.perf_counter()
            fn(k % len(frames))
            ts.append(time.perf_counter() - t)
        return float(np.median(ts) * 1e3)

    def centre(mask: np.ndarray, k: int) -> None:
        depth = float(calib.world_to_camera(tcps[k])[0, 2])
        extract_centerline(mask, n_nodes=20, anchor_uv=calib.project(tcps[k])[0],
                           expected_length_px=length_m * calib.K[0, 0] / depth)

    masks = [seg(f) for f in frames]
    return {
        "learned_ms": med(lambda k: seg(frames[k])),
        "classical_ms": med(lambda k: classical(frames[k])),
        "centerline_ms": med(lambda k: centre(masks[k], k)),
        "learned_plus_centerline_ms": med(lambda k: centre(seg(frames[k]), k)),
    }


def part_loopcam(model: str | None, episodes: int = 3) -> dict:
    """The control loop's own camera: tip control's "tracking" view (640x480, the 1.6 px red cable) after one
    random action per episode; learned-mask DICE and time at three network scales, and the classical one."""
    import gymnasium as gym

    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.sim.rendering import make_renderer

    env = gym.make("DynDLO/TipControl-v0")
    base = env.unwrapped
    env.reset(seed=0)
    cam = MujocoCamera(base.model, base.data, "tracking", 640, 480)
    rend = make_renderer(base.model, 480, 640)
    rend.enable_segmentation_rendering()
    rng = np.random.default_rng(0)
    frames, truths = [], []
    for ep in range(episodes):
        env.reset(seed=300_000 + ep)
        env.step(rng.uniform(-1, 1, env.action_space.shape))
        frames.append(cam.read().rgb)
        rend.update_scene(base.data, camera="tracking")
        s = rend.render()
        truths.append(CableLook.of(base.model).mask(s))
    cam.close()
    rend.close()
    env.close()
    out = {}
    for short in (240, 360, 480):
        seg = LearnedSegmenter(onnx_bytes(model), short_side=short)  # 480: the frame's own size
        ts = []
        for k in range(30):
            t = time.perf_counter()
            seg(frames[k % len(frames)])
            ts.append(time.perf_counter() - t)
        out[f"learned_{short}"] = {
            "dice": [round(dice(seg(f), t), 3) for f, t in zip(frames, truths, strict=True)],
            "ms": float(np.median(ts) * 1e3),
        }
    classical = BackgroundSegmenter(open_radius=0)
    out["classical"] = {
        "dice": [round(dice(classical(f), t), 3) for f, t in zip(frames, truths, strict=True)]
    }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", help="ONNX file or shipped name (default: the shipped default segmenter)")
    ap.add_argument("--short-side", default="auto",
                    help="network input's short side: an int, 'none' (the frame's own size) or 'auto'")
    ap.add_argument("--external", default=str(EXTERNAL))
    ap.add_argument("--styles", default=",".join(STYLES), help="styles of the styles part (comma-separated)")
    ap.add_argument("--style-seed", type=int, default=1000,
                    help="seed of the generated scenes (1000: development; 2000: the sealed test range)")
    ap.add_argument("--per-style", type=int, default=50, help="generated scenes per style")
    ap.add_argument("--sets", nargs="*", help="seg-data folders to score instead of generating scenes")
    ap.add_argument("--whip-seed", type=int, default=0)
    ap.add_argument("--parts", default="external,styles,flat,phase,speed")
    ap.add_argument("--worst", metavar="DIR", help="write the worst images per kind as PNG panels here")
    ap.add_argument("--quick", action="store_true",
                    help="a few images of every kind, no videos: checks that the benchmark runs")
    ap.add_argument("--against", metavar="REPORT.json",
                    help="another network's report of this benchmark on the same images: adds 'paired', the "
                    "per-image DICE difference per kind with its standard error")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    against = None
    if args.against:  # read before scoring: a bad file fails at once
        try:
            against = json.loads(Path(args.against).read_text())
        except (OSError, ValueError) as e:
            raise SystemExit(f"--against {args.against}: not a readable JSON report ({e})") from e
        if not isinstance(against, dict) or not ({"external", "styles"} & set(against)):
            raise SystemExit(f"--against {args.against}: expected a report of this benchmark with 'external' "
                             f"or 'styles', got keys {sorted(against) if isinstance(against, dict) else []}")
    cv2.setNumThreads(1)
    ss = args.short_side.lower()
    short = "auto" if ss == "auto" else None if ss == "none" else int(ss)
    seg = LearnedSegmenter(onnx_bytes(args.model), short_side=short)
    report: dict = {
        "model": args.model or "shipped default",
        "short_side": seg.short_side,
        "machine": f"{platform.machine()} {os.cpu_count()} cpus, {platform.python_version()}",
        "quick": args.quick,
    }
    parts = args.parts.split(",")
    worst = Path(args.worst) if args.worst else None
    t0 = time.perf_counter()
    if "external" in parts:
        if Path(args.external).is_dir():
            report["external"] = part_external(seg, Path(args.external), 2 if args.quick else None, worst)
            print(json.dumps(report["external"]["summary"], indent=1))
        else:
            print(f"skipping external: {args.external} not found")
    if "labels" in parts:
        if Path(args.external).is_dir():
            report["labels"] = part_labels(Path(args.external), 2 if args.quick else None, seg)
            print(json.dumps(report["labels"], indent=1))
        else:
            print(f"skipping labels: {args.external} not found")
    if "styles" in parts:
        styles = [s for s in args.styles.split(",") if s]
        unknown = [s for s in styles if s not in STYLES]
        if unknown:
            raise SystemExit(f"--styles: unknown {unknown}; styles: {list(STYLES)}")
        report["styles"] = part_styles(seg, styles, args.style_seed, 2 if args.quick else args.per_style,
                                       [Path(p) for p in args.sets] if args.sets else None, worst)
        print(json.dumps({k: {x: v[x] for x in ("n", "dice_mean", "dice_1px_mean", "near_empty_share",
                                                  "no_cable_samples")}
                          for k, v in report["styles"].items()}, indent=1))
    if "flat" in parts:
        report["flat"] = part_flat(seg)
        print(json.dumps(report["flat"], indent=1))
    if "phase" in parts:
        report["phase"] = part_phase(seg)
        print(json.dumps({k: v for k, v in report["phase"].items() if k != "median_probability"}, indent=1))
    if "speed" in parts:
        report["speed"] = part_speed(seg, args.whip_seed, repeats=5 if args.quick else 200,
                                     seconds=0.4 if args.quick else 1.0)
        print(json.dumps(report["speed"], indent=1))
    if "whip" in parts and not args.quick:
        report["whip"] = part_whip(seg, args.whip_seed)
        print(json.dumps(report["whip"], indent=1))
    if "loopcam" in parts and not args.quick:
        report["loopcam"] = part_loopcam(args.model)
        print(json.dumps(report["loopcam"], indent=1))
    pairing_error = None
    if against is not None:
        report["against"] = {"report": args.against, "model": against.get("model")}
        try:
            report["paired"] = paired(report, against)
            print(json.dumps(report["paired"], indent=1))
        except ValueError as e:  # the scores are written all the same
            pairing_error = f"--against {args.against}: {e}; the scores are in {args.out}, with no 'paired'"
    report["wall_s"] = time.perf_counter() - t0
    Path(args.out).write_text(json.dumps(report, indent=1))
    if pairing_error:
        raise SystemExit(pairing_error)
    return 0


if __name__ == "__main__":
    sys.exit(main())
