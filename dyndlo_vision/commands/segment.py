"""``dyndlo-vision segment INPUT... --out DIR``: cable masks and ordered centrelines of photos and folders.

Each image is processed on its own (no memory between images; sizes may differ). For ``NAME.ext`` it writes
``DIR/NAME_mask.png`` (0/255, the input's size) and ``DIR/NAME_centerline.json`` (ordered polylines in
pixels, longest first, each end marked free or cut by the border). Every input is read and every output name
checked before anything is written, and each file is written atomically: bad input (a missing or unreadable
file, a folder without images, two inputs with one name, an existing output without ``--overwrite``) exits
with status 2 and leaves nothing behind.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

HELP = "segment cables in photos/image folders: NAME_mask.png and NAME_centerline.json per image"

SEGMENTERS = ("learned", "background", "hsv")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``segment``."""
    from dyndlo_vision.commands import _options as options
    from dyndlo_vision.tracking.networks import PHOTO_NAME

    p.add_argument("inputs", nargs="+", metavar="INPUT", help="image files and/or folders of images")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    options.add_segmenter(p, SEGMENTERS, "learned")
    options.add_segmenter_model(p, default=PHOTO_NAME)
    options.add_short_side(p)
    options.add_hsv_bounds(p)
    p.add_argument("--max-cables", type=int, default=8, help="most polylines per image")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    options.add_quiet(p)


def _segmenter(args: argparse.Namespace) -> Any:
    """The segmenter the options name (:func:`~dyndlo_vision.commands._options.segmenter_config`), built
    where every segmenter is (:func:`~dyndlo_vision.tracking.segmenters.build_segmenter`); each image on its
    own, so the background one estimates the background from the image itself."""
    from dyndlo_vision.commands._options import segmenter_config
    from dyndlo_vision.tracking.networks import PHOTO_NAME
    from dyndlo_vision.tracking.segmenters import build_segmenter

    return build_segmenter(segmenter_config(args, default_model=PHOTO_NAME, background="frame"))[0]


def run(args: argparse.Namespace) -> int:
    """Segments every input; 0 on success."""
    import cv2
    import numpy as np
    from tqdm import tqdm

    from dyndlo_vision._atomic import write_atomic
    from dyndlo_vision.tracking.polylines import extract_polylines

    if args.max_cables < 1:
        raise ValueError(f"--max-cables must be >= 1, got {args.max_cables}")
    from dyndlo_vision.cameras.files import image_files

    files = image_files(args.inputs)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"--out {out} exists and is not a folder")
    stems: dict[str, Path] = {}
    for f in files:
        if f.stem in stems:
            raise ValueError(f"inputs {stems[f.stem]} and {f} would both write {f.stem}_mask.png; rename one")
        stems[f.stem] = f
        if not args.overwrite:
            for suffix in ("_mask.png", "_centerline.json"):
                if (out / f"{f.stem}{suffix}").exists():
                    raise FileExistsError(f"{out / (f.stem + suffix)} exists; pass --overwrite to replace it")
    # Every input must decode before anything is written (truncated files included).
    for f in files:
        if cv2.imread(str(f), cv2.IMREAD_COLOR) is None:
            raise ValueError(f"cannot read image {f} (not an image OpenCV decodes, or truncated)")
    segmenter = _segmenter(args)
    out.mkdir(parents=True, exist_ok=True)
    name = args.segmenter if args.segmenter != "learned" else f"learned:{args.segmenter_model or 'shipped'}"
    for f in tqdm(files, desc="segment", unit="img", file=sys.stderr, disable=args.quiet, dynamic_ncols=True):
        bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"cannot read image {f}")
        rgb = np.ascontiguousarray(bgr[..., ::-1])
        mask = np.asarray(segmenter(rgb), dtype=bool)
        polys = extract_polylines(mask, max_cables=args.max_cables)
        mask_u8 = np.where(mask, 255, 0).astype(np.uint8)
        doc = {
            "image": str(f),
            "width": int(rgb.shape[1]),
            "height": int(rgb.shape[0]),
            "segmenter": name,
            "mask_pixels": int(mask.sum()),
            "polylines": [p.to_json() for p in polys],
        }
        write_atomic(out / f"{f.stem}_mask.png", lambda tmp, m=mask_u8: _imwrite(tmp, m))
        write_atomic(
            out / f"{f.stem}_centerline.json",
            lambda tmp, d=doc: Path(tmp).write_text(json.dumps(d, indent=1)),
        )
    return 0


def _imwrite(path: str, img: Any) -> None:
    import cv2

    if not cv2.imwrite(path, img):
        raise OSError(f"could not write {path}")
