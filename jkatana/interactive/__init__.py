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
- :mod:`~jkatana.interactive.glrender`: the pyrender program-cache subclass,
  float textures, single-sample offscreen renderer (imports pyrender).
- :mod:`~jkatana.interactive.scene`: blade, reflectance map, built-in
  environments and cameras.
- :mod:`~jkatana.interactive.viewer`: the windowed Viewer (``jkatana view``).

Nothing here imports pyrender at package import time: the GL platform must be
chosen first (see :mod:`jkatana.interactive.gl`).
"""

from jkatana.interactive.bake import Baked as Baked, cached_bake as cached_bake
from jkatana.interactive.gl import GLUnavailable as GLUnavailable
