"""Choosing the OpenGL platform and importing pyrender cleanly.

**Supported combination** (pinned in ``pyproject.toml``): pyrender 0.1.45 with
the PyOpenGL 3.1.0 it pins, pyglet 1.5 (pyrender's Viewer uses the pyglet 1.x
API; pyglet 2 breaks it). Headless rendering uses **EGL** (Mesa's llvmpipe
without a GPU, the GPU's driver with one): PyOpenGL 3.1.0 makes EGL core
contexts correctly. Its OSMesa binding cannot make the core-profile context
pyrender asks for, so OSMesa is only a fallback when the user has installed a
newer PyOpenGL (``pip install 'PyOpenGL>=3.1.10'`` overrides pyrender's pin;
pip warns about it); we do not depend on that by default so that
``pip install -e .`` resolves without conflicts.

**numpy 2.** pyrender 0.1.45 uses ``np.infty`` (scene bounds, shadows, the
Viewer), an alias numpy 2.0 removed (NEP 52). :func:`import_pyrender` defines
exactly that one alias, ``np.infty = np.inf``, if it is missing, before
importing pyrender; nothing else in numpy or pyrender is touched.

**Platform.** ``PYOPENGL_PLATFORM`` must be set before PyOpenGL is imported:
``egl`` (default for headless) or ``osmesa``; for the windowed Viewer it must
be unset (pyglet's GLX context). A process therefore uses one mode; the CLI
and the tests start a fresh process for the other.

Debian packages (installed by ``scripts/setup.sh``): ``libegl1`` (the GLVND
EGL loader), ``libegl-mesa0`` (Mesa's EGL vendor library), ``libgl1-mesa-dri``
(the llvmpipe/GPU drivers), ``libgles2``, ``libosmesa6`` (OSMesa), ``libgl1``
and ``xvfb`` + ``xauth`` (a virtual X display for the windowed test).
"""

from __future__ import annotations

import ctypes.util
import os
import sys
from pathlib import Path

#: Debian package providing each library, for error messages.
PACKAGES = {"EGL": "libegl1", "EGL_mesa": "libegl-mesa0", "dri": "libgl1-mesa-dri",
            "OSMesa": "libosmesa6", "GL": "libgl1", "Xvfb": "xvfb"}


class GLUnavailable(RuntimeError):
    """No usable OpenGL context; the message names the missing Debian package."""


def _mesa_egl_vendor() -> bool:
    dirs = ["/usr/share/glvnd/egl_vendor.d", "/etc/glvnd/egl_vendor.d"]
    extra = os.environ.get("__EGL_VENDOR_LIBRARY_DIRS")
    if extra:
        dirs = extra.split(":")
    return any(Path(d).is_dir() and any(Path(d).glob("*.json")) for d in dirs)


def missing_package(platform: str) -> str | None:
    """The Debian package that is missing for ``platform`` ('egl', 'osmesa', 'window'), or None."""
    if platform == "egl":
        if ctypes.util.find_library("EGL") is None:
            return PACKAGES["EGL"]
        if not _mesa_egl_vendor():
            return PACKAGES["EGL_mesa"]
        if not any(Path(p).exists() for p in ("/usr/lib/x86_64-linux-gnu/dri/swrast_dri.so",
                                                "/usr/lib/aarch64-linux-gnu/dri/swrast_dri.so",
                                                "/usr/lib/x86_64-linux-gnu/dri", "/usr/lib/dri")):
            return PACKAGES["dri"]
        return None
    if platform == "osmesa":
        return None if ctypes.util.find_library("OSMesa") else PACKAGES["OSMesa"]
    if platform == "window":
        return None if ctypes.util.find_library("GL") else PACKAGES["GL"]
    raise ValueError(platform)


def _pyopengl_version() -> tuple[int, ...]:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return tuple(int(x) for x in version("PyOpenGL").split(".")[:3] if x.isdigit())
    except PackageNotFoundError:
        return (0,)


def osmesa_usable() -> bool:
    """OSMesa core contexts need libOSMesa and PyOpenGL ≥ 3.1.10 (3.1.0 lacks ``OSMesaCreateContextAttribs``)."""
    return missing_package("osmesa") is None and _pyopengl_version() >= (3, 1, 10)


def diagnose(platform: str | None) -> str:
    """One line saying what to install so that a headless context can be made."""
    egl = missing_package("egl")
    if egl:
        hint = f"install the Debian package {egl} (EGL)"
        if missing_package("osmesa") is None and not osmesa_usable():
            hint += "; the OSMesa fallback would need PyOpenGL>=3.1.10 (pyrender pins 3.1.0)"
        return hint
    if platform == "osmesa" and not osmesa_usable():
        return ("OSMesa needs PyOpenGL>=3.1.10 and the Debian package libosmesa6; or use EGL "
                "(PYOPENGL_PLATFORM=egl, Debian packages libegl1 libegl-mesa0)")
    return f"install the Debian package {PACKAGES['dri']} (Mesa drivers: llvmpipe without a GPU)"


def choose_platform(windowed: bool = False) -> str | None:
    """Set ``PYOPENGL_PLATFORM`` (unless the user did) and return it; None means windowed (GLX)."""
    if "OpenGL" in sys.modules:
        return os.environ.get("PYOPENGL_PLATFORM")
    if windowed:
        os.environ.pop("PYOPENGL_PLATFORM", None)
        return None
    if "PYOPENGL_PLATFORM" not in os.environ:
        plat = "osmesa" if missing_package("egl") is not None and osmesa_usable() else "egl"
        os.environ["PYOPENGL_PLATFORM"] = plat
    return os.environ["PYOPENGL_PLATFORM"]


def import_pyrender(windowed: bool = False):
    """Import pyrender for headless (EGL/OSMesa) or windowed use, with the numpy-2 ``np.infty`` alias.

    **Raises:** :class:`GLUnavailable` naming the missing package if PyOpenGL
    cannot load its platform library.
    """
    plat = choose_platform(windowed)
    import numpy as np

    if not hasattr(np, "infty"):
        np.infty = np.inf  # removed in numpy 2.0 (NEP 52); pyrender 0.1.45 still uses it
    try:
        import pyrender
    except ImportError as err:  # PyOpenGL raises ImportError/AttributeError when libEGL is absent
        raise GLUnavailable(f"cannot import pyrender on platform {plat or 'window'} ({err}); "
                            f"{diagnose(plat) if plat else 'install the Debian package libgl1'}") from err
    except AttributeError as err:
        raise GLUnavailable(f"OpenGL platform {plat} unusable ({err}); {diagnose(plat)}") from err
    return pyrender


def describe_context() -> dict:
    """Renderer, version and platform of the current GL context."""
    from OpenGL import GL

    return {"renderer": GL.glGetString(GL.GL_RENDERER).decode(),
            "version": GL.glGetString(GL.GL_VERSION).decode(),
            "platform": os.environ.get("PYOPENGL_PLATFORM", "window")}
