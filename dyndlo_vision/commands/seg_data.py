"""``dyndlo-vision seg-data``: write a domain-randomised cable image/mask dataset (MuJoCo or 2-D composites).

Thin wrapper over :func:`dyndlo_vision.learning.segdata.write_dataset`. Run it again with the same ``--out``,
``--seed`` and sizes to resume (or to extend it with a larger ``--count``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dyndlo_vision.learning.segdata import DEFAULT_WIDTHS_PX, MUJOCO_STYLES, STYLES, SegDataConfig

HELP = "render a domain-randomised cable image/mask dataset (resumable)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``seg-data``."""
    from dyndlo_vision.commands import _options as options

    p.add_argument(
        "--out", required=True, metavar="DIR", help="dataset folder (created; resumed if it holds one)"
    )
    p.add_argument("--count", type=int, default=2000, help="number of samples")
    p.add_argument("--seed", type=int, default=0, help="seed of the randomisation (training used 0)")
    options.add_image_size(p, 320, 240)
    defaults = SegDataConfig()
    p.add_argument("--texture-share", type=float, default=defaults.texture_share,
                   help="share of samples whose background is a procedural texture; the others keep the "
                   "rendered floor")
    p.add_argument("--lum-match-share", type=float, default=defaults.lum_match_share,
                   help="share of textured samples scaled to the cable's brightness (colour-only contrast)")
    p.add_argument("--grey-floor-share", type=float, default=defaults.grey_floor_share,
                   help="share of rendered-floor samples with a neutral grey floor, the task scenes' look "
                   "(0: a random colour each; the shipped networks' data)")
    p.add_argument("--style", choices=STYLES, default=defaults.style,
                   help="random-scenes: random cables among random props from random cameras; task-scenes: "
                   "the control loop's own scenes (tip control, vaulting) through their loop cameras, the "
                   "cable moved by random actions; wires, bundles, harness, busy, own-colour: many cables "
                   "composited in 2-D on real-looking surfaces (docs/segmentation.md)")
    p.add_argument("--min-width", type=float, default=None, metavar="PX",
                   help="least cable width in pixels (default: 0.7 for the MuJoCo styles, 1 for the "
                   "composited ones)")
    p.add_argument("--max-width", type=float, default=None, metavar="PX",
                   help="most cable width in pixels (default: 12 for the MuJoCo styles, 40 for the "
                   "composited ones)")
    p.add_argument("--upscale", type=float, default=defaults.upscale, metavar="S",
                   help="enlarge every image and label S times (bilinear) after rendering at --width x "
                   "--height, as the loop enlarges its frames for its network (1-4; default 1: as rendered)")
    options.add_quiet(p)


def run(args: argparse.Namespace) -> int:
    """Writes (or resumes) the dataset; 0 on success."""
    from tqdm import tqdm

    from dyndlo_vision.learning.segdata import write_dataset

    lo, hi = DEFAULT_WIDTHS_PX["mujoco" if args.style in MUJOCO_STYLES else "composite"]
    config = SegDataConfig(width=args.width, height=args.height, texture_share=args.texture_share,
                           lum_match_share=args.lum_match_share, grey_floor_share=args.grey_floor_share,
                           style=args.style, upscale=args.upscale,
                           min_width_px=lo if args.min_width is None else args.min_width,
                           max_width_px=hi if args.max_width is None else args.max_width)
    config.check()
    if args.count < 1:
        raise ValueError(f"--count must be >= 1, got {args.count}")
    with tqdm(
        total=args.count, desc="seg-data", unit="img", file=sys.stderr, disable=args.quiet, dynamic_ncols=True
    ) as bar:
        n = write_dataset(Path(args.out), args.count, args.seed, config, progress=bar)
    if not args.quiet:
        print(f"wrote {n} new samples to {args.out}", file=sys.stderr)
    return 0
