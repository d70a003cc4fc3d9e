"""Spectral shading of G-buffer pixels under an environment (JAX, jitted).

Every visible pixel carries a normal N, a view direction V (towards the
camera) and the reflectance-map parameters at its UV (w, μ0, μ1). The
outgoing radiance is the rendering equation with the paper's blended BRDF
(Mochizuki et al., eq. 5)::

    L_o(λ) = ∫ [w f_hiraji + (1 − w) f_hamon](L, V, λ) cos θi L_env(L, λ) dL
             + Σ_lights f(L_j, V, λ) cos θi E_j(λ) / r_j²

with f·cos θi from :meth:`jkatana.models.Hiraji.brdf_cos` /
:meth:`jkatana.models.Hamon.brdf_cos` (normalised convention unless a
calibration is given). The integral is estimated by one of four modes, all
static (trace-time) choices recorded in a :class:`Plan`:

- ``"reference"`` — importance sampling of the lobe mixture (Gaussian facet
  normals, exact pdf) and of the environment (piecewise-constant luminance
  density), combined with multiple importance sampling, balance heuristic
  (Veach & Guibas 1995). Unbiased; its error is measured against a converged
  frame by ``benchmarks/bench_render.py``.
- ``"paper"`` — the paper's method (§5): a fixed number of jittered reflection
  rays around the mirror direction (stratified facet normals in a disk of
  radius 2.5 μ), averaged with Gaussian weights D(φ, μ). Biased (truncated,
  self-normalised) but cheap; 30 rays in the paper.
- ``"prefiltered"`` — split-sum: the environment pre-convolved with the
  reflection lobe for a few μ, looked up at the mirror direction and
  multiplied by the Fresnel factor (Karis 2013, "Real Shading in Unreal
  Engine 4"). No noise, an approximation whose error is measured.
- ``"lowrank"`` — ``"reference"`` sampling, but with the environment
  projected on its first ``rank`` principal spectra (SVD over texels), so that
  per sample only ``rank`` channels are looked up and the Fresnel factor is
  folded into a (cos θ, rank, XYZ) table. A grey environment is exactly rank 1:
  the renderer detects it and always runs one band (:func:`env_basis`).

Sampling design of the MIS modes:

- the lobes are the objects of :mod:`jkatana.models.lobes` (value, sampler
  and pdf together): hiraji :class:`~jkatana.models.lobes.Gaussian`, hamon
  :class:`~jkatana.models.lobes.GaussianVCavity`, or any lobe a parameter file
  names (``Plan.hiraji_lobe``/``hamon_lobe``: GGX, GTR, a two-lobe mixture,
  Beckmann for the Mitsuba comparison), blended and sampled as a
  :class:`~jkatana.models.lobes.Mixture` with weights w, 1 − w;
- the Fresnel factor is folded into the environment (:func:`fold_fresnel`,
  ``Plan.fresnel_rank``): per sample a ``3R``-channel lookup instead of one per
  wavelength, exact up to the rank of F(cos θ, λ);
- per-pixel points are a 3D Sobol sequence (Joe & Kuo 2008) with random
  digital shifts (Owen 2003), the environment warp taking 2 of them
  (:meth:`~jkatana.light.sampling.EnvSampler.sample_uniform2`), so that each
  strategy sees a well-stratified 2D set;
- one point set per output pixel across its subpixels (``Plan.subpixels``,
  :class:`PixelIds`): subpixel ``q`` of ``S`` takes points ``q·N … q·N + N − 1``
  of the pixel's ``S·N``-point sequence, so the union is one (0, m, 2)-net.

Effects on demand (all decided on the host before tracing, so a switched-off
effect is absent from the compiled program): no hamon pixels → no
Torrance–Sparrow term; all hiraji μ0 below ``MIRROR_MU`` → a mirror lookup,
no lobe sampling; no point lights → none evaluated.

Spectra leave the jitted function as CIE XYZ with ``k = 1/∫ȳ dλ`` (a flat
spectrum of 1 has Y = 1; Mitsuba 3's film uses the same normalisation), and
optionally as spectra.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jkatana.models.geometry import tangent_frame, to_local, to_world
from jkatana.models.lobes import (Gaussian, GaussianVCavity, Mixture, key_params, lobe_key, lobe_with_width,
                                  normalised_params, reflect)
from jkatana.models.microfacet import gaussian_facet, gaussian_normalisation
# the shader's inputs and helpers live by job in their own modules; re-exported here as the render API
from jkatana.render.environment import (Environment, background, bilinear_equirect, bilinear_equirect_uv,  # noqa: F401
                                        build_environment, env_basis, env_lookup, env_uv, lookup_prefiltered,
                                        unbasis)
from jkatana.render.fresnel_fold import (FRESNEL_RANK_TOL, FRESNEL_TABLE, Material, fold_fresnel,  # noqa: F401
                                         fresnel_rank_for, fresnel_table, is_folded, table_lookup)
from jkatana.render.plan import LOBE_MODES, MIRROR_MU, MODES, Light, Pixels, Plan, Rays, Visibility  # noqa: F401
from jkatana.render.points import PixelIds, mis_offset, sample_points, uniforms  # noqa: F401

# ---------------------------------------------------------------- lobes per region


def _norms(plan: Plan, mat: Material, px: Pixels):
    """Per-pixel lobe scales: N(μ) of the paper's lobes (normalised convention; ``None`` where a region has
    another lobe, normalised by itself) or χ/K, β/K (calibrated). Hoisted out of the sample loop."""
    if plan.calibration is None:
        n0 = (gaussian_normalisation(px.mu0) if (plan.hiraji and not plan.mirror and plan.hiraji_lobe is None)
              else None)
        n1 = gaussian_normalisation(px.mu1) if (plan.hamon and plan.hamon_lobe is None) else None
        return n0, n1
    return mat.chi / plan.calibration, mat.beta / plan.calibration


def _region_lobe(plan: Plan, key, width, norm, paper):
    """``(lobe, gain)`` of one region: the paper's lobe ``paper`` (scale ``norm``, gain ``None``) or, for a
    :func:`~jkatana.models.lobes.lobe_shape` key, that lobe at the per-pixel ``width``.

    Another lobe in the normalised convention is its energy-normalised form
    (:func:`~jkatana.models.lobes.normalised_params`, gain ``None``); calibrated,
    it is the lobe as fitted times ``norm`` = s/K, where s is the params file's
    scale: the fit's model is ρ = s · f_r cos θi · F̄ (:mod:`jkatana.fit._model`),
    so s/K converts camera units to reflectance exactly as χ/K does for the
    paper's lobe.
    """
    normalised = plan.calibration is None
    if key is None:
        return paper(width, norm, normalised=normalised), None
    if plan.mode not in LOBE_MODES:
        raise ValueError(f"lobe {key[0]!r} renders in modes {list(LOBE_MODES)} only, not {plan.mode!r}")
    if normalised:
        key = lobe_key(normalised_params(key_params(key)))
    return lobe_with_width(key, width, width.dtype), (None if normalised else norm)


def _lobes(plan: Plan, px: Pixels, norms):
    """The sampled lobes of the pixels with their blend weights and gains: ``[(lobe, weight, gain), ...]``.

    Hiraji: ``plan.hiraji_lobe`` at width μ0 (the paper's
    :class:`~jkatana.models.lobes.Gaussian` when ``None``) unless it is a perfect
    mirror, weight w; hamon: ``plan.hamon_lobe`` at width μ1 (the paper's
    :class:`~jkatana.models.lobes.GaussianVCavity` when ``None``), weight 1 − w
    (Mochizuki et al., eq. 5). ``gain`` (``None``: 1) multiplies a lobe's value
    but not its sampling weight.
    """
    out = []
    if plan.hiraji and not plan.mirror:
        lobe, gain = _region_lobe(plan, plan.hiraji_lobe, px.mu0, norms[0], Gaussian)
        out.append((lobe, px.w, gain))
    if plan.hamon:
        lobe, gain = _region_lobe(plan, plan.hamon_lobe, px.mu1, norms[1], GaussianVCavity)
        out.append((lobe, 1.0 - px.w, gain))
    return out


def _sampler(lobes):
    """One lobe, or the blend of two sampled by its weights (:class:`~jkatana.models.lobes.Mixture`)."""
    if len(lobes) == 1:
        return lobes[0][0]
    (a, w, _), (b, _, _) = lobes
    return Mixture(a, b, w)


def _mix_w(plan: Plan, px: Pixels):
    """Probability of sampling the hiraji lobe."""
    if plan.mirror or not plan.hiraji:
        return jnp.zeros_like(px.w)
    if not plan.hamon:
        return jnp.ones_like(px.w)
    return px.w


def _fcos_terms(lobes, L, V):
    """f·cos θi without Fresnel per lobe term, weighted by the blend and gain: ``[(a, Fresnel cosine), ...]``."""
    return [((w * a) if g is None else (w * g) * a, c) for lobe, w, g in lobes for a, c in lobe.terms(L, V)]


# ---------------------------------------------------------------- the shader


def _frame(px: Pixels):
    """Per-pixel tangent frame and the view direction in it."""
    N = px.normal
    t, b = tangent_frame(N)
    return (t, b, N), to_local(px.view, t, b, N)


def _mirror_ray(Vl, fr):
    Rl = jnp.stack([-Vl[:, 0], -Vl[:, 1], Vl[:, 2]], -1)
    return Rl, to_world(Rl, *fr)


def _paper_grid(S: int):
    nu = max(1, int(round(math.sqrt(S))))
    return nu, -(-S // nu)


def _paper_ray(plan: Plan, px: Pixels, Vl, fr, key, k):
    """The k-th of the paper's jittered rays: ``(L_local, L_world, φ, μ)``."""
    nu, nv = _paper_grid(plan.samples)
    P = Vl.shape[0]
    kk = jax.random.fold_in(key, k)
    j = jax.random.uniform(kk, (P, 3), Vl.dtype)
    su = (jnp.asarray(k // nv, Vl.dtype) + j[:, 0]) / nu
    sv = (jnp.asarray(k % nv, Vl.dtype) + j[:, 1]) / nv
    # lobe choice per sample (mixture), then a stratified point in the disk φ ≤ 2.5 μ
    use0 = j[:, 2] < _mix_w(plan, px)
    mu = jnp.where(use0, px.mu0, px.mu1)
    phi = 2.5 * mu * jnp.sqrt(su)
    psi = 2 * jnp.pi * sv
    s = jnp.sin(phi)
    h = jnp.stack([s * jnp.cos(psi), s * jnp.sin(psi), jnp.cos(phi)], -1)
    Ll = reflect(Vl, h)
    return Ll, to_world(Ll, *fr), phi, mu


def _mis_rays(plan: Plan, env: Environment, sampler, Vl, fr, offset, k, ids: PixelIds | None = None):
    """The k-th MIS pair: ``(Ll, Lw, pdf)`` from the lobe mixture ``sampler``, ``(Ll2, Lw2, pe2, uv2)`` from the
    environment (``None`` without environment sampling; ``uv2`` the map coordinates of ``Lw2``, or ``None``)."""
    dtype = Vl.dtype
    r0, r1, r2, re = uniforms(plan, offset, k, dtype, ids)
    Ll, pb = sampler.sample(Vl, jnp.stack([r1, r2], -1), r0)
    Lw = to_world(Ll, *fr)
    if not plan.env_sampling:
        return Ll, Lw, pb, None, None, None, None
    d_map, pe2, u2, v2 = env.sampler.sample_uniform2(re)
    Lw2, uv2 = d_map @ env.rotation, (u2, v2)
    return Ll, Lw, pb, to_local(Lw2, *fr), Lw2, pe2, uv2


def _light_ray(lights: Light, j: int, px: Pixels):
    """Direction to light j (world), its 1/r² falloff and distance (inf for directional)."""
    vec, kind = lights.vector[j], lights.kind[j]
    to_l = vec[None, :] - px.position
    r2 = jnp.sum(to_l * to_l, -1)
    d_point = to_l / jnp.sqrt(jnp.maximum(r2, 1e-20))[:, None]
    d_dir = jnp.broadcast_to(vec / jnp.linalg.norm(vec), d_point.shape)
    Lw = jnp.where(kind > 0.5, d_dir, d_point)
    falloff = jnp.where(kind > 0.5, 1.0, 1.0 / jnp.maximum(r2, 1e-20))
    dist = jnp.where(kind > 0.5, jnp.inf, jnp.sqrt(r2))
    return Lw, falloff, dist


def _has_lobe(plan: Plan) -> bool:
    return (plan.hiraji and not plan.mirror) or plan.hamon


def ray_directions(plan: Plan, env: Environment, lights: Light | None, px: Pixels, key,
                   ids: PixelIds | None = None) -> Rays:
    """Every direction :func:`shade` will look up for these pixels and this key, as :class:`Rays`.

    Built from the same sampling helpers as :func:`shade` (same key → same
    directions), so a host step can ray-cast them against occluders and hand
    the result back to :func:`shade` as a :class:`Visibility`. Pure JAX.
    """
    fr, Vl = _frame(px)
    P, dtype = Vl.shape[0], Vl.dtype
    _, mirror = _mirror_ray(Vl, fr)
    empty = jnp.zeros((P, 0, 3), dtype)
    lobe, envd = empty, empty
    ks = jnp.arange(plan.samples)
    if plan.mode == "paper" and _has_lobe(plan):
        lobe = jax.vmap(lambda k: _paper_ray(plan, px, Vl, fr, key, k)[1], out_axes=1)(ks)
    elif plan.mode in ("reference", "lowrank") and _has_lobe(plan):
        offset = mis_offset(key, P, dtype, plan, ids)
        sampler = _sampler(_lobes(plan, px, (1.0, 1.0)))  # sampling needs the widths only

        def one(k):
            _, Lw, _, _, Lw2, _, _ = _mis_rays(plan, env, sampler, Vl, fr, offset, k, ids)
            return Lw, (Lw2 if Lw2 is not None else jnp.zeros((P, 3), dtype))

        lobe, envd = jax.vmap(one, out_axes=1)(ks)
        if not plan.env_sampling:
            envd = empty
    n = plan.lights if lights is not None else 0
    if n:
        ls = [_light_ray(lights, j, px) for j in range(n)]
        ldir = jnp.stack([x[0] for x in ls], 1)
        ldist = jnp.stack([jnp.broadcast_to(x[2], (P,)) for x in ls], 1)
    else:
        ldir, ldist = empty, jnp.zeros((P, 0), dtype)
    return Rays(mirror, lobe, envd, ldir, ldist)


def shade(plan: Plan, mat: Material, env: Environment, lights: Light | None, px: Pixels,
          cmf: Float[Array, "wl 3"], key, vis: Visibility | None = None,
          ids: PixelIds | None = None) -> tuple[Array, Array | None]:
    """Radiance of G-buffer pixels → ``(XYZ (P, 3), spectra (P, wl) or None)``.

    ``cmf`` are the XYZ weights (x̄ȳz̄ Δλ / ∫ȳ). Pure JAX; jit with ``plan``
    static. Differentiable in ``mat``, ``env.channels``/``env.basis``, ``lights``
    and ``px`` (normals, maps). With ``plan.visibility``, ``vis`` holds the
    visibility (0/1, or fractional) of each direction of :func:`ray_directions`
    for the same pixels and key; every environment and light contribution along
    that direction is multiplied by it (occluders are black: they block light
    and neither emit nor reflect). In ``"prefiltered"`` mode the lobe's
    visibility is approximated by that of the mirror direction.
    With ``plan.subpixels > 1`` and ``ids`` (:class:`PixelIds`), the MIS modes
    draw each G-buffer sample's points from its pixel's shared sequence
    (``key`` is then the frame's key: the scramble comes from the pixel index);
    the ``"paper"`` mode ignores ``ids``.
    """
    if plan.visibility and vis is None:
        raise ValueError("plan.visibility needs a Visibility (see ray_directions)")
    vis = vis if plan.visibility else None
    dtype = px.normal.dtype
    P = px.normal.shape[0]
    fr, Vl = _frame(px)
    factored = plan.factored
    folded = is_folded(plan)
    norms = _norms(plan, mat, px)
    lobes = _lobes(plan, px, norms)
    sampler = _sampler(lobes) if lobes else None
    if folded:
        R = plan.fresnel_rank
        if plan.lights or plan.spectral or mat.ftable.shape[-1] != R or env.channels.shape[-1] != 3 * R:
            raise ValueError("Plan(fresnel_rank=R) needs fold_fresnel's material and environment, "
                             "and no lights or spectral output")
        acc = jnp.zeros((P, 3), dtype)
    elif factored:
        # (T, J, 3): Fresnel folded with the basis spectra and the CMFs
        xtable = jnp.einsum("tl,jl,lc->tjc", mat.ftable, env.basis, cmf)
        acc = jnp.zeros((P, 3), dtype)
    else:
        acc = jnp.zeros((P, env.channels.shape[-1]), dtype)

    def combine(cos, E):
        """F(cos)·E in the accumulator's space."""
        if folded:
            return jnp.einsum("pr,prc->pc", table_lookup(mat.ftable, cos), E.reshape(E.shape[0], -1, 3))
        if factored:
            return jnp.einsum("pjc,pj->pc", table_lookup(xtable, cos), E)
        return table_lookup(mat.ftable, cos) * E

    def radiance_terms(Ll, Lw, weight, uv=None):
        """Σ_lobes scalar·F(cos)·E(L) · weight, in the accumulator's space (``uv``: map coordinates of Lw)."""
        terms = _fcos_terms(lobes, Ll, Vl)
        E = env_lookup(env, Lw) if uv is None else bilinear_equirect_uv(env.channels, *uv)  # (P, J)
        total = 0.0
        for a, c in terms:
            total = total + (a * weight)[:, None] * combine(c, E)
        return total

    def add_mirror_like(acc, weight, E, cos):
        wv = jnp.where(Vl[:, 2] > 0, weight, 0.0)
        if vis is not None:
            wv = wv * vis.mirror
        return acc + wv[:, None] * combine(cos, E)

    # --- mirror hiraji: one deterministic lookup
    if plan.hiraji and plan.mirror:
        _, Rw = _mirror_ray(Vl, fr)
        acc = add_mirror_like(acc, px.w, env_lookup(env, Rw), jnp.clip(Vl[:, 2], 0.0, 1.0))

    S = plan.samples
    ks = jnp.arange(S)
    if plan.mode == "prefiltered" and _has_lobe(plan):
        # split sum: F(cos θv) × prefiltered env at the mirror direction, per lobe
        _, Rw = _mirror_ray(Vl, fr)
        cos = jnp.clip(Vl[:, 2], 0.0, 1.0)
        for on, weight, mu in ((plan.hiraji and not plan.mirror, px.w, px.mu0), (plan.hamon, 1.0 - px.w, px.mu1)):
            if on:
                acc = add_mirror_like(acc, weight, lookup_prefiltered(env, mu, Rw), cos)
    elif plan.mode == "paper" and _has_lobe(plan):
        def body(carry, xs):
            acc_, wsum = carry
            k, v = xs
            Ll, Lw, phi, mu = _paper_ray(plan, px, Vl, fr, key, k)
            gauss = gaussian_facet(phi, jnp.maximum(mu, 1e-7))
            pdf = sampler.pdf(Ll, Vl)
            ok = (Ll[:, 2] > 0) & (pdf > 0)
            g = jnp.where(ok, gauss / jnp.where(ok, pdf, 1.0), 0.0)  # Gaussian weight × 1/pdf → throughput
            if v is not None:
                g = g * v
            return (acc_ + radiance_terms(Ll, Lw, g), wsum + gauss), None

        xs = (ks, None if vis is None else vis.lobe.T)
        (lob, wsum), _ = jax.lax.scan(body, (jnp.zeros_like(acc), jnp.zeros((P,), dtype)), xs)
        acc = acc + lob / jnp.maximum(wsum, 1e-30)[:, None]
    elif _has_lobe(plan):  # reference / lowrank: MIS of lobe and environment sampling
        offset = mis_offset(key, P, dtype, plan, ids)

        def body(acc_, xs):
            k, v1, v2 = xs
            Ll, Lw, pb, Ll2, Lw2, pe2, uv2 = _mis_rays(plan, env, sampler, Vl, fr, offset, k, ids)
            uv = env_uv(env, Lw)  # one atan2 pair serves the density and the lookup
            pe = env.sampler.pdf_uv(*uv) if plan.env_sampling else 0.0
            ok = (Ll[:, 2] > 0) & (pb > 0)
            wgt = jnp.where(ok, 1.0 / jnp.where(ok, pb + pe, 1.0), 0.0)
            if v1 is not None:
                wgt = wgt * v1
            acc_ = acc_ + radiance_terms(Ll, Lw, wgt, uv)
            if plan.env_sampling:
                pb2 = sampler.pdf(Ll2, Vl)
                ok2 = (Ll2[:, 2] > 0) & (pe2 > 0)
                wgt2 = jnp.where(ok2, 1.0 / jnp.where(ok2, pb2 + pe2, 1.0), 0.0)
                if v2 is not None:
                    wgt2 = wgt2 * v2
                acc_ = acc_ + radiance_terms(Ll2, Lw2, wgt2, uv2)
            return acc_, None

        xs = (ks, None, None) if vis is None else (ks, vis.lobe.T, vis.env.T if plan.env_sampling else None)
        lob, _ = jax.lax.scan(body, jnp.zeros_like(acc), xs)
        acc = acc + lob / S

    # --- analytic lights (point: kind 0, directional: kind 1); a delta hiraji lobe never sees one
    if plan.lights and lights is not None:
        for j in range(plan.lights):
            Lw, falloff, _ = _light_ray(lights, j, px)
            if vis is not None:
                falloff = falloff * vis.lights[:, j]
            Ll = to_local(Lw, *fr)
            spec = lights.spectrum[j]
            for a, c in _fcos_terms(lobes, Ll, Vl):
                Fs = table_lookup(mat.ftable, c) * spec[None, :]
                if factored:
                    acc = acc + (a * falloff)[:, None] * (Fs @ cmf)
                else:
                    acc = acc + (a * falloff)[:, None] * Fs @ unbasis(env)
    if factored or folded:
        return acc, None
    spectra = acc @ env.basis  # identity when not factored
    return spectra @ cmf, (spectra if plan.spectral else None)


__all__ = ["MIRROR_MU", "MODES", "FRESNEL_RANK_TOL", "FRESNEL_TABLE", "Environment", "Light", "Material", "PixelIds",
           "Pixels", "Plan", "Rays", "Visibility", "background", "bilinear_equirect", "bilinear_equirect_uv",
           "build_environment", "env_basis", "env_lookup", "env_uv", "fold_fresnel", "fresnel_rank_for",
           "fresnel_table", "ray_directions", "sample_points", "shade"]
