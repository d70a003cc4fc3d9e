"""The fitted forward model: a lobe of :mod:`jkatana.models.lobes` in camera units, with the instrument's response.

Every model is ``ρ = s · Σ_j a_j(L, V) · F̄(cos_F_j) [+ floor]``, where the
lobe's :meth:`~jkatana.models.lobes.Lobe.terms` give f_r cos θi without the
Fresnel factor as terms ``(a_j, cos_F_j)``, F̄(cos θ) = F(n(λ), k(λ), θ) @ w
is the Fresnel reflectance integrated against the band weights w(λ) (camera
sensitivity × light, :func:`jkatana.measure.camera.band_weights`; SPEC §4),
tabulated once per table on a uniform grid of cos θ (4097 nodes, linear
interpolation) and s is a scale in camera units. The lobe formulas live in
:mod:`jkatana.models.lobes` only; this module chooses how each lobe's
parameters are fitted (:data:`FIT_MODELS`):

| model | lobe | natural parameters | fitted as |
| --- | --- | --- | --- |
| ``hiraji`` | paper eq. (1), calibrated ``Gaussian`` | χ, μ | log χ, log μ |
| ``hamon`` | paper eq. (2), calibrated ``GaussianVCavity`` | β, μ | log β, log μ |
| ``beckmann`` | ``Beckmann`` | scale, α | log, log |
| ``ggx`` | ``GGX`` | scale, α | log, log |
| ``gtr`` | ``GTR`` (heavy tails for γ < 2) | scale, α, γ | log, log, γ = 1 + 3·sigmoid |
| ``two-lobe`` | ``Mixture(GGX(α), GGX(α_haze), w)`` | scale, α, α_haze, w | log, log, α_haze = α(1 + eᵗ), w = sigmoid |

The paper's models are eqs. (3)–(4) of Mochizuki et al. exactly: ρ = χ D(φ, μ0)
F̄(θi) and ρ = β D(φ, μ1) F̄(θH) G / cos θr.

Options beyond the paper (:class:`ModelSpec`):

- **tilt** t (radians; reported in degrees): the sample is rotated by t in
  the plane of incidence, *positive towards the light* (the convention of
  :mod:`jkatana.measure.synthetic`): L and V are rotated about the y axis by
  t, so θi' = θi − t, θr' = θr + t and the peak moves to θr = θi − 2t.
- **floor** (camera units): a constant added to every value (stray light,
  black-level error).
- **instrument** ``(source_radius, aperture_radius, n)`` (radians): the
  source's angular radius and the detector aperture's angular radius seen
  from the sample. The model is averaged over uniform disks of directions
  around L and around V, each by an n-point Vogel (1979) sunflower rule
  (equal weights; deterministic, so fits stay smooth), i.e. the lobe
  convolved with the instrument's angular response: a lobe narrower than the
  instrument is fitted as what the instrument saw.

Parameter vector (the fit's unknowns, in this order): ``[log scale, log width,
shape…, tilt (rad), floor]`` where tilt and floor are present only when on.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.models.fitted import (FIT_MODELS, MODELS, SCALE_NAME, SHAPE_NAMES, FitModel, ModelSpec,  # noqa: F401
                                   _sigmoid, build_lobe, default_shape, from_natural, to_natural)
from jkatana.models.fresnel import fbar_many as _fbar_many
from jkatana.models.lobes import Geometry
from jkatana.models.microfacet import vcavity_over_cos

_TABLE_NODES = 4097


class Terms(eqx.Module):
    """Parameter-free arrays of one table (one point per entry; padded entries have weight 0).

    ``L``, ``V`` unit directions ``(n, 3)`` at the nominal geometry; ``phi``
    the signed in-plane facet angle (rad) and ``amp`` the paper models'
    amplitude (F̄ for hiraji, F̄(θH)·G/cos θr for hamon; 1 for other lobes) at
    the nominal geometry, used by the closed-form start; ``theta_i``,
    ``theta_r`` (rad); ``f_table`` F̄ on a uniform grid of cos θ over [0, 1];
    ``f_exact`` ``[cos, F̄, dF̄/dcos]`` exact at the nominal cos θi and cos θH
    of each point, so that models evaluated at the nominal geometry use F̄
    to float64 rounding rather than to the table's interpolation error (~1e-9);
    ``geo`` the nominal directions' :class:`~jkatana.models.lobes.Geometry`
    (its cos θi and cos θH are ``f_exact``'s cosines), from which a model
    without a tilt evaluates its lobe without recomputing the half vector.
    """

    phi: Float[Array, " n"]
    amp: Float[Array, " n"]
    theta_i: Float[Array, " n"]
    theta_r: Float[Array, " n"]
    f_table: Float[Array, " t"]
    L: Float[Array, "n 3"]
    V: Float[Array, "n 3"]
    f_exact: Float[Array, "2 3 n"]
    geo: Geometry


def _amplitude_cos(model, theta_i, theta_r):
    """The cosine at which the paper's model ``model`` takes F̄ (cos θi for hiraji, cos θH for hamon), else None."""
    if model == "hiraji":
        return np.cos(theta_i)
    if model == "hamon":
        return np.cos(0.5 * (theta_i + theta_r))
    return None


@jax.jit
def _vcavity_numpy(cos_phi, cos_r, cos_i, cos_h):
    return vcavity_over_cos(cos_phi, cos_r, cos_i, cos_h)


def _amplitude_numpy(model, theta_i, theta_r, fbar):
    """Amplitude a(θi, θr) of the paper's models (numpy float64) for the closed-form start; ``fbar`` F̄ at
    :func:`_amplitude_cos` (None for other models)."""
    if model == "hiraji":
        return fbar
    if model != "hamon":
        return np.ones_like(theta_i)
    phi = 0.5 * (theta_r - theta_i)
    theta_h = 0.5 * (theta_i + theta_r)
    with jax.enable_x64(True):
        g = np.asarray(_vcavity_numpy(np.cos(phi), np.maximum(np.cos(theta_r), 0.0),
                                      np.maximum(np.cos(theta_i), 0.0), np.cos(theta_h)))
    return fbar * g


@functools.partial(jax.jit, static_argnames=("dtype",))
def _geometry(L, V, dtype):
    return Geometry.of(L.astype(dtype), V.astype(dtype))


def prepare(model: str, theta_i_deg, theta_r_deg, n, k, weights, dtype=jnp.float64, *,
            azimuth_deg=None) -> Terms:
    """Precompute the parameter-free terms for a table's geometry.

    **Arguments:**

    - `model`: a name of :data:`FIT_MODELS`.
    - `theta_i_deg`, `theta_r_deg`: ``(N,)`` incidence and receiving angles in
      degrees, goniometer plane (:func:`jkatana.models.in_plane`; θr = θi is
      specular).
    - `n`, `k`: optical constants on the spectral grid, ``(wl,)``.
    - `weights`: band weights ``(wl,)`` (:func:`jkatana.measure.camera.band_weights`).
    - `dtype`: dtype of the returned arrays (the terms are computed in float64).
    - `azimuth_deg`: receiver azimuth out of the plane of incidence
      (:mod:`jkatana.brdf.geometry`; default 0, in plane).

    **Returns:** :class:`Terms`.
    """
    from jkatana.brdf.geometry import goniometer_vectors

    ti = np.deg2rad(np.asarray(theta_i_deg, np.float64))
    tr = np.deg2rad(np.asarray(theta_r_deg, np.float64))
    az = np.zeros_like(ti) if azimuth_deg is None else np.asarray(azimuth_deg, np.float64)
    grid_cos = np.linspace(0.0, 1.0, _TABLE_NODES)
    visible = (np.cos(ti) >= 0) & (np.cos(tr) >= 0)
    Lv, Vv = goniometer_vectors(np.rad2deg(ti), np.rad2deg(tr), az)
    with jax.enable_x64(True):
        geo = _geometry(Lv, Vv, np.dtype(dtype))
    h = 1e-6
    nominal = [np.asarray(c, np.float64) for c in (geo.cos_i, geo.cos_th)]
    amp_cos = _amplitude_cos(model, ti, tr)
    cosines = [grid_cos, *([] if amp_cos is None else [amp_cos])]
    first = len(cosines)  # (c + h, c − h, c) per nominal cosine from here on
    for c in nominal:
        cosines += [np.minimum(c + h, 1.0), np.maximum(c - h, 0.0), c]
    fb = _fbar_many(cosines, n, k, weights)  # every lookup of this table in one compiled program
    table = fb[0]
    amp = np.asarray(_amplitude_numpy(model, ti, tr, None if amp_cos is None else fb[1]), np.float64)
    amp = np.where(visible, amp, 0.0)
    exact = []
    for j, c in enumerate(nominal):
        up, down, at = fb[first + 3 * j: first + 3 * j + 3]
        d = (up - down) / (np.minimum(c + h, 1.0) - np.maximum(c - h, 0.0))
        exact.append(np.stack([c, at, d]))
    return Terms(f_exact=jnp.asarray(np.stack(exact), dtype), phi=jnp.asarray(0.5 * (tr - ti), dtype), amp=jnp.asarray(amp, dtype),
                 theta_i=jnp.asarray(ti, dtype), theta_r=jnp.asarray(tr, dtype),
                 f_table=jnp.asarray(table, dtype), L=jnp.asarray(Lv, dtype), V=jnp.asarray(Vv, dtype),
                 geo=geo)


def fbar(cos_theta, table):
    """F̄ at ``cos_theta`` from the uniform-in-cos table (linear interpolation, clipped to [0, 1])."""
    c = jnp.clip(cos_theta, 0.0, 1.0)
    x = c * (table.shape[0] - 1)
    i = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, table.shape[0] - 2)
    t = x - i.astype(x.dtype)
    return table[i] * (1 - t) + table[i + 1] * t


def _rot_y(v, t):
    c, s = jnp.cos(t), jnp.sin(t)
    return jnp.stack([v[..., 0] * c + v[..., 2] * s, v[..., 1], -v[..., 0] * s + v[..., 2] * c], axis=-1)


def disk_offsets(radius: float, n: int) -> np.ndarray:
    """``(n, 2)`` tangent-plane offsets (radians) filling a disk of ``radius`` uniformly (Vogel 1979 spiral)."""
    j = np.arange(n) + 0.5
    r = radius * np.sqrt(j / n)
    a = j * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(a), r * np.sin(a)], -1) if n > 1 else np.zeros((1, 2))


def _perturb(d, offsets):
    """Directions ``(k, n, 3)``: unit ``d (n, 3)`` moved by tangent-plane ``offsets (k, 2)`` (radians)."""
    y = jnp.asarray([0.0, 1.0, 0.0], d.dtype)
    e1 = jnp.cross(y, d)
    e1 = e1 / jnp.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = jnp.cross(d, e1)
    off = jnp.asarray(offsets, d.dtype)
    out = d[None] + off[:, 0, None, None] * e1[None] + off[:, 1, None, None] * e2[None]
    return out / jnp.linalg.norm(out, axis=-1, keepdims=True)


def _fbar_point(c, terms):
    """F̄ at the terms' cosines: exact (first-order about the nominal cos θi or cos θH) within 1e-9, else the table."""
    out = fbar(c, terms.f_table)
    for j in range(2):
        c0, f0, d0 = terms.f_exact[j, 0], terms.f_exact[j, 1], terms.f_exact[j, 2]
        out = jnp.where(jnp.abs(c - c0) < 1e-9, f0 + d0 * (c - c0), out)
    return out


class At(eqx.Module):
    """Where a model is evaluated: the directions' :class:`~jkatana.models.lobes.Geometry` and F̄ at its
    cos θi and cos θH (``fresnel[0]``, ``fresnel[1]``), all parameter-free unless the tilt is fitted.

    Built once per table and spec by :func:`evaluation_point` (a solver passes it to every step, so the half
    vector and the Fresnel lookups are not recomputed per step); :func:`green` builds it itself when not given.
    """

    geo: Geometry
    fresnel: Float[Array, "2 *b"]


def _at(geo: Geometry, terms: Terms, nominal: bool) -> At:
    if nominal:  # the nominal cosines are f_exact's own: F̄ there exactly
        return At(geo, terms.f_exact[:, 1])
    return At(geo, jnp.stack([_fbar_point(geo.cos_i, terms), _fbar_point(geo.cos_th, terms)]))


def evaluation_point(terms: Terms, spec: ModelSpec, tilt=None) -> At:
    """The :class:`At` of the model for ``spec`` on ``terms``' directions: nominal (``terms.geo``), rotated by
    ``tilt`` (radians; required when ``spec.tilt``), and over the instrument's disks of directions."""
    if spec.tilt and tilt is None:
        raise ValueError("a tilted model's evaluation point depends on the tilt")
    L, V = terms.L, terms.V
    if spec.tilt:
        L, V = _rot_y(L, tilt), _rot_y(V, tilt)
    if spec.instrument is not None:
        src, ap, n = spec.instrument
        Ls = _perturb(L, disk_offsets(src, n if src > 0 else 1))
        Vs = _perturb(V, disk_offsets(ap, n if ap > 0 else 1))
        return _at(Geometry.of(Ls[:, None], Vs[None, :]), terms, False)
    if spec.tilt:
        return _at(Geometry.of(L, V), terms, False)
    return _at(terms.geo, terms, True)


def _lobe_value(lobe, at: At, terms: Terms):
    """Σ_j a_j F̄(cos_F_j): F̄ from ``at`` where a term's Fresnel cosine is the geometry's cos θi or cos θH
    (every lobe of :mod:`jkatana.models.lobes`), else looked up."""
    total = 0.0
    for a, c in lobe.terms_at(at.geo):
        if c is at.geo.cos_i:
            f = at.fresnel[0]
        elif c is at.geo.cos_th:
            f = at.fresnel[1]
        else:
            f = _fbar_point(c, terms)
        total = total + a * f
    return total


def green(p: Float[Array, " p"], terms: Terms, spec: ModelSpec, at: At | None = None) -> Float[Array, " n"]:
    """Model values in camera units for the parameter vector ``p`` (module docstring).

    `at`: :func:`evaluation_point` of ``terms`` and ``spec``, when the caller has it (not with a tilt).
    """
    fm = spec.fit_model
    scale = jnp.exp(p[0])
    if at is None or spec.tilt:
        at = evaluation_point(terms, spec, p[spec.tilt_index] if spec.tilt else None)
    q = p[1:1 + spec.n_shape]
    if spec.tilt:  # the evaluation point depends on the parameters: plain forward-mode derivative
        val = _unit_value(q, terms, at, spec)
    elif fm.name == "two-lobe":
        val = _two_lobe_value(q, terms, at, spec)
    else:
        val = _shape_value(q, terms, at, spec)
    out = scale * val
    if spec.floor:
        out = out + p[spec.floor_index]
    return out


def mixture_parts(log_width, terms: Terms, spec: ModelSpec, at: At | None = None) -> Float[Array, " n"]:
    """The first part of a two-lobe model at width ``exp(log_width)``, unit scale and weight (its lobe from
    :meth:`FitModel.build`; instrument-averaged like :func:`green`), for a start that fits the parts'
    amplitudes linearly. The two-lobe model's parts are of one family (GGX), so this is also its second part
    at that width. Evaluated at zero tilt (`at`: :func:`evaluation_point` of the untilted spec)."""
    lobe = spec.fit_model.build(default_shape(spec, log_width, log_width.dtype))
    at = evaluation_point(terms, dataclasses.replace(spec, tilt=False)) if at is None else at
    val = _lobe_value(lobe.first, at, terms)
    return jnp.mean(val, axis=(0, 1)) if spec.instrument is not None else val


def _unit_value(q, terms: Terms, at: At, spec: ModelSpec):
    """The model's lobe at shape vector ``q`` with unit scale, instrument-averaged, at ``at``."""
    val = _lobe_value(spec.fit_model.build(q), at, terms)
    return jnp.mean(val, axis=(0, 1)) if spec.instrument is not None else val


@functools.partial(jax.custom_jvp, nondiff_argnums=(3,))
def _shape_value(q, terms: Terms, at: At, spec: ModelSpec):
    """:func:`_unit_value` whose derivative is its Jacobian in ``q`` alone: a solver's Jacobian of
    ``s·f(q)`` then pushes one tangent per shape parameter through the lobe, not one per fitted parameter
    (the scale's column is the value itself; the table's arrays are constants)."""
    return _unit_value(q, terms, at, spec)


@_shape_value.defjvp
def _shape_jvp(spec, primals, tangents):
    """The value and its Jacobian in ``q`` from one linearisation: the lobe's value is evaluated once and its
    linear map applied to each unit vector (``jacfwd`` beside a separate primal call evaluated the value twice)."""
    q, terms, at = primals
    val, lin = jax.linearize(lambda q: _unit_value(q, terms, at, spec), q)
    jac = jax.vmap(lin, out_axes=-1)(jnp.eye(q.shape[0], dtype=q.dtype))
    return val, jac @ tangents[0]


def _two_lobe_logs(q):
    """log α₁, log α₂ and w of the two-lobe shape vector ``q``: :meth:`FitModel.build`'s map (module table),
    in log form for the chain rule."""
    return q[0], q[0] + jnp.logaddexp(0.0, q[1]), _sigmoid(q[2])


@functools.partial(jax.custom_jvp, nondiff_argnums=(3,))
def _two_lobe_value(q, terms: Terms, at: At, spec: ModelSpec):
    """The two-lobe model's unit-scale value w·f(α₁) + (1 − w)·f(α₂) at shape vector ``q`` (module table), with
    its derivative by the chain rule through the parts (:func:`_two_lobe_jvp`)."""
    l1, l2, w = _two_lobe_logs(q)
    return w * mixture_parts(l1, terms, spec, at) + (1.0 - w) * mixture_parts(l2, terms, spec, at)


@_two_lobe_value.defjvp
def _two_lobe_jvp(spec, primals, tangents):
    """Each part depends on one width only, so the derivative in the three shape parameters needs each part's
    derivative in its own log width (one forward-mode tangent per part) instead of three tangents through both
    parts: log α₁ = q₀, log α₂ = q₀ + log(1 + e^{q₁}), w = sigmoid(q₂). The table's arrays are constants."""
    q, terms, at = primals
    dq = tangents[0]
    l1, l2, w = _two_lobe_logs(q)
    part = lambda t: mixture_parts(t, terms, spec, at)  # noqa: E731
    f1, d1 = jax.jvp(part, (l1,), (jnp.ones_like(l1),))
    f2, d2 = jax.jvp(part, (l2,), (jnp.ones_like(l2),))
    dl2 = dq[0] + _sigmoid(q[1]) * dq[1]
    return (w * f1 + (1.0 - w) * f2,
            w * d1 * dq[0] + (1.0 - w) * d2 * dl2 + w * (1.0 - w) * dq[2] * (f1 - f2))


__all__ = ["ModelSpec", "Terms", "FitModel", "FIT_MODELS", "prepare", "green", "to_natural", "from_natural",
           "MODELS", "SCALE_NAME", "SHAPE_NAMES", "fbar", "disk_offsets", "default_shape", "At",
           "evaluation_point", "mixture_parts"]
