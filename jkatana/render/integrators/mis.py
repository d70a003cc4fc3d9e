"""The multiple-importance-sampling integrator (``"reference"``, ``"lowrank"``): unbiased.

Two strategies sample each pixel's integral: the lobe mixture (the lobes' own ``sample``/``pdf``,
:mod:`jkatana.models.lobes`, blended by w and 1 − w as Mochizuki et al.'s eq. 5) and the
environment's piecewise-constant luminance density
(:class:`~jkatana.light.sampling.EnvSampler`, optionally inside a window about the mirror
direction, :func:`env_window`). A sample of either weighs f / (S p_lobe + S_env p_env), the
balance heuristic with sample counts (Veach & Guibas 1995, "Optimally Combining Sampling
Techniques for Monte Carlo Rendering", §3), through :func:`~jkatana.light.sampling.mis_weight`;
summed over both strategies' samples the estimate is unbiased. This is the structure of
Mitsuba 3's ``direct`` integrator (emitter and BSDF sampling, balance heuristic) for an
environment light.

Split caps (:attr:`~jkatana.render.environment.Environment.caps`) add a third strategy per cap:
one direction uniform in the cap's cone per sample, combined with the lobe samples by the
balance heuristic on the cap's integrand, while lobe and environment samples share the
remainder's. ``"lowrank"`` runs the same estimator on an environment projected on its first
principal spectra (the renderer builds it; :func:`~jkatana.render.environment.env_basis`).

The points are per-pixel Sobol sequences with random digital shifts
(:func:`~jkatana.render.points.uniforms`; with :class:`~jkatana.render.points.PixelIds`, one
sequence per output pixel across its subpixels).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jkatana.light.envmap import gather_taps
from jkatana.light.sampling import mis_weight
from jkatana.models.geometry import to_local, to_world
from jkatana.render.caps import _cap_offsets, _cap_ray
from jkatana.render.environment import Environment, env_uv, from_map, to_map
from jkatana.render.integrators.base import Context, has_lobe, mirror_ray, radiance_terms, taps
from jkatana.render.plan import Pixels, Plan
from jkatana.render.points import PixelIds, mis_offset, uniforms
from jkatana.render.regions import _lobes, _sampler


class _Streams(NamedTuple):
    """The call's sample streams: the pixels' point offsets (lobe and environment; per cap), the strategies'
    sample counts as arrays and the environment's sampling window (or ``None``)."""

    offset: Any
    cap_offset: list
    n_lobe: Any
    n_env: Any
    window: Any


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


def lobe_ray(plan: Plan, sampler, Vl, fr, offset, k, ids: PixelIds | None = None):
    """The k-th lobe sample: ``(Ll, Lw, pdf)`` from the lobe mixture ``sampler``."""
    r0, r1, r2, _ = uniforms(plan, offset, k, Vl.dtype, ids)
    Ll, pb = sampler.sample(Vl, jnp.stack([r1, r2], -1), r0)
    return Ll, to_world(Ll, *fr), pb


def env_ray(plan: Plan, env: Environment, fr, offset, k, ids: PixelIds | None = None, win=None):
    """The k-th of ``plan.n_env`` environment samples: ``(Ll, Lw, pdf, uv)`` (``uv`` the map coordinates of
    ``Lw``), inside the texel window ``win`` if one is given (:func:`env_window`)."""
    _, _, _, re = uniforms(plan, offset, k, fr[0].dtype, ids, plan.n_env)
    if win is None:
        d_map, pe, u, v = env.sampler.sample_uniform2(re)
    else:
        d_map, pe, u, v = env.sampler.sample_window(win, re)
    Lw = from_map(env, d_map)
    return to_local(Lw, *fr), Lw, pe, (u, v)


def sample_passes(n: int, rays, body, acc, per_sample=None, block: int = 8):
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


def _streams(ctx: Context) -> _Streams:
    plan, px, dtype, P = ctx.plan, ctx.px, ctx.Vl.dtype, ctx.Vl.shape[0]
    offset = mis_offset(ctx.key, P, dtype, plan, ctx.ids)
    cap_offset = _cap_offsets(plan, ctx.key, P, dtype, ctx.ids, ctx.caps.caps.count) if ctx.caps is not None else []
    win = env_window(plan, ctx.env, px, mirror_ray(ctx.Vl, ctx.frame)[1])
    return _Streams(offset, cap_offset, jnp.asarray(plan.samples, dtype), jnp.asarray(plan.n_env, dtype), win)


def _cap_samples(ctx: Context, st: _Streams, acc_, k):
    """Each cap's own sample k: uniform in its cone, balance heuristic with the lobe strategy."""
    caps = ctx.caps
    for kc in range(caps.caps.count):
        _, u1, u2, _ = uniforms(ctx.plan, st.cap_offset[kc], k, ctx.Vl.dtype, ctx.ids)
        Lwc = _cap_ray(caps.caps, caps.centres, kc, u1, u2)
        Llc = to_local(Lwc, *ctx.frame)
        pbc = ctx.sampler.pdf(Llc, ctx.Vl)
        okc = Llc[:, 2] > 0
        wc = mis_weight(caps.density[kc], pbc, st.n_lobe, st.n_lobe, valid=okc, per_density=True)
        if caps.visibility[kc] is not None:
            wc = wc * caps.visibility[kc]
        acc_ = acc_ + radiance_terms(ctx, Llc, Lwc, 1.0, E=wc[:, None] * caps.channels[kc])
    return acc_


def _lobe_strategy(ctx: Context, st: _Streams):
    """``(rays, body)`` of :func:`sample_passes` for the lobe samples (and, with caps, each cap's own)."""
    env, caps = ctx.env, ctx.caps

    def rays(k):
        Ll, Lw, pb = lobe_ray(ctx.plan, ctx.sampler, ctx.Vl, ctx.frame, st.offset, k, ctx.ids)
        uv = env_uv(env, Lw)  # one atan2 pair serves the density and the lookup
        return Ll, Lw, pb, uv, taps(env, uv)

    def body(acc_, k, drawn, v1):
        Ll, Lw, pb, uv, taps_ = drawn
        win = st.window
        pe = (env.sampler.pdf_uv(*uv) if win is None else env.sampler.pdf_window(win, *uv)) if ctx.plan.n_env else 0.0
        ok = (Ll[:, 2] > 0) & (pb > 0)
        wgt = mis_weight(pb, pe, st.n_lobe, st.n_env, valid=ok, per_density=True)
        if v1 is not None:
            wgt = wgt * v1
        if caps is None:
            return acc_ + radiance_terms(ctx, Ll, Lw, wgt, taps_)
        # the lobe sample serves two integrands: the remainder (MIS with the environment
        # strategy) and each cap it falls in (MIS with that cap's cone strategy, S samples each)
        E = wgt[:, None] * gather_taps(env.channels, taps_)
        ins = caps.caps.inside(Lw, env.rotation)
        for kc in range(caps.caps.count):
            wc = mis_weight(pb, caps.density[kc], st.n_lobe, st.n_lobe, valid=ok & ins[:, kc], per_density=True)
            if v1 is not None:
                wc = wc * v1
            E = E + wc[:, None] * caps.channels[kc]
        acc_ = acc_ + radiance_terms(ctx, Ll, Lw, 1.0, E=E)
        return _cap_samples(ctx, st, acc_, k)

    return rays, body


def _env_strategy(ctx: Context, st: _Streams):
    """``(rays, body)`` of :func:`sample_passes` for the environment samples."""
    def rays(k):
        Ll2, Lw2, pe2, uv2 = env_ray(ctx.plan, ctx.env, ctx.frame, st.offset, k, ctx.ids, st.window)
        return Ll2, Lw2, pe2, taps(ctx.env, uv2)

    def body(acc_, k, drawn, v2):
        Ll2, Lw2, pe2, taps2 = drawn
        pb2 = ctx.sampler.pdf(Ll2, ctx.Vl)
        ok2 = (Ll2[:, 2] > 0) & (pe2 > 0)
        wgt2 = mis_weight(pe2, pb2, st.n_env, st.n_lobe, valid=ok2, per_density=True)
        if v2 is not None:
            wgt2 = wgt2 * v2
        return acc_ + radiance_terms(ctx, Ll2, Lw2, wgt2, taps2)

    return rays, body


def radiance(ctx: Context, acc):
    """``acc`` plus the lobe strategy's ``plan.samples`` samples and the environment's ``plan.n_env``, each
    weighted by the balance heuristic (and each cap's samples, when the environment has caps)."""
    if not has_lobe(ctx.plan):
        return acc
    st, vis = _streams(ctx), ctx.vis
    lob = sample_passes(ctx.plan.samples, *_lobe_strategy(ctx, st), jnp.zeros_like(acc),
                        None if vis is None else vis.lobe.T)
    if ctx.plan.n_env:
        lob = sample_passes(ctx.plan.n_env, *_env_strategy(ctx, st), lob, None if vis is None else vis.env.T)
    return acc + lob


def directions(ctx: Context):
    """``(the lobe samples' world directions (P, S, 3), the environment samples' (P, S_env, 3) or None)``."""
    plan, Vl, fr, ids = ctx.plan, ctx.Vl, ctx.frame, ctx.ids
    if not has_lobe(plan):
        return None, None
    offset = mis_offset(ctx.key, Vl.shape[0], Vl.dtype, plan, ids)
    sampler = _sampler(_lobes(plan, ctx.px, (1.0, 1.0)))  # sampling needs the widths only
    lobe = jax.vmap(lambda k: lobe_ray(plan, sampler, Vl, fr, offset, k, ids)[1], out_axes=1)(jnp.arange(plan.samples))
    if not plan.n_env:
        return lobe, None
    win = env_window(plan, ctx.env, ctx.px, mirror_ray(Vl, fr)[1])
    env = jax.vmap(lambda k: env_ray(plan, ctx.env, fr, offset, k, ids, win)[1], out_axes=1)(jnp.arange(plan.n_env))
    return lobe, env
