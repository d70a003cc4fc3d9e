"""The green-channel forward models of eqs. (3)–(4), with parameter-free terms precomputed.

Mochizuki et al. fit, per region, the camera's green value ρg of

- eq. (3), hiraji: ρ = χ · D(φ, μ0) · F̄(θi)
- eq. (4), hamon:  ρ = β · D(φ, μ1) · F̄(θH) · G / cos θr

where D(φ, μ) = exp(−ln2 φ²/μ²) and F̄(θ) = F(n(λ), k(λ), θ) @ w is the
Fresnel reflectance integrated against the band weights w(λ) (camera green
sensitivity × light, :func:`jkatana.measure.camera.band_weights`; SPEC §4).

Everything that does not depend on the fitted parameters — F̄, G/cos θr and
φ — is computed once per table in float64 (:func:`prepare`); the model is then
``scale · D(φ, μ) · a`` with a per-point amplitude ``a`` and costs a few flops
per point. Two optional parameters beyond the paper's:

- **tilt** t (radians; reported in degrees): the sample is rotated by t in
  the plane of incidence, *positive towards the light* (the convention of
  :mod:`jkatana.measure.synthetic`). The surface sees θi' = θi − t,
  θr' = θr + t, so φ' = φ + t, θH unchanged, and the peak moves to
  θr = θi − 2t. With tilt on, F̄(θi') and G/cos θr' depend on δ
  and are evaluated from a fine 1-D table of F̄ (linear interpolation,
  4097 nodes over 0–90°, error < 1e-7 relative, measured in the tests).
- **floor** (camera units): a constant added to every value (stray light,
  black-level error).

Parameter vector (the fit's unknowns, in this order): ``[log scale, log μ,
tilt (rad), floor]`` where the last two are present only when switched on.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.models.microfacet import vcavity_over_cos

LN2 = math.log(2.0)
MODELS = ("hiraji", "hamon")
SCALE_NAME = {"hiraji": "chi", "hamon": "beta"}
_TABLE_NODES = 4097


@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """Which model and which optional parameters (static, hashable)."""

    model: str = "hiraji"
    tilt: bool = False
    floor: bool = False

    def __post_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")

    @property
    def names(self) -> tuple[str, ...]:
        """Natural-unit names of the parameters, in vector order."""
        out = [SCALE_NAME[self.model], "mu"]
        if self.tilt:
            out.append("tilt_deg")
        if self.floor:
            out.append("floor")
        return tuple(out)

    @property
    def size(self) -> int:
        return 2 + int(self.tilt) + int(self.floor)


class Terms(eqx.Module):
    """Parameter-free terms of one table (one point per entry; padded entries have weight 0).

    ``phi`` signed in-plane facet angle (rad); ``amp`` the amplitude F̄ (hiraji)
    or F̄(θH)·G/cos θr (hamon) at the nominal geometry; ``theta_i``, ``theta_r``
    (rad) for the tilt path; ``f_table`` F̄ on a uniform θ grid over [0, π/2].
    """

    phi: Float[Array, " n"]
    amp: Float[Array, " n"]
    theta_i: Float[Array, " n"]
    theta_r: Float[Array, " n"]
    f_table: Float[Array, " t"]


def _fbar_numpy(cos_theta, n, k, w):
    """F̄(θ) = F(n, k, θ) @ w in float64 with jkatana.models' exact conductor Fresnel."""
    from jkatana.models.fresnel import fresnel_conductor

    f = fresnel_conductor(jnp.asarray(cos_theta, jnp.float64)[..., None],
                          jnp.asarray(n, jnp.float64), jnp.asarray(k, jnp.float64))
    return np.asarray(f, np.float64) @ np.asarray(w, np.float64)


def _amplitude_numpy(model, theta_i, theta_r, fbar):
    """Amplitude a(θi, θr) for the model, numpy float64, from an F̄(θ) callable."""
    if model == "hiraji":
        return fbar(np.cos(theta_i))
    phi = 0.5 * (theta_r - theta_i)
    theta_h = 0.5 * (theta_i + theta_r)
    g = np.asarray(vcavity_over_cos(np.cos(phi), np.maximum(np.cos(theta_r), 0.0),
                                    np.maximum(np.cos(theta_i), 0.0), np.cos(theta_h)))
    return fbar(np.cos(theta_h)) * g


def prepare(model: str, theta_i_deg, theta_r_deg, n, k, weights, dtype=jnp.float64) -> Terms:
    """Precompute the parameter-free terms for a table's geometry.

    **Arguments:**

    - `model`: ``"hiraji"`` or ``"hamon"``.
    - `theta_i_deg`, `theta_r_deg`: ``(N,)`` incidence and receiving angles in
      degrees, goniometer plane (:func:`jkatana.models.in_plane`; θr = θi is
      specular).
    - `n`, `k`: optical constants on the spectral grid, ``(wl,)``.
    - `weights`: band weights ``(wl,)`` (:func:`jkatana.measure.camera.band_weights`).
    - `dtype`: dtype of the returned arrays (the terms are computed in float64).

    **Returns:** :class:`Terms`.
    """
    ti = np.deg2rad(np.asarray(theta_i_deg, np.float64))
    tr = np.deg2rad(np.asarray(theta_r_deg, np.float64))
    grid_theta = np.linspace(0.0, np.pi / 2, _TABLE_NODES)
    with jax.enable_x64(True):
        table = _fbar_numpy(np.cos(grid_theta), n, k, weights)
        amp = np.asarray(_amplitude_numpy(model, ti, tr, lambda c: _fbar_numpy(c, n, k, weights)),
                         np.float64)
    visible = (np.cos(ti) >= 0) & (np.cos(tr) >= 0)
    amp = np.where(visible, amp, 0.0)
    return Terms(phi=jnp.asarray(0.5 * (tr - ti), dtype), amp=jnp.asarray(amp, dtype),
                 theta_i=jnp.asarray(ti, dtype), theta_r=jnp.asarray(tr, dtype),
                 f_table=jnp.asarray(table, dtype))


def _interp_fbar(theta, table):
    theta = jnp.clip(jnp.abs(theta), 0.0, jnp.pi / 2)
    x = theta * ((table.shape[0] - 1) / (jnp.pi / 2))
    i = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, table.shape[0] - 2)
    t = x - i.astype(x.dtype)
    return table[i] * (1 - t) + table[i + 1] * t


def _facet(phi, mu):
    """D(φ, μ) with the exponent clipped where exp underflows (finite value and gradient)."""
    dtype = jnp.result_type(phi, mu)
    cut = float(-np.log(np.finfo(dtype).tiny)) * 0.99
    x = LN2 * (phi / mu) ** 2
    xs = jnp.minimum(x, cut)
    return jnp.where(x < cut, jnp.exp(-xs), 0.0)


def green(p: Float[Array, " p"], terms: Terms, spec: ModelSpec) -> Float[Array, " n"]:
    """Model green values for the parameter vector ``p`` (module docstring)."""
    scale = jnp.exp(p[0])
    mu = jnp.exp(p[1])
    j = 2
    if spec.tilt:
        delta = p[j]
        j += 1
        ti = terms.theta_i - delta
        tr = terms.theta_r + delta
        phi = terms.phi + delta
        if spec.model == "hiraji":
            amp = _interp_fbar(ti, terms.f_table)
        else:
            th = 0.5 * (ti + tr)
            g = vcavity_over_cos(jnp.cos(phi), jnp.maximum(jnp.cos(tr), 0.0),
                                 jnp.maximum(jnp.cos(ti), 0.0), jnp.cos(th))
            amp = _interp_fbar(th, terms.f_table) * g
        amp = jnp.where((jnp.cos(ti) >= 0) & (jnp.cos(tr) >= 0), amp, 0.0)
    else:
        phi, amp = terms.phi, terms.amp
    out = scale * _facet(phi, mu) * amp
    if spec.floor:
        out = out + p[j]
    return out


def to_natural(p, spec: ModelSpec) -> dict[str, float]:
    """Parameter vector → natural units (``tilt_deg`` in degrees)."""
    p = np.asarray(p, np.float64)
    out = {spec.names[0]: float(np.exp(p[0])), "mu": float(np.exp(p[1]))}
    j = 2
    if spec.tilt:
        out["tilt_deg"] = float(np.rad2deg(p[j]))
        j += 1
    if spec.floor:
        out["floor"] = float(p[j])
    return out


def from_natural(values: dict, spec: ModelSpec) -> np.ndarray:
    """Natural units → parameter vector (inverse of :func:`to_natural`)."""
    out = [math.log(values[spec.names[0]]), math.log(values["mu"])]
    if spec.tilt:
        out.append(math.radians(values.get("tilt_deg", 0.0)))
    if spec.floor:
        out.append(float(values.get("floor", 0.0)))
    return np.asarray(out, np.float64)


__all__ = ["ModelSpec", "Terms", "prepare", "green", "to_natural", "from_natural", "MODELS", "SCALE_NAME"]
