"""The paper's integrator (``"paper"``, ``"paper-published"``): jittered rays about the mirror direction.

Mochizuki et al. §5: a fixed number of jittered reflection rays (``Plan.samples``, 30 in the
paper) whose facet normals are stratified in a disk of radius 2.5 μ about the normal, averaged
with Gaussian weights D(φ, μ) (:func:`~jkatana.models.microfacet.gaussian_facet`). Each ray's
weight is D/pdf of the lobe mixture, and the sum is divided by Σ D: biased (truncated and
self-normalised) but cheap. The lobe per ray is chosen by the blend (w, 1 − w). With split caps
(``"paper"``) the rays see the remainder and the caps are added by the deterministic cap rule;
``"paper-published"`` is the same estimator on the whole map, exactly as published (a sun's
glint falls between its rays). The rays are drawn from the call's key, not from
:class:`~jkatana.render.points.PixelIds`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from jkatana.models.geometry import to_world
from jkatana.models.lobes import reflect
from jkatana.models.microfacet import gaussian_facet
from jkatana.render.integrators.base import Context, add_cap_rule, has_lobe, radiance_terms
from jkatana.render.regions import _mix_w


def _paper_grid(S: int):
    """The ``(radial, angular)`` strata of ``S`` rays: about √S each."""
    nu = max(1, int(round(math.sqrt(S))))
    return nu, -(-S // nu)


def paper_ray(ctx: Context, k):
    """The k-th of the paper's jittered rays: ``(L_local, L_world, φ, μ)``."""
    plan, px, Vl = ctx.plan, ctx.px, ctx.Vl
    nu, nv = _paper_grid(plan.samples)
    P = Vl.shape[0]
    kk = jax.random.fold_in(ctx.key, k)
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
    return Ll, to_world(Ll, *ctx.frame), phi, mu


def radiance(ctx: Context, acc):
    """``acc`` plus the Gaussian-weighted, self-normalised average of the rays, and the caps by the cap rule."""
    if not has_lobe(ctx.plan):
        return acc
    P, dtype = ctx.Vl.shape[0], ctx.Vl.dtype

    def body(carry, xs):
        acc_, wsum = carry
        k, v = xs
        Ll, Lw, phi, mu = paper_ray(ctx, k)
        gauss = gaussian_facet(phi, jnp.maximum(mu, 1e-7))
        pdf = ctx.sampler.pdf(Ll, ctx.Vl)
        ok = (Ll[:, 2] > 0) & (pdf > 0)
        g = jnp.where(ok, gauss / jnp.where(ok, pdf, 1.0), 0.0)  # Gaussian weight × 1/pdf → throughput
        if v is not None:
            g = g * v
        return (acc_ + radiance_terms(ctx, Ll, Lw, g), wsum + gauss), None

    xs = (jnp.arange(ctx.plan.samples), None if ctx.vis is None else ctx.vis.lobe.T)
    (lob, wsum), _ = jax.lax.scan(body, (jnp.zeros_like(acc), jnp.zeros((P,), dtype)), xs)
    acc = acc + lob / jnp.maximum(wsum, 1e-30)[:, None]
    if ctx.caps is not None:
        acc = add_cap_rule(ctx.plan, ctx.mat, ctx.px, ctx.Vl, ctx.frame, ctx.caps, ctx.lobes, ctx.combine, acc)
    return acc


def directions(ctx: Context):
    """``(the rays' world directions (P, S, 3), no environment samples)``."""
    if not has_lobe(ctx.plan):
        return None, None
    ks = jnp.arange(ctx.plan.samples)
    return jax.vmap(lambda k: paper_ray(ctx, k)[1], out_axes=1)(ks), None
