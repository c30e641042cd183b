"""Subcommands of ``dyndlo-vision``: one module each, exposing ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. Modules import their heavy dependencies inside ``run``, so ``--help`` stays fast."""

from __future__ import annotations

#: Command name -> module under ``dyndlo_vision.commands``.
COMMANDS: dict[str, str] = {
    "demo": "demo",
    "track": "track",
    "calibrate": "calibrate",
    "evaluate": "evaluate",
    "plot": "plot",
    "train": "train",
    "distill": "distill",
    "seg-data": "seg_data",
    "seg-train": "seg_train",
    "segment": "segment",
    "run": "run",
}
