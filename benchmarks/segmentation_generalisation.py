"""How well cable segmentation generalises: the learned segmenter against the classical one (issue 14).

Three parts, all on data the learned segmenter was not trained on:

* ``external``: the labelled real photos in ``../shared/data/external`` (mBEST S1-S3, cables_dataset):
  mask DICE per image, mean per data set, and on the held-out half (``learning.segtrain.external_split``,
  odd positions) separately, because a fine-tuned model saw the even half.
* ``flat``: flat-coloured synthetic cables 1-11 px wide on plain walls (640x480): median DICE per width.
* ``phase``: a straight, nearly vertical 1.6 px line (anti-aliased) on plain grey walls, drawn at each of the
  four horizontal offsets within the 4x4 pixel blocks ``cable-segmenter-fine`` reads: the median cable
  probability on the line per offset, and the share of lines found (median > 0.5) at the worst and the best
  offset. A network that depends on where a thin line falls in its blocks shows a gap between them.
* ``renders``: the seg-data generator with seeds the training never used (``--render-seed``, default 1000):
  mask DICE.
* ``loopcam``: the control loop's own camera view (tip control, 640x480, a 1.6 px red cable): mask DICE
  and time of the learned segmenter at network short sides 240, 360 and 480, and of the classical one.
* ``speed``: one-core timings (see ``part_speed``).
* ``whip``: rendered whip videos (640x480, 25 fps) of a dark cable 2-3 px wide held by a dark spherical
  gripper, in styles the generator never produced: ``plain`` (a plain light wall), ``textured-blur`` (a
  wood-grain wall, orange cable, motion blur: the mean of 8 renders over the 40 ms frame), ``occluded`` (a
  grey pole in front of the swing). The tip is the last node of the ordered centreline from the gripper's
  projected pixel, with the known cable length (nodes past the observed length are not measured), lifted to
  the plane y = 0. Reported: mask DICE, tip RMSE on frames where the tip is measured, the share of frames
  with a measured tip,
  and the share of frames whose measured tip is wrong (> 50 mm from the truth) or on the gripper (< 40 mm
  from the TCP).

Classical = ``BackgroundSegmenter(open_radius=0)`` with its self-estimated background (``track``'s segmenter
for a single image); on the whip videos also with the per-pixel median background of the video, as
``track --background median`` does.

    python benchmarks/segmentation_generalisation.py --out /tmp/seg_generalisation.json [--model FILE.onnx]
    python benchmarks/segmentation_generalisation.py --quick --out /tmp/q.json   # a smoke test

The loop's per-frame time per segmenter is ``benchmarks/tracking_speed.py``.
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

from dyndlo_vision.learning.segdata import SceneSampler, SegDataConfig  # noqa: E402
from dyndlo_vision.learning.segtrain import external_split  # noqa: E402
from dyndlo_vision.sim.cable_look import CableLook  # noqa: E402
from dyndlo_vision.tracking import BackgroundSegmenter, dice  # noqa: E402
from dyndlo_vision.tracking.centerline import extract_centerline  # noqa: E402
from dyndlo_vision.tracking.learned import LearnedSegmenter  # noqa: E402
from dyndlo_vision.tracking.networks import onnx_bytes  # noqa: E402
from dyndlo_vision.tracking.tracker import Measurement, Plane, lift_with_plane, tip_from_polyline  # noqa: E402

EXTERNAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "external"


def _read(path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"cannot read {path}")
    return np.ascontiguousarray(bgr[..., ::-1])


def part_external(seg, root: Path) -> dict:
    split = external_split(root)
    rows = []
    classical = BackgroundSegmenter(open_radius=0)
    for part, pairs in split.items():
        for img_path, lab_path in pairs:
            rgb = _read(img_path)
            truth = cv2.imread(str(lab_path), cv2.IMREAD_GRAYSCALE) > 0
            t = time.perf_counter()
            m_l = seg(rgb)
            ms = (time.perf_counter() - t) * 1e3
            m_c = classical(rgb)
            dataset = "mbest" if "mbest" in str(img_path) else "cables_dataset"
            rows.append(
                {
                    "image": str(img_path.relative_to(root)),
                    "dataset": dataset,
                    "split": part,
                    "dice_learned": dice(m_l, truth),
                    "dice_classical": dice(m_c, truth),
                    "classical_empty": bool(not m_c.any()),
                    "learned_ms": ms,
                }
            )
    summary = {}
    for dataset in ("mbest", "cables_dataset", "all"):
        for part in ("heldout", "train", "all"):
            sel = [
                r
                for r in rows
                if (dataset == "all" or r["dataset"] == dataset) and (part == "all" or r["split"] == part)
            ]
            if sel:
                summary[f"{dataset}/{part}"] = {
                    "n": len(sel),
                    "dice_learned": float(np.mean([r["dice_learned"] for r in sel])),
                    "dice_classical": float(np.mean([r["dice_classical"] for r in sel])),
                    "classical_empty_share": float(np.mean([r["classical_empty"] for r in sel])),
                }
    return {"summary": summary, "rows": rows}


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


def part_renders(seg, seed: int, n: int) -> dict:
    cfg = SegDataConfig()
    d_l, d_c = [], []
    classical = BackgroundSegmenter(open_radius=0)
    group = 0
    while len(d_l) < n:
        sampler = SceneSampler(cfg, seed, group)
        try:
            for _ in range(cfg.samples_per_scene):
                rgb, mask, _ = sampler.sample()
                truth = mask > 0
                d_l.append(dice(seg(rgb), truth))
                d_c.append(dice(classical(rgb), truth))
        finally:
            sampler.close()
        group += 1
    return {
        "seed": seed,
        "n": len(d_l),
        "dice_learned": float(np.mean(d_l)),
        "dice_classical": float(np.mean(d_c)),
    }


#: ``_whip_video(..., views=2)``: the second camera, right of the first and higher, aimed at the hanging
#: cable. Its baseline with the first camera is not in the plane of the whip, so the cable seldom lies in an
#: epipolar plane (docs/RESULTS.md, session 18). Adding it to the model changes neither the physics nor the
#: first camera's frames.
WHIP_SECOND_CAMERA = ((1.55, -1.2, 1.1), (0.65, 0.0, 0.3))


def _whip_video(style: str, seed: int, seconds: float = 3.0, views: int = 1):
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
        frames, truths, tips, tcps, calib, length_m = _whip_video(style, seed)
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


def part_speed(seg, checkpoint: str | None, seed: int, repeats: int = 200) -> dict:
    """Median ms per 640x480 frame on one core: learned segmenter (cv2.dnn), the same network in torch
    (with ``--checkpoint``), the classical segmenter, and the centreline on the learned mask."""
    frames, _, _, tcps, calib, length_m = _whip_video("plain", seed, seconds=1.0)
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

    masks = [seg(f) for f in frames]

    def centre(k: int) -> None:
        depth = float(calib.world_to_camera(tcps[k])[0, 2])
        extract_centerline(
            masks[k],
            n_nodes=20,
            anchor_uv=calib.project(tcps[k])[0],
            expected_length_px=length_m * calib.K[0, 0] / depth,
        )

    def both(k: int) -> None:
        m = seg(frames[k])
        depth = float(calib.world_to_camera(tcps[k])[0, 2])
        extract_centerline(
            m,
            n_nodes=20,
            anchor_uv=calib.project(tcps[k])[0],
            expected_length_px=length_m * calib.K[0, 0] / depth,
        )

    res = {
        "learned_cv2dnn_ms": med(lambda k: seg(frames[k])),
        "classical_ms": med(lambda k: classical(frames[k])),
        "centerline_ms": med(centre),
        "learned_plus_centerline_ms": med(both),
    }
    if checkpoint:
        import torch

        from dyndlo_vision.learning.segtrain import build_net, full_res_logits

        torch.set_num_threads(1)
        ck = torch.load(checkpoint, weights_only=False)
        arch = ck["config"].get("arch", "cablenet")
        net = build_net(arch, *ck["config"].get("widths", (8, 16, 32)))
        net.load_state_dict(ck["net"])
        net.eval()
        w, h = seg.input_size(480, 640)

        def torch_seg(k: int) -> None:
            small = frames[k] if (w, h) == (640, 480) else cv2.resize(frames[k], (w, h), cv2.INTER_AREA)
            x = torch.from_numpy(small.astype(np.float32).transpose(2, 0, 1)[None] / 255.0 - 0.5)
            with torch.inference_mode():
                lg = full_res_logits(net, x, arch)[0, 0].numpy()
            if lg.shape != (480, 640):
                lg = cv2.resize(lg, (640, 480), interpolation=cv2.INTER_LINEAR)
            _ = lg > 0

        # Interleaved with the cv2.dnn segmenter, so both see the same machine load.
        a, b = [], []
        for k in range(repeats):
            t = time.perf_counter()
            seg(frames[k % len(frames)])
            a.append(time.perf_counter() - t)
            t = time.perf_counter()
            torch_seg(k % len(frames))
            b.append(time.perf_counter() - t)
        res["interleaved_learned_cv2dnn_ms"] = float(np.median(a) * 1e3)
        res["interleaved_learned_torch_ms"] = float(np.median(b) * 1e3)
    return res


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
    ap.add_argument("--model", help="ONNX file (default: the shipped segmenter)")
    ap.add_argument(
        "--short-side",
        default="auto",
        help="network input's short side: an int, 'none' (the frame's own size) or 'auto' (the network's)",
    )
    ap.add_argument("--external", default=str(EXTERNAL))
    ap.add_argument("--render-seed", type=int, default=1000)
    ap.add_argument("--renders", type=int, default=100)
    ap.add_argument("--whip-seed", type=int, default=0)
    ap.add_argument("--parts", default="external,flat,renders,whip,loopcam,speed")
    ap.add_argument("--checkpoint", help="seg-train checkpoint.pt: also time the network in torch")
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true",
                    help="the flat and renders parts on 3 renders (a smoke test)")
    args = ap.parse_args()
    if args.quick:
        args.parts, args.renders = "flat,renders", 3
    cv2.setNumThreads(1)
    ss = args.short_side.lower()
    short = "auto" if ss == "auto" else None if ss == "none" else int(ss)
    seg = LearnedSegmenter(onnx_bytes(args.model), short_side=short)
    report: dict = {
        "model": args.model or "shipped",
        "short_side": seg.short_side,
        "machine": f"{platform.machine()} {os.cpu_count()} cpus, {platform.python_version()}",
    }
    parts = args.parts.split(",")
    if "external" in parts:
        if Path(args.external).is_dir():
            report["external"] = part_external(seg, Path(args.external))
            print(json.dumps(report["external"]["summary"], indent=1))
        else:
            print(f"skipping external: {args.external} not found")
    if "flat" in parts:
        report["flat"] = part_flat(seg)
        print(json.dumps(report["flat"], indent=1))
    if "phase" in parts:
        report["phase"] = part_phase(seg)
        print(json.dumps({k: v for k, v in report["phase"].items() if k != "median_probability"}, indent=1))
    if "renders" in parts:
        report["renders"] = part_renders(seg, args.render_seed, args.renders)
        print(json.dumps(report["renders"], indent=1))
    if "whip" in parts:
        report["whip"] = part_whip(seg, args.whip_seed)
        print(json.dumps(report["whip"], indent=1))
    if "loopcam" in parts:
        report["loopcam"] = part_loopcam(args.model)
        print(json.dumps(report["loopcam"], indent=1))
    if "speed" in parts:
        report["speed"] = part_speed(seg, args.checkpoint, args.whip_seed)
        print(json.dumps(report["speed"], indent=1))
    Path(args.out).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
