"""Validation of jkatana against independent references; not part of the shipped library.

- :mod:`validation.mitsuba`: the reference renderer against Mitsuba 3 (Jakob et al. 2022).
- :mod:`validation.gl_agreement`: the interactive GL frame against the reference renderer.
- :mod:`validation.shader_cap_rule`: the interactive shader's cap rule transcribed to NumPy, checked against the
  library's cap quadrature (the shader itself runs in GLSL).

The tests, the benchmarks and the experiments import these from a source checkout;
``jkatana`` itself never does (nor does it import :mod:`benchmarks`).
"""
