"""Spectral shading of G-buffer pixels under an environment (JAX, jitted).

Every visible pixel carries a normal N, a view direction V (towards the
camera) and the reflectance-map parameters at its UV (w, μ0, μ1). The
outgoing radiance is the rendering equation with the paper's blended BRDF
(Mochizuki et al., eq. 5)::

    L_o(λ) = ∫ [w f_hiraji + (1 − w) f_hamon](L, V, λ) cos θi L_env(L, λ) dL
             + Σ_lights f(L_j, V, λ) cos θi E_j(λ) / r_j²

with f·cos θi from :meth:`jkatana.models.Hiraji.brdf_cos` /
:meth:`jkatana.models.Hamon.brdf_cos` (normalised convention unless a
calibration is given). :func:`shade` is a dispatch: the terms every mode shares
are here (a perfect-mirror hiraji's one lookup, its view of a split cap, the
analytic lights), and the environment integral over the lobes is the plan's
integrator's (:data:`jkatana.render.integrators.INTEGRATORS`, a static,
trace-time choice recorded in ``Plan.mode``):

- ``"reference"``, ``"lowrank"``: lobe and environment importance sampling
  combined by multiple importance sampling (:mod:`jkatana.render.integrators.mis`);
- ``"paper"``, ``"paper-published"``: the paper's jittered, Gaussian-weighted
  rays (:mod:`jkatana.render.integrators.paper`);
- ``"prefiltered"``: split sum (:mod:`jkatana.render.integrators.prefiltered`).

Compact sources split off the map (:attr:`Environment.caps
<jkatana.render.environment.Environment.caps>`, spherical caps of uniform
radiance, :mod:`jkatana.light.sun`) are lights of their own: the deterministic
modes integrate them by a cap rule (:func:`shade_caps` alone, so that a frame
can shade them on the pixels a cap can reach), the sampling modes sample them.
Without caps none of this is traced.

The Fresnel factor may be folded into the environment (``Plan.fresnel_rank``,
:func:`~jkatana.render.fresnel_fold.fold_fresnel`): per sample a ``3R``-channel
lookup instead of one per wavelength, exact up to the rank of F(cos θ, λ).
Effects on demand (all decided on the host before tracing, so a switched-off
effect is absent from the compiled program): no hamon pixels → no
Torrance–Sparrow term; all hiraji μ0 below ``MIRROR_MU`` → a mirror lookup,
no lobe sampling; no point lights → none evaluated.

Spectra leave the jitted function as CIE XYZ with ``k = 1/∫ȳ dλ`` (a flat
spectrum of 1 has Y = 1; Mitsuba 3's film uses the same normalisation), and
optionally as spectra.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from jkatana.models.geometry import to_local
from jkatana.render.caps import _caps
from jkatana.render.environment import Environment, env_lookup, unbasis
from jkatana.render.fresnel_fold import Material, is_folded, table_lookup
from jkatana.render import integrators
from jkatana.render.integrators import integrator_for
from jkatana.render.integrators.base import (Context, accumulator, add_cap_rule, add_mirror_caps, add_mirror_like,
                                             cap_constants, context, has_lobe, mirror_ray, pixel_frame, ray_context)
from jkatana.render.plan import Light, Pixels, Plan, Rays, Visibility
from jkatana.render.points import PixelIds
from jkatana.render.regions import _fcos_terms


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


def _light_directions(plan: Plan, env: Environment, lights: Light | None, px: Pixels):
    """``(directions (P, n, 3), distances (P, n))`` of the lights and then of one shadow ray per pixel toward
    each split cap's centre (distance ∞)."""
    P, dtype = px.normal.shape[0], px.normal.dtype
    n = plan.lights if lights is not None else 0
    ls = [_light_ray(lights, j, px) for j in range(n)]
    dirs = [x[0] for x in ls]
    dists = [jnp.broadcast_to(x[2], (P,)) for x in ls]
    caps = _caps(env)
    if caps is not None:
        Cw = caps.world(env.rotation).astype(dtype)
        dirs += [jnp.broadcast_to(Cw[k], (P, 3)) for k in range(caps.count)]
        dists += [jnp.full((P,), jnp.inf, dtype)] * caps.count
    if dirs:
        return jnp.stack(dirs, 1), jnp.stack(dists, 1)
    return jnp.zeros((P, 0, 3), dtype), jnp.zeros((P, 0), dtype)


def ray_directions(plan: Plan, env: Environment, lights: Light | None, px: Pixels, key,
                   ids: PixelIds | None = None) -> Rays:
    """Every direction :func:`shade` will look up for these pixels and this key, as :class:`Rays`.

    Built from the same sampling helpers as :func:`shade` (same key → same
    directions: the integrator's ``directions``), so a host step can ray-cast them
    against occluders and hand the result back to :func:`shade` as a
    :class:`Visibility`. Pure JAX.

    An environment with split caps adds one direction per cap after the
    lights (``Rays.lights[:, plan.lights + k]``, distance ∞): the ray toward the
    cap's centre. Its visibility stands for the whole cap (a sub-degree sun:
    penumbrae narrower than the cap's angular size are not resolved), for the
    cap rule of the deterministic modes and for the cap's own samples in the
    Monte Carlo modes; lobe samples that fall in a cap keep their own
    visibility.
    """
    ctx = ray_context(plan, env, lights, px, key, ids)
    empty = jnp.zeros((px.normal.shape[0], 0, 3), px.normal.dtype)
    lobe, envd = integrator_for(plan.mode).strategy().directions(ctx)
    ldir, ldist = _light_directions(plan, env, lights, px)
    return Rays(mirror_ray(ctx.Vl, ctx.frame)[1], empty if lobe is None else lobe, empty if envd is None else envd,
                ldir, ldist)


def _output(plan: Plan, env: Environment, cmf, acc) -> tuple[Array, Array | None]:
    """:func:`shade`'s ``(XYZ, spectra or None)`` from its accumulator."""
    if plan.factored or is_folded(plan):
        return acc, None
    spectra = acc @ env.basis  # identity when not factored
    return spectra @ cmf, (spectra if plan.spectral else None)


def _add_mirror(ctx: Context, acc):
    """A perfect-mirror hiraji: one deterministic lookup along the mirror ray, and its view of each cap."""
    plan, Vl = ctx.plan, ctx.Vl
    if plan.hiraji and plan.mirror:
        _, Rw = mirror_ray(Vl, ctx.frame)
        acc = add_mirror_like(acc, ctx.px.w, env_lookup(ctx.env, Rw), jnp.clip(Vl[:, 2], 0.0, 1.0), Vl, ctx.vis,
                              ctx.combine)
    if ctx.caps is not None:
        acc = add_mirror_caps(plan, ctx.px, Vl, ctx.frame, ctx.env, ctx.caps, ctx.vis, ctx.combine, acc)
    return acc


def _add_lights(ctx: Context, acc):
    """The analytic lights (point: kind 0, directional: kind 1); a delta hiraji lobe never sees one."""
    plan, lights = ctx.plan, ctx.lights
    if not (plan.lights and lights is not None):
        return acc
    for j in range(plan.lights):
        Lw, falloff, _ = _light_ray(lights, j, ctx.px)
        if ctx.vis is not None:
            falloff = falloff * ctx.vis.lights[:, j]
        Ll = to_local(Lw, *ctx.frame)
        spec = lights.spectrum[j]
        for a, c in _fcos_terms(ctx.lobes, Ll, ctx.Vl):
            Fs = table_lookup(ctx.mat.ftable, c) * spec[None, :]
            if plan.factored:
                acc = acc + (a * falloff)[:, None] * (Fs @ ctx.cmf)
            else:
                acc = acc + (a * falloff)[:, None] * Fs @ unbasis(ctx.env)
    return acc


def shade_caps(plan: Plan, mat: Material, env: Environment, px: Pixels, cmf: Float[Array, "wl 3"],
               vis: Visibility | None = None) -> tuple[Array, Array | None]:
    """The split caps' share of :func:`shade` in the modes that integrate them by the cap rule
    (:attr:`Integrator.cap_rule <jkatana.render.integrators.Integrator.cap_rule>`: ``"prefiltered"``,
    ``"paper"``): each cap by the cap rule, and a perfect-mirror hiraji's view of it;
    ``(XYZ (P, 3), spectra or None)``.

    :func:`shade` with ``env``'s caps removed plus this is :func:`shade` (to float32 rounding: the
    terms are summed in another order), so a frame can shade the caps on its own subset of pixels
    (:func:`jkatana.render.caps.cap_pixels`). Pure JAX; jit with ``plan`` static.
    """
    integrator = integrator_for(plan.mode)
    if not integrator.cap_rule:
        modes = [i.name for i in integrators.INTEGRATORS.values() if i.cap_rule]
        raise ValueError(f"shade_caps: the cap rule of the modes {modes}, not {plan.mode!r}")
    dtype, P = px.normal.dtype, px.normal.shape[0]
    acc, combine = accumulator(plan, mat, env, cmf, P, dtype)
    vis = vis if plan.visibility else None
    caps = cap_constants(plan, env, vis, P, dtype)
    if caps is None:
        return _output(plan, env, cmf, acc)
    fr, Vl = pixel_frame(px)
    acc = add_mirror_caps(plan, px, Vl, fr, env, caps, vis, combine, acc)
    if has_lobe(plan):
        acc = add_cap_rule(plan, mat, px, Vl, fr, caps, None, combine, acc, tabulated=integrator.prefiltered)
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
    integrator = integrator_for(plan.mode)
    ctx, acc = context(plan, mat, env, lights, px, cmf, key, vis if plan.visibility else None, ids)
    if integrator.whole_map and ctx.caps is not None:
        raise ValueError(f"the {plan.mode} mode shades the whole map: build its environment without split_sun")
    acc = _add_mirror(ctx, acc)
    acc = integrator.strategy().radiance(ctx, acc)
    acc = _add_lights(ctx, acc)
    return _output(plan, env, cmf, acc)
