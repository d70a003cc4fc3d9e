"""Fresnel reflectance of a conductor (complex index η = n + i k) against air.

Exact unpolarised reflectance F = (Rs + Rp)/2 (Born & Wolf, *Principles of
Optics*, 7th ed. 1999, §14.2), in the real-arithmetic form with
a² + b² = √((n² − k² − sin²θ)² + 4n²k²), a² − b² = n² − k² − sin²θ
(e.g. Heckbert 1991; pbrt-v3 ``FrConductor``), rewritten without
cancellation:

    Rs = ((a − cosθ)² + b²) / ((a + cosθ)² + b²)
    Rp = Rs · ((a cosθ − sin²θ)² + (b cosθ)²) / ((a cosθ + sin²θ)² + (b cosθ)²)

a² and b² are taken from the larger of (A ± t0)/2 and the other from
a·b = n·k, so neither loses digits when k → 0 or when n < 1. The formula
reduces to the dielectric Fresnel equations at k = 0 (including total
reflection for n < 1), gives 1 at θ = 90°, and
((n − 1)² + k²)/((n + 1)² + k²) at normal incidence.

Schlick's approximation (Schlick 1994, "An inexpensive BRDF model for
physically-based rendering", CGF 13(3)) is provided for comparison only.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jkatana.models._safe import safe_div, safe_sqrt


def fresnel_conductor(cos_theta: Float[ArrayLike, "*#b"], n: Float[ArrayLike, "*#b"], k: Float[ArrayLike, "*#b"]
                      ) -> Float[Array, "*#b"]:
    """Exact unpolarised Fresnel reflectance of air → conductor (n + i k).

    **Arguments:** `cos_theta` (cosine of the angle of incidence, clipped to
    [0, 1]), `n`, `k`; all broadcast together — pass ``cos[..., None]`` with
    ``n, k`` of shape ``(wl,)`` to get ``(..., wl)``.

    **Returns:** F ∈ [0, 1], finite with finite gradients everywhere
    including θ = 90°, k = 0 (total reflection when n < 1) and n = 1; n, k
    above max^(1/4)/4 of the dtype (float32: 1.1e9) are clamped there
    (:func:`_clamp_index`: F is 1 to the dtype's resolution).
    """
    c = jnp.clip(cos_theta, 0.0, 1.0)
    n, k = _clamp_index(n), _clamp_index(k)
    c2 = c * c
    s2 = 1.0 - c2
    n2, k2 = n * n, k * k
    t0 = n2 - k2 - s2
    nk = n * k
    A = safe_sqrt(t0 * t0 + 4.0 * nk * nk)  # a² + b²
    pos = t0 >= 0
    big = 0.5 * (A + jnp.abs(t0))  # a² if t0 ≥ 0 else b²: no cancellation
    small = safe_div(nk * nk, big)  # the other one, from a b = n k
    a2 = jnp.where(pos, big, small)
    b2 = jnp.where(pos, small, big)
    a = safe_sqrt(a2)
    rs = safe_div((a - c) ** 2 + b2, (a + c) ** 2 + b2, fallback=1.0)
    ac = a * c
    bc2 = b2 * c2
    ratio = safe_div((ac - s2) ** 2 + bc2, (ac + s2) ** 2 + bc2, fallback=1.0)
    return 0.5 * rs * (1.0 + ratio)


def _clamp_index(x):
    """n or k limited to max^(1/4)/4 of the dtype (float32: 1.1e9), so that (n k)² stays finite.

    Beyond it F differs from 1 by less than 4/n (float32: 4e-9, below its
    resolution), so the clamp changes no representable value.
    """
    x = jnp.asarray(x)
    dtype = x.dtype if jnp.issubdtype(x.dtype, jnp.floating) else jnp.result_type(float)
    return jnp.minimum(x, float(jnp.finfo(dtype).max) ** 0.25 / 4.0)


def fresnel_dielectric(cos_theta, eta):
    """Unpolarised Fresnel reflectance air → dielectric of real index ``eta`` (k = 0 case)."""
    return fresnel_conductor(cos_theta, eta, jnp.zeros_like(eta))


def normal_incidence(n, k):
    """F(0°) = ((n − 1)² + k²)/((n + 1)² + k²)."""
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


def fresnel_schlick(cos_theta, f0):
    """Schlick (1994): F ≈ F0 + (1 − F0)(1 − cosθ)⁵ — an approximation, for comparison."""
    c = jnp.clip(cos_theta, 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


@jax.jit
def _fresnel_table(cos_theta, n, k):
    return fresnel_conductor(cos_theta[..., None], n, k)


def fbar_numpy(cos_theta, n, k, w):
    """F̄(θ) = F(n, k, θ) @ w: :func:`fresnel_conductor` at each cosine (float64, whatever the JAX precision
    setting) integrated against band weights ``w (wl,)`` (SPEC §4), one compiled program per shape of
    ``cos_theta`` (a table's every lookup goes through one call of :func:`fbar_many`)."""
    with jax.enable_x64(True):
        f = _fresnel_table(*(jnp.asarray(a, jnp.float64) for a in (cos_theta, n, k)))
    return np.asarray(f, np.float64) @ np.asarray(w, np.float64)


def fbar_many(cosines, n, k, w) -> list[np.ndarray]:
    """:func:`fbar_numpy` at each array of ``cosines``, evaluated as one array (one compilation per total size)."""
    flat = [np.ravel(np.asarray(c, np.float64)) for c in cosines]
    out = fbar_numpy(np.concatenate(flat), n, k, w)
    return [part.reshape(np.shape(c)) for part, c in
            zip(np.split(out, np.cumsum([f.size for f in flat])[:-1]), cosines)]
