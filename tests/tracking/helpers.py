"""Shared helpers for the tracking tests (geometry, drawing)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from dyndlo_vision.tracking.camera_model import PinholeCamera

#: ../shared/data/external relative to the repository root.
EXTERNAL_DIR = Path(__file__).resolve().parents[2].parent / "shared/data/external"


def look_at_camera(
    eye: tuple[float, float, float] = (0.2, -0.9, 1.1),
    target: tuple[float, float, float] = (0.0, 0.0, 0.0),
    width: int = 640,
    height: int = 480,
    f: float = 520.0,
    dist: tuple[float, ...] = (),
) -> PinholeCamera:
    """A camera at ``eye`` looking at ``target`` (world z up), OpenCV axes."""
    eye_a = np.asarray(eye, float)
    z = np.asarray(target, float) - eye_a
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack((x, y, z))
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    return PinholeCamera(width, height, K, np.asarray(dist, float), R, -R @ eye_a, fps=25.0)


def down_camera() -> PinholeCamera:
    """2 m above the origin looking straight down: the ray through pixel (50 + 100 a, 40 + 100 b) runs along
    (a, -b, -1) in the world (pixel (60, 20) along (0.1, 0.2, -1)); the one through the principal point
    (50, 40) exactly along -z."""
    K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
    return PinholeCamera(101, 81, K, np.zeros(0), np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 2.0]))


def gt_params(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Arc-length position along ``curve`` of the nearest curve vertex to each point."""
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(curve, axis=0).T))))
    d = np.hypot(points[:, None, 0] - curve[None, :, 0], points[:, None, 1] - curve[None, :, 1])
    return s[np.argmin(d, axis=1)]


def curve_length(curve: np.ndarray) -> float:
    """Arc length of a polyline."""
    return float(np.sum(np.hypot(*np.diff(curve, axis=0).T)))


def assert_track_refuses(argv: list[str], message: str, outputs: Path, capsys: pytest.CaptureFixture) -> None:
    """``dyndlo-vision track ARGV`` exits with status 2, says ``message`` (a regex) on stderr, and leaves the
    ``outputs`` folder empty."""
    from dyndlo_vision.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["track", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert re.search(message, err), err
    assert list(outputs.iterdir()) == []

