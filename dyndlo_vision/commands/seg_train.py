"""``dyndlo-vision seg-train``: train the learned cable segmenter on a ``seg-data`` dataset; export ONNX.

Thin wrapper over :func:`dyndlo_vision.learning.segtrain.train`. ``--resume`` continues from
``OUT/checkpoint.pt`` (written every 250 steps and on Ctrl-C).
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "train the learned cable segmenter on a seg-data dataset (resumable), export ONNX"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``seg-train``."""
    from dyndlo_vision.commands import _options as options
    from dyndlo_vision.tracking.networks import SHIPPED_NAMES

    p.add_argument("--data", required=True, nargs="+", metavar="DIR",
                   help="dataset(s) written by seg-data; several are pooled, every sample equally likely")
    p.add_argument("--out", required=True, metavar="DIR", help="run folder (checkpoint, ONNX, JSON)")
    p.add_argument("--steps", type=int, default=6000, help="optimiser steps")
    p.add_argument("--batch", type=int, default=8, help="images per step")
    p.add_argument("--lr", type=float, default=3e-3, help="peak learning rate (cosine decay)")
    p.add_argument("--seed", type=int, default=0, help="seed of sampling and augmentation")
    p.add_argument("--pos-weight", type=float, default=3.0,
                   help="weight of cable pixels in the cross-entropy (higher: fewer missed cable pixels, "
                   "more false ones)")
    p.add_argument(
        "--external", metavar="DIR", help="labelled real photos (shared/data/external) to fine-tune on"
    )
    p.add_argument(
        "--external-share",
        type=float,
        default=0.0,
        help="share of each batch from the external train split (its held-out half is never used)",
    )
    p.add_argument("--external-short-side", type=int, default=240, metavar="PX",
                   help="the external photos' short side before augmentation: the scale the network will "
                   "run them at (default 240; 480 for the block networks)")
    p.add_argument("--max-scale", type=float, default=1.5, metavar="S",
                   help="each training image is resized by a random scale from 0.6 to this before its crop "
                   "(default 1.5); segment enlarges photos smaller than the network's short side (2.2: "
                   "cable-segmenter-photo-wide, for the 1.67x of a 384x288 photo)")
    p.add_argument("--external-balanced", action="store_true",
                   help="draw each external source equally often, then a photo within it (default: every "
                   "photo equally often)")
    p.add_argument(
        "--arch",
        choices=("cablenet-s2d4", "cablenet"),
        default="cablenet-s2d4",
        help="network: cablenet-s2d4 (full-resolution mask, as cable-segmenter-fine) or cablenet (half "
        "resolution, as cable-segmenter)",
    )
    p.add_argument("--widths", default="8,16,32", metavar="C1,C2,C3",
                   help="channels of the network's three levels (default 8,16,32, the shipped networks'); "
                   "narrower runs faster. With --init, twice the network's widths widen it: it starts out "
                   "computing what it did")
    p.add_argument("--blocks", type=int, default=0, metavar="N",
                   help="residual blocks at the network's finest level (default 0), where a cable's edges "
                   "are told from a shadow or a stroke beside it. With --init, more blocks than the network "
                   "has deepen it: it starts out computing what it did")
    p.add_argument("--init", metavar="CHECKPOINT.pt|NET.onnx|NAME",
                   help="start from these weights (fine-tuning): a seg-train checkpoint, an exported ONNX "
                   f"network or a shipped one by name ({', '.join(SHIPPED_NAMES)}); an ONNX network, or a "
                   "checkpoint of a run from one, is fine-tuned with its batch norms frozen (the export "
                   "folded their statistics away)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    options.add_resume(p)
    options.add_quiet(p)


def run(args: argparse.Namespace) -> int:
    """Trains; 0 on success, 130 on Ctrl-C (checkpoint saved)."""
    import sys

    from dyndlo_vision.learning.segtrain import TrainConfig, needs_frozen_batch_norm, train

    if args.steps < 1 or args.batch < 1:
        raise ValueError(f"--steps and --batch must be >= 1, got {args.steps}, {args.batch}")
    if not 0.0 <= args.external_share <= 1.0:
        raise ValueError(f"--external-share must be in [0, 1], got {args.external_share}")
    if not args.pos_weight > 0:
        raise ValueError(f"--pos-weight must be > 0, got {args.pos_weight}")
    if args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    try:
        widths = tuple(int(c) for c in str(args.widths).split(","))
    except ValueError:
        widths = ()
    if len(widths) != 3 or min(widths) < 1:
        raise ValueError(f"--widths must be three positive integers C1,C2,C3, got {args.widths!r}")
    cfg = TrainConfig(
        widths=widths,  # type: ignore[arg-type]
        blocks=args.blocks,
        steps=args.steps,
        batch=args.batch,
        lr=args.lr,
        seed=args.seed,
        pos_weight=args.pos_weight,
        external_share=args.external_share,
        arch=args.arch,
        external_short_side=args.external_short_side,
        external_balanced=args.external_balanced,
        max_scale=args.max_scale,
        frozen_batch_norm=bool(args.init) and needs_frozen_batch_norm(args.init),
    )
    try:
        meta = train(
            [Path(d) for d in args.data],
            Path(args.out),
            cfg,
            resume=args.resume,
            external=Path(args.external) if args.external else None,
            init=Path(args.init) if args.init else None,
            progress=not args.quiet,
            threads=args.threads,
        )
    except KeyboardInterrupt:
        ext = (f" --external {args.external} --external-share {args.external_share} --external-short-side "
               f"{args.external_short_side}" + (" --external-balanced" if args.external_balanced else "")
               if args.external else "")
        ext += f" --init {args.init}" if args.init else ""
        print(
            f"interrupted; resume with: dyndlo-vision seg-train --resume --data {' '.join(args.data)} "
            f"--out {args.out} --steps {args.steps} --batch {args.batch} --lr {args.lr} --seed {args.seed} "
            f"--pos-weight {args.pos_weight} --arch {args.arch}"
            f" --widths {args.widths} --blocks {args.blocks} --max-scale {args.max_scale}{ext}",
            file=sys.stderr,
        )
        return 130
    print(f"wrote {args.out}/cable_segmenter.onnx ({meta['parameters']} parameters)", file=sys.stderr)
    return 0
