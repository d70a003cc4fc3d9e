"""The lobe tables of the bake: each lobe's energy on the Fresnel basis and its shape moments, per (μ, θv).

A_r(cos θv, μ) = Σ_λ b_r(λ) ∫ f_r cos θi dω_i for the hiraji and hamon
regions' lobes exactly as their :meth:`~jkatana.models.lobes.Lobe.brdf_cos`
defines them — the paper's (eqs. 1–2) or those of parameter files
(:func:`region_lobes`), normalised convention — by
quadrature in half-vector space (dω_i = 4 (V·H) dω_h, Walter et al. 2007,
eq. 14). It carries the Fresnel variation over the lobe, the V-cavity G of
eq. (2) and the lobe's energy: the second factor of the split sum (Karis 2013,
"Real Shading in Unreal Engine 4"), with the spectral dimension factored by the
Fresnel basis. The same quadrature gives the reflected lobe's first and second
angular moments about the mirror direction, from which :func:`moment_taps`
builds the moment-matched three-tap pattern.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np


from jkatana.interactive.levels import MU_LEVELS
from jkatana.models import Conductor
from jkatana.models.lobe_id import LobeId
from jkatana.models.lobes import Gaussian, GaussianVCavity


#: The paper's lobes (hiraji: Gaussian, eq. 1; hamon: Gaussian V-cavity, eq. 2), normalised, as families
#: width ↦ lobe: the regions' lobes of every table unless a parameter file names another.
PAPER_LOBES = (Gaussian, GaussianVCavity)


def region_lobes(keys: dict | None = None) -> tuple:
    """The lobe families ``(hiraji, hamon)`` of the tables for the regions' lobes as
    :func:`jkatana.render.renderer.load_material` returns them (``{region: None or lobe key}``; None: the
    paper's lobe of that region)."""
    keys = keys or {}
    return tuple(paper if keys.get(region) is None else
                 keys[region].normalised()
                 for region, paper in zip(("hiraji", "hamon"), PAPER_LOBES))


#: The families whose three taps are fitted (:func:`jkatana.interactive.taps.tap_fit`) and shipped for iron beside
#: the paper's: one lobe shape each (a single microfacet lobe's shape is its distribution alone).
FITTED_FAMILIES = (LobeId.of({"lobe": "ggx", "alpha": 1.0}),
                   LobeId.of({"lobe": "beckmann", "alpha": 1.0}))


def gtr_core_factor(gamma: float) -> float:
    """The GGX width whose distribution has the half maximum of GTR's at width 1 and exponent γ.

    GTR's D ∝ (α² cos²φ + sin²φ)^−γ = cos^−2γ φ (α² + tan²φ)^−γ (Burley 2012, "Physically-based shading at
    Disney", eq. 4, appendix B) falls to half its peak at tan²φ = α² (2^{1/γ} − 1), GGX's (γ = 2; Walter et al.
    2007, eq. 33) at α² (√2 − 1): the factor √((2^{1/γ} − 1)/(√2 − 1)), 1 at γ = 2."""
    return math.sqrt((2.0 ** (1.0 / gamma) - 1.0) / (math.sqrt(2.0) - 1.0))


def family_core(family) -> tuple:
    """``(base, c)``: the family whose fitted taps hold the core of ``family``'s lobe, ``base(c μ)`` standing for
    ``family(μ)`` near the mirror direction: the paper's lobes and :data:`FITTED_FAMILIES` themselves (c = 1, or
    a width ratio inside a mixture); GTR the GGX of equal half maximum (:func:`gtr_core_factor`); a
    :class:`~jkatana.models.lobes.Mixture` its narrower part's core (the wider part's light is the tail taps',
    :func:`jkatana.interactive.taps.tail_fit`). Other families: ``(family, 1.0)``, fitted themselves."""
    if family in PAPER_LOBES:
        return family, 1.0
    name, p = family.family, dict(family.fields)
    if name in ("ggx", "beckmann"):
        return LobeId.of({"lobe": name, "alpha": 1.0}), float(p["alpha"])
    if name in ("gaussian", "gaussian-vcavity") and p.get("normalised", True):
        return PAPER_LOBES[name == "gaussian-vcavity"], float(p["mu"])
    if name == "gtr":
        return FITTED_FAMILIES[0], float(p["alpha"]) * gtr_core_factor(float(p["gamma"]))
    if name == "mixture":
        return min((family_core(p[part]) for part in ("first", "second")), key=lambda bc: bc[1])
    return family, 1.0


def family_names(lobes) -> tuple[str, ...]:
    """Stable names of lobe families (a cache key's part): a lobe class's ``name``, a
    :class:`~jkatana.models.lobe_id.LobeId`'s name."""
    return tuple(str(f.name) for f in lobes)


def halfvector_quadrature(mu, n_phi: int = 32, n_psi: int = 48, extent: float = 4.5, tails: bool = False):
    """Quadrature of the half-vector hemisphere around N = +z for a lobe of width μ.

    Gauss–Legendre in the facet angle φ ∈ [0, min(extent·μ, π/2)] (the paper's
    Gaussian: D < 1e-6 beyond 4.5 μ), uniform in azimuth; ``mu`` may be a traced
    JAX scalar. ``tails=True`` (every other lobe: GGX and GTR have algebraic
    tails): Gauss–Legendre in t ∈ [0, 1] with tan φ = μ tan(πt/2), the whole
    hemisphere, the nodes dense in the core and reaching into the tails.
    **Returns** ``(H (Q, 3), dω_h (Q,))``.
    """
    x, wx = np.polynomial.legendre.leggauss(n_phi)
    if tails:
        t = (jnp.asarray(x) + 1) / 2 * (jnp.pi / 2)
        tan_t = jnp.tan(t)
        phi = jnp.arctan(mu * tan_t)
        wphi = jnp.asarray(wx) / 2 * (jnp.pi / 2) * mu * (1 + tan_t ** 2) / (1 + (mu * tan_t) ** 2)
    else:
        top = jnp.minimum(extent * mu, jnp.pi / 2)
        phi = (jnp.asarray(x) + 1) / 2 * top
        wphi = jnp.asarray(wx) / 2 * top
    psi = (np.arange(n_psi) + 0.5) / n_psi * 2 * np.pi
    P, S = jnp.meshgrid(phi, jnp.asarray(psi), indexing="ij")
    Hh = jnp.stack([jnp.sin(P) * jnp.cos(S), jnp.sin(P) * jnp.sin(S), jnp.cos(P)], -1).reshape(-1, 3)
    w = (wphi[:, None] * jnp.sin(P) * (2 * np.pi / n_psi)).reshape(-1)
    return Hh, w


def lobe_integral(model, conductor: Conductor, V_local, n_phi=32, n_psi=48, moments: bool = False, *,
                  width=None, tails: bool = False):
    """∫ f_r cos θi dω_i (spectral) of ``model`` (a lobe of :mod:`jkatana.models.lobes`, or Hiraji, Hamon) for
    local view directions ``V (..., 3)``.

    Quadrature in half-vector space (:func:`halfvector_quadrature` scaled to
    ``width``, default ``model.mu``; ``tails`` as there), dω_i = 4 (V·H) dω_h
    (Walter et al. 2007, eq. 14). With ``moments=True`` also returns the lobe's
    mean squared angle from the mirror direction (weights summed over λ).
    """
    dt = conductor.n.dtype
    Hh, wh = halfvector_quadrature(jnp.asarray(model.mu if width is None else width, dt), n_phi, n_psi,
                                   tails=tails)
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


@functools.partial(jax.jit, static_argnames=("lobes",))
def _lut_column(mu, conductor, V, b, lobes):
    out, shape = [], []
    for family in lobes:
        paper = family in PAPER_LOBES
        total, (mean, var_par, var_perp) = lobe_integral(family(mu), conductor, V, moments=True, width=mu,
                                                         tails=not paper)
        out.append(total @ b.T)
        # variance at normal incidence (V[-1]: isotropic) of the paper's lobe of width μ (the level's kernel)
        if paper:
            iso = 0.5 * (var_par[-1] + var_perp[-1])
        else:
            _, (_, g_par, g_perp) = lobe_integral(Gaussian(mu), conductor, V[-1:], moments=True)
            iso = 0.5 * (g_par[-1] + g_perp[-1])
        shape.append(jnp.stack([0.5 * jnp.log(var_perp / iso),       # across-plane width → prefilter level
                                jnp.sqrt(jnp.maximum(var_par - var_perp, 0.0)),   # ± tap offset (rad)
                                mean], -1))                          # lobe centre offset towards N (rad)
    return jnp.stack(out), jnp.stack(shape)


def lobe_lut(conductor: Conductor, b: np.ndarray, mus=MU_LEVELS, n_cos: int = 64, lobes: tuple = PAPER_LOBES):
    """A_r(cos θv, μ) for hiraji and hamon: ``(2, n_mu, n_cos, rank)``, cos grid uniform on [0, 1]; the
    regions' lobes are ``lobes`` (families width ↦ lobe, :func:`region_lobes`), μ their width.

    Also returns ``shape (2, n_mu, n_cos, 3)``, the reflected lobe's moments
    from the same quadrature, in angles from the mirror direction R: (0) half
    the log of its variance across the plane of incidence relative to that of
    the paper's Gaussian lobe of width μ at normal incidence (the level the
    environment is prefiltered with; for the paper's lobes, themselves),
    (1) the extra spread along the plane, √(var_par − var_perp), (2) the mean
    offset along the plane towards N. Off normal incidence the lobe narrows
    across the plane (by ≈ cos θ) but not along it; the shader reads the
    environment prefiltered for the across-plane width at three taps, R rotated in the plane by mean and mean ± √2·spread with weights
    ¼, ½, ¼ — a kernel with the lobe's first and second moments that keeps
    the peak of a small bright source (a sun) within ~10 %.
    """
    cos = np.linspace(0.0, 1.0, n_cos)
    cos_c = np.maximum(cos, 1e-3)
    V = np.stack([np.sqrt(1 - cos_c ** 2), np.zeros_like(cos_c), cos_c], -1)
    dt = conductor.n.dtype
    cols = [_lut_column(jnp.asarray(mu, dt), conductor, jnp.asarray(V, dt), jnp.asarray(b, dt), tuple(lobes))
            for mu in mus]
    out = np.stack([np.asarray(c[0], np.float64) for c in cols], axis=1)
    shape = np.stack([np.asarray(c[1], np.float64) for c in cols], axis=1)
    return cos, out, shape


#: The functions whose source text keys the lobe table
#: (:func:`jkatana.interactive.tables.cached_material_tables`).
LUT_SOURCES = (lobe_lut, _lut_column, lobe_integral, halfvector_quadrature)


def moment_taps(spread: np.ndarray) -> np.ndarray:
    """The moment-matched binomial pattern of :func:`lobe_lut` (weights ¼, ½, ¼ at mean, mean ± √2·spread,
    filter width from the across-plane variance) in :func:`jkatana.interactive.taps.tap_fit`'s layout
    ``(..., 1 + 2T)``."""
    off = np.sqrt(2.0) * spread[..., 1:2] * np.array([-1.0, 0.0, 1.0])
    w = np.broadcast_to(np.array([0.25, 0.5, 0.25]), off.shape)
    return np.concatenate([spread[..., :1], spread[..., 2:3] + off, w], -1)
