"""The shipped learned cable segmenters: ONNX networks and the JSON beside each (how it was made).

Five networks, for different pictures (docs/segmentation.md):

* ``cable-segmenter`` (the default of ``track --segmenter learned`` and the real robot's camera): RGB at a
  short side of 240 px, mask at half that. The fastest of the five on a 640x480 frame.
* ``cable-segmenter-photo-wide`` (the default of ``segment``): ``cable-segmenter-photo`` widened to twice
  its channels, deepened by two residual blocks at its finest level (156 k parameters) and trained on further
  on the same data, last with the images enlarged up to 2.2x (as ``segment`` enlarges small photos). The best
  of the five on held-out real photos and on every composited style; about 3x slower than
  ``cable-segmenter-photo``.
* ``cable-segmenter-photo``: ``cable-segmenter-fine`` fine-tuned on composited scenes of many cables on
  real-looking surfaces, MuJoCo renders, and the train half of both sources of the shared labelled photos
  drawn equally often; weaker than ``cable-segmenter`` on MuJoCo renders.
* ``cable-segmenter-fine``: the frame in 4x4 blocks at 480 px, mask at the frame's full resolution. Made for
  cables 1-3 px wide, such as the loop camera's 1.6 px cable, which the first network cuts into fragments;
  weaker on wide, flat-coloured cables.
* ``cable-segmenter-loop`` (the simulated loop's ``--segmenter learned``): ``cable-segmenter-fine``
  fine-tuned on renders of the loop's own scenes (``seg-data --style task-scenes``). In the loop its tip
  estimate is closer to the truth than the fine network's; on other scenes and real photos it is weaker.

This module only hands out the bytes and the metadata, beside the code that runs them (``tracking`` imports
nothing else of the package); the network runs in :class:`dyndlo_vision.tracking.learned.LearnedSegmenter`::

    seg = LearnedSegmenter(onnx_bytes())                       # the default network
    seg = LearnedSegmenter(onnx_bytes(FINE_NAME))              # the full-resolution one
    seg = LearnedSegmenter(onnx_bytes("runs/seg/cable_segmenter.onnx"))
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

__all__ = ["FINE_NAME", "LOOP_NAME", "PHOTO_NAME", "SHIPPED_NAME", "SHIPPED_NAMES", "SHIPPED_SUMMARIES",
           "check_network",
           "onnx_bytes", "segmenter_metadata"]

#: The default network (``onnx_bytes()``): ``track --segmenter learned`` and the real robot's camera.
SHIPPED_NAME = "cable-segmenter"
#: The default of ``segment`` (photos, no time budget).
PHOTO_NAME = "cable-segmenter-photo-wide"
FINE_NAME = "cable-segmenter-fine"
LOOP_NAME = "cable-segmenter-loop"
#: Each shipped network and what it is for, in a few words (the commands' option help lists them from here).
SHIPPED_SUMMARIES = {
    PHOTO_NAME: "full resolution, the best on real photos",
    "cable-segmenter-photo": "half as wide, 3x faster",
    SHIPPED_NAME: "half resolution, fastest",
    FINE_NAME: "full resolution, for cables 1-3 px wide",
    LOOP_NAME: "cable-segmenter-fine tuned on the simulated loop's scenes",
}
SHIPPED_NAMES = (SHIPPED_NAME, PHOTO_NAME, "cable-segmenter-photo", FINE_NAME, LOOP_NAME)


def _shipped(name: str, suffix: str) -> Any:
    if name not in SHIPPED_NAMES:
        raise ValueError(f"no shipped segmenter {name!r}; shipped: {list(SHIPPED_NAMES)}")
    return resources.files(__name__).joinpath(f"{name}{suffix}")


def segmenter_metadata(name: str = SHIPPED_NAME) -> dict[str, Any]:
    """A shipped segmenter's JSON (the commands and data that produced it, and its measured scores)."""
    return dict(json.loads(_shipped(name, ".json").read_text()))


def check_network(path: str | Path, option: str) -> None:
    """Refuses a command's ``option`` value, before anything is written, unless it is a shipped name or an
    existing file (what :func:`onnx_bytes` reads).

    Raises:
        FileNotFoundError: naming the option, the value and the shipped names.
    """
    if str(path) not in SHIPPED_NAMES and not Path(path).is_file():
        raise FileNotFoundError(f"{option} {path} does not exist (shipped names: {', '.join(SHIPPED_NAMES)})")


def onnx_bytes(path: str | Path | None = None) -> bytes:
    """A network as bytes: the default shipped one (``None``), a shipped one by name (:data:`SHIPPED_NAMES`),
    or the ONNX file at ``path`` (e.g. from ``seg-train``).

    Raises:
        FileNotFoundError: ``path`` is neither a shipped name nor an existing file.
    """
    if path is None:
        path = SHIPPED_NAME
    if str(path) in SHIPPED_NAMES:
        return bytes(_shipped(str(path), ".onnx").read_bytes())
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"segmenter file {p} does not exist (shipped names: {list(SHIPPED_NAMES)})")
    return p.read_bytes()
