"""Off-screen renderer construction (the GL backend is chosen by ``dyndlo_vision._gl`` at import)."""

from __future__ import annotations

import os
from typing import Any


def make_renderer(model: Any, height: int, width: int) -> Any:
    """Return a ``mujoco.Renderer``, with an error that says how to get a GL backend when none works."""
    import mujoco

    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as exc:  # MuJoCo raises several types depending on the backend
        raise RuntimeError(
            f"off-screen rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: {exc}. "
            "Install EGL (apt-get install libegl1) or OSMesa (apt-get install libosmesa6), "
            "or set MUJOCO_GL explicitly."
        ) from exc
