"""The shipped learned cable segmenter: ``cable-segmenter.onnx`` and the JSON beside it (how it was made).

:func:`load_segmenter` returns a :class:`dyndlo_vision.tracking.learned.LearnedSegmenter` over the shipped
ONNX file, or over a file of one's own from ``dyndlo-vision seg-train`` (``OUT/cable_segmenter.onnx``).
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

from dyndlo_vision.tracking.learned import LearnedSegmenter

__all__ = ["SHIPPED_NAME", "load_segmenter", "segmenter_metadata"]

SHIPPED_NAME = "cable-segmenter"


def _shipped(suffix: str) -> Any:
    return resources.files(__name__).joinpath(f"{SHIPPED_NAME}{suffix}")


def segmenter_metadata() -> dict[str, Any]:
    """The shipped segmenter's JSON (the command and data that produced it, and its measured scores)."""
    return dict(json.loads(_shipped(".json").read_text()))


def load_segmenter(path: str | Path | None = None, **kwargs: Any) -> LearnedSegmenter:
    """The shipped segmenter (``path=None``) or the ONNX file at ``path``; ``kwargs`` go to the segmenter.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file is not an ONNX network OpenCV can run.
    """
    if path is None:
        data = _shipped(".onnx").read_bytes()
    else:
        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"segmenter file {p} does not exist")
        data = p.read_bytes()
    return LearnedSegmenter(data, **kwargs)
