"""The shipped learned cable segmenter: ``cable-segmenter.onnx`` and the JSON beside it (how it was made).

This module only hands out the bytes and the metadata (``policies`` imports nothing above ``tasks``); the
network runs in :class:`dyndlo_vision.tracking.learned.LearnedSegmenter`::

    seg = LearnedSegmenter(onnx_bytes())                       # the shipped network
    seg = LearnedSegmenter(onnx_bytes("runs/seg/cable_segmenter.onnx"), short_side=240)
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

__all__ = ["SHIPPED_NAME", "onnx_bytes", "segmenter_metadata"]

SHIPPED_NAME = "cable-segmenter"


def _shipped(suffix: str) -> Any:
    return resources.files(__name__).joinpath(f"{SHIPPED_NAME}{suffix}")


def segmenter_metadata() -> dict[str, Any]:
    """The shipped segmenter's JSON (the commands and data that produced it, and its measured scores)."""
    return dict(json.loads(_shipped(".json").read_text()))


def onnx_bytes(path: str | Path | None = None) -> bytes:
    """The shipped network (``path=None``) or the ONNX file at ``path`` (e.g. from ``seg-train``), as bytes.

    Raises:
        FileNotFoundError: ``path`` does not exist.
    """
    if path is None:
        return bytes(_shipped(".onnx").read_bytes())
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"segmenter file {p} does not exist")
    return p.read_bytes()
