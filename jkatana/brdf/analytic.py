"""Analytic BRDFs of the fitted models, for writing measured-BRDF files whose truth is known.

:func:`analytic_brdf` turns a model of :data:`jkatana.models.fitted.FIT_MODELS`
with natural parameter values into ``f(wi, wo) → (..., C)`` — the BRDF in the
fit's camera units per unit irradiance, one column per camera channel — by
the same lobe objects (:mod:`jkatana.models.lobes`) and band-integrated
Fresnel F̄ the fit uses: f_r = s · Σ_j a_j F̄_c(cos_F_j) / cos θi. Slicing it
in a protocol therefore gives exactly the fit's forward model, so a round
trip (write MERL / ``.bsdf`` / table → read → slice → fit) tests the file
formats and the slicing, not a model mismatch. :func:`lobe_ndf` gives the
lobe's facet distribution for the ``.bsdf`` writer.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def _spec_and_lobe(model: str, values: dict):
    from jkatana.models.fitted import ModelSpec, from_natural

    spec = ModelSpec(model)
    p = from_natural(values, spec)
    return spec, p


def analytic_brdf(model: str, values: dict, *, setup=None, channels=("red", "green", "blue")):
    """``f(wi, wo) → (..., len(channels))`` for ``model`` at ``values`` (module docstring).

    `setup`: a :class:`jkatana.measure.setup.Setup` (optical constants, grid,
    light); its camera names the colour-science camera whose ``channels`` are
    used (``"NAME:channel"``).
    """
    from jkatana.measure.camera import band_weights, camera_sensitivity, light_spectrum
    from jkatana.measure.setup import Setup
    from jkatana.models.fresnel import fbar_numpy

    setup = Setup() if setup is None else setup
    spec, p = _spec_and_lobe(model, values)
    n, k = setup.nk()
    cam = str(setup.camera).rpartition(":")[0] or str(setup.camera)
    grid_cos = np.linspace(0.0, 1.0, 4097)
    tables = []
    with jax.enable_x64(True):
        E = light_spectrum(setup.light, setup.grid)
        for ch in channels:
            w = band_weights(E, camera_sensitivity(f"{cam}:{ch}", setup.grid), setup.grid)
            tables.append(fbar_numpy(grid_cos, n, k, w))
    tables = np.stack(tables)  # (C, 4097)
    scale = float(np.exp(p[0]))

    def f(wi, wo):
        with jax.enable_x64(True):
            lobe = spec.fit_model.build(jnp.asarray(p[1:1 + spec.n_shape], jnp.float64))
            L = jnp.asarray(wi, jnp.float64)
            V = jnp.asarray(wo, jnp.float64)
            total = 0.0
            for a, c in lobe.terms(L, V):
                fb = np.stack([np.interp(np.clip(np.asarray(c), 0, 1), grid_cos, t) for t in tables], -1)
                total = total + np.asarray(a)[..., None] * fb
            cos_i = np.asarray(L[..., 2])
            out = scale * total / np.where(cos_i > 0, cos_i, 1.0)[..., None]
            return np.where((cos_i > 0)[..., None], out, 0.0)

    return f


def lobe_ndf(model: str, values: dict, floor: float = 1e-3):
    """``D(cos θm)`` of the model's lobe (relative), plus ``floor`` × its peak.

    The floor gives the ``.bsdf`` writer's warp some mass in the lobe's tails,
    so its tables resolve them (the reflectance table compensates exactly).
    """
    from jkatana.models import lobes as LB
    from jkatana.models.microfacet import gaussian_facet

    spec, p = _spec_and_lobe(model, values)

    def one(lobe, phi, c):
        if isinstance(lobe, LB.Mixture):
            return lobe.weight * one(lobe.first, phi, c) + (1 - lobe.weight) * one(lobe.second, phi, c)
        if hasattr(lobe, "D"):
            return lobe.D(phi, c)
        return gaussian_facet(phi, lobe.mu)

    def D(cos_m):
        with jax.enable_x64(True):
            lobe = spec.fit_model.build(jnp.asarray(p[1:1 + spec.n_shape], jnp.float64))
            c = jnp.clip(jnp.asarray(cos_m, jnp.float64), 0.0, 1.0)
            phi = jnp.arccos(c)
            d = np.asarray(one(lobe, phi, c), np.float64)
            peak = float(np.asarray(one(lobe, jnp.zeros(()), jnp.ones(()))))
            return d + floor * peak

    return D


__all__ = ["analytic_brdf", "lobe_ndf"]
