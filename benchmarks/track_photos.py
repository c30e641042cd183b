"""``dyndlo-vision track`` on single real photos it was never tuned on: where does it put the cable's tip?

Each labelled photo of ``../shared/data/external`` (mBEST S1-S3, cables_dataset) is copied alone into a
folder and tracked as a one-frame video in pixel mode, with no anchor (the upper cable end is the held end),
as a user would run ``track`` on a photo. One frame is too few to learn a background from, so ``track``'s
classical default estimates one background colour per frame; the learned segmenter segments the frame on its
own. Each variant runs the command in a subprocess.

Truth: the ends of every labelled cable. cables_dataset gives each cable's ordered points (its first and last
point are its ends); for mBEST the ends are the free ends of each label's skeleton. Reported per variant and
data set: the share of photos with a measured tip, the median distance from the measured tip to the nearest
true cable end, and the share of photos whose measured tip is wrong: more than ``--wrong-px`` (default 25)
from every cable end. A tip at a crossing or in the middle of a cable is a confident wrong answer.

    python benchmarks/track_photos.py --out /tmp/track_photos.json [--variants "classical;learned"]
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dyndlo_vision.tracking.centerline import thin  # noqa: E402

EXTERNAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "external"
VARIANTS = {
    "classical": ["--segmenter", "background"],  # track's default
    "learned": ["--segmenter", "learned"],
    "learned fine": ["--segmenter", "learned", "--segmenter-model", "cable-segmenter-fine"],
}


def _skeleton_ends(mask: np.ndarray) -> np.ndarray:
    """(K, 2) u,v of the free ends of ``mask``'s skeleton (pixels with exactly one 8-neighbour)."""
    skel = thin(mask.astype(np.uint8)).astype(np.uint8)
    neighbours = cv2.filter2D(skel, -1, np.ones((3, 3), np.float32), borderType=cv2.BORDER_CONSTANT) - skel
    v, u = np.nonzero((skel > 0) & (neighbours == 1))
    return np.column_stack([u, v]).astype(float)


def photos(root: Path) -> list[tuple[str, Path, np.ndarray, np.ndarray]]:
    """(data set, photo, true cable ends (K, 2), all-cable mask) for every labelled photo."""
    found = []
    for img in sorted((root / "mbest").glob("S*/img*.jpg")):
        labels = cv2.imread(str(img.with_name(img.stem + "_labels.png")), cv2.IMREAD_GRAYSCALE)
        ends = [_skeleton_ends(labels == k) for k in np.unique(labels) if k > 0]
        found.append(("mbest", img, np.concatenate(ends), labels > 0))
    for img in sorted((root / "cables_dataset").glob("*.jpg")):
        ends = []
        for line in img.with_suffix(".txt").read_text().splitlines():
            values = [float(x) for x in line.split()]
            if not values:
                continue
            pts = np.asarray(values[1:], float).reshape(-1, 2)
            ends += [pts[0], pts[-1]]
        mask = cv2.imread(str(img.with_name(img.stem + "_mask_all.png")), cv2.IMREAD_GRAYSCALE) > 0
        found.append(("cables_dataset", img, np.asarray(ends), mask))
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--data", default=str(EXTERNAL), help="the external data folder")
    parser.add_argument("--variants", default="classical;learned",
                        help=f"';'-separated names from {sorted(VARIANTS)}")
    parser.add_argument("--wrong-px", type=float, default=25.0)
    args = parser.parse_args()
    items = photos(Path(args.data))
    if not items:
        print(f"no labelled photos under {args.data}", file=sys.stderr)
        return 2
    results: dict = {"command": " ".join(sys.argv), "machine": platform.platform(), "variants": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.variants.split(";"):
            rows = []
            t0 = time.perf_counter()
            for dataset, img, ends, cable in items:
                folder = Path(tmp) / f"{dataset}_{img.parent.name}_{img.stem}"
                folder.mkdir(exist_ok=True)
                shutil.copy(img, folder / img.name)
                out = Path(tmp) / "track.csv"
                argv = [sys.executable, "-m", "dyndlo_vision", "track", str(folder), "--out", str(out),
                        "--quiet", *VARIANTS[name]]
                done = subprocess.run(argv, capture_output=True, text=True)
                if done.returncode != 0:
                    print(done.stderr, file=sys.stderr)
                    rows.append({"dataset": dataset, "photo": str(img), "status": done.returncode})
                    continue
                with open(out, newline="") as f:
                    row = next(csv.DictReader(f))
                measured = row["visible"] == "1"
                entry = {"dataset": dataset, "photo": f"{img.parent.name}/{img.name}", "status": 0,
                         "measured": measured}
                if measured:
                    tip = np.array([float(row["u"]), float(row["v"])])
                    entry["tip_to_end_px"] = float(np.min(np.linalg.norm(ends - tip, axis=1)))
                    v, u = np.nonzero(cable)
                    entry["tip_to_cable_px"] = float(np.min(np.hypot(u - tip[0], v - tip[1])))
                rows.append(entry)
            summary = {}
            for dataset in ("mbest", "cables_dataset", "all"):
                sel = [r for r in rows if dataset in ("all", r["dataset"]) and r["status"] == 0]
                meas = [r for r in sel if r["measured"]]
                err = [r["tip_to_end_px"] for r in meas]
                summary[dataset] = {
                    "photos": len(sel),
                    "measured_share": len(meas) / max(len(sel), 1),
                    "tip_to_end_px_median": float(np.median(err)) if err else None,
                    "wrong_share": sum(e > args.wrong_px for e in err) / max(len(sel), 1),
                    "off_cable_share": sum(r["tip_to_cable_px"] > args.wrong_px for r in meas)
                    / max(len(sel), 1),
                }
                s = summary[dataset]
                print(f"{name:14s} {dataset:15s} photos {s['photos']:3d}  measured "
                      f"{s['measured_share']:5.0%}  tip to nearest end, median "
                      f"{s['tip_to_end_px_median'] or float('nan'):6.1f} px  wrong "
                      f"(> {args.wrong_px:g} px from every end) {s['wrong_share']:5.0%}  off every cable "
                      f"{s['off_cable_share']:5.0%}", flush=True)
            results["variants"][name] = {"summary": summary, "photos": rows,
                                         "wall_s": round(time.perf_counter() - t0, 1)}
    Path(args.out).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
