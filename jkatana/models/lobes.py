"""Reflection lobes as objects: value, importance sampling and pdf side by side.

Each lobe is one :class:`equinox.Module` holding its parameters (leaves: any
float dtype, any batch shape that broadcasts with the directions), in the
way pbrt-v4 keeps a BxDF's ``f``, ``Sample_f`` and ``PDF`` together (Pharr,
Jakob & Humphreys, *Physically Based Rendering*, 4th ed., 2023, §9.1). All
methods are pure JAX, vectorised over any batch shape, and jit/vmap/grad-able
in float32 and float64. Directions are unit vectors in the local shading
frame (N = +z, :mod:`jkatana.models.geometry`): ``L`` towards the light,
``V`` towards the viewer.

API of every lobe:

- ``terms(L, V) -> ((a, cos_F), ...)``: f_r(L, V)·cos θi **without the Fresnel
  factor**, as a tuple of terms; term ``j`` is multiplied by ``F(cos_F_j, λ)``.
  A single lobe has one term (its own Fresnel cosine: cos θi for the paper's
  hiraji lobe, cos θH for microfacet lobes); a :class:`Mixture` has the terms
  of both parts, weighted. Keeping F outside lets a renderer take it from a
  table or fold it into the environment.
- ``terms_at(g)``: the same terms from the directions' precomputed
  :class:`Geometry` (``terms(L, V)`` is ``terms_at(Geometry.of(L, V))``: one
  formula). A caller that evaluates many parameter sets on the same
  directions (a fitter, once per solver step) computes the half vector once;
  a returned Fresnel cosine is then one of ``g``'s own arrays, so such a
  caller can tabulate F at it once as well.
- ``f_cos(L, V)``: Σ a_j — the value with F ≡ 1 (white furnace).
- ``brdf_cos(L, V, conductor)``: Σ a_j F(cos_F_j, λ) → ``(*b, wl)``.
- ``sample(V, u, uc=None) -> (L, pdf)``: an incident direction from uniforms
  ``u (*b, 2)`` in [0, 1) (``uc (*b,)`` picks a :class:`Mixture`'s part) and
  its density per steradian of L. ``L`` may lie below the surface; its value
  is then 0. Samples whose facet normal faces away from V get pdf 0 (and
  value 0): drop them (unbiased, since f_r = 0 there).
- ``pdf(L, V)``: the density of ``sample`` per steradian of L.
- ``sample_facet(V, u)``: the facet normal ``sample`` reflects V about (the
  visible normals of V for :class:`Beckmann` and :class:`GGX`, ``sample_h(u)``
  for the others).
- ``sample_h(u)``, ``pdf_h(φ, cos φ)``: a view-independent facet-normal sampler
  (density D cos φ for the microfacet lobes) and its density per steradian of
  h, for callers that reflect themselves.
- ``reflected_width()``: the angular width σ (rad) of the reflected lobe about
  the mirror direction, that of the Gaussian ``exp(−ψ²/2σ²)`` in the angle ψ
  from it whose second moment ``E[ψ²] = 2σ²`` is the lobe's f·cos at normal
  incidence (narrow-lobe limit): the scale of the cap rules' nodes
  (:mod:`jkatana.light.capquad`).
- ``to_params() -> dict`` / ``LOBES[name].from_params(dict)`` /
  :func:`lobe_from_params`: a JSON-able description ``{"lobe": name, ...}``
  so that a parameter file can name its lobe.

Microfacet lobes (:class:`Beckmann`, :class:`GGX`, :class:`GTR`) are normalised
Cook–Torrance BRDFs f_r = F D G / (4 cos θi cos θr) (Cook & Torrance 1982;
Walter, Marschner, Li & Torrance 2007, "Microfacet models for refraction
through rough surfaces", EGSR, eq. 20) with separable Smith shadowing.
:class:`Beckmann` and :class:`GGX` are sampled by the distribution of normals
visible from V, D_V(h) = max(0, V·h) D(h) / (cos θr (1 + Λ(V))) (Heitz &
d'Eon 2014, "Importance sampling microfacet-based BSDFs using the distribution
of visible normals", EGSR), with Smith's exact Λ in the pdf (its normalisation;
the value keeps its own G1), so the pdf per steradian of L is
D(h) / (4 cos θr (1 + Λ(V))) and f·cos/pdf = G1(L)·G1(V)/G1_exact(V) ≤ 1 for
GGX, ≤ 1.0035 for Beckmann (Walter et al.'s rational G1, within 0.35 %): no
1/cos θr growth at grazing view. :class:`GTR` (no closed-form visible-normal
sampler for general γ) is sampled by D cos φ and the reflection Jacobian
1/(4 V·H) (Walter et al. eq. 14). The paper's two lobes (Mochizuki
et al., eqs. 1–2) are :class:`Gaussian` and :class:`GaussianVCavity`; they use
the facet angle φ from ``atan2`` (exact for narrow lobes in float32) and are
sampled by a Rayleigh distribution of φ (density ∝ D(φ, μ) sin φ ≈ φ D), not
truncated: facet normals beyond φ = π/2 get pdf 0, so the pdf integrates to
``1 − exp(−ln2 (π/2)²/μ²)`` over facet normals (:meth:`Gaussian.facet_mass`;
< 1e-6 for μ ≤ 0.42).

For fitting camera units, multiply ``brdf_cos`` by a fitted scale; the
paper's camera-unit forms are :class:`jkatana.models.Hiraji` /
:class:`jkatana.models.Hamon`, built on these lobes.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.special
import numpy as np
from jaxtyping import Array, Bool, Float

from jkatana.models._safe import safe_div, safe_sqrt
from jkatana.models.geometry import half_vector_tan_terms, half_vector_terms
from jkatana.models.microfacet import (LN2, beckmann_tan, beckmann_visible_area, gaussian_facet,
                                       gaussian_normalisation, ggx_visible_area, smith_beckmann, vcavity_over_cos)

#: Largest uniform used by the inverse-CDF warps (keeps log(1 − u) finite in float32).
U_MAX = 1.0 - 1e-7
#: Smallest lobe width (μ or α, radians / RMS slope) the samplers use: narrower lobes sample as this one.
WIDTH_MIN = 1e-7
#: Floor of cos θH and cos θr used as divisors in the lobes' Jacobians (as pbrt-v4's microfacet code).
COS_FLOOR = 1e-7


def reflect(V: Float[Array, "*#b 3"], h: Float[Array, "*#b 3"]) -> Float[Array, "*#b 3"]:
    """Mirror ``V`` about the unit facet normal ``h``: L = 2 (V·h) h − V."""
    return 2.0 * jnp.sum(V * h, -1, keepdims=True) * h - V


def _vec3(x, y, z):
    """The vectors (x, y, z) ``(*b, 3)`` as x e_x + y e_y + z e_z (exact: products with 0 and 1).

    Broadcast rather than ``jnp.stack``: XLA's CPU backend fuses a stack's
    operands into one loop over the ``(*b, 3)`` output that evaluates every
    component's whole producer per output element, unvectorised.
    """
    e = jnp.eye(3, dtype=jnp.result_type(x, y, z))
    return x[..., None] * e[0] + y[..., None] * e[1] + z[..., None] * e[2]


def _from_polar(cos_t, sin_t, psi):
    return _vec3(sin_t * jnp.cos(psi), sin_t * jnp.sin(psi), cos_t)


def _split(u):
    u = jnp.asarray(u)
    return u[..., 0], u[..., 1]


class Geometry(eqx.Module):
    """The parameter-free geometry of direction pairs (L, V) that every lobe's value is a function of.

    ``cos_i`` = N·L, ``cos_r`` = N·V and :func:`~jkatana.models.geometry.half_vector_terms`'s facet angle
    ``phi``, ``cos_phi`` = N·H, ``cos_th`` = L·H and ``valid`` (False where L = −V), and ``tan_phi``
    (:func:`~jkatana.models.geometry.half_vector_tan_terms`: what the microfacet distributions take, read
    from L + V without ``atan2``), all broadcast to one batch shape. :meth:`Lobe.terms_at` evaluates a
    lobe from it, so directions that are evaluated with many parameter values (a fitter's solver steps)
    pay for the half vector and its angles once.
    """

    cos_i: Float[Array, "*b"]
    cos_r: Float[Array, "*b"]
    phi: Float[Array, "*b"]
    cos_phi: Float[Array, "*b"]
    cos_th: Float[Array, "*b"]
    valid: Bool[Array, "*b"]
    tan_phi: Float[Array, "*b"]

    @classmethod
    def of(cls, L: Float[Array, "*#b 3"], V: Float[Array, "*#b 3"]) -> "Geometry":
        """The geometry of unit directions ``L``, ``V`` (local frame, N = +z; batch shapes broadcast)."""
        phi, cos_phi, cos_th, valid = half_vector_terms(L, V)
        tan_phi = half_vector_tan_terms(L, V)[0]
        shape = phi.shape
        return cls(jnp.broadcast_to(L[..., 2], shape), jnp.broadcast_to(V[..., 2], shape), phi, cos_phi, cos_th,
                   valid, tan_phi)


class Lobe(eqx.Module):
    """Base class: subclasses define ``terms_at``, ``sample``, ``pdf`` and the class attribute ``name``.

    ``widths`` names the fields that set the lobe's angular width (μ of the
    Gaussian lobes, α of the microfacet ones): :meth:`jkatana.models.lobe_id.LobeId.shape_of` and
    :meth:`~jkatana.models.lobe_id.LobeId.at_width` scale them together.
    """

    name: ClassVar[str] = ""
    widths: ClassVar[tuple[str, ...]] = ()

    def terms(self, L, V):
        """f_r cos θi without the Fresnel factor as terms ``((a, cos_F), ...)`` (module docstring)."""
        return self.terms_at(Geometry.of(L, V))

    def terms_at(self, g: Geometry):
        """:meth:`terms` from the directions' precomputed :class:`Geometry` (the lobe's formula)."""
        raise NotImplementedError

    def sample_h(self, u):
        """A facet normal from uniforms ``u (*b, 2)``, independent of the view (density :meth:`pdf_h`)."""
        raise NotImplementedError

    def sample_facet(self, V, u):
        """The facet normal :meth:`sample` reflects ``V`` about: :meth:`sample_h` unless the lobe samples the
        normals visible from V."""
        return self.sample_h(u)

    def sample(self, V, u, uc=None):
        """An incident direction and its density per steradian of L (module docstring)."""
        return _sampled(self, V, self.sample_facet(V, u))

    def pdf(self, L, V):
        raise NotImplementedError

    def reflected_width(self) -> Float[Array, "*p"]:
        """Width σ (rad) of the reflected lobe about the mirror direction (module docstring)."""
        raise NotImplementedError

    def f_cos(self, L: Float[Array, "*#b 3"], V: Float[Array, "*#b 3"]) -> Float[Array, "*#b"]:
        """f_r cos θi with the Fresnel factor taken as 1 (sum of :meth:`terms`)."""
        total = 0.0
        for a, _ in self.terms(L, V):
            total = total + a
        return total

    def brdf_cos(self, L, V, conductor) -> Float[Array, "*#b wl"]:
        """f_r cos θi with the conductor's Fresnel factor: Σ_j a_j F(cos_F_j, λ) → ``(*b, wl)``."""
        total = 0.0
        for a, c in self.terms(L, V):
            total = total + a[..., None] * conductor.fresnel(c)
        return total

    def to_params(self) -> dict:
        """``{"lobe": name, field: value, ...}`` with plain floats/lists (JSON-able)."""
        out = {"lobe": self.name}
        for f in _field_names(type(self)):
            v = getattr(self, f)
            if isinstance(v, Lobe):
                out[f] = v.to_params()
            elif isinstance(v, (bool, str)) or v is None:
                out[f] = v
            else:
                out[f] = np.asarray(v).tolist()
        return out

    @classmethod
    def from_params(cls, params: dict, dtype=None) -> "Lobe":
        """Inverse of :meth:`to_params` (the ``"lobe"`` key, if present, must name this class)."""
        p = dict(params)
        name = p.pop("lobe", cls.name)
        if name != cls.name:
            raise ValueError(f"params name lobe {name!r}, not {cls.name!r}")
        kw = {}
        for k, v in p.items():
            if k not in _field_names(cls):
                raise ValueError(f"unknown field {k!r} of lobe {cls.name!r}")
            if isinstance(v, dict):
                kw[k] = lobe_from_params(v, dtype)
            elif isinstance(v, (bool, str)) or v is None:
                kw[k] = v
            else:
                kw[k] = jnp.asarray(v, dtype) if dtype is not None else jnp.asarray(v)
        return cls(**kw)


def _field_names(cls) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


def _sampled(lobe, V, h):
    """``(L, pdf(L, V))`` for the sampled facet normal ``h``; pdf 0 where h is below the surface or faces away from V.

    Such samples are dropped (f_r = 0 there), so the density of the remaining ones
    is :meth:`Lobe.pdf` (reflection maps h and −h to the same L; only the branch
    with V·h > 0, h_z > 0 is counted). The pdf is evaluated from L, as the value
    is, so f·cos/pdf keeps its bound; where a float32 L cannot resolve the lobe
    (angular error ~eps/cos θH against a width μ, e.g. μ = 1e-6 with cos θr < 0.9)
    a sample may get pdf 0 and is dropped like the others.
    """
    L = reflect(V, h)
    ok = (h[..., 2] > 0) & (jnp.sum(V * h, -1) > 0)
    return L, jnp.where(ok, lobe.pdf(L, V), 0.0)


# ---------------------------------------------------------------- the paper's Gaussian lobes


def _rayleigh_h(mu, u):
    """Facet normal with φ ~ Rayleigh(σ = μ/√(2 ln 2)) (density ∝ φ D(φ, μ)), azimuth uniform."""
    u1, u2 = _split(u)
    sigma = jnp.maximum(mu, WIDTH_MIN) / math.sqrt(2 * LN2)
    phi = sigma * jnp.sqrt(-2.0 * jnp.log1p(-jnp.minimum(u1, U_MAX)))
    return _from_polar(jnp.cos(phi), jnp.sin(phi), 2 * jnp.pi * u2)


def _rayleigh_pdf_h(mu, phi):
    """Density per steradian of the facet normals of :func:`_rayleigh_h`: exp(−φ²/2σ²) / (2π σ² sinc φ), 0 beyond π/2."""
    sigma2 = (jnp.maximum(mu, WIDTH_MIN) ** 2) / (2 * LN2)
    d = jnp.exp(-jnp.minimum(phi * phi / (2 * sigma2), 80.0))
    return jnp.where(phi < jnp.pi / 2, d / (2 * jnp.pi * sigma2) / jnp.sinc(phi / jnp.pi), 0.0)


def _rayleigh_pdf(mu, L, V):
    """Density per steradian of L of :func:`_rayleigh_h` reflected about V: p_h / (4 V·H), 0 where V·H ≤ 0."""
    phi, _, cos_th, valid = half_vector_terms(L, V)
    p_h = _rayleigh_pdf_h(mu, phi)
    return jnp.where(valid & (cos_th > 0), p_h / (4.0 * jnp.maximum(cos_th, COS_FLOOR)), 0.0)


class _GaussianBase(Lobe):
    mu: Float[Array, "*p"]
    scale: Float[Array, "*p"]
    normalised: bool = eqx.field(static=True)
    widths: ClassVar[tuple[str, ...]] = ("mu",)

    def __init__(self, mu, scale=None, normalised: bool = True):
        """``mu``: half-width at half-maximum of the facet angle (rad). ``normalised=True``: ``scale`` is
        N(μ) (:func:`~jkatana.models.microfacet.gaussian_normalisation`, computed here when omitted) and the
        lobe tends to a perfect mirror as μ → 0; ``False``: ``scale`` multiplies D as given (the paper's
        χ/K or β/K, calibrated convention)."""
        self.mu = mu
        self.normalised = bool(normalised)
        if scale is None:
            if not normalised:
                raise ValueError("a calibrated Gaussian lobe needs its scale")
            scale = gaussian_normalisation(mu)
        self.scale = scale

    def sample_h(self, u):
        """Facet normal: φ ~ Rayleigh(σ = μ/√(2 ln 2)), azimuth uniform (not truncated at π/2)."""
        return _rayleigh_h(self.mu, u)

    def pdf(self, L, V):
        return _rayleigh_pdf(self.mu, L, V)

    def pdf_h(self, phi, cos_phi):
        """Density per steradian of sampled facet normals at facet angle φ."""
        return _rayleigh_pdf_h(self.mu, phi)

    def reflected_width(self) -> Float[Array, "*p"]:
        """σ = μ √(2/ln2): the moment-matched width of the reflected lobe.

        D = exp(−ln2 φ²/μ²) (Mochizuki et al., eq. 1) is a Gaussian in the facet
        tilt with ``E[φ²] = μ²/ln2`` over the tangent plane; at normal incidence
        the reflected ray lies at ``ψ = 2φ`` from the mirror direction, so
        ``E[ψ²] = 4μ²/ln2 = 2σ²``, up to a relative ``O(σ²)`` from
        ``sin ψ ≠ ψ`` and the lobe's 1/cos θH or shadowing factor.
        """
        return jnp.asarray(self.mu) * math.sqrt(2.0 / LN2)

    def facet_mass(self):
        """Probability that a sampled facet normal lies in the upper hemisphere: 1 − exp(−ln2 (π/2)²/μ²)."""
        mu = jnp.maximum(jnp.asarray(self.mu), WIDTH_MIN)
        return -jnp.expm1(-LN2 * (jnp.pi / 2) ** 2 / (mu * mu))

    def to_params(self) -> dict:
        out = super().to_params()
        if self.normalised:
            out.pop("scale")  # recomputed from μ
        return out


class Gaussian(_GaussianBase):
    """The paper's hiraji lobe (Mochizuki et al., eq. 1): f_r cos θi = s · D(φ, μ), Fresnel at θi.

    D(φ, μ) = exp(−ln2 φ²/μ²) (:func:`~jkatana.models.microfacet.gaussian_facet`).
    Normalised: s = N(μ)/(4 cos θH) (Walter et al. 2007, eq. 20 with the paper's
    D and no shadowing), so ∫ f_r cos θi dω → 1 as μ → 0; calibrated: s = χ/K.
    0 where L or V is below the surface or L = −V.
    """

    name: ClassVar[str] = "gaussian"

    def terms_at(self, g: Geometry):
        visible = g.valid & (g.cos_i >= 0) & (g.cos_r >= 0)
        d = jnp.where(visible, gaussian_facet(g.phi, self.mu), 0.0)
        s = safe_div(self.scale, 4.0 * g.cos_th) if self.normalised else self.scale
        return ((s * d, g.cos_i),)


class GaussianVCavity(_GaussianBase):
    """The paper's hamon lobe (eq. 2), Torrance–Sparrow (1967): s · D(φ, μ) · G / cos θr, Fresnel at θH.

    G is the V-cavity term (:func:`~jkatana.models.microfacet.vcavity_over_cos`
    gives G / cos θr finite at grazing view). Normalised: s = N(μ)/4 (Cook–Torrance
    form F D̂ G /(4 cos θr) with D̂ = N(μ) D); calibrated: s = β/K.
    """

    name: ClassVar[str] = "gaussian-vcavity"

    def terms_at(self, g: Geometry):
        visible = g.valid & (g.cos_i >= 0) & (g.cos_r >= 0)
        g_over_cos = vcavity_over_cos(g.cos_phi, jnp.maximum(g.cos_r, 0.0), jnp.maximum(g.cos_i, 0.0), g.cos_th)
        dg = jnp.where(visible, gaussian_facet(g.phi, self.mu) * g_over_cos, 0.0)
        s = self.scale / 4.0 if self.normalised else self.scale
        return ((s * dg, g.cos_th),)


# ---------------------------------------------------------------- microfacet lobes


class _Microfacet(Lobe):
    """f_r cos θi = D(h) G1(V) G1(L) / (4 cos θr), Fresnel at θH; sampled by D(h) cos φ.

    D depends on the facet normal through tan φ and cos φ only (:meth:`D_tan`);
    value and pdf take tan φ straight from L + V
    (:func:`~jkatana.models.geometry.half_vector_tan_terms`, no ``atan2``).
    """

    widths: ClassVar[tuple[str, ...]] = ("alpha",)

    def D_tan(self, tan_phi, cos_phi):
        """The distribution of normals from tan φ and cos φ (0 where cos φ ≤ 0): the formula."""
        raise NotImplementedError

    def D(self, phi, cos_phi):
        """The distribution of normals at facet angle φ (:meth:`D_tan` with tan φ from φ)."""
        c = jnp.cos(phi)
        return self.D_tan(jnp.tan(jnp.where(c > 0, phi, 0.0)), c)

    def G(self, cos_r, cos_i):
        raise NotImplementedError

    def sample_h(self, u):
        raise NotImplementedError

    def terms_at(self, g: Geometry):
        ok = g.valid & (g.cos_i > 0) & (g.cos_r > 0)
        d = self.D_tan(g.tan_phi, g.cos_phi)
        shadow = self.G(g.cos_r, g.cos_i)
        return ((jnp.where(ok, d * shadow / (4.0 * jnp.maximum(g.cos_r, COS_FLOOR)), 0.0), g.cos_th),)

    def pdf(self, L, V):
        tan_nh, cos_nh, cos_th, valid = half_vector_tan_terms(L, V)
        return jnp.where(valid & (cos_th > 0),
                         self.D_tan(tan_nh, cos_nh) * cos_nh / (4.0 * jnp.maximum(cos_th, COS_FLOOR)), 0.0)

    def pdf_h(self, phi, cos_phi):
        """Density per steradian of sampled facet normals: D cos φ."""
        return self.D(phi, cos_phi) * cos_phi

    def reflected_width(self) -> Float[Array, "*p"]:
        """σ = √2 α: the moment-matched width of the Beckmann lobe of this α, shared by GGX and GTR.

        Beckmann: α is the RMS slope of the facets (Beckmann & Spizzichino 1963;
        Walter et al. 2007, eq. 25), ``E[tan²φ] = α²`` under D cos φ dω_h, and the
        reflected ray at normal incidence lies at ``ψ = 2φ``, so
        ``E[ψ²] ≈ 4α² = 2σ²`` (relative ``O(α²)`` from ``φ ≠ tan φ``). GTR's
        slopes have the core density ∝ (α² + tan²φ)^−γ (Burley 2012), whose
        second moment is ``α²/(γ − 2)`` for γ > 2 (moment-matched width
        ``α √(2/(γ − 2))``: this σ at γ = 3, α at γ = 4) and unbounded for
        γ ≤ 2 (GGX is γ = 2): a heavy tail has no moment-matched Gaussian.
        For GGX and GTR σ is the scale of the core, √γ times its
        peak-curvature width ``α √(2/γ)`` (the Gaussian with the same second
        derivative of ln f·cos at the mirror direction). The width places a
        cap rule's nodes: a wrong one costs accuracy there, not correctness.
        """
        return jnp.asarray(self.alpha) * math.sqrt(2.0)


class _VisibleMicrofacet(_Microfacet):
    """A microfacet lobe sampled by the normals visible from V (Heitz & d'Eon 2014).

    Subclasses give :meth:`visible_area`, cos θ (1 + Λ(θ)) with Smith's exact Λ of
    their D (the normalisation of the visible normals), and :meth:`sample_facet`.
    """

    def visible_area(self, cos_theta):
        """∫ max(0, ω·h) D(h) dω_h for a direction ω at cos θ = ``cos_theta``."""
        raise NotImplementedError

    def pdf(self, L, V):
        """D(h) / (4 cos θr (1 + Λ(V))): D_V(h) = max(0, V·h) D(h) / (cos θr (1 + Λ)) times the reflection
        Jacobian 1/(4 V·h) (Walter et al. 2007, eq. 14); 0 where V·h ≤ 0 or V is at or below the horizon."""
        tan_nh, cos_nh, cos_th, valid = half_vector_tan_terms(L, V)
        area = self.visible_area(V[..., 2])
        ok = valid & (cos_th > 0) & (V[..., 2] > 0) & (area > 0)
        return jnp.where(ok, self.D_tan(tan_nh, cos_nh) / (4.0 * jnp.where(ok, area, 1.0)), 0.0)


def _view_azimuth(V):
    """``(|V_xy|, cos, sin)`` of the view's azimuth; (0, 1, 0) at normal view."""
    r = safe_sqrt(V[..., 0] ** 2 + V[..., 1] ** 2)
    flat = r > 0
    r_s = jnp.where(flat, r, 1.0)
    return r, jnp.where(flat, V[..., 0] / r_s, 1.0), jnp.where(flat, V[..., 1] / r_s, 0.0)


#: Halley steps of the Beckmann visible-slope inversion from Jakob's start: the first in the erf domain, the
#: second on the slope itself. |CDF(x) − u| ≤ 5e-9 after both over cot θ ∈ [0, 1e4], u ∈ [0, 1) in float64
#: (≤ 2e-6 in float32, whose own resolution is 6e-8); 5e-2 from the start alone, 1e-4 after one step.
BECKMANN_HALLEY_STEPS = 2
_COT_MAX = 1e4  # beyond it the view is normal for the slope sampler: erf(cot) = 1, exp(−cot²) = 0


def _beckmann_visible_slope(cot, u, steps: int = BECKMANN_HALLEY_STEPS):
    """The slope x̃ ≤ cot θ of a Beckmann (α = 1) facet visible from a view at cot θ, from a uniform ``u``.

    Its CDF is P(x̃) = (cot θ (1 + erf x̃) + exp(−x̃²)/√π) / (cot θ (1 + erf cot θ) + exp(−cot²θ)/√π)
    (Heitz & d'Eon 2014, "Importance sampling microfacet-based BSDFs using the distribution of
    visible normals", EGSR, supplemental; written times cot θ so that it is finite at grazing view).
    Start: Jakob's (2014, "An improved visible normal sampling routine for the Beckmann distribution",
    Mitsuba 0.5 / pbrt-v3's ``BeckmannSample11``) fitted b = erf x̃, within 5e-2 of u in P. Then
    Halley's cubically convergent steps on P(x̃) − u, whose derivatives need no transcendental beyond
    P's own: in the erf domain P' = (cot θ − x̃)/den and P'' = −(√π/2) exp(x̃²)/den (first step, inside
    Jakob's bisection bracket [−1, erf cot θ], so a step leaving it falls back to the midpoint); on the
    slope P' = (2/√π) exp(−x̃²)(cot θ − x̃)/den and P''/P' = −2x̃ − 1/(cot θ − x̃) (second step, from
    the erfinv the first one needs anyway, so no erfinv after it; kept only where its Halley
    denominator is positive, i.e. the step is in its convergent regime). b is kept within eps of ±1,
    so the float32 tails beyond |x̃| ≈ 3.9 (mass < 3e-7) are drawn at that slope. ``steps``: 0, 1 or 2.
    """
    dtype = cot.dtype
    eps = float(jnp.finfo(dtype).eps)
    sqrt_pi = math.sqrt(math.pi)
    cot = jnp.minimum(cot, _COT_MAX)
    c = jax.scipy.special.erf(cot)
    den = cot * (1.0 + c) + jnp.exp(-cot * cot) * (1.0 / sqrt_pi)
    # the start's view angle θ = atan(1/cot θ) to ±0.004 rad (a start only: the steps correct it)
    z = jnp.where(cot >= 1.0, 1.0 / jnp.maximum(cot, 1.0), cot)
    at = z * (math.pi / 4 + 0.273 * (1.0 - z))
    theta = jnp.where(cot >= 1.0, at, math.pi / 2 - at)
    fit = 1.0 + theta * (-0.876 + theta * (0.4265 - 0.0594 * theta))
    u = jnp.clip(u, 0.0, U_MAX)
    b = jnp.clip(c - (1.0 + c) * jnp.exp(fit * jnp.log1p(-u)), eps - 1.0, 1.0 - eps)
    x = jax.scipy.special.erfinv(b)
    if steps >= 1:  # Halley in b = erf x̃: b ← b − g d / (d² + g (√π/4) exp(x̃²)), g = den (P − u), d = cot θ − x̃
        e = jnp.exp(-x * x)
        g = cot * (1.0 + b) + e * (1.0 / sqrt_pi) - u * den
        d = cot - x
        lo, hi = jnp.where(g > 0, -1.0, b), jnp.where(g > 0, b, c)
        q = d * d * e + g * (sqrt_pi / 4)  # the Halley denominator times exp(−x̃²) (> 0)
        b = b - g * d * e / jnp.where(q > 0, q, 1.0)
        b = jnp.clip(jnp.where((b >= lo) & (b <= hi) & (q > 0), b, 0.5 * (lo + hi)), eps - 1.0, 1.0 - eps)
        x = jax.scipy.special.erfinv(b)
    if steps >= 2:  # Halley in x̃: x̃ ← x̃ − g √π d / (2 exp(−x̃²) d² + g √π (x̃ d + ½)), erf x̃ = b
        e = jnp.exp(-x * x)
        g = cot * (1.0 + b) + e * (1.0 / sqrt_pi) - u * den
        d = cot - x
        q = 2.0 * e * d * d + g * sqrt_pi * (x * d + 0.5)
        x = jnp.minimum(jnp.where(q > 0, x - g * sqrt_pi * d / jnp.where(q > 0, q, 1.0), x), cot)
    return x


class Beckmann(_VisibleMicrofacet):
    """Cook–Torrance with the Beckmann distribution and separable Smith shadowing.

    D = exp(−tan²φ/α²)/(π α² cos⁴φ) (Beckmann & Spizzichino 1963, normalised as
    Walter et al. 2007, eq. 25), G1 by Walter et al.'s rational approximation
    (eq. 27); the combination Mitsuba 3's ``roughconductor`` (``beckmann``,
    ``sample_visible = true``) uses. Sampled by the normals visible from V
    (:meth:`sample_facet`: Heitz & d'Eon 2014's stretch, slope sampling and
    rotation, the slope by :func:`_beckmann_visible_slope`); :meth:`sample_h`
    samples D cos φ: tan²φ = −α² ln(1 − u) (Walter et al., eq. 28).
    α = RMS slope. D is evaluated from tan φ
    (:func:`~jkatana.models.microfacet.beckmann_tan`), not from cos φ, so narrow
    lobes keep their shape in float32.
    """

    alpha: Float[Array, "*p"]
    name: ClassVar[str] = "beckmann"

    def D_tan(self, tan_phi, cos_phi):
        return beckmann_tan(tan_phi, cos_phi, self.alpha)

    def G(self, cos_r, cos_i):
        return smith_beckmann(cos_r, cos_i, self.alpha)

    def visible_area(self, cos_theta):
        return beckmann_visible_area(cos_theta, jnp.maximum(self.alpha, WIDTH_MIN))

    def sample_h(self, u):
        u1, u2 = _split(u)
        t2 = -(self.alpha**2) * jnp.log1p(-jnp.minimum(u1, U_MAX))
        c = jax.lax.rsqrt(1.0 + t2)
        return _from_polar(c, safe_sqrt(t2) * c, 2 * jnp.pi * u2)

    def sample_facet(self, V, u):
        """A normal visible from V (Heitz & d'Eon 2014, §4): in the view stretched to α = 1 the slopes are
        x̃ ~ :func:`_beckmann_visible_slope` toward V and ỹ ~ N(0, ½) across it; rotated to V's
        azimuth and scaled by α, the normal is (−x, −y, 1)/‖·‖."""
        u1, u2 = _split(u)
        a = jnp.maximum(self.alpha, WIDTH_MIN)
        r, cos_v, sin_v = _view_azimuth(V)
        cz = jnp.maximum(V[..., 2], 0.0)
        cot = cz / jnp.maximum(a * r, cz / _COT_MAX)  # cot θ of the stretched view
        x = _beckmann_visible_slope(cot, u1)
        eps = float(jnp.finfo(x.dtype).eps)
        y = jax.scipy.special.erfinv(jnp.clip(2.0 * u2 - 1.0, eps - 1.0, 1.0 - eps))
        sx, sy = a * (cos_v * x - sin_v * y), a * (sin_v * x + cos_v * y)
        c = jax.lax.rsqrt(1.0 + sx * sx + sy * sy)
        return _vec3(-sx * c, -sy * c, c)


def _smith_g1_ggx(cos_theta, alpha):
    """Exact Smith G1 for GGX (Walter et al. 2007, eq. 34): 2 cos / (cos + √(cos² + α² sin²)); 0 at cos ≤ 0."""
    c = jnp.clip(cos_theta, 0.0, 1.0)
    root = safe_sqrt(c * c + alpha * alpha * (1.0 - c * c))
    return safe_div(2.0 * c, c + root)


class GGX(_VisibleMicrofacet):
    """Cook–Torrance with the GGX / Trowbridge–Reitz distribution and exact Smith shadowing.

    D = α² / (π cos⁴φ (α² + tan²φ)²) (Trowbridge & Reitz 1975; Walter et al. 2007,
    eq. 33), G1 = 2/(1 + √(1 + α² tan²θ)) (eq. 34). Sampled by the normals visible
    from V (:meth:`sample_facet`: Dupuy & Benyoub 2023, "Sampling visible GGX normals
    with spherical caps", HPG, the same density as Heitz 2018's closed form);
    :meth:`sample_h` samples D cos φ: tan²φ = α² u/(1 − u) (eq. 35). tan φ is taken
    from L + V, not from cos φ, so narrow lobes keep their shape in float32.
    """

    alpha: Float[Array, "*p"]
    name: ClassVar[str] = "ggx"

    def D_tan(self, tan_phi, cos_phi):
        a = jnp.maximum(self.alpha, WIDTH_MIN)
        c, t = cos_phi, tan_phi
        live = (c > 0) & (t < 3e7 * a)
        q = jnp.where(live, t, 0.0) / a  # tan φ / α: O(1) in the lobe, keeps float32 gradients in range
        c2 = jnp.where(live, c * c, 1.0)
        peak = 1.0 / (jnp.pi * a) / a
        return jnp.where(live, peak / (c2 * c2 * (1.0 + q * q) ** 2), 0.0)

    def G(self, cos_r, cos_i):
        a = jnp.maximum(self.alpha, WIDTH_MIN)
        return _smith_g1_ggx(cos_r, a) * _smith_g1_ggx(cos_i, a)

    def visible_area(self, cos_theta):
        return ggx_visible_area(cos_theta, jnp.maximum(self.alpha, WIDTH_MIN))

    def sample_facet(self, V, u):
        """A normal visible from V: in the view stretched to α = 1 the visible normal is the view plus a
        uniform point of the spherical cap z ≥ −V_z of the unit sphere (Dupuy & Benyoub 2023, listing 3);
        scaled back by α."""
        u1, u2 = _split(u)
        a = jnp.maximum(self.alpha, WIDTH_MIN)
        wx, wy, wz = a * V[..., 0], a * V[..., 1], jnp.maximum(V[..., 2], 0.0)
        n = jax.lax.rsqrt(jnp.maximum(wx * wx + wy * wy + wz * wz, float(jnp.finfo(V.dtype).tiny)))
        wx, wy, wz = wx * n, wy * n, wz * n
        z = (1.0 - jnp.minimum(u1, U_MAX)) * (1.0 + wz) - wz
        s = safe_sqrt(1.0 - z * z)
        psi = 2 * jnp.pi * u2
        mx, my, mz = a * (s * jnp.cos(psi) + wx), a * (s * jnp.sin(psi) + wy), jnp.maximum(z + wz, 0.0)
        m = jax.lax.rsqrt(jnp.maximum(mx * mx + my * my + mz * mz, float(jnp.finfo(V.dtype).tiny)))
        return _vec3(mx * m, my * m, mz * m)

    def sample_h(self, u):
        u1, u2 = _split(u)
        a = jnp.maximum(self.alpha, WIDTH_MIN)
        u1 = jnp.minimum(u1, U_MAX)
        t2 = a * a * u1 / (1.0 - u1)
        c = jax.lax.rsqrt(1.0 + t2)
        s = safe_sqrt(t2) * c
        return _from_polar(c, s, 2 * jnp.pi * u2)


def _exprel(x):
    """expm1(x)/x, 1 at x = 0 (finite value and gradient)."""
    small = jnp.abs(x) < 1e-4
    xs = jnp.where(small, 1.0, x)
    return jnp.where(small, 1.0 + 0.5 * x, jnp.expm1(xs) / xs)


def _log_exprel(x):
    """log(expm1(x)/x) without overflow: x + log(exprel(−x)) for x > 0."""
    pos = x > 0
    return jnp.where(pos, x, 0.0) + jnp.log(_exprel(jnp.where(pos, -x, x)))


def _log1prel(y):
    """log1p(y)/y, 1 at y = 0."""
    small = jnp.abs(y) < 1e-4
    ys = jnp.where(small, 1.0, y)
    return jnp.where(small, 1.0 - 0.5 * y, jnp.log1p(ys) / ys)


class GTR(_Microfacet):
    """Generalised Trowbridge–Reitz (Burley 2012, "Physically-based shading at Disney", SIGGRAPH course).

    D = c / (α² cos²φ + sin²φ)^γ with c = (γ − 1)(α² − 1) / (π (1 − α^{2(1−γ)})),
    written as c = exprel(ln α²) / (π exprel((1 − γ) ln α²)) (exprel(x) = (eˣ − 1)/x),
    which is finite at γ = 1 (Berry's distribution) and α = 1 (uniform D = 1/π).
    γ = 2 is GGX; γ < 2 gives heavier tails (the haze of polished metal), γ > 2
    lighter ones. Evaluated as exp(log c − γ log q) with one logarithm of the
    bracket q = (α cos φ)² + sin²φ, sin φ taken as tan φ · cos φ (tan φ from
    L + V, accurate near the peak where 1 − cos²φ is not): q lies in
    [min(α², 1), 1], so neither q nor its power underflows or overflows
    (α = 1e-6…1, γ ≤ 4, cos φ → 0; float32 and float64), and the gradients
    stay finite.
    Sampled by D cos φ (Burley 2012, appendix B):
    cos²φ = (1 − [α^{2(1−γ)}(1 − u) + u]^{1/(1−γ)}) / (1 − α²), in a form that
    stays accurate at γ → 1 and α → 1. Shadowing: separable Smith G1 of GGX
    with the same α (Burley 2012 does the same; exact only at γ = 2): for
    γ < 2 the tails are under-shadowed, and the albedo can exceed 1 at grazing
    view by a few per cent (γ = 1, α = 0.3, θr = 74°: 1.017).
    Domain: 0 < α ≤ 1, 1 ≤ γ ≤ 4.
    """

    alpha: Float[Array, "*p"]
    gamma: Float[Array, "*p"]
    name: ClassVar[str] = "gtr"

    def _a(self):
        a = jnp.clip(self.alpha, WIDTH_MIN, 1.0)
        return a, 2.0 * jnp.log(a)

    def D_tan(self, tan_phi, cos_phi):
        a, l = self._a()
        g = self.gamma
        c = cos_phi
        live = c > 0
        c_s = jnp.where(live, c, 1.0)
        ac, s = a * c_s, jnp.where(live, tan_phi, 0.0) * c_s  # α cos φ and sin φ = tan φ cos φ
        log_c = _log_exprel(l) - _log_exprel((1.0 - g) * l) - math.log(math.pi)
        log_d = log_c - g * jnp.log(ac * ac + s * s)
        return jnp.where(live, jnp.exp(jnp.minimum(log_d, 80.0)), 0.0)

    def G(self, cos_r, cos_i):
        a, _ = self._a()
        return _smith_g1_ggx(cos_r, a) * _smith_g1_ggx(cos_i, a)

    def sample_h(self, u):
        u1, u2 = _split(u)
        u1 = jnp.minimum(u1, U_MAX)
        _, l = self._a()
        s = 1.0 - self.gamma
        sl = s * l
        # q = ln(α^{2(1−γ)}(1−u) + u)/(1−γ), the log of the bracket raised to 1/(1−γ)
        near = jnp.abs(sl) < 1.0  # γ ≈ 1 or α ≈ 1: series-safe form
        sl_n = jnp.where(near, sl, 0.0)
        y = jnp.expm1(sl_n) * (1.0 - u1)
        q_over_l = (1.0 - u1) * _exprel(sl_n) * _log1prel(y)
        sl_f = jnp.where(near, 1.0, sl)
        s_f = jnp.where(near, 1.0, s)
        log_t = jnp.logaddexp(sl_f + jnp.log1p(-u1), jnp.log(jnp.maximum(u1, 1e-38)))
        q_far = log_t / s_f
        l_n = jnp.where(jnp.abs(l) > 0, l, -1.0)
        # cos² = expm1(q)/expm1(l) = (q/l) exprel(q)/exprel(l)
        q = jnp.where(near, q_over_l * l, q_far)
        ratio = jnp.where(near, q_over_l, q_far / l_n)
        c2 = jnp.where(jnp.abs(l) > 0, ratio * _exprel(q) / _exprel(l), 1.0 - u1)
        c2 = jnp.clip(c2, 0.0, 1.0)
        return _from_polar(jnp.sqrt(c2), safe_sqrt(1.0 - c2), 2 * jnp.pi * u2)


# ---------------------------------------------------------------- mixtures


class Mixture(Lobe):
    """Two lobes summed with weights ``weight`` and ``1 − weight``, sampled by that mixture.

    f = w f₁ + (1 − w) f₂; pdf = w p₁ + (1 − w) p₂ (one-sample MIS by the mixture,
    Veach 1997, §9.2.4). ``uc < w`` picks the first part. The sharp + haze lobe of
    polished metal is ``Mixture(GGX(α₁), GTR(α₂, γ), w)``; the paper's blend (eq. 5)
    is ``Mixture(Gaussian(μ0), GaussianVCavity(μ1), w)``. Two parts of the same
    class draw ONE facet normal from the per-sample selected parameters.
    """

    first: Lobe
    second: Lobe
    weight: Float[Array, "*p"]
    name: ClassVar[str] = "mixture"

    def terms_at(self, g: Geometry):
        w = self.weight
        return (tuple((w * a, c) for a, c in self.first.terms_at(g))
                + tuple(((1.0 - w) * a, c) for a, c in self.second.terms_at(g)))

    def pdf(self, L, V):
        return self.weight * self.first.pdf(L, V) + (1.0 - self.weight) * self.second.pdf(L, V)

    def pdf_h(self, phi, cos_phi):
        return self.weight * self.first.pdf_h(phi, cos_phi) + (1.0 - self.weight) * self.second.pdf_h(phi, cos_phi)

    def reflected_width(self) -> Float[Array, "*p"]:
        """σ = √(w σ₁² + (1 − w) σ₂²): the second moment of the mixture, that of its parts weighted.

        Exact for the mixture's pdf and for the f·cos of parts that each reflect
        the same energy at normal incidence (normalised lobes, to their
        ``O(σ²)`` albedo loss). For a sharp part over a wide haze one Gaussian
        is a coarse node scale: a cap rule resolves such a mixture better part
        by part, each at its own width.
        """
        w = self.weight
        return jnp.sqrt(w * self.first.reflected_width() ** 2 + (1.0 - w) * self.second.reflected_width() ** 2)

    def _pick(self, uc, draw):
        """The facet normal ``draw(part, uc_part)`` of the part ``uc`` picks.

        A part that is itself a :class:`Mixture` gets ``uc`` rescaled to [0, 1)
        within the picked interval (uc/w or (uc − w)/(1 − w)), so one uniform
        chooses among any number of nested parts. Two parts of the same class
        draw once, from the selected parameters.
        """
        w = self.weight
        use1 = uc < w
        a, b = self.first, self.second
        nested = isinstance(a, Mixture) or isinstance(b, Mixture)
        if not nested and type(a) is type(b) and jax.tree.structure(a) == jax.tree.structure(b):
            return draw(jax.tree.map(lambda x, y: jnp.where(use1, x, y), a, b), None)
        uc1 = jnp.clip(safe_div(uc, w), 0.0, U_MAX)
        uc2 = jnp.clip(safe_div(uc - w, 1.0 - w), 0.0, U_MAX)
        return jnp.where(use1[..., None], draw(a, uc1), draw(b, uc2))

    def sample_h(self, u, uc):
        """View-independent facet normal of the part ``uc`` picks (density :meth:`pdf_h`)."""
        a, b = self.first, self.second
        if isinstance(a, _GaussianBase) and isinstance(b, _GaussianBase):  # one Rayleigh sampler, two widths
            return _rayleigh_h(jnp.where(uc < self.weight, a.mu, b.mu), u)
        return self._pick(uc, lambda part, ucp: part.sample_h(u, ucp) if isinstance(part, Mixture)
                          else part.sample_h(u))

    def sample_facet(self, V, u, uc):
        """The facet normal :meth:`sample` reflects ``V`` about: that of the part ``uc`` picks."""
        a, b = self.first, self.second
        if isinstance(a, _GaussianBase) and isinstance(b, _GaussianBase):
            return self.sample_h(u, uc)
        return self._pick(uc, lambda part, ucp: part.sample_facet(V, u, ucp) if isinstance(part, Mixture)
                          else part.sample_facet(V, u))

    def sample(self, V, u, uc=None):
        if uc is None:
            raise ValueError("a Mixture needs the lobe-choice uniform uc")
        return _sampled(self, V, self.sample_facet(V, u, uc))


#: Lobes by name (``to_params()["lobe"]``).
LOBES: dict[str, type[Lobe]] = {c.name: c for c in (Gaussian, GaussianVCavity, Beckmann, GGX, GTR, Mixture)}


def lobe_from_params(params: dict, dtype=None) -> Lobe:
    """The lobe a ``to_params()`` dict describes (its ``"lobe"`` key names the class in :data:`LOBES`)."""
    name = params.get("lobe")
    if name not in LOBES:
        raise ValueError(f"unknown lobe {name!r}; known: {sorted(LOBES)}")
    return LOBES[name].from_params(params, dtype)


__all__ = ["LOBES", "Lobe", "Geometry", "Gaussian", "GaussianVCavity", "Beckmann", "GGX", "GTR", "Mixture", "reflect",
           "lobe_from_params"]
