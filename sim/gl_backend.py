"""Choose MuJoCo's headless OpenGL backend before ``mujoco`` is imported.

MuJoCo reads MUJOCO_GL once, at import. A value the user set is respected.
Otherwise EGL is used when libEGL is installed (Mesa renders on the CPU
through it without a display), and OSMesa when only libOSMesa is.
"""

from __future__ import annotations

import ctypes.util
import os
import sys

APT_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6"


class NoGLBackendError(RuntimeError):
    """Neither EGL nor OSMesa is installed."""


def select_gl_backend() -> str:
    """Set MUJOCO_GL (and PYOPENGL_PLATFORM) and return the backend name."""
    backend = os.environ.get("MUJOCO_GL")
    if backend is None:
        if "mujoco" in sys.modules:
            raise RuntimeError("import sim before mujoco: MUJOCO_GL must be set before mujoco is imported")
        if ctypes.util.find_library("EGL"):
            backend = "egl"
        elif ctypes.util.find_library("OSMesa"):
            backend = "osmesa"
        else:
            raise NoGLBackendError(
                "no headless OpenGL found for MuJoCo: install EGL or OSMesa "
                f"(Debian: apt-get install --no-install-recommends {APT_PACKAGES}), "
                "or set MUJOCO_GL yourself"
            )
        os.environ["MUJOCO_GL"] = backend
    os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend
