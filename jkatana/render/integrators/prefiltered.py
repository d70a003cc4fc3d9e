"""The ``"prefiltered"`` integrator: split sum, no noise.

Per lobe, the environment pre-convolved with the reflection lobe for a few widths μ
(:attr:`~jkatana.render.environment.Environment.prefiltered`, or a region's own lobe's levels,
:attr:`~jkatana.render.environment.Environment.lobe_prefiltered`), looked up at the mirror
direction and multiplied by the Fresnel factor at the view's cosine (Karis 2013, "Real Shading
in Unreal Engine 4", the split-sum approximation). An approximation whose error is measured
(``benchmarks/bench_render.py``). The lobe's visibility is that of the mirror direction. Split
caps are added by the deterministic cap rule (:func:`~jkatana.render.integrators.base.add_cap_rule`,
N(μ) tabulated).
"""

from __future__ import annotations

import jax.numpy as jnp

from jkatana.render.environment import lookup_prefiltered_many
from jkatana.render.integrators.base import Context, add_cap_rule, add_mirror_like, has_lobe, mirror_ray


def _region_levels(ctx: Context):
    """``[(blend weight, μ, levels, gain or None), ...]`` of the regions with a lobe: each region's levels are
    the paper's lobe's, or its own lobe's (albedo included) times its gain (calibrated convention)."""
    plan, px, env = ctx.plan, ctx.px, ctx.env
    regions = [(weight, mu, region) for on, weight, mu, region in
               ((plan.hiraji and not plan.mirror, px.w, px.mu0, 0), (plan.hamon, 1.0 - px.w, px.mu1, 1)) if on]
    keys = (plan.hiraji_lobe, plan.hamon_lobe)
    if any(keys[r] is not None for _, _, r in regions) and len(env.lobe_prefiltered) != 2:
        raise ValueError("a region with its own lobe needs its levels: build the environment with "
                         "prefilter_lobes")
    return [(weight, mu, env.prefiltered if keys[r] is None else env.lobe_prefiltered[r],
             None if (keys[r] is None or plan.calibration is None) else ctx.norms[r])
            for weight, mu, r in regions]


def radiance(ctx: Context, acc):
    """``acc`` plus F(cos θv) × each region's prefiltered environment at the mirror direction, and the caps."""
    if not has_lobe(ctx.plan):
        return acc
    _, Rw = mirror_ray(ctx.Vl, ctx.frame)
    cos = jnp.clip(ctx.Vl[:, 2], 0.0, 1.0)
    regions = _region_levels(ctx)
    found = lookup_prefiltered_many(ctx.env, [mu for _, mu, _, _ in regions], Rw, [lv for _, _, lv, _ in regions])
    for (weight, _, _, gain), E in zip(regions, found):
        acc = add_mirror_like(acc, weight if gain is None else weight * gain, E, cos, ctx.Vl, ctx.vis, ctx.combine)
    if ctx.caps is not None:
        acc = add_cap_rule(ctx.plan, ctx.mat, ctx.px, ctx.Vl, ctx.frame, ctx.caps, None, ctx.combine, acc,
                           tabulated=True)
    return acc


def directions(ctx: Context):
    """No lobe or environment samples: the lobe's one direction is the mirror ray (``Rays.mirror``)."""
    return None, None
