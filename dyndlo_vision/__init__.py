"""DynDLO: learning dynamic cable manipulation in MuJoCo, with perception in the loop.

Importing the package picks an off-screen GL backend (when ``MUJOCO_GL`` is unset) and registers the
Gymnasium environments ``DynDLO/TipControl-v0``, ``DynDLO/Vaulting-v0``, ``DynDLO/Hooking-v0`` and
``DynDLO/TimeOscillation-v0``.
"""

from dyndlo_vision._gl import select_gl_backend

select_gl_backend()

from dyndlo_vision.tasks import register_envs  # noqa: E402

register_envs()

__version__ = "0.1.0"
