"""Choose a headless OpenGL backend for MuJoCo *before* ``mujoco`` is imported.

MuJoCo's Python package picks its GL backend from the ``MUJOCO_GL`` environment variable
when it is first imported (``egl``, ``osmesa`` or ``glfw``). When the variable is unset we
probe the system libraries and choose EGL (GPU or Mesa's software EGL), then OSMesa; when
neither exists we leave it unset and `vitaplace.engine.sim.render` raises a clear error
the first time a camera is needed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.base.libraries import first_loadable

_LIBS = {"egl": ("EGL", "libEGL.so.1"), "osmesa": ("OSMesa", "libOSMesa.so.8")}

class GLUnavailableError(UserError, RuntimeError):
    """No OpenGL context can be created for offscreen rendering (the message says what to install)."""


INSTALL_HINT = (
    "Headless rendering needs EGL or OSMesa: install `libegl1` (EGL, preferred; Mesa's software "
    "EGL works without a GPU) and set MUJOCO_GL=egl, or install `libosmesa6` and set MUJOCO_GL=osmesa "
    "(e.g. `sudo apt-get install libegl1` then `export MUJOCO_GL=egl`)."
)

#: what `select_gl_backend` decided, for error messages
STATE: dict[str, str | None] = {"chosen": None, "reason": None}


def _loadable(backend: str) -> bool:
    short, soname = _LIBS[backend]
    return first_loadable((ctypes.util.find_library(short), soname)) is not None


def select_gl_backend() -> str | None:
    """Set ``MUJOCO_GL`` (and ``PYOPENGL_PLATFORM``) if unset; return the backend in use.

    Respects a value the user already set. Has no effect on rendering if ``mujoco`` was
    imported before this function ran (MuJoCo reads the variable at import time).
    """
    if STATE["reason"] is not None:  # decided already (this runs at package import)
        return STATE["chosen"]
    current = os.environ.get("MUJOCO_GL")
    if current:
        if current.lower() in _LIBS and "mujoco" not in sys.modules and not _loadable(current.lower()):
            # MuJoCo's own import would fail with an obscure PyOpenGL AttributeError
            raise GLUnavailableError(
                f"MUJOCO_GL={current} but lib{_LIBS[current.lower()][0]} cannot be loaded. {INSTALL_HINT}"
            )
        STATE["chosen"] = current
        STATE["reason"] = "MUJOCO_GL set by the user"
        return current
    if "mujoco" in sys.modules:
        STATE["reason"] = "mujoco was imported before vitaplace could choose a GL backend"
        return None
    for backend in ("egl", "osmesa"):
        if _loadable(backend):
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            STATE["chosen"] = backend
            STATE["reason"] = f"found lib{_LIBS[backend][0]}"
            return backend
    STATE["reason"] = "neither libEGL nor libOSMesa could be loaded"
    return None
