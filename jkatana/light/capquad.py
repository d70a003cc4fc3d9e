"""Cap × lobe quadrature: a reflection lobe integrated over a spherical-cap light.

A compact source split off an environment map (:mod:`jkatana.light.sun`) is
a cap of known direction, radius and uniform radiance; its reflected radiance
is ``L_cap ∫_cap f_r(L, V) cos θ_L dω``, integrated here deterministically.
:func:`cap_nodes` is the rule (directions and weights about the lobe's centre,
placed by the lobe's width :meth:`~jkatana.models.lobes.Lobe.reflected_width`),
:func:`cap_integral` applies it to a BRDF, :func:`cap_point_integral` and
:func:`cap_disc_nodes` are the cheap rules for lobes much wider than the cap,
:func:`cap_coverage` the antialiased cap indicator of a mirror.

## The rule (:func:`cap_nodes`, :func:`cap_integral`)

``∫_cap f_r(L, V) cos θ_L dω`` by a product Gauss–Legendre rule in polar
coordinates ``(ψ, φ)`` about the lobe's centre R (the mirror direction of
V), with the cap's boundary treated exactly:

- azimuth φ: if R is inside the cap, the whole circle with the midpoint rule
  (exponentially convergent for the smooth periodic integrand) in the
  elliptic angle η, ``tan(φ − φ_p) = c tan η`` about the plane of incidence
  φ_p, which gives every node an equal share of a lobe narrowed by ``c``
  (below), with ``c`` relaxed towards 1 as the lobe widens past the cap;
  otherwise the arc ``|φ| ≤ β`` that meets the cap, ``sin β = sin r / sin δ``
  (δ = ∠(R, C)), with GL nodes in τ for ``φ = β sin τ``, which removes the
  square-root end behaviour of the chord length;
- along each azimuth the cap occupies ``ψ ∈ [ψ₀ − w, ψ₀ + w]`` (clipped at
  0), from the right spherical triangle through the cap centre C
  (Napier's rules; e.g. Todhunter 1886, *Spherical Trigonometry*):
  ``sin d = sin δ sin φ``, ``tan ψ₀ = tan δ cos φ``, ``cos w = cos r / cos d``
  (evaluated in half-angle form, accurate for sub-degree caps in float32);
- radially the substitution ``u = ψ²/(2σ²)`` and GL nodes in
  ``t = (1 − e^{−(u − u₀)})/(1 − e^{−Δu})``, the inverse-CDF variable of a
  Gaussian of width σ in ψ. For the paper's Gaussian facet lobe
  ``D = exp(−ln2 φ_h²/μ²)`` (Mochizuki et al.) the reflected lobe is such a
  Gaussian with ``σ = μ √(2/ln2)`` (ψ ≈ 2 φ_h), narrowed by ``cos θ`` across
  the plane of incidence (a facet tilt out of that plane turns the reflected
  ray by ``2 φ_h cos θ``), which σ follows per azimuth. The transformed
  integrand is then nearly constant whether the lobe is far narrower than
  the cap (a mirror: the result tends to ``F(θ) · [R inside the cap]``,
  antialiased over the lobe's own width) or far wider (the cap a point).

Gauss–Legendre nodes: Golub & Welsch (1969), "Calculation of Gauss
quadrature rules", Math. Comp. 23, via :func:`numpy.polynomial.legendre.leggauss`.

Error bound of the default rule (4 radial × 16 azimuthal nodes, 64 BRDF
evaluations), relative to the value with the cap centred on R, for the
paper's lobe at μ = 0.001…0.3, incidence 0–69°, the sun's 0.255° cap, pinned
against a dense quadrature in ``tests/test_light_capquad.py``: ≤ 2e-2 where the
cap's edge crosses a lobe narrower than the cap (the antialiasing of the
glint's outline: there the integrand has a near-step in φ that the rule
resolves only to its node spacing), ≤ 1e-3 everywhere else. More azimuths
shrink the edge error.
"""

from __future__ import annotations

import math
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.light.sun import SunCap, cap_solid_angle
from jkatana.models._safe import norm, normalize, safe_atan2, safe_div, safe_sqrt
from jkatana.models.geometry import tangent_frame


def cap_nodes(R: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius, sigma, *, normal=None,
              n_radial: int = 4, n_azimuth: int = 16) -> tuple[Float[Array, "*b A Q 3"], Float[Array, "*b A Q"]]:
    """Directions and weights of the cap rule about a lobe centre (module docstring).

    ``Σ w g(L) ≈ ∫_cap g dω`` for ``g`` a lobe of width ``sigma`` about ``R``.

    **Arguments:**

    - `R`: lobe centre (unit); `C`: cap centre (unit); `radius`: cap radius
      (rad); `sigma`: lobe width (rad, > 0) about R.
    - `normal`: the surface normal (same frame) when the lobe is a reflection
      lobe, narrowed by ``cos θ = R·N`` across the plane of incidence; None:
      isotropic.
    - `n_radial`, `n_azimuth`: nodes per azimuth and azimuths.

    **Returns:** ``(L, w)`` with ``A = n_azimuth``, ``Q = n_radial``. Pure JAX,
    jittable, finite values and gradients (R = C, R on the cap's edge, a lobe
    far narrower or wider than the cap).
    """
    R = jnp.asarray(R)
    C = jnp.asarray(C)
    R, C = jnp.broadcast_arrays(R, C)
    dt = jnp.result_type(R, C)  # the directions set the precision (Python-float radius/σ do not promote)
    R, C = normalize(R.astype(dt)), normalize(C.astype(dt))
    r = jnp.asarray(radius, dt)[..., None]
    sigma = jnp.asarray(sigma, dt)[..., None]
    e1, e2, sin_d, delta = _frame_towards_cap(R, C, dt)
    inside = (delta < r[..., 0])[..., None]
    c_an, phi_p = _anisotropy(R, normal, e1, e2, delta, dt)
    phi, w_phi = _azimuths(inside, c_an, phi_p, r, sigma, sin_d, n_azimuth, dt)
    lo, hi = _chord(phi, sin_d, delta, r)
    # lobe width along each azimuth: σ / √(cos²(φ − φ_p) + sin²(φ − φ_p)/c²)
    tdir = jnp.cos(phi)[..., None] * e1[..., None, :] + jnp.sin(phi)[..., None] * e2[..., None, :]
    cp, sp = jnp.cos(phi - phi_p), jnp.sin(phi - phi_p)
    sig = sigma * jax.lax.rsqrt(cp * cp + sp * sp / (c_an * c_an))
    psi, w = _radial(lo, hi, sig, w_phi, n_radial, dt)
    L = jnp.cos(psi)[..., None] * R[..., None, None, :] + jnp.sin(psi)[..., None] * tdir[..., None, :]
    return L, w


def _frame_towards_cap(R, C, dt):
    """A frame at R with e1 towards C (any ⟂ when C = R), e2 = R × e1; sin δ and δ = ∠(R, C)."""
    cos_d = jnp.sum(R * C, axis=-1)
    perp = C - cos_d[..., None] * R
    sin_d = norm(perp)
    delta = safe_atan2(sin_d, cos_d)
    perp = perp - jnp.sum(perp * R, -1, keepdims=True) * R  # C ≈ R: perp is rounding noise, not ⟂ R
    e1 = jnp.where((norm(perp) > 16 * float(jnp.finfo(dt).eps))[..., None], normalize(perp), tangent_frame(R)[0])
    e2 = jnp.cross(R, e1)
    return e1, e2, sin_d, delta


def _anisotropy(R, normal, e1, e2, delta, dt):
    """A reflection lobe's anisotropy: c = cos θ = R·N (clipped to [0.05, 1]) and the azimuth φ_p of the plane
    of incidence about R; an isotropic lobe (no normal) has c = 1, φ_p = 0."""
    if normal is None:
        return jnp.ones_like(delta)[..., None], jnp.zeros_like(delta)[..., None]
    N = jnp.asarray(normal, dt)
    c_an = jnp.clip(jnp.sum(R * N, axis=-1), 0.05, 1.0)[..., None]
    p = normalize(N - jnp.sum(R * N, -1, keepdims=True) * R)
    phi_p = safe_atan2(jnp.sum(p * e2, -1), jnp.sum(p * e1, -1))[..., None]
    return c_an, phi_p


def _azimuths(inside, c_an, phi_p, r, sigma, sin_d, n_azimuth: int, dt):
    """The azimuths φ about R and their weights. Inside the cap: the whole circle, midpoint rule in the
    elliptic angle η (tan(φ − φ_p) = c tan η), which spreads an anisotropic lobe's mass evenly over the nodes.
    Outside: the arc |φ| ≤ β that meets the cap, GL in τ for φ = β sin τ."""
    eta = jnp.asarray(2 * np.pi * (np.arange(n_azimuth) + 0.5) / n_azimuth - np.pi, dt)
    ce, se = jnp.cos(eta), jnp.sin(eta)
    c_map = c_an ** (r * r / (r * r + sigma * sigma))  # c for a lobe narrower than the cap, 1 wider
    phi_in = phi_p + jnp.arctan2(c_map * se, ce)
    w_in = (2 * np.pi / n_azimuth) * c_map / (ce * ce + (c_map * se) ** 2)
    x_a, w_a = np.polynomial.legendre.leggauss(n_azimuth)
    ratio = safe_div(jnp.sin(r), sin_d[..., None], fallback=1.0)
    # outside only (ratio ≤ 1 there), kept off 1 where arcsin' is infinite
    beta = jnp.arcsin(jnp.clip(jnp.where(inside, 0.5, ratio), 0.0, 1.0 - float(jnp.finfo(dt).eps)))
    tau = jnp.asarray(0.5 * np.pi * x_a, dt)
    w_a = jnp.asarray(w_a, dt)
    phi = jnp.where(inside, phi_in, beta * jnp.sin(tau))
    w_phi = jnp.where(inside, w_in, 0.5 * np.pi * w_a * beta * jnp.cos(tau))
    return phi, w_phi


def _chord(phi, sin_d, delta, r):
    """The cap's chord along each azimuth, ψ ∈ [ψ0 − w, ψ0 + w] clipped to [0, π] (Napier's rules in half-angle
    form, module docstring)."""
    sd = sin_d[..., None]
    sin_dp = sd * jnp.sin(phi)
    cos_dp = safe_sqrt(1.0 - sin_dp * sin_dp)
    hav_dp = safe_div(sin_dp * sin_dp, 2.0 * (1.0 + cos_dp))
    hav_w = safe_div(jnp.sin(0.5 * r) ** 2 - hav_dp, cos_dp)
    half = 2.0 * jnp.arcsin(jnp.clip(safe_sqrt(hav_w), 0.0, 1.0))
    psi0 = jnp.arctan2(sd * jnp.cos(phi), jnp.cos(delta)[..., None])
    lo = jnp.maximum(psi0 - half, 0.0)
    hi = jnp.clip(psi0 + half, lo, np.pi)
    return lo, hi


def _radial(lo, hi, sig, w_phi, n_radial: int, dt):
    """Radial nodes ψ on [lo, hi] along each azimuth and the rule's weights (the azimuth's ``w_phi`` times the
    radial weight and the solid angle's sin ψ): u = ψ²/(2σ²), GL in the inverse-CDF variable t of e^{−u} (module
    docstring)."""
    x_r, w_r = np.polynomial.legendre.leggauss(n_radial)
    t = jnp.asarray(0.5 * (x_r + 1.0), dt)
    wt = jnp.asarray(0.5 * w_r, dt)
    inv2s2 = 0.5 / (sig * sig)
    u_lo = (lo * lo * inv2s2)[..., None]
    du = ((hi - lo) * (hi + lo) * inv2s2)[..., None]
    c = -jnp.expm1(-du)
    u = u_lo - jnp.log1p(-t * c)
    psi = sig[..., None] * safe_sqrt(2.0 * u)
    w = (w_phi[..., None] * wt * (sig * sig)[..., None] * jnp.sinc(psi / np.pi) * c / (1.0 - t * c))
    return psi, w


def cap_integral(brdf_cos: Callable, V: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius, sigma, *,
                 n_radial: int = 4, n_azimuth: int = 16) -> Float[Array, "*b wl"]:
    """``∫_cap f_r(L, V) cos θ_L dω`` for a reflection lobe about the mirror direction of V.

    **Arguments:**

    - `brdf_cos(L, V) -> (..., wl)`: f_r cos θ_L in the local shading frame
      (N = +z), broadcasting over leading axes (e.g. ``partial(Hiraji.brdf_cos,
      conductor=...)``).
    - `V`: view direction, local frame; `C`: cap centre, local frame.
    - `radius`: cap radius (rad); `sigma`: the lobe's width in the reflected
      direction (:meth:`~jkatana.models.lobes.Lobe.reflected_width` of the lobe).
    - `n_radial`, `n_azimuth`: the rule's size (``n_radial × n_azimuth`` BRDF
      evaluations per point).

    Multiply by :attr:`SunCap.radiance` for the reflected radiance
    (:func:`reflected_cap_radiance`). Pure JAX, jittable over pixels.

    Cost: ``n_radial × n_azimuth`` BRDF evaluations per point. The Fresnel
    factor varies by at most ``|dF/dθ| · r`` over the cap, so a renderer may
    pass the lobe alone (a trailing axis of 1) and multiply by ``F`` at the
    cap's centre; where the lobe is much wider than the cap,
    :func:`cap_point_integral` needs one evaluation.
    """
    V = jnp.asarray(V)
    R = V * jnp.asarray([-1.0, -1.0, 1.0], V.dtype)
    L, w = cap_nodes(R, C, radius, sigma, normal=jnp.asarray([0.0, 0.0, 1.0], V.dtype),
                     n_radial=n_radial, n_azimuth=n_azimuth)
    f = brdf_cos(L, jnp.broadcast_to(V[..., None, None, :], L.shape))
    return jnp.einsum("...aq,...aql->...l", w.astype(f.dtype), f)


def cap_point_integral(brdf_cos: Callable, V: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius
                       ) -> Float[Array, "*b wl"]:
    """The cap as a point light: ``f_r(C, V) cos θ_C · Ω_cap``, one BRDF evaluation.

    The midpoint rule of :func:`cap_integral`'s integral: for a lobe of width
    σ much wider than the cap its relative error is of order ``(r/σ)²`` (the
    lobe's curvature across the cap), so a renderer can use it wherever
    ``σ ≫ r`` and keep :func:`cap_integral` for the glints.
    """
    V = jnp.asarray(V)
    C = normalize(jnp.asarray(C, V.dtype))
    omega = cap_solid_angle(jnp.asarray(radius, V.dtype))
    return brdf_cos(C, jnp.broadcast_to(V, C.shape)) * omega[..., None]


def cap_disc_nodes(C: Float[Array, "*b 3"], radius) -> tuple[Float[Array, "*b 4 3"], Float[Array, "*b 4"]]:
    """Stroud's degree-3 rule on a small cap: 4 directions, independent of the lobe.

    The disc rule S2:3-1 of Stroud (1971), *Approximate Calculation of Multiple
    Integrals* (Prentice-Hall): points at distance ``ρ/√2`` from a disc's centre
    on two orthogonal axes, equal weights, integrate every polynomial of degree
    ≤ 3 exactly. On the sphere: the directions at angle ``r/√2`` from the cap
    centre C along two orthogonal tangents, each weighted ``Ω_cap/4``. For a lobe
    of width σ ≫ r the error is of order ``(r/σ)⁴`` (the lobe's quartic term
    across the cap; for a Gaussian centred on the cap ``t²/24`` with
    ``t = r²/(2σ²)``), against ``(r/σ)²`` for the point light of
    :func:`cap_point_integral`: pinned in ``tests/test_light_capquad.py`` (≤ 1e-3 of
    the peak value for σ ≥ 8 r, :data:`STROUD_MIN_WIDTH`, at incidence up to 70°,
    where a reflection lobe is narrowed to σ cos θ across the plane of incidence). The directions are the
    same for every shading point, so a renderer evaluates its lobe 4 times per
    cap and point instead of the 64 of :func:`cap_nodes`.

    **Returns:** ``(L, w)``: ``L (..., 4, 3)`` unit directions, ``w (..., 4)`` weights (sr).
    """
    C = normalize(jnp.asarray(C))
    r = jnp.asarray(radius, C.dtype)
    e1 = normalize(tangent_frame(C)[0])
    e2 = jnp.cross(C, e1)
    a = r / math.sqrt(2.0)
    ca, sa = jnp.cos(a)[..., None], jnp.sin(a)[..., None]
    L = jnp.stack([ca * C + sa * e1, ca * C - sa * e1, ca * C + sa * e2, ca * C - sa * e2], axis=-2)
    w = jnp.broadcast_to((0.25 * cap_solid_angle(r))[..., None], L.shape[:-1])  # Ω/4 each
    return L, w


#: Nodes (radial, azimuthal) of :func:`cap_nodes` a renderer uses: the defaults, whose error is stated above.
CAP_RULE = (4, 16)

#: Smallest lobe width, in cap radii (σ ≥ STROUD_MIN_WIDTH · r), for which :func:`cap_disc_nodes` is used.
STROUD_MIN_WIDTH = 8.0


def reflected_cap_radiance(cap: SunCap, brdf_cos: Callable, V_local: Float[Array, "*b 3"],
                           frame: Float[Array, "*b 3 3"], sigma, **rule) -> Float[Array, "*b wl"]:
    """Radiance reflected towards V from ``cap``: ``L_cap(λ) ∫_cap f_r cos θ dω``.

    `frame`: world → local rotation of :func:`jkatana.light.sampling.frame_from_normal`.
    `rule`: ``n_radial``, ``n_azimuth`` of :func:`cap_integral`.
    """
    C = jnp.einsum("...ij,j->...i", frame, cap.direction.astype(frame.dtype))
    integral = cap_integral(brdf_cos, V_local, C, cap.radius, sigma, **rule)
    return jnp.asarray(cap.radiance, integral.dtype) * integral


def cap_coverage(R: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius, width, *, n_radial: int = 4,
                 n_azimuth: int = 16) -> Float[Array, "*b"]:
    """Fraction of a normalised Gaussian footprint of ``width`` (rad) about ``R`` inside the cap.

    The antialiased indicator ``[R inside the cap]`` of a perfect mirror:
    its reflected radiance from the cap is ``F(θ) · L_cap · cap_coverage(R, …)``,
    with ``width`` the angular footprint of the pixel (or of the lobe).
    Tends to 1 inside, 0 outside, ½ on the edge as ``width → 0``.
    """
    L, w = cap_nodes(R, C, radius, width, n_radial=n_radial, n_azimuth=n_azimuth)
    Rb = jnp.asarray(R, L.dtype)[..., None, None, :]
    cos_psi = jnp.sum(L * Rb, axis=-1)
    psi = safe_atan2(jnp.linalg.norm(jnp.cross(L, Rb), axis=-1), cos_psi)
    s = jnp.asarray(width, L.dtype)[..., None, None]
    g = jnp.exp(-0.5 * (psi / s) ** 2) / (2 * jnp.pi * s * s)
    return jnp.sum(w * g, axis=(-2, -1))
