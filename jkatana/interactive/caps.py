"""Compact bright sources (suns) split off the map for the shaders, and the shader's cap response.

A sun holds most of an outdoor map's power in a few texels, which no
prefiltered level of a 128-row map resolves.
:func:`jkatana.light.sun.split_compact_sources` splits such sources off as
spherical caps (direction C, angular radius r, spectral radiance L_cap); the
*remainder* is what is projected and prefiltered, and each cap (at most
:data:`MAX_CAPS`) becomes shader uniforms: C, r and
Q_{r,c} = Ω_cap Σ_λ b_r(λ) W_c(λ) L_cap(λ) (:func:`sun_caps`). The shader
adds, over a tap pattern j (direction R_j, weight w_j, level width μ_j),

    XYZ_c += Σ_r A_r Q_{r,c} Σ_j w_j k̂(∠(R_j, C); μ_j, r),

the lobe integrated against the cap instead of the map. The pattern is the
moment-matched one (:func:`jkatana.interactive.lobe_tables.moment_taps`) even
where the map is read with the fitted taps: those match the lobe in L1 over
the sphere, not point by point, and a cap samples the kernel at about one
point. k̂ is the level's prefilter kernel (:func:`jkatana.interactive.taps.prefilter_kernel`,
the paper's Gaussian lobe in reflected directions, D(h, μ)/cos h with h half the
angle from the tap, normalised) convolved with the cap's uniform disc as a Gaussian of
the same mass whose value at the cap's centre is the exact one: the kernel is
a Gaussian of variance σ² = 2/c per axis in the angle, c = ln2/μ², a disc of
radius r about its centre holds 1 − e^{−r²/2σ²} = 1 − e^{−x} of it,
x = c r²/4, so c → c' = 4 (1 − e^{−x})/r² (→ c (1 − x/2), the moment-matched
1/c + r²/8, for a small cap; a peak of 1, a mirror's, for a large one)
(:func:`cap_kernel`). Without a compact source nothing is split and the
shader has no cap code (``JK_CAPS`` 0).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from jkatana.interactive.taps import prefilter_kernel
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
    q = np.stack([float(c.solid_angle) * np.einsum("l,rl,lc->rc", np.asarray(c.radiance, np.float64), b, weights)
                  for c in caps])
    return np.asarray(split.remainder.radiance, np.float64), direction, radius, q


def cap_kernel(tap_dir: ArrayLike, mu: ArrayLike, cap_dir: ArrayLike, radius: ArrayLike) -> np.ndarray:
    """The shader's cap response (``shade.glsl``'s ``jk_cap_kernel``): the normalised prefilter kernel of
    width ``mu`` (:func:`jkatana.interactive.taps.prefilter_kernel`) about the tap direction, integrated
    over a cap of angular ``radius`` about ``cap_dir`` and divided by the cap's solid angle, as the kernel at
    a changed width (module docstring): the kernel is D(h, μ) / cos h ∝ exp(−c h²) / cos h with h half the
    angle between the two directions and c = ln2/μ²; convolved with the disc it is taken at c' = 4 (1 −
    e^{−x})/r², x = c r²/4 (c (1 − x/2) below x = 1e-3), i.e. at the width μ' = √(ln2/c'). The shader
    evaluates the same in closed form, normalised by (4π/c')(1 − 1/(6c') + 1/(60c'²)) (no horizon: the
    two differ by the kernel's mass below the horizon, which only the widest level has). Broadcasts."""
    tap_dir, cap_dir = np.asarray(tap_dir, np.float64), np.asarray(cap_dir, np.float64)
    c0 = np.log(2.0) / np.asarray(mu, np.float64) ** 2
    r2 = np.asarray(radius, np.float64) ** 2
    x = 0.25 * c0 * r2
    c = np.where(x < 1e-3, c0 * (1.0 - 0.5 * x), 4.0 * -np.expm1(-x) / np.maximum(r2, 1e-30))
    sin_h = np.minimum(0.5 * np.linalg.norm(tap_dir - cap_dir, axis=-1), 1.0)
    mu_c, sin2_h = np.broadcast_arrays(np.sqrt(np.log(2.0) / c), sin_h * sin_h)
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    return np.asarray(prefilter_kernel(jnp.asarray(sin2_h, dt), jnp.asarray(mu_c, dt)), np.float64)
