"""Choose MuJoCo's off-screen GL backend (EGL, else OSMesa) before anything imports ``mujoco``.

MuJoCo reads ``MUJOCO_GL`` when it is first imported, so the package ``__init__`` imports this module first.
A user's own ``MUJOCO_GL`` always wins.
"""

from __future__ import annotations

import ctypes.util
import glob
import os


def _egl_has_device() -> bool:
    """Whether EGL has a GPU to render on, judged from device nodes.

    Probing by loading libEGL in this process is not an option: it leaves a GL dispatch library loaded
    that later breaks OSMesa's function loading (``gladLoadGL error``).
    """
    if ctypes.util.find_library("EGL") is None:
        return False
    return bool(glob.glob("/dev/nvidia[0-9]*") or glob.glob("/dev/dri/renderD*"))


def select_gl_backend() -> str | None:
    """Set ``MUJOCO_GL`` to "egl" or "osmesa" when unset and no display is available; return the choice."""
    if "MUJOCO_GL" in os.environ:
        return os.environ["MUJOCO_GL"]
    if os.environ.get("DISPLAY"):
        return None  # a desktop session: let MuJoCo use GLFW
    if _egl_has_device():
        os.environ["MUJOCO_GL"] = "egl"
    elif ctypes.util.find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    else:
        return None
    if os.environ["MUJOCO_GL"] == "egl":
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    return os.environ["MUJOCO_GL"]
