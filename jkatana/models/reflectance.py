"""The paper's reflection models: hiraji (eq. 1), hamon (eq. 2), blend (eq. 5).

Mochizuki, Hayashi, Sarashina, Tanaka, Woo, "A Rendering Method for Japanese
Swords Based on Measured Data", Nagano University:

- eq. (1), hiraji (平地, the mirror-like flat):
  C(λ) = χ · D(φ, μ0) · F(n(λ), k(λ), θi) · E(λ)
- eq. (2), hamon (刃紋, the temper line), Torrance–Sparrow (1967):
  C(λ) = β · F(n(λ), k(λ), θH) · D(φ, μ1) · G(N, V, L) / cos θr · E(λ)
- eq. (5), spatial blend: C = w C_f + (1 − w) C_t.

Two unit conventions (SPEC §3), chosen explicitly:

**Camera units** (:meth:`Hiraji.camera`, :meth:`Hamon.camera`): the paper's
equations as printed; χ and β are in camera units (χ = 79000, β = 43000 for
the green channel in the paper). Used for fitting measurements.

**Rendering** (:meth:`Hiraji.brdf_cos`, :meth:`Hamon.brdf_cos`): returns
f_r(L, V)·cos θi, the factor that multiplies incident radiance in the
rendering equation. Two ways to get absolute units:

- ``calibration=K`` (camera units per unit radiance of the source seen
  directly by the same camera, e.g. through a reference mirror or a white
  standard): f_r cos θi = C(λ) / (K · E(λ)), i.e. the fitted χ, β used as is.
- ``calibration=None`` (default, no calibration available): the lobe is
  *normalised* so that as μ → 0 it tends to a perfect mirror of reflectance
  F — the scale χ or β is replaced by the microfacet normalisation
  N(μ)/(4 cos θH) (hiraji) or N(μ)/4 (hamon), with N(μ) from
  :func:`~jkatana.models.microfacet.gaussian_normalisation`. Then
  ∫ f_r cos θi dω_i → F(θ) as μ → 0 (Walter et al. 2007, eq. 20 with the
  paper's D). Only the lobe *shapes* (μ0, μ1) and n, k come from the fit.

Directions are in the local shading frame (N = +z), see
:mod:`jkatana.models.geometry`. All functions broadcast any batch shape and
return a trailing wavelength axis.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jkatana.models.fresnel import fresnel_conductor
from jkatana.models.lobes import Gaussian, GaussianVCavity
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid


class Conductor(eqx.Module):
    """Optical constants n(λ), k(λ) on a wavelength grid (last axis = wavelength)."""

    n: Float[Array, "*c wl"]
    k: Float[Array, "*c wl"]

    @classmethod
    def from_table(cls, source: str = "Fe-Johnson", grid: WavelengthGrid = DEFAULT_GRID,
                   dtype=jnp.float64) -> "Conductor":
        """From a shipped or user refractiveindex.info table, interpolated to ``grid``."""
        from jkatana.spectral.optical_constants import load

        n, k = load(source).on_grid(grid)
        return cls(jnp.asarray(n, dtype), jnp.asarray(k, dtype))

    def fresnel(self, cos_theta: Float[ArrayLike, "*b"]) -> Float[Array, "*b wl"]:
        """F(n(λ), k(λ), θ) for every λ: ``(*b,)`` cosines → ``(*b, wl)``, in the precision of n, k."""
        return fresnel_conductor(jnp.asarray(cos_theta, self.n.dtype)[..., None], self.n, self.k)


def _spectral(x, E):
    return x if E is None else x * E


def _lobe_times_fresnel(lobe, cos_theta, conductor: "Conductor"):
    """``lobe[..., None] * F(cos θ, λ)``: geometry once per pair, Fresnel once per (pair, λ).

    The ``optimization_barrier`` keeps XLA from fusing the per-pair geometry
    (atan2, exp, the shadowing term) into the per-wavelength loop, where it
    would be recomputed for every wavelength (``benchmarks/bench_models.py``
    times it). Values and gradients are unchanged (the barrier is an identity).
    """
    lobe, cos_theta = jax.lax.optimization_barrier((lobe, cos_theta))
    return lobe[..., None] * conductor.fresnel(cos_theta)


class Hiraji(eqx.Module):
    """Paper eq. (1): χ D(φ, μ0) F(θi) E(λ). Defaults are the paper's fit.

    The lobe itself is :class:`jkatana.models.lobes.Gaussian`; this class adds the
    paper's camera-unit scale χ and the two rendering conventions.
    """

    chi: Float[ArrayLike, "*#p"] = 79000.0
    mu: Float[ArrayLike, "*#p"] = 0.05

    def lobe(self, calibration: float | None = None) -> Gaussian:
        """The rendering lobe: normalised (``calibration=None``) or with scale χ/K."""
        if calibration is None:
            return Gaussian(self.mu)
        return Gaussian(self.mu, self.chi / calibration, normalised=False)

    def camera(self, L: Float[ArrayLike, "*#b 3"], V: Float[ArrayLike, "*#b 3"], conductor: Conductor,
               E: Float[ArrayLike, "wl"] | None = None) -> Float[Array, "*#b wl"]:
        """Eq. (1) in camera units: χ · D(φ, μ0) · F(θi) [· E(λ)]."""
        ((a, c),) = Gaussian(self.mu, self.chi, normalised=False).terms(L, V)
        return _spectral(_lobe_times_fresnel(a, c, conductor), E)

    def brdf_cos(self, L, V, conductor: Conductor, calibration: float | None = None
                 ) -> Float[Array, "*#b wl"]:
        """f_r cos θi for rendering (module docstring: calibrated or normalised)."""
        ((a, c),) = self.lobe(calibration).terms(L, V)
        return _lobe_times_fresnel(a, c, conductor)


class Hamon(eqx.Module):
    """Paper eq. (2), Torrance–Sparrow: β F(θH) D(φ, μ1) G / cos θr E(λ).

    The lobe itself is :class:`jkatana.models.lobes.GaussianVCavity`.
    """

    beta: Float[ArrayLike, "*#p"] = 43000.0
    mu: Float[ArrayLike, "*#p"] = 0.05

    def lobe(self, calibration: float | None = None) -> GaussianVCavity:
        """The rendering lobe: normalised (``calibration=None``) or with scale β/K."""
        if calibration is None:
            return GaussianVCavity(self.mu)
        return GaussianVCavity(self.mu, self.beta / calibration, normalised=False)

    def camera(self, L, V, conductor: Conductor, E=None) -> Float[Array, "*#b wl"]:
        """Eq. (2) in camera units: β · F(θH) · D(φ, μ1) · G / cos θr [· E(λ)]."""
        ((a, c),) = GaussianVCavity(self.mu, self.beta, normalised=False).terms(L, V)
        return _spectral(_lobe_times_fresnel(a, c, conductor), E)

    def brdf_cos(self, L, V, conductor: Conductor, calibration: float | None = None):
        """f_r cos θi for rendering: Cook–Torrance F D̂ G /(4 cos θr) with D̂ = N(μ) D, or β/K."""
        ((a, c),) = self.lobe(calibration).terms(L, V)
        return _lobe_times_fresnel(a, c, conductor)


def blend(w: Float[ArrayLike, "*#b"], c_f: Float[ArrayLike, "*#b wl"], c_t: Float[ArrayLike, "*#b wl"]):
    """Eq. (5): w C_f + (1 − w) C_t, w = 1 mirror-like (hiraji), 0 rough (hamon)."""
    w = jnp.asarray(w)[..., None]
    return w * c_f + (1.0 - w) * c_t


#: The paper's fitted values (camera green-channel units), Mochizuki et al. §6.1.
PAPER_HIRAJI = dict(chi=79000.0, mu=0.05)
PAPER_HAMON = dict(beta=43000.0, mu=0.05)


def paper_models(dtype=jnp.float64) -> tuple[Hiraji, Hamon]:
    """Hiraji and Hamon with the paper's parameters as ``dtype`` scalars."""
    return (Hiraji(*(jnp.asarray(v, dtype) for v in PAPER_HIRAJI.values())),
            Hamon(*(jnp.asarray(v, dtype) for v in PAPER_HAMON.values())))


__all__ = ["Conductor", "Hiraji", "Hamon", "blend", "paper_models", "PAPER_HIRAJI", "PAPER_HAMON"]
