"""Interactive path: pyrender with custom GLSL whose tables are baked from the JAX models.

- :mod:`~jkatana.interactive.bake`: the shader tables (low-rank Fresnel basis,
  environment projected on it and prefiltered per μ, lobe LUT, display
  transform), computed from :mod:`jkatana.models` and :mod:`jkatana.spectral`;
  one module per table: :mod:`~jkatana.interactive.levels` (prefiltered levels),
  :mod:`~jkatana.interactive.lobe_tables` (lobe energy and moments),
  :mod:`~jkatana.interactive.taps` (the fitted tap pattern),
  :mod:`~jkatana.interactive.caps` (suns split off as caps),
  :mod:`~jkatana.interactive.tables` (cached and shipped tables).
- :mod:`~jkatana.interactive.gl`: OpenGL platform choice (EGL, OSMesa,
  window), the pyrender/PyOpenGL versions, the numpy-2 alias.
- :mod:`~jkatana.interactive.glstate`: the baked tables as float GL textures and the
  per-frame settings (:class:`~jkatana.interactive.glstate.ShadingState`).
- :mod:`~jkatana.interactive.glprograms`: the shaders' sources and the pyrender
  program-cache subclass that serves them.
- :mod:`~jkatana.interactive.glrender`: the render passes (deferred G-buffer and
  shading, forward), the single-sample offscreen renderer (imports pyrender).
- :mod:`~jkatana.interactive.scene`: blade, reflectance map, built-in
  environments and cameras.
- :mod:`~jkatana.interactive.viewer`: the windowed Viewer (``jkatana view``).

Nothing here imports pyrender at package import time: the GL platform must be
chosen first (see :mod:`jkatana.interactive.gl`). The package's own names are
re-exported lazily (PEP 562 module ``__getattr__``): importing a submodule, as
the ``jkatana view`` command does, imports that submodule and what it needs,
not the bake and its JAX models; ``from jkatana.interactive import Baked``
imports :mod:`~jkatana.interactive.bake` on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from jkatana.interactive.bake import Baked as Baked, cached_bake as cached_bake
    from jkatana.interactive.gl import GLUnavailable as GLUnavailable

#: re-exported name → the submodule that defines it
_EXPORTS = {
    "Baked": "jkatana.interactive.bake",
    "cached_bake": "jkatana.interactive.bake",
    "GLUnavailable": "jkatana.interactive.gl",
}

__all__ = ["Baked", "GLUnavailable", "cached_bake"]


def __getattr__(name: str):
    """A re-exported name, its submodule imported on first use (then kept in the package's namespace)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
