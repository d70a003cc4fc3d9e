"""Compact bright sources (suns) split off the map for the shaders.

A sun holds most of an outdoor map's power in a few texels, which no
prefiltered level of a 128-row map resolves.
:func:`jkatana.light.sun.split_compact_sources` splits such sources off as
spherical caps (direction C, angular radius r, spectral radiance L_cap); the
*remainder* is what is projected and prefiltered, and each cap (at most
:data:`MAX_CAPS`) becomes shader uniforms: C, r and
Q_{r,c} = Ω_cap Σ_λ b_r(λ) W_c(λ) L_cap(λ) (:func:`sun_caps`). The shader
integrates the lobe against each cap by its closed-form rule
(``jk_caps_xyz``; a NumPy transcription for the tests is the checkout's
``validation/shader_cap_rule.py``). Without a compact source nothing is split
and the shader has no cap code (``JK_CAPS`` 0).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jkatana.light.fresnel_basis import project_on_basis
from jkatana.spectral import WavelengthGrid

#: Most compact sources (sun caps) the shaders take as uniforms (:func:`jkatana.light.sun.find_compact_sources`'s
#: default ``max_sources``).
MAX_CAPS = 4


def sun_caps(radiance: np.ndarray, grid: WavelengthGrid, b: np.ndarray, weights: np.ndarray):
    """Split the compact bright sources off ``radiance (H, W, wl)`` for the shaders.

    :func:`jkatana.light.sun.split_compact_sources` (its default criterion, at most :data:`MAX_CAPS`
    sources) finds them; each cap's spectral radiance is projected as the map is, on the Fresnel basis
    ``b (rank, wl)`` and the CIE weights ``weights (wl, 3)`` of eq. (6), times the cap's solid angle:
    ``Q_{r,c} = Ω_cap Σ_λ b_r(λ) W_c(λ) L_cap(λ)``.

    **Returns** ``(remainder (H, W, wl) float64, cap_dir (n, 3), cap_radius (n,), cap_q (n, rank, 3))``;
    ``n = 0`` and the map itself when nothing is compact.
    """
    from jkatana.light.envmap import EnvMap
    from jkatana.light.sun import split_compact_sources

    rank = b.shape[0]
    split = split_compact_sources(EnvMap(jnp.asarray(radiance, jnp.float32), grid), max_sources=MAX_CAPS)
    if not split.caps:
        return radiance, np.zeros((0, 3)), np.zeros((0,)), np.zeros((0, rank, 3))
    caps = split.caps
    direction = np.stack([np.asarray(c.direction, np.float64) for c in caps])
    radius = np.array([float(c.radius) for c in caps])
    q = np.stack([float(c.solid_angle) * project_on_basis(np.asarray(c.radiance, np.float64), b, weights, xp=np)
                  for c in caps])
    return np.asarray(split.remainder.radiance, np.float64), direction, radius, q
