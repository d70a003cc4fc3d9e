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
  (Veach & Guibas 1995), with the two strategies' sample counts
  (``Plan.samples``, ``Plan.env_samples``). Unbiased; its error is measured against a converged
  frame by ``benchmarks/bench_render.py``.
- ``"paper"`` — the paper's method (§5): a fixed number of jittered reflection
  rays around the mirror direction (stratified facet normals in a disk of
  radius 2.5 μ), averaged with Gaussian weights D(φ, μ). Biased (truncated,
  self-normalised) but cheap; 30 rays in the paper. With split caps (below)
  the rays see the remainder and the caps are added by the cap rule;
  ``"paper-published"`` is the same estimator on the whole map, exactly as
  published (a sun's glint falls between its rays).
- ``"prefiltered"`` — split-sum: the environment pre-convolved with the
  reflection lobe for a few μ, looked up at the mirror direction and
  multiplied by the Fresnel factor (Karis 2013, "Real Shading in Unreal
  Engine 4"). No noise, an approximation whose error is measured.
- ``"lowrank"`` — ``"reference"`` sampling, but with the environment
  projected on its first ``rank`` principal spectra (SVD over texels), so that
  per sample only ``rank`` channels are looked up and the Fresnel factor is
  folded into a (cos θ, rank, XYZ) table. A grey environment is exactly rank 1:
  the renderer detects it and always runs one band (:func:`env_basis`).

Compact sources split off the map (:attr:`Environment.caps`, spherical caps
of uniform radiance, :mod:`jkatana.light.sun`): the environment's lookups,
sampler and prefiltered levels are the remainder's, and each cap is a light
of its own:

- ``"prefiltered"`` and ``"paper"``: ``L_cap ∫_cap f_r cos θi dω`` per lobe by
  a deterministic cap rule (:func:`jkatana.light.capquad.cap_nodes`, 4 × 16 nodes
  about the lobe's mirror direction, or Stroud's 4 directions of
  :func:`~jkatana.light.capquad.cap_disc_nodes` when every lobe is ≥ 8 cap radii
  wide, ``Plan.cap_rule``; Fresnel at the cap centre), no noise;
- ``"reference"`` and ``"lowrank"``: a third strategy, one direction uniform in
  each cap's cone per sample, combined with the lobe samples by the balance
  heuristic (Veach & Guibas 1995) on the cap's integrand, while the lobe and
  environment samples share the remainder's: unbiased for the split map;
- a perfect-mirror hiraji sees a cap where its mirror ray falls inside it;
  camera rays see the caps in the background.

Without caps (none found, or not split) none of this is traced.
:func:`shade_caps` is the deterministic modes' cap terms alone: a prefiltered
frame shades them on the pixels a cap can reach
(:func:`jkatana.render.caps.cap_pixels`, :func:`jkatana.render.frame.shade_pixels`).

Sampling design of the MIS modes:

- the lobes are the objects of :mod:`jkatana.models.lobes` (value, sampler
  and pdf together): hiraji :class:`~jkatana.models.lobes.Gaussian`, hamon
  :class:`~jkatana.models.lobes.GaussianVCavity`, or any lobe a parameter file
  names (``Plan.hiraji_lobe``/``hamon_lobe``: GGX, GTR, a two-lobe mixture,
  Beckmann for the Mitsuba comparison), blended and sampled as a
  :class:`~jkatana.models.lobes.Mixture` with weights w, 1 − w;
- the Fresnel factor is folded into the environment (:func:`fold_fresnel`,
  ``Plan.fresnel_rank``): per sample a ``3R``-channel lookup instead of one per
  wavelength, exact up to the rank of F(cos θ, λ); by default these modes take the
  rank within :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL_SAMPLED` (a bias
  far below their noise, bounded per pixel by max|F − F_R| / min F);
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

from jkatana.light.envmap import Taps, bilinear_taps, gather_taps
from jkatana.light.sampling import mis_weight
from jkatana.models.geometry import tangent_frame, to_local, to_world
from jkatana.models.lobes import reflect
from jkatana.models.microfacet import gaussian_facet
# the shader's inputs and helpers live by job in their own modules; re-exported here as the render API
from jkatana.render.environment import (Caps, Environment, background, bilinear_equirect, bilinear_equirect_uv, to_map,  # noqa: F401
                                        build_environment, env_basis, env_lookup, env_uv, from_map,
                                        lookup_prefiltered_many, unbasis)
from jkatana.render.fresnel_fold import (FRESNEL_RANK_TOL, FRESNEL_TABLE, Material, fold_fresnel,  # noqa: F401
                                         fresnel_rank_for, fresnel_table, is_folded, table_lookup)
from jkatana.render.plan import MIRROR_MU, MODES, Light, Pixels, Plan, Rays, Visibility  # noqa: F401
from jkatana.render.points import PixelIds, mis_offset, sample_points, uniforms  # noqa: F401

# the lobes per region and the cap lights live in their own modules
from jkatana.render.caps import _cap_offsets, _cap_ray, _cap_rule_terms, _caps, _tabulated_norms, cap_rule_for  # noqa: F401
from jkatana.render.regions import _fcos_terms, _lobes, _mix_w, _norms, _sampler


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


def _lobe_ray(plan: Plan, sampler, Vl, fr, offset, k, ids: PixelIds | None = None):
    """The k-th lobe sample of the MIS modes: ``(Ll, Lw, pdf)`` from the lobe mixture ``sampler``."""
    r0, r1, r2, _ = uniforms(plan, offset, k, Vl.dtype, ids)
    Ll, pb = sampler.sample(Vl, jnp.stack([r1, r2], -1), r0)
    return Ll, to_world(Ll, *fr), pb


def _taps(env: Environment, uv) -> Taps:
    """The bilinear taps of map coordinates ``uv`` in ``env``'s channels (:func:`~jkatana.light.envmap.bilinear_taps`)."""
    return bilinear_taps(*uv, env.channels.shape[0], env.channels.shape[1])


def _sample_passes(n: int, rays, body, acc, per_sample=None, block: int = 8):
    """``acc`` after ``acc = body(acc, k, rays(k), per_sample[k])`` for the samples ``k < n`` of one strategy.

    The samples are drawn in blocks of up to ``block``, each in a pass of its own (``rays``: the
    strategy's arithmetic), then loaded and accumulated in a second pass (``body``: the texture loads and what
    needs them). XLA's CPU backend compiles a loop that holds a gather (a texture load) to scalar code; in
    one loop with the loads the sampling arithmetic (inverse CDFs, ``atan2``, the bilinear taps) would run
    scalar too, where apart it is vectorised. A block's samples are held between the passes (≈ 60 bytes per
    pixel and sample). When the blocks do not divide ``n`` the last is padded with samples whose contribution
    is dropped. ``per_sample``: ``(n, P)`` or ``None``.
    """
    blocks = -(-n // block)
    size = -(-n // blocks)
    ks = jnp.arange(blocks * size, dtype=jnp.int32).reshape(blocks, size)
    xs = None
    if per_sample is not None:
        pad = blocks * size - n
        xs = jnp.concatenate([per_sample, jnp.zeros((pad,) + per_sample.shape[1:], per_sample.dtype)]) if pad \
            else per_sample
        xs = xs.reshape((blocks, size) + per_sample.shape[1:])

    def one_block(acc_, item):
        kb, xb = item
        drawn = jax.lax.scan(lambda c, k: (c, rays(k)), None, kb)[1]

        def step(a, it):
            k, r, x = it
            out = body(a, k, r, x)
            return (out if blocks * size == n else jnp.where(k < n, out, a)), None

        return jax.lax.scan(step, acc_, (kb, drawn, xb))[0], None

    return jax.lax.scan(one_block, acc, (ks, xs))[0]


def env_window(plan: Plan, env: Environment, px: Pixels, mirror_world):
    """The texel window the MIS modes sample the environment in (:meth:`EnvSampler.window
    <jkatana.light.sampling.EnvSampler.window>`), or ``None`` (the whole map: ``plan.env_window`` off, or no
    environment samples).

    The cone about the mirror direction of half-angle ``2 atan(k μ)``, ``k = plan.env_window`` and μ the
    widest sampled region's per-pixel width (a Beckmann/GGX α, the paper's μ: the facet slope scale), so the
    environment's samples go where the lobe is rather than below the horizon or far outside the lobe. A
    choice of variance, not of the result: the balance heuristic with the lobe strategy, whose density is
    positive wherever the lobe is, keeps the estimate unbiased for any window (Veach & Guibas 1995).
    """
    if not plan.env_window or not plan.n_env:
        return None
    widths = [mu for on, mu in ((plan.hiraji and not plan.mirror, px.mu0), (plan.hamon, px.mu1)) if on]
    mu = widths[0] if len(widths) == 1 else jnp.maximum(*widths)
    half = jnp.minimum(2.0 * jnp.arctan(plan.env_window * mu), jnp.pi)
    return env.sampler.window(to_map(env, mirror_world), half)


def _env_ray(plan: Plan, env: Environment, fr, offset, k, ids: PixelIds | None = None, win=None):
    """The k-th of ``plan.n_env`` environment samples: ``(Ll, Lw, pdf, uv)`` (``uv`` the map coordinates of
    ``Lw``), inside the texel window ``win`` if one is given (:func:`env_window`)."""
    _, _, _, re = uniforms(plan, offset, k, fr[0].dtype, ids, plan.n_env)
    if win is None:
        d_map, pe, u, v = env.sampler.sample_uniform2(re)
    else:
        d_map, pe, u, v = env.sampler.sample_window(win, re)
    Lw = from_map(env, d_map)
    return to_local(Lw, *fr), Lw, pe, (u, v)


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

    An environment with split caps adds one direction per cap after the
    lights (``Rays.lights[:, plan.lights + k]``, distance ∞): the ray toward the
    cap's centre. Its visibility stands for the whole cap (a sub-degree sun:
    penumbrae narrower than the cap's angular size are not resolved), for the
    cap rule of the deterministic modes and for the cap's own samples in the
    Monte Carlo modes; lobe samples that fall in a cap keep their own
    visibility.
    """
    fr, Vl = _frame(px)
    P, dtype = Vl.shape[0], Vl.dtype
    _, mirror = _mirror_ray(Vl, fr)
    empty = jnp.zeros((P, 0, 3), dtype)
    lobe, envd = empty, empty
    ks = jnp.arange(plan.samples)
    if plan.mode in ("paper", "paper-published") and _has_lobe(plan):
        lobe = jax.vmap(lambda k: _paper_ray(plan, px, Vl, fr, key, k)[1], out_axes=1)(ks)
    elif plan.mode in ("reference", "lowrank") and _has_lobe(plan):
        offset = mis_offset(key, P, dtype, plan, ids)
        sampler = _sampler(_lobes(plan, px, (1.0, 1.0)))  # sampling needs the widths only
        lobe = jax.vmap(lambda k: _lobe_ray(plan, sampler, Vl, fr, offset, k, ids)[1], out_axes=1)(ks)
        if plan.n_env:
            win = env_window(plan, env, px, mirror)
            envd = jax.vmap(lambda k: _env_ray(plan, env, fr, offset, k, ids, win)[1],
                            out_axes=1)(jnp.arange(plan.n_env))
    n = plan.lights if lights is not None else 0
    ls = [_light_ray(lights, j, px) for j in range(n)]
    dirs = [x[0] for x in ls]
    dists = [jnp.broadcast_to(x[2], (P,)) for x in ls]
    caps = _caps(env)
    if caps is not None:  # one shadow ray per pixel toward each cap's centre, after the lights
        Cw = caps.world(env.rotation).astype(dtype)
        dirs += [jnp.broadcast_to(Cw[k], (P, 3)) for k in range(caps.count)]
        dists += [jnp.full((P,), jnp.inf, dtype)] * caps.count
    if dirs:
        ldir, ldist = jnp.stack(dirs, 1), jnp.stack(dists, 1)
    else:
        ldir, ldist = empty, jnp.zeros((P, 0), dtype)
    return Rays(mirror, lobe, envd, ldir, ldist)


def _accumulator(plan: Plan, mat: Material, env: Environment, cmf, P: int, dtype):
    """``(zero accumulator, combine)`` of :func:`shade`: ``combine(cos, E)`` is F(cos)·E in the accumulator's
    space: XYZ from ``3R`` folded channels (``Plan.fresnel_rank``, :func:`fold_fresnel`), XYZ from the basis's
    channels (``Plan.factored``: Fresnel, basis spectra and CMFs in one ``(T, J, 3)`` table), else the
    environment's channels (full spectra)."""
    if is_folded(plan):
        R = plan.fresnel_rank
        if plan.lights or plan.spectral or mat.ftable.shape[-1] != R or env.channels.shape[-1] != 3 * R:
            raise ValueError("Plan(fresnel_rank=R) needs fold_fresnel's material and environment, "
                             "and no lights or spectral output")

        def combine(cos, E):
            return jnp.einsum("pr,prc->pc", table_lookup(mat.ftable, cos), E.reshape(E.shape[0], -1, 3))

        return jnp.zeros((P, 3), dtype), combine
    if plan.factored:
        xtable = jnp.einsum("tl,jl,lc->tjc", mat.ftable, env.basis, cmf)  # (T, J, 3)
        return jnp.zeros((P, 3), dtype), lambda cos, E: jnp.einsum("pjc,pj->pc", table_lookup(xtable, cos), E)
    return jnp.zeros((P, env.channels.shape[-1]), dtype), lambda cos, E: table_lookup(mat.ftable, cos) * E


def _output(plan: Plan, env: Environment, cmf, acc) -> tuple[Array, Array | None]:
    """:func:`shade`'s ``(XYZ, spectra or None)`` from its accumulator."""
    if plan.factored or is_folded(plan):
        return acc, None
    spectra = acc @ env.basis  # identity when not factored
    return spectra @ cmf, (spectra if plan.spectral else None)


def _add_mirror_like(acc, weight, E, cos, Vl, vis: Visibility | None, combine):
    """``acc`` plus ``weight·F(cos)·E`` where the view is above the surface (times the mirror ray's visibility)."""
    wv = jnp.where(Vl[:, 2] > 0, weight, 0.0)
    if vis is not None:
        wv = wv * vis.mirror
    return acc + wv[:, None] * combine(cos, E)


def _add_mirror_caps(plan: Plan, px: Pixels, Vl, fr, env: Environment, caps: Caps, Ecap, vis, combine, acc):
    """A perfect-mirror hiraji sees a cap where its mirror ray falls inside it."""
    if not (plan.hiraji and plan.mirror):
        return acc
    _, Rw = _mirror_ray(Vl, fr)
    ins = caps.inside(Rw, env.rotation).astype(Vl.dtype)
    for k in range(caps.count):
        acc = _add_mirror_like(acc, px.w * ins[:, k], Ecap[k], jnp.clip(Vl[:, 2], 0.0, 1.0), Vl, vis, combine)
    return acc


def _add_cap_rule(plan: Plan, mat: Material, px: Pixels, Vl, fr, caps: Caps, Cw, Ecap, cap_vis, lobes, combine, acc):
    """The deterministic modes: ``acc`` plus each cap integrated against each lobe by ``plan.cap_rule``
    (:func:`~jkatana.render.caps._cap_rule_terms`; ``None``: ``"nodes"``). ``lobes``: :func:`shade`'s, or ``None``
    (made here); the prefiltered mode's own, with N(μ) tabulated."""
    rule = plan.cap_rule or "nodes"
    # the prefiltered mode evaluates no lobe but the cap's: N(μ) from a table, not a quadrature per pixel
    if plan.mode == "prefiltered" or lobes is None:
        tabulated = plan.mode == "prefiltered"
        lobes = _lobes(plan, px, _tabulated_norms(plan, mat, px) if tabulated else _norms(plan, mat, px))
    for k in range(caps.count):
        for a, c in _cap_rule_terms(lobes, Vl, fr, Cw[k], caps.radius[k].astype(Vl.dtype), rule):
            wgt = a if cap_vis[k] is None else a * cap_vis[k]
            acc = acc + wgt[:, None] * combine(c, Ecap[k])
    return acc


def _cap_constants(plan: Plan, env: Environment, caps: Caps, vis: Visibility | None, P: int, dtype):
    """The split caps' constants of a frame: ``(world centres (K, 3), per cap its channels broadcast to the
    P pixels, per cap its shadow rays' visibility or None)``."""
    Cw = caps.world(env.rotation).astype(dtype)
    Ecap = [jnp.broadcast_to(c.astype(dtype), (P, c.shape[-1])) for c in caps.channels]
    cap_vis = [None if vis is None else vis.lights[:, plan.lights + k] for k in range(caps.count)]
    return Cw, Ecap, cap_vis


def shade_caps(plan: Plan, mat: Material, env: Environment, px: Pixels, cmf: Float[Array, "wl 3"],
               vis: Visibility | None = None) -> tuple[Array, Array | None]:
    """The split caps' share of :func:`shade` in the deterministic modes (``"prefiltered"``, ``"paper"``):
    each cap by the cap rule, and a perfect-mirror hiraji's view of it; ``(XYZ (P, 3), spectra or None)``.

    :func:`shade` with ``env``'s caps removed plus this is :func:`shade` (to float32 rounding: the
    terms are summed in another order), so a frame can shade the caps on its own subset of pixels
    (:func:`jkatana.render.caps.cap_pixels`). Pure JAX; jit with ``plan`` static.
    """
    if plan.mode not in ("prefiltered", "paper"):
        raise ValueError(f"shade_caps: the cap rule of the prefiltered and paper modes, not {plan.mode!r}")
    caps = _caps(env)
    dtype, P = px.normal.dtype, px.normal.shape[0]
    acc, combine = _accumulator(plan, mat, env, cmf, P, dtype)
    if caps is None:
        return _output(plan, env, cmf, acc)
    vis = vis if plan.visibility else None
    fr, Vl = _frame(px)
    Cw, Ecap, cap_vis = _cap_constants(plan, env, caps, vis, P, dtype)
    acc = _add_mirror_caps(plan, px, Vl, fr, env, caps, Ecap, vis, combine, acc)
    if _has_lobe(plan):
        acc = _add_cap_rule(plan, mat, px, Vl, fr, caps, Cw, Ecap, cap_vis, None, combine, acc)
    return _output(plan, env, cmf, acc)


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
    norms = _norms(plan, mat, px)
    lobes = _lobes(plan, px, norms)
    sampler = _sampler(lobes) if lobes else None
    acc, combine = _accumulator(plan, mat, env, cmf, P, dtype)

    def radiance_terms(Ll, Lw, weight, taps=None, E=None):
        """Σ_lobes scalar·F(cos)·E(L) · weight, in the accumulator's space (``taps``: the bilinear taps of Lw
        in the map, :func:`_taps`; ``E``: the incident channels if already known)."""
        terms = _fcos_terms(lobes, Ll, Vl)
        if E is None:
            E = env_lookup(env, Lw) if taps is None else gather_taps(env.channels, taps)  # (P, J)
        total = 0.0
        for a, c in terms:
            total = total + (a * weight)[:, None] * combine(c, E)
        return total

    def add_mirror_like(acc, weight, E, cos):
        return _add_mirror_like(acc, weight, E, cos, Vl, vis, combine)

    # --- mirror hiraji: one deterministic lookup
    if plan.hiraji and plan.mirror:
        _, Rw = _mirror_ray(Vl, fr)
        acc = add_mirror_like(acc, px.w, env_lookup(env, Rw), jnp.clip(Vl[:, 2], 0.0, 1.0))

    # --- split caps: constants of the frame (world centres, densities, channels)
    caps = _caps(env)
    if caps is not None:
        if plan.mode == "paper-published":
            raise ValueError("the paper-published mode shades the whole map: build its environment without split_sun")
        Cw, Ecap, cap_vis = _cap_constants(plan, env, caps, vis, P, dtype)
        p_cap = (1.0 / caps.solid_angle()).astype(dtype)

        def add_cap_rule(acc):
            """The deterministic modes: each cap integrated against each lobe by the cap rule."""
            return _add_cap_rule(plan, mat, px, Vl, fr, caps, Cw, Ecap, cap_vis, lobes, combine, acc)

        acc = _add_mirror_caps(plan, px, Vl, fr, env, caps, Ecap, vis, combine, acc)

    S = plan.samples
    ks = jnp.arange(S)
    if plan.mode == "prefiltered" and _has_lobe(plan):
        # split sum: F(cos θv) × prefiltered env at the mirror direction, per lobe
        _, Rw = _mirror_ray(Vl, fr)
        cos = jnp.clip(Vl[:, 2], 0.0, 1.0)
        # each region's levels: the paper's lobe's, or its own lobe's (albedo included) times its gain
        regions = [(weight, mu, region) for on, weight, mu, region in
                   ((plan.hiraji and not plan.mirror, px.w, px.mu0, 0), (plan.hamon, 1.0 - px.w, px.mu1, 1)) if on]
        keys = (plan.hiraji_lobe, plan.hamon_lobe)
        if any(keys[r] is not None for _, _, r in regions) and len(env.lobe_prefiltered) != 2:
            raise ValueError("a region with its own lobe needs its levels: build the environment with "
                             "prefilter_lobes")
        sets = [env.prefiltered if keys[r] is None else env.lobe_prefiltered[r] for _, _, r in regions]
        gains = [None if (keys[r] is None or plan.calibration is None) else norms[r] for _, _, r in regions]
        found = lookup_prefiltered_many(env, [mu for _, mu, _ in regions], Rw, sets)
        for (weight, _, _), gain, E in zip(regions, gains, found):
            acc = add_mirror_like(acc, weight if gain is None else weight * gain, E, cos)
        if caps is not None:
            acc = add_cap_rule(acc)
    elif plan.mode in ("paper", "paper-published") and _has_lobe(plan):
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
        if caps is not None:
            acc = add_cap_rule(acc)
    elif _has_lobe(plan):  # reference / lowrank: MIS of lobe and environment sampling (and of each cap)
        # balance heuristic with sample counts (Veach & Guibas 1995): a sample of either strategy weighs
        # f / (S p_lobe + S_env p_env), which sums over both strategies' samples to an unbiased estimate
        offset = mis_offset(key, P, dtype, plan, ids)
        cap_offset = _cap_offsets(plan, key, P, dtype, ids, caps.count) if caps is not None else []
        S_env = plan.n_env
        n_lobe, n_env = jnp.asarray(S, dtype), jnp.asarray(S_env, dtype)
        win = env_window(plan, env, px, _mirror_ray(Vl, fr)[1])

        def lobe_rays(k):
            Ll, Lw, pb = _lobe_ray(plan, sampler, Vl, fr, offset, k, ids)
            uv = env_uv(env, Lw)  # one atan2 pair serves the density and the lookup
            return Ll, Lw, pb, uv, _taps(env, uv)

        def lobe_body(acc_, k, rays, v1):
            Ll, Lw, pb, uv, taps = rays
            pe = (env.sampler.pdf_uv(*uv) if win is None else env.sampler.pdf_window(win, *uv)) if S_env else 0.0
            ok = (Ll[:, 2] > 0) & (pb > 0)
            wgt = mis_weight(pb, pe, n_lobe, n_env, valid=ok, per_density=True)
            if v1 is not None:
                wgt = wgt * v1
            if caps is None:
                return acc_ + radiance_terms(Ll, Lw, wgt, taps)
            # the lobe sample serves two integrands: the remainder (MIS with the environment
            # strategy) and each cap it falls in (MIS with that cap's cone strategy, S samples each)
            E = wgt[:, None] * gather_taps(env.channels, taps)
            ins = caps.inside(Lw, env.rotation)
            for kc in range(caps.count):
                wc = mis_weight(pb, p_cap[kc], n_lobe, n_lobe, valid=ok & ins[:, kc], per_density=True)
                if v1 is not None:
                    wc = wc * v1
                E = E + wc[:, None] * Ecap[kc]
            acc_ = acc_ + radiance_terms(Ll, Lw, 1.0, E=E)
            # each cap's own sample: uniform in its cone, balance heuristic with the lobe
            for kc in range(caps.count):
                _, u1, u2, _ = uniforms(plan, cap_offset[kc], k, dtype, ids)
                Lwc = _cap_ray(caps, Cw, kc, u1, u2)
                Llc = to_local(Lwc, *fr)
                pbc = sampler.pdf(Llc, Vl)
                okc = Llc[:, 2] > 0
                wc = mis_weight(p_cap[kc], pbc, n_lobe, n_lobe, valid=okc, per_density=True)
                if cap_vis[kc] is not None:
                    wc = wc * cap_vis[kc]
                acc_ = acc_ + radiance_terms(Llc, Lwc, 1.0, E=wc[:, None] * Ecap[kc])
            return acc_

        def env_rays(k):
            Ll2, Lw2, pe2, uv2 = _env_ray(plan, env, fr, offset, k, ids, win)
            return Ll2, Lw2, pe2, _taps(env, uv2)

        def env_body(acc_, k, rays, v2):
            Ll2, Lw2, pe2, taps2 = rays
            pb2 = sampler.pdf(Ll2, Vl)
            ok2 = (Ll2[:, 2] > 0) & (pe2 > 0)
            wgt2 = mis_weight(pe2, pb2, n_env, n_lobe, valid=ok2, per_density=True)
            if v2 is not None:
                wgt2 = wgt2 * v2
            return acc_ + radiance_terms(Ll2, Lw2, wgt2, taps2)

        lob = _sample_passes(S, lobe_rays, lobe_body, jnp.zeros_like(acc), None if vis is None else vis.lobe.T)
        if S_env:
            lob = _sample_passes(S_env, env_rays, env_body, lob, None if vis is None else vis.env.T)
        acc = acc + lob

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
    return _output(plan, env, cmf, acc)


__all__ = ["MIRROR_MU", "MODES", "FRESNEL_RANK_TOL", "FRESNEL_TABLE", "Caps", "Environment", "Light", "Material", "PixelIds",
           "Pixels", "Plan", "Rays", "Visibility", "background", "bilinear_equirect", "bilinear_equirect_uv",
           "build_environment", "env_basis", "env_lookup", "env_uv", "fold_fresnel", "fresnel_rank_for",
           "fresnel_table", "ray_directions", "sample_points", "shade", "shade_caps"]
