"""Fixtures for the tracking tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from dyndlo_vision.tracking.camera_model import PinholeCamera

from .helpers import EXTERNAL_DIR, look_at_camera


@pytest.fixture
def camera() -> PinholeCamera:
    return look_at_camera()


@pytest.fixture
def distorted_camera() -> PinholeCamera:
    return look_at_camera(dist=(-0.25, 0.08, 0.001, -0.0015, -0.01))


@pytest.fixture(scope="session")
def external_dir() -> Path:
    if not EXTERNAL_DIR.is_dir():
        pytest.skip(f"external data not found at {EXTERNAL_DIR}")
    return EXTERNAL_DIR
