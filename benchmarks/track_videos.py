"""``dyndlo-vision track`` on generated whip videos, as a user runs it: how often it is measured, wrong, or
reports the gripper as the tip, and how far off it is.

Each video comes from :mod:`dyndlo_vision.learning.whipdata` (many factors per seed: backgrounds, cable,
gripper, camera, light, blur, frame rate, compression, motion with rests, whips, whirls and drags, occluders).
``track`` runs in a subprocess with the command line a user types (``--calib camera.json --plane 0,1,0,0
--point tip``), the held end clicked in the first frame (``--anchor`` at the gripper's pixel), plus
``--args``. Scored per frame against the truth at the frame's time stamp (the middle of its exposure):

* measured: the share of frames with ``visible=1`` (of all frames, and of those whose tip is in view);
* wrong: ``visible=1`` and the reported ``x,y,z`` more than 50 mm from the true tip;
* gripper: ``visible=1``, the reported point within 40 mm of the gripper while the tip is at least 100 mm
  away;
* the median (p90) world error of measured frames, sharp and blurred apart (blurred: the tip moved more than
  3 px on the image during the exposure);
* the true tip's acceleration at the frame rate (second differences of its position), 99th percentile and
  largest: what the filter must follow without gating out a correct measurement.

Development seeds by default; ``--sealed`` evaluates the sealed test range (look at it once, at the end).

    python benchmarks/track_videos.py --seeds 0:40 --videos /tmp/whip --out whip.json [--args "..."]
    python benchmarks/track_videos.py --sealed --seeds 900000:900060 --videos /tmp/sealed --out sealed.json
    python benchmarks/track_videos.py --quick
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dyndlo_vision.learning.whipdata import (
    DEV_SEEDS,
    SEALED_SEEDS,
    WhipSpec,
    load_truth,
    motion_kind,
    sample_spec,
    score_frames,
    summarise,
    write_video,
)
from dyndlo_vision.tracking.camera_model import PinholeCamera


def _seeds(text: str) -> range:
    a, _, b = text.partition(":")
    return range(int(a), int(b) if b else int(a) + 1)


def _factors(spec: WhipSpec, calib: PinholeCamera) -> dict[str, str]:
    """The video's factors, binned for the breakdown tables."""
    width_px = 2 * spec.cable_radius_m * float(calib.K[1, 1]) / spec.camera_distance_m
    dark = max(spec.cable_rgb) < 0.25 and max(spec.gripper_rgb) < 0.25
    return {
        "wall": spec.wall_kind,
        "occluder": spec.occluder,
        "blur": "motion blur" if spec.blurred else "sharp",
        "fps": f"{spec.fps:g}",
        "cable px": "<2.5" if width_px < 2.5 else "2.5-5" if width_px < 5 else ">=5",
        "gripper": "as dark as the cable" if dark or spec.gripper_rgb == spec.cable_rgb else "other",
        "view": "oblique" if abs(spec.camera_yaw_deg) > 15 or abs(spec.camera_pitch_deg) > 10 else "frontal",
        "arm": "arm" if spec.arm else "no arm",
    }


def _read_track(path: Path, n: int) -> tuple[np.ndarray, np.ndarray]:
    xyz = np.full((n, 3), np.nan)
    measured = np.zeros(n, dtype=bool)
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            k = int(row["frame"])
            if k >= n:
                continue
            measured[k] = row["visible"] == "1"
            if row["x"]:
                xyz[k] = [float(row[c]) for c in "xyz"]
    return xyz, measured


def run_video(folder: Path, extra: list[str], out_csv: Path) -> tuple[dict, float, str]:
    """Runs ``track`` on one rendered video; the per-frame scores, the wall time and stderr."""
    truth = load_truth(folder / "truth.npz")
    calib = PinholeCamera.from_json(folder / "camera.json")
    u, v = truth.tcp_uv[0]
    argv = [sys.executable, "-m", "dyndlo_vision", "track", str(folder / "video.mp4"), "--calib",
            str(folder / "camera.json"), "--plane", "0,1,0,0", "--anchor", f"{u:.0f},{v:.0f}",
            "--point", "tip", "--out", str(out_csv), "--quiet",
            *[a.replace("{tcp}", str(folder / "tcp.csv")) for a in extra]]
    t0 = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"track failed on {folder} (exit {done.returncode}): {done.stderr[-2000:]}")
    xyz, measured = _read_track(out_csv, len(truth.t))
    return score_frames(truth, calib, xyz, measured), wall, done.stderr


def tip_accelerations(tip: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The tip's acceleration magnitudes (m/s^2) from second differences of its positions at times ``t``."""
    dt = np.diff(t)
    v = np.diff(tip, axis=0) / dt[:, None]
    return np.linalg.norm(np.diff(v, axis=0), axis=1) / (0.5 * (dt[1:] + dt[:-1]))


def _table(title: str, groups: dict[str, dict]) -> str:
    keys = ("frames", "measured_share", "wrong_frames", "gripper_frames", "median_mm_sharp",
            "median_mm_blurred", "p90_mm_sharp", "p90_mm_blurred")
    lines = [f"{title}:", f"  {'':28s}" + "".join(f"{k:>18s}" for k in keys)]
    for name, s in groups.items():
        lines.append(f"  {name:28s}" + "".join(f"{'-' if s[k] is None else s[k]!s:>18s}" for k in keys))
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", default="0:40", help="A:B, the seeds A..B-1 (default 0:40)")
    parser.add_argument("--sealed", action="store_true", help="the seeds are from the sealed test range")
    parser.add_argument("--videos", help="folder the rendered videos are kept in and reused from (default: a "
                        "temporary folder)")
    parser.add_argument("--args", default="", help="more track arguments, e.g. \"--segmenter learned\"; "
                        "{tcp} stands for the video's TCP log")
    parser.add_argument("--out", help="JSON file of the results")
    parser.add_argument("--quick", action="store_true",
                        help="two short development videos, 3 s of seeds 3 and 33, the second "
                        "with motion blur (a smoke test)")
    args = parser.parse_args()
    seeds = _seeds(args.seeds)
    allowed = SEALED_SEEDS if args.sealed else DEV_SEEDS
    if seeds.start not in allowed or seeds.stop - 1 not in allowed:
        raise SystemExit(
            f"--seeds {args.seeds} is outside the {'sealed' if args.sealed else 'development'} "
            f"range {allowed.start}:{allowed.stop}"
        )
    max_seconds = None
    if args.quick:
        seeds, max_seconds = [3, 33], 3.0  # two scenes the cable is seen in, long enough to learn its length;
        # 33 blurs its whips at 30 fps (a 60 fps video renders twice the frames, each from several sub-frames)
    extra = shlex.split(args.args)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.videos) if args.videos else Path(tmp)
        pooled: dict[str, list] = {}
        by_factor: dict[str, dict[str, dict[str, list]]] = {}
        per_video = []
        accelerations = []
        for seed in seeds:
            spec = sample_spec(seed)
            folder = root / f"{seed:06d}"
            if not (folder / "truth.npz").exists():
                write_video(spec, folder, None if max_seconds is None else int(max_seconds * spec.fps))
            frames, wall, _ = run_video(folder, extra, Path(tmp) / f"{seed}.csv")
            calib = PinholeCamera.from_json(folder / "camera.json")
            truth = load_truth(folder / "truth.npz")
            factors = _factors(spec, calib)
            kinds = motion_kind(spec, truth.t)
            summary = summarise(frames)
            accel = tip_accelerations(truth.tip, truth.t)
            accelerations.append(accel)
            summary["tip_accel_p99_m_s2"] = round(float(np.percentile(accel, 99)), 1)
            per_video.append({"seed": seed, "wall_s": round(wall, 1), **factors, **summary})
            print(f"seed {seed}: " + ", ".join(f"{k} {v}" for k, v in summary.items()), flush=True)
            for key, arr in frames.items():
                pooled.setdefault(key, []).append(arr)
            for name, value in factors.items():
                group = by_factor.setdefault(name, {}).setdefault(value, {})
                for key, arr in frames.items():
                    group.setdefault(key, []).append(arr)
            for kind in np.unique(kinds):
                group = by_factor.setdefault("motion", {}).setdefault(str(kind), {})
                for key, arr in frames.items():
                    group.setdefault(key, []).append(arr[kinds == kind])
    total = summarise({k: np.concatenate(v) for k, v in pooled.items()})
    accel = np.concatenate(accelerations)
    total["tip_accel_p99_m_s2"] = round(float(np.percentile(accel, 99)), 1)
    total["tip_accel_max_m_s2"] = round(float(accel.max()), 1)
    breakdown = {
        name: {
            value: summarise({k: np.concatenate(v) for k, v in group.items()})
            for value, group in sorted(groups.items())
        }
        for name, groups in by_factor.items()
    }
    print(_table("all videos", {"all": total}))
    for name, groups in breakdown.items():
        print(_table(name, groups))
    if args.out:
        Path(args.out).write_text(
            json.dumps(
                {
                    "command": " ".join(sys.argv),
                    "machine": platform.platform(),
                    "sealed": args.sealed,
                    "seeds": f"{seeds.start}:{seeds.stop}" if isinstance(seeds, range) else list(seeds),
                    "track_args": args.args,
                    "all": total,
                    "breakdown": breakdown,
                    "videos": per_video,
                },
                indent=1,
            )
        )
    ok = total["frames"] > 0 and not math.isnan(float(total["measured_share"] or 0))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
