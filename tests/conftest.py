"""Shared test configuration: headless rendering and the optional external data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")

EXTERNAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "external"


@pytest.fixture(scope="session")
def external_data() -> Path:
    """The ../shared/data/external folder; skips the test when it is absent."""
    if not EXTERNAL_DATA.is_dir():
        pytest.skip(f"external data not found at {EXTERNAL_DATA}")
    return EXTERNAL_DATA
