"""``dyndlo-vision plot RUN...``: success rate and mean reward against timesteps (the paper's Fig. 3)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "plot learning curves of one or more training runs to a PNG"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``plot``."""
    p.add_argument("runs", nargs="+", help="run folders written by `dyndlo-vision train`")
    p.add_argument("--out", default="learning_curves.png", help="PNG path (default: learning_curves.png)")
    p.add_argument("--title", default=None, help="figure title (default: none)")


def run(args: argparse.Namespace) -> int:
    """Plot and report the groups drawn."""
    from dyndlo_vision.learning.plots import plot_runs

    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"--out {out}: expected a .png path")
    if not out.parent.exists():
        raise ValueError(f"output folder {out.parent} does not exist")
    groups = plot_runs([Path(r) for r in args.runs], out, args.title)
    for group, members in groups.items():
        print(f"{group}: {', '.join(members)}")
    print(f"wrote {out}")
    return 0
