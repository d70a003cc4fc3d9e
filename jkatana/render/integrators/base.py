"""What every integrator reads: the pixels' shading context and the terms the modes share.

:class:`Context` gathers, once per call of :func:`jkatana.render.shading.shade`, what the
integrators of :mod:`jkatana.render.integrators` estimate from: the plan, the inputs, each
pixel's tangent frame and view direction, its lobes (:mod:`jkatana.render.regions`, blended
by w and 1 − w as the paper's eq. 5, Mochizuki et al.) and the accumulator's space
(:func:`accumulator`). The terms here are those several modes add: the lobes' f·cos θi·F·E
along a direction (:func:`radiance_terms`), a mirror-like lookup (:func:`add_mirror_like`)
and the deterministic cap rule (:func:`add_cap_rule`).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax.numpy as jnp
from jaxtyping import Array

from jkatana.light.envmap import Taps, bilinear_taps, gather_taps
from jkatana.models.geometry import tangent_frame, to_local, to_world
from jkatana.render.caps import _cap_rule_terms, _caps, _tabulated_norms
from jkatana.render.environment import Caps, Environment, env_lookup
from jkatana.render.fresnel_fold import Material, is_folded, table_lookup
from jkatana.render.plan import Light, Pixels, Plan, Visibility
from jkatana.render.points import PixelIds
from jkatana.render.regions import _fcos_terms, _lobes, _norms, _sampler


class CapConstants(NamedTuple):
    """The split caps of a frame: world centres ``(K, 3)``, per cap its channels broadcast to the pixels, per
    cap its shadow rays' visibility (or ``None``), and per cap the uniform density over its cone (1/Ω)."""

    caps: Caps
    centres: Array
    channels: list
    visibility: list
    density: Array


class Context(NamedTuple):
    """One call's shading inputs and what is derived from them before any mode's estimate.

    ``frame``: the tangent frame ``(t, b, N)``; ``Vl``: the view direction in it; ``norms``, ``lobes``,
    ``sampler``: :func:`~jkatana.render.regions._norms`, :func:`~jkatana.render.regions._lobes` and their
    mixture (``None`` without a lobe); ``combine(cos, E)``: F(cos)·E in the accumulator's space
    (:func:`accumulator`); ``caps``: :class:`CapConstants`, or ``None`` without split caps.
    """

    plan: Plan
    mat: Material
    env: Environment
    lights: Light | None
    px: Pixels
    cmf: Array
    key: Any
    vis: Visibility | None
    ids: PixelIds | None
    frame: tuple
    Vl: Array
    norms: tuple
    lobes: list
    sampler: Any
    combine: Callable
    caps: CapConstants | None


def pixel_frame(px: Pixels):
    """Per-pixel tangent frame and the view direction in it."""
    N = px.normal
    t, b = tangent_frame(N)
    return (t, b, N), to_local(px.view, t, b, N)


def mirror_ray(Vl, fr):
    """The view's mirror direction about the normal: ``(local, world)``."""
    Rl = jnp.stack([-Vl[:, 0], -Vl[:, 1], Vl[:, 2]], -1)
    return Rl, to_world(Rl, *fr)


def has_lobe(plan: Plan) -> bool:
    """Whether any region has a lobe to integrate (a perfect-mirror hiraji has none)."""
    return (plan.hiraji and not plan.mirror) or plan.hamon


def taps(env: Environment, uv) -> Taps:
    """The bilinear taps of map coordinates ``uv`` in ``env``'s channels
    (:func:`~jkatana.light.envmap.bilinear_taps`)."""
    return bilinear_taps(*uv, env.channels.shape[0], env.channels.shape[1])


def accumulator(plan: Plan, mat: Material, env: Environment, cmf, P: int, dtype):
    """``(zero accumulator, combine)`` of :func:`~jkatana.render.shading.shade`: ``combine(cos, E)`` is F(cos)·E
    in the accumulator's space: XYZ from ``3R`` folded channels (``Plan.fresnel_rank``,
    :func:`~jkatana.render.fresnel_fold.fold_fresnel`), XYZ from the basis's channels (``Plan.factored``:
    Fresnel, basis spectra and CMFs in one ``(T, J, 3)`` table), else the environment's channels (full
    spectra)."""
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


def cap_constants(plan: Plan, env: Environment, vis: Visibility | None, P: int, dtype) -> CapConstants | None:
    """The environment's split caps as :class:`CapConstants` for ``P`` pixels, or ``None`` without caps."""
    caps = _caps(env)
    if caps is None:
        return None
    Cw = caps.world(env.rotation).astype(dtype)
    Ecap = [jnp.broadcast_to(c.astype(dtype), (P, c.shape[-1])) for c in caps.channels]
    cap_vis = [None if vis is None else vis.lights[:, plan.lights + k] for k in range(caps.count)]
    return CapConstants(caps, Cw, Ecap, cap_vis, (1.0 / caps.solid_angle()).astype(dtype))


def context(plan: Plan, mat: Material, env: Environment, lights: Light | None, px: Pixels, cmf, key,
            vis: Visibility | None, ids: PixelIds | None) -> tuple[Context, Array]:
    """``(Context, zero accumulator)`` of one call of :func:`~jkatana.render.shading.shade`."""
    fr, Vl = pixel_frame(px)
    norms = _norms(plan, mat, px)
    lobes = _lobes(plan, px, norms)
    acc, combine = accumulator(plan, mat, env, cmf, px.normal.shape[0], px.normal.dtype)
    caps = cap_constants(plan, env, vis, px.normal.shape[0], px.normal.dtype)
    ctx = Context(plan, mat, env, lights, px, cmf, key, vis, ids, fr, Vl, norms, lobes,
                  _sampler(lobes) if lobes else None, combine, caps)
    return ctx, acc


def ray_context(plan: Plan, env: Environment, lights: Light | None, px: Pixels, key,
                ids: PixelIds | None) -> Context:
    """A :class:`Context` for an integrator's ``directions`` only (:func:`~jkatana.render.shading.ray_directions`):
    the frame, view and random streams, without material, accumulator, lobes or caps."""
    fr, Vl = pixel_frame(px)
    return Context(plan, None, env, lights, px, None, key, None, ids, fr, Vl, None, None, None, None, None)


def radiance_terms(ctx: Context, Ll, Lw, weight, taps_=None, E=None):
    """Σ_lobes scalar·F(cos)·E(L) · weight, in the accumulator's space (``taps_``: the bilinear taps of ``Lw``
    in the map, :func:`taps`; ``E``: the incident channels if already known)."""
    terms = _fcos_terms(ctx.lobes, Ll, ctx.Vl)
    if E is None:
        E = env_lookup(ctx.env, Lw) if taps_ is None else gather_taps(ctx.env.channels, taps_)  # (P, J)
    total = 0.0
    for a, c in terms:
        total = total + (a * weight)[:, None] * ctx.combine(c, E)
    return total


def add_mirror_like(acc, weight, E, cos, Vl, vis: Visibility | None, combine):
    """``acc`` plus ``weight·F(cos)·E`` where the view is above the surface (times the mirror ray's visibility)."""
    wv = jnp.where(Vl[:, 2] > 0, weight, 0.0)
    if vis is not None:
        wv = wv * vis.mirror
    return acc + wv[:, None] * combine(cos, E)


def add_mirror_caps(plan: Plan, px: Pixels, Vl, fr, env: Environment, caps: CapConstants, vis, combine, acc):
    """A perfect-mirror hiraji sees a cap where its mirror ray falls inside it."""
    if not (plan.hiraji and plan.mirror):
        return acc
    _, Rw = mirror_ray(Vl, fr)
    ins = caps.caps.inside(Rw, env.rotation).astype(Vl.dtype)
    for k in range(caps.caps.count):
        acc = add_mirror_like(acc, px.w * ins[:, k], caps.channels[k], jnp.clip(Vl[:, 2], 0.0, 1.0), Vl, vis, combine)
    return acc


def add_cap_rule(plan: Plan, mat: Material, px: Pixels, Vl, fr, caps: CapConstants, lobes, combine, acc,
                 tabulated: bool = False):
    """The deterministic modes: ``acc`` plus each cap integrated against each lobe by ``plan.cap_rule``
    (:func:`~jkatana.render.caps._cap_rule_terms`; ``None``: ``"nodes"``). ``lobes``: the context's, or ``None``
    (made here, with N(μ) from :func:`~jkatana.render.caps._tabulated_norms` where ``tabulated``: the
    prefiltered mode evaluates no lobe but the cap's, so a table beats a quadrature per pixel)."""
    rule = plan.cap_rule or "nodes"
    if lobes is None:
        lobes = _lobes(plan, px, _tabulated_norms(plan, mat, px) if tabulated else _norms(plan, mat, px))
    for k in range(caps.caps.count):
        for a, c in _cap_rule_terms(lobes, Vl, fr, caps.centres[k], caps.caps.radius[k].astype(Vl.dtype), rule):
            wgt = a if caps.visibility[k] is None else a * caps.visibility[k]
            acc = acc + wgt[:, None] * combine(c, caps.channels[k])
    return acc
