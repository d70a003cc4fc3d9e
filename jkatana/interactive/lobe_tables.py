"""The lobe tables of the bake: each lobe's energy on the Fresnel basis and its shape moments, per (μ, θv).

A_r(cos θv, μ) = Σ_λ b_r(λ) ∫ f_r cos θi dω_i for the hiraji and hamon
models exactly as :meth:`jkatana.models.Hiraji.brdf_cos` and
:meth:`jkatana.models.Hamon.brdf_cos` define them (normalised convention), by
quadrature in half-vector space (dω_i = 4 (V·H) dω_h, Walter et al. 2007,
eq. 14). It carries the Fresnel variation over the lobe, the V-cavity G of
eq. (2) and the lobe's energy: the second factor of the split sum (Karis 2013,
"Real Shading in Unreal Engine 4"), with the spectral dimension factored by the
Fresnel basis. The same quadrature gives the reflected lobe's first and second
angular moments about the mirror direction, from which :func:`moment_taps`
builds the moment-matched three-tap pattern.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.interactive.levels import MU_LEVELS
from jkatana.models import Conductor, Hamon, Hiraji


def halfvector_quadrature(mu, n_phi: int = 32, n_psi: int = 48, extent: float = 4.5):
    """Quadrature of the half-vector hemisphere around N = +z for a lobe of width μ.

    Gauss–Legendre in the facet angle φ ∈ [0, min(extent·μ, π/2)] (D < 1e-6
    beyond 4.5 μ), uniform in azimuth; ``mu`` may be a traced JAX scalar.
    **Returns** ``(H (Q, 3), dω_h (Q,))``.
    """
    x, wx = np.polynomial.legendre.leggauss(n_phi)
    top = jnp.minimum(extent * mu, jnp.pi / 2)
    phi = (jnp.asarray(x) + 1) / 2 * top
    wphi = jnp.asarray(wx) / 2 * top
    psi = (np.arange(n_psi) + 0.5) / n_psi * 2 * np.pi
    P, S = jnp.meshgrid(phi, jnp.asarray(psi), indexing="ij")
    Hh = jnp.stack([jnp.sin(P) * jnp.cos(S), jnp.sin(P) * jnp.sin(S), jnp.cos(P)], -1).reshape(-1, 3)
    w = (wphi[:, None] * jnp.sin(P) * (2 * np.pi / n_psi)).reshape(-1)
    return Hh, w


def lobe_integral(model, conductor: Conductor, V_local, n_phi=32, n_psi=48, moments: bool = False):
    """∫ f_r cos θi dω_i (spectral) of ``model`` (Hiraji or Hamon) for local view directions ``V (..., 3)``.

    Quadrature in half-vector space (:func:`halfvector_quadrature` scaled to
    ``model.mu``), dω_i = 4 (V·H) dω_h (Walter et al. 2007, eq. 14). With
    ``moments=True`` also returns the lobe's mean squared angle from the mirror
    direction (weights summed over λ).
    """
    dt = conductor.n.dtype
    Hh, wh = halfvector_quadrature(jnp.asarray(model.mu, dt), n_phi, n_psi)
    V = jnp.asarray(V_local, dt)[..., None, :]
    Hj = Hh.astype(dt)
    vh = jnp.sum(V * Hj, -1, keepdims=True)
    L = 2 * vh * Hj - V
    f = model.brdf_cos(L, V, conductor)                                             # (..., Q, wl)
    dw = 4.0 * jnp.maximum(vh, 0.0) * wh.astype(dt)[:, None]
    total = jnp.sum(f * dw, axis=-2)
    if not moments:
        return total
    # angles of L from the mirror direction R, along the plane of incidence (t, towards N) and across it (y)
    R = V * jnp.asarray([-1.0, -1.0, 1.0], dt)
    nt = jnp.asarray([0.0, 0.0, 1.0], dt) - R[..., 2:3] * R
    t = nt / jnp.maximum(jnp.linalg.norm(nt, axis=-1, keepdims=True), 1e-12)
    t = jnp.where(jnp.linalg.norm(nt, axis=-1, keepdims=True) > 1e-9, t, jnp.asarray([1.0, 0.0, 0.0], dt))
    y = jnp.cross(R, t)
    lr = jnp.sum(L * R, -1)
    a_par = jnp.arctan2(jnp.sum(L * t, -1), lr)
    a_perp = jnp.arctan2(jnp.sum(L * y, -1), lr)
    wsum = jnp.sum(f * dw, axis=-1)
    norm = jnp.maximum(jnp.sum(wsum, -1), 1e-30)
    mean = jnp.sum(wsum * a_par, -1) / norm
    var_par = jnp.sum(wsum * (a_par - mean[..., None]) ** 2, -1) / norm
    var_perp = jnp.sum(wsum * a_perp ** 2, -1) / norm
    return total, (mean, var_par, var_perp)


@jax.jit
def _lut_column(mu, conductor, V, b):
    out, shape = [], []
    for cls in (Hiraji, Hamon):
        model = cls(jnp.ones((), mu.dtype), mu)
        total, (mean, var_par, var_perp) = lobe_integral(model, conductor, V, moments=True)
        out.append(total @ b.T)
        iso = 0.5 * (var_par[-1] + var_perp[-1])                  # V[-1] is normal incidence: isotropic
        shape.append(jnp.stack([0.5 * jnp.log(var_perp / iso),       # across-plane width → prefilter level
                                jnp.sqrt(jnp.maximum(var_par - var_perp, 0.0)),   # ± tap offset (rad)
                                mean], -1))                          # lobe centre offset towards N (rad)
    return jnp.stack(out), jnp.stack(shape)


def lobe_lut(conductor: Conductor, b: np.ndarray, mus=MU_LEVELS, n_cos: int = 64):
    """A_r(cos θv, μ) for hiraji and hamon: ``(2, n_mu, n_cos, rank)``, cos grid uniform on [0, 1].

    Also returns ``shape (2, n_mu, n_cos, 3)``, the reflected lobe's moments
    from the same quadrature, in angles from the mirror direction R: (0) half
    the log of its variance across the plane of incidence relative to normal
    incidence, (1) the extra spread along the plane, √(var_par − var_perp),
    (2) the mean offset along the plane towards N. Off normal incidence the
    lobe narrows across the plane (by ≈ cos θ) but not along it; the shader
    reads the environment prefiltered for the across-plane width at three
    taps, R rotated in the plane by mean and mean ± √2·spread with weights
    ¼, ½, ¼ — a kernel with the lobe's first and second moments that keeps
    the peak of a small bright source (a sun) within ~10 %.
    """
    cos = np.linspace(0.0, 1.0, n_cos)
    cos_c = np.maximum(cos, 1e-3)
    V = np.stack([np.sqrt(1 - cos_c ** 2), np.zeros_like(cos_c), cos_c], -1)
    dt = conductor.n.dtype
    cols = [_lut_column(jnp.asarray(mu, dt), conductor, jnp.asarray(V, dt), jnp.asarray(b, dt)) for mu in mus]
    out = np.stack([np.asarray(c[0], np.float64) for c in cols], axis=1)
    shape = np.stack([np.asarray(c[1], np.float64) for c in cols], axis=1)
    return cos, out, shape


#: The functions whose source text keys the lobe table (:func:`jkatana.interactive.tables.cached_material_tables`).
LUT_SOURCES = (lobe_lut, _lut_column, lobe_integral, halfvector_quadrature)


def moment_taps(spread: np.ndarray) -> np.ndarray:
    """The moment-matched binomial pattern of :func:`lobe_lut` (weights ¼, ½, ¼ at mean, mean ± √2·spread,
    filter width from the across-plane variance) in :func:`jkatana.interactive.taps.tap_fit`'s layout ``(..., 1 + 2T)``."""
    off = np.sqrt(2.0) * spread[..., 1:2] * np.array([-1.0, 0.0, 1.0])
    w = np.broadcast_to(np.array([0.25, 0.5, 0.25]), off.shape)
    return np.concatenate([spread[..., :1], spread[..., 2:3] + off, w], -1)
