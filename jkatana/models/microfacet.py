"""Facet distributions and shadowing/masking terms.

- :func:`gaussian_facet` — the paper's distribution (Mochizuki et al., eqs.
  1–2): D(φ, μ) = exp(−ln 2 · φ²/μ²), μ the half-width at half-maximum of the
  facet angle φ (radians), peak 1 (the scale lives in χ or β).
- :func:`gaussian_normalisation` — 1/∫ D cosφ dω over the hemisphere, so that
  N(μ)·D is a normalised normal distribution (used by the rendering form).
- :func:`beckmann` — Beckmann & Spizzichino (1963), in the normalised form of
  Walter et al. (2007), "Microfacet models for refraction through rough
  surfaces", EGSR: D = exp(−tan²φ/α²)/(π α² cos⁴φ); :func:`beckmann_phi` is
  the same from φ (accurate for narrow lobes in float32).
- :func:`vcavity` — Torrance & Sparrow (1967) / Cook & Torrance (1982) V-cavity
  G = min(1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·L)/(V·H)).
- :func:`smith_beckmann` — separable Smith G with Walter et al.'s (2007)
  rational approximation of the Beckmann G1.
- :func:`beckmann_visible_area`, :func:`ggx_visible_area` — the projected
  area cos θ (1 + Λ(θ)) of a unit patch of microsurface seen from θ, with
  Smith's exact Λ (Heitz 2014, "Understanding the masking-shadowing function
  in microfacet-based BRDFs", JCGT 3(2), §5.1 and §5.2): the normalisation of
  the distribution of visible normals (Heitz & d'Eon 2014).

Guards: μ → 0 (the exponent is cut where exp underflows, so neither the
value nor the derivative sees inf), cos φ → 0 (Beckmann's tan²), V·H → 0 and
N·V → 0 (divisors floored at eps² of the dtype inside a double where).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import jax.scipy.special
import numpy as np

from jkatana.models._safe import ratio, safe_sqrt

LN2 = math.log(2.0)
# Gauss–Legendre nodes on [0, 1] for the normalisation integral (smooth integrand).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


def _exp_cutoff(dtype) -> float:
    """Largest x with exp(−x) still a normal number of ``dtype`` (float32: ~87, float64: ~708)."""
    return float(-np.log(np.finfo(dtype).tiny)) * 0.99


def gaussian_facet(phi, mu):
    """Paper's facet distribution D(φ, μ) = exp(−ln2 φ²/μ²) (peak 1 at φ = 0).

    Finite value and gradient for μ down to the dtype's tiny and φ of any size:
    where the exponent would exceed the underflow point, D is exactly 0 and the
    computation is done on substituted values; φ/μ is differentiated without
    forming μ² (:func:`~jkatana.models._safe.ratio`), which underflows for
    μ < 1e-19 in float32.
    """
    phi = jnp.asarray(phi)
    mu = jnp.asarray(mu)
    dtype = jnp.result_type(phi, mu)
    x_max = _exp_cutoff(dtype)
    ratio_max = math.sqrt(x_max / LN2)
    live = jnp.abs(phi) < ratio_max * jnp.abs(mu)  # no division: safe at μ = 0
    phi_s = jnp.where(live, phi, 0.0)
    mu_s = jnp.where(live, mu, 1.0)
    return jnp.where(live, jnp.exp(-LN2 * ratio(phi_s, mu_s) ** 2), 0.0)


def gaussian_normalisation(mu):
    """N(μ) = 1 / (2π ∫₀^{π/2} D(φ, μ) cosφ sinφ dφ) for the paper's D.

    N(μ)·D(φ, μ) integrates to 1 against cos φ dω_h, the normalisation of a
    microfacet normal distribution (Walter et al. 2007, eq. 4). Computed by
    48-point Gauss–Legendre quadrature over [0, min(π/2, c μ)], where c is the
    point beyond which D underflows — exact to quadrature error (< 1e-12 for
    μ ≤ 0.5) and differentiable. For small μ, N → ln2 / (π μ²). Widths below
    tiny^(1/4) of the dtype (float32: 3.3e-10 rad) are computed at that width,
    so N and its derivative stay finite.

    A Python scalar μ gives a Python float (weakly typed: it does not promote
    float32 arrays it multiplies); an array μ gives an array of its dtype.
    """
    if isinstance(mu, (int, float)) and not isinstance(mu, np.generic):
        return float(_normalisation(np, np.asarray(mu, np.float64), np.float64))
    mu = jnp.asarray(mu)  # np.float64 stays float64 under x64 (float32 without x64)
    dtype = mu.dtype if jnp.issubdtype(mu.dtype, jnp.floating) else jnp.result_type(float)
    return _normalisation(jnp, mu, dtype)


def _normalisation(xp, mu, dtype):
    """:func:`gaussian_normalisation` with array namespace ``xp`` (NumPy for Python scalars, so it works under jit)."""
    ratio_max = math.sqrt(_exp_cutoff(dtype) / LN2)
    floor = float(np.finfo(dtype).tiny) ** 0.25
    mu_abs = xp.abs(mu)
    mu_safe = xp.where(mu_abs > floor, mu_abs, floor)  # a select, not maximum: no 0 · inf below the floor
    upper = xp.minimum(np.pi / 2, ratio_max * mu_safe)
    x = xp.asarray(_GL_X, dtype)
    w = xp.asarray(_GL_W, dtype)
    phi = upper[..., None] * x
    # D(φ) cosφ sinφ with the substitution φ = μ t keeps the integrand O(1) at tiny μ:
    t = phi / mu_safe[..., None]
    integrand = xp.exp(-LN2 * t * t) * xp.cos(phi) * xp.sinc(phi / np.pi) * t
    # ∫ D cos sin dφ = μ² ∫ e^{-ln2 t²} cos(φ) (sin φ / φ) t dt over t ∈ [0, upper/μ]; the factor 1/μ²
    # is applied as (1/μ)(1/μ), so its derivative never forms 1/(μ²)², which overflows float32 at μ ~ 1e-9
    integral_t = (upper / mu_safe) * xp.sum(w * integrand, axis=-1)
    inv = 1.0 / mu_safe
    return inv * inv / (2.0 * np.pi * integral_t)


def beckmann(cos_phi, alpha):
    """Normalised Beckmann distribution D(φ, α) = exp(−tan²φ/α²)/(π α² cos⁴φ).

    ``cos_phi`` = N·H; α is the RMS slope. 0 for cos φ ≤ 0 and where the
    exponential underflows; finite gradients there. In float32 this loses
    facet angles below ~2.4e-4 (1 − cos²φ rounds to 0): for narrow lobes use
    :func:`beckmann_phi`.
    """
    c = jnp.asarray(cos_phi)
    alpha = jnp.asarray(alpha)
    dtype = jnp.result_type(c, alpha)
    c2 = c * c
    s2 = jnp.maximum(1.0 - c2, 0.0)
    x_max = _exp_cutoff(dtype) * 0.5  # leave headroom for the 1/cos⁴ factor
    live = (c > 0) & (s2 < x_max * alpha * alpha * c2) & (alpha != 0)
    c_s = jnp.where(live, c, 1.0)
    a = jnp.where(live, alpha, 1.0)
    # tan φ / α, differentiated without forming α² or α⁴ (float32 gradients at α = 1e-8 stay finite)
    q = ratio(safe_sqrt(jnp.where(live, s2, 0.0)), c_s * a)
    c2_s = c_s * c_s
    value = jnp.exp(-q * q) / (jnp.pi * a) / a / (c2_s * c2_s)
    return jnp.where(live, value, 0.0)


def beckmann_phi(phi, alpha):
    """Beckmann D from the facet angle φ itself (preferred over :func:`beckmann`).

    Same distribution, D = exp(−tan²φ/α²)/(π α² cos⁴φ), but tan²φ is taken
    from φ rather than from cos φ: in float32, 1 − cos²φ is 0 for φ < 2.4e-4,
    so ``beckmann(cos φ)`` returns the peak value 1/(π α²) there even when the
    true value has underflowed (α = 1e-6). Pass φ from
    :func:`~jkatana.models.geometry.half_vector_terms` (atan2 form).
    0 for φ ≥ π/2 and where the exponential underflows; finite gradients.
    """
    phi = jnp.asarray(phi)
    c = jnp.cos(phi)
    return beckmann_tan(jnp.tan(jnp.where(c > 0, phi, 0.0)), c, alpha)


def beckmann_tan(tan_phi, cos_phi, alpha):
    """Beckmann D = exp(−tan²φ/α²)/(π α² cos⁴φ) from tan φ and cos φ of the facet normal.

    The form behind :func:`beckmann_phi`, for callers that have tan φ without
    φ (:func:`~jkatana.models.geometry.half_vector_tan_terms`, no ``atan2``).
    0 for cos φ ≤ 0 and where the exponential underflows; finite gradients.
    """
    t = jnp.asarray(tan_phi)
    c = jnp.asarray(cos_phi)
    alpha = jnp.asarray(alpha)
    dtype = jnp.result_type(t, c, alpha)
    x_max = _exp_cutoff(dtype) * 0.5
    live = (c > 0) & (jnp.abs(t) < jnp.sqrt(x_max) * jnp.abs(alpha))
    a = jnp.where(live, alpha, 1.0)
    q = jnp.where(live, t, 0.0) / a  # tan φ / α: O(1) in the lobe, keeps float32 gradients in range
    c2_s = jnp.where(live, c * c, 1.0)
    value = jnp.exp(-q * q) / (jnp.pi * a) / a / (c2_s * c2_s)
    return jnp.where(live, value, 0.0)


def _cos_floor(dtype) -> float:
    """Floor for cosines used as divisors: eps² of the dtype (float32: 1.4e-14)."""
    return float(np.finfo(dtype).eps) ** 2


def vcavity(cos_nh, cos_nv, cos_nl, cos_vh):
    """Torrance–Sparrow V-cavity G = min(1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·L)/(V·H)).

    Torrance & Sparrow (1967), in the form of Cook & Torrance (1982), eq. 8.
    Written as min(1, 2 N·H min(N·V, N·L) / V·H) with V·H floored at eps² of
    the dtype inside the division (double where): 0, not NaN, where V·H ≤ 0,
    and a finite derivative as V·H → 0.
    """
    cos_vh = jnp.asarray(cos_vh)
    dtype = jnp.result_type(cos_nh, cos_nv, cos_nl, cos_vh)
    ok = cos_vh > 0
    vh = jnp.where(ok, jnp.maximum(cos_vh, _cos_floor(dtype)), 1.0)
    g = jnp.minimum(1.0, 2.0 * cos_nh * jnp.minimum(cos_nv, cos_nl) / vh)
    return jnp.where(ok, jnp.clip(g, 0.0, 1.0), 0.0)


def vcavity_over_cos(cos_nh, cos_nv, cos_nl, cos_vh):
    """G / cos θr for eq. (2), finite at grazing view (N·V → 0).

    G / N·V = min(1/N·V, (2 N·H / V·H) · min(1, N·L / N·V)). As N·V → 0 with
    N·L > 0 this tends to 2 N·H / V·H, the masking-limited value, which is
    what is returned at N·V = 0 exactly. N·V and V·H are floored at eps² of the
    dtype inside the divisions (double where), so value and gradient stay
    finite; the floor changes the value only where N·V < eps² and N·L < N·V
    (both directions within 1e-14 rad of the horizon in float32). 0 where
    V·H ≤ 0 or N·V < 0.
    """
    cos_vh = jnp.asarray(cos_vh)
    cos_nv = jnp.asarray(cos_nv)
    dtype = jnp.result_type(cos_nh, cos_nv, cos_nl, cos_vh)
    floor = _cos_floor(dtype)
    ok = (cos_vh > 0) & (cos_nv >= 0)
    nv = jnp.where(ok, jnp.maximum(cos_nv, floor), 1.0)
    vh = jnp.where(ok, jnp.maximum(cos_vh, floor), 1.0)
    masking = (2.0 * cos_nh / vh) * jnp.minimum(1.0, jnp.maximum(cos_nl, 0.0) / nv)
    value = jnp.minimum(1.0 / nv, masking)
    return jnp.where(ok, jnp.maximum(value, 0.0), 0.0)


def smith_g1_beckmann(cos_theta, alpha):
    """Walter et al. (2007) rational approximation of Smith's G1 for Beckmann.

    a = 1/(α tanθ); G1 = (3.535a + 2.181a²)/(1 + 2.276a + 2.577a²) for a < 1.6,
    else 1. 0 for cos θ ≤ 0; 1 at normal incidence (tan θ = 0).
    """
    c = jnp.clip(jnp.asarray(cos_theta), 0.0, 1.0)
    s = safe_sqrt(1.0 - c * c)  # derivative 0, not inf, at normal incidence
    # a = c / (α s); use the branch a ≥ 1.6  ⇔  c ≥ 1.6 α s  without dividing
    high = c >= 1.6 * alpha * s
    a = jnp.where(high, 1.0, c / jnp.where(high, 1.0, alpha * s))
    g1 = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    return jnp.where(c > 0, jnp.where(high, 1.0, g1), 0.0)


def beckmann_visible_area(cos_theta, alpha):
    """∫ max(0, ω·h) D(h) dω_h = cos θ (1 + Λ(θ)) for Beckmann D with Smith's exact Λ.

    Λ = (erf(a) − 1)/2 + exp(−a²)/(2a√π), a = 1/(α tan θ) (Heitz 2014, JCGT 3(2),
    eq. 75; Walter et al. 2007, eq. 27 before its rational approximation), written
    as (cos θ (1 + erf a) + α sin θ exp(−a²)/√π)/2 so that it has no division by
    a: finite at grazing view (α sin θ/(2√π) at cos θ = 0) and at normal view
    (cos θ). ``cos_theta`` is clipped to [0, 1]. G1 = cos θ / this area, so the
    density of visible normals D_ω(h) = max(0, ω·h) D(h) / this area integrates
    to 1 (Heitz & d'Eon 2014, "Importance sampling microfacet-based BSDFs using
    the distribution of visible normals", EGSR, eq. 2).
    """
    c = jnp.clip(jnp.asarray(cos_theta), 0.0, 1.0)
    alpha = jnp.asarray(alpha)
    s = safe_sqrt(1.0 - c * c)
    den = alpha * s
    live = den > c * 1e-4  # a = c/(α s) < 1e4: elsewhere erf(a) = 1 and exp(−a²) = 0 in float64
    a = jnp.where(live, c, 1.0) / jnp.where(live, den, 1.0)
    tail = jnp.where(live, den * jnp.exp(-a * a) * (1.0 / math.sqrt(math.pi)), 0.0)
    return 0.5 * (c * (1.0 + jnp.where(live, jax.scipy.special.erf(a), 1.0)) + tail)


def ggx_visible_area(cos_theta, alpha):
    """∫ max(0, ω·h) D(h) dω_h = cos θ (1 + Λ(θ)) for GGX D with Smith's exact Λ.

    Λ = (√(1 + α² tan²θ) − 1)/2 (Heitz 2014, JCGT 3(2), eq. 72), so the area is
    (cos θ + √(cos²θ + α² sin²θ))/2: no division, α sin θ/2 at grazing view.
    ``cos_theta`` is clipped to [0, 1]; G1 = cos θ / this area (Walter et al.
    2007, eq. 34).
    """
    c = jnp.clip(jnp.asarray(cos_theta), 0.0, 1.0)
    return 0.5 * (c + safe_sqrt(c * c + alpha * alpha * (1.0 - c * c)))


def smith_beckmann(cos_nv, cos_nl, alpha):
    """Separable Smith masking-shadowing G = G1(V) G1(L) (Walter et al. 2007)."""
    return smith_g1_beckmann(cos_nv, alpha) * smith_g1_beckmann(cos_nl, alpha)
