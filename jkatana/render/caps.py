"""Spherical-cap lights in the shader: a compact bright source split off the environment.

A sun found in the environment (:mod:`jkatana.light.sun`) travels as
:class:`~jkatana.render.environment.Caps`; the deterministic modes integrate each
cap against each lobe by a fixed rule (:func:`jkatana.light.capquad.cap_nodes`, or
Stroud's 4-point disc rule, Stroud 1971, for lobes much wider than the cap), and
the sampling modes draw one direction per cap, uniform in its cone, combined with
the other strategies by the balance heuristic (Veach & Guibas 1995). Without caps
none of this is traced. :func:`cap_pixels` bounds where a cap's term can matter (the
pixels whose mirror direction lies within a few lobe widths of it), so that a frame
can shade the caps on those pixels only.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool

from jkatana.light import capquad
from jkatana.models.geometry import tangent_frame, to_local
from jkatana.models.lobes import Gaussian, GaussianVCavity, Mixture, reflect
from jkatana.models.microfacet import gaussian_normalisation
from jkatana.render.environment import Caps, Environment
from jkatana.render.fresnel_fold import Material
from jkatana.render.plan import Pixels, Plan
from jkatana.render.points import mis_offset
from jkatana.render.regions import _lobes, _norms


def _caps(env: Environment) -> Caps | None:
    """The environment's caps, or None: then no cap code is traced."""
    return env.caps if env.caps is not None and env.caps.count else None


def _parts(lobes):
    """``[(lobe, weight, gain), ...]`` with every :class:`~jkatana.models.lobes.Mixture` split into its two parts
    (weights ``w·weight``, ``(1 − w)·weight``): the cap rule places its nodes by one width per lobe
    (:meth:`~jkatana.models.lobes.Lobe.reflected_width`), and a mixture's terms are its parts' terms so weighted."""
    out = []
    for lobe, weight, gain in lobes:
        if isinstance(lobe, Mixture):
            out += _parts([(lobe.first, weight * lobe.weight, gain), (lobe.second, weight * (1.0 - lobe.weight), gain)])
        else:
            out.append((lobe, weight, gain))
    return out


def _cap_rule_terms(lobes, Vl, fr, Cw, radius, rule: str):
    """``[(weight · ∫_cap a dω, Fresnel cosine at the cap centre), ...]`` per lobe term, ``(P,)`` each.

    ``rule``: ``"nodes"``: the rule of :func:`jkatana.light.capquad.cap_nodes` about each
    lobe's mirror direction with the lobe's own width
    (:meth:`~jkatana.models.lobes.Lobe.reflected_width`),
    :data:`~jkatana.light.capquad.CAP_RULE` nodes per point, any lobe width; ``"stroud"``: the 4 fixed
    directions of :func:`~jkatana.light.capquad.cap_disc_nodes`, for lobes at least
    :data:`~jkatana.light.capquad.STROUD_MIN_WIDTH` cap radii wide; or one of those per lobe part
    (:func:`_parts` order), comma-separated (``"nodes,stroud"``: a narrow hiraji lobe by the nodes,
    a wide hamon lobe by Stroud's 4 directions), as :func:`cap_rule_for` chooses. Applied to the
    Fresnel-free values ``a`` of the lobe objects; the Fresnel factor is taken at
    the cap's centre (it varies by ``|dF/dθ| · r`` across the cap, below 1e-4 for
    a sub-degree sun on iron).
    """
    Cl = to_local(Cw, *fr)
    out = []
    lobes = _parts(lobes)
    rules = _per_part(rule, len(lobes))
    if "stroud" in rules:
        Lw, qs = capquad.cap_disc_nodes(Cw, radius)  # (4, 3), (4,): the same for every pixel
        Ls = to_local(Lw[:, None, :], *fr)  # (4, P, 3)
    n_radial, n_azimuth = capquad.CAP_RULE
    R = jnp.stack([-Vl[:, 0], -Vl[:, 1], Vl[:, 2]], -1)
    N = jnp.asarray([0.0, 0.0, 1.0], Vl.dtype)
    for (lobe, weight, gain), part_rule in zip(lobes, rules):
        weight = weight if gain is None else weight * gain
        if part_rule == "stroud":
            for (a, _), (_, c) in zip(lobe.terms(Ls, Vl), lobe.terms(Cl, Vl)):
                out.append((weight * jnp.einsum("n,np->p", qs.astype(a.dtype), a), c))
            continue
        sigma = jnp.broadcast_to(jnp.maximum(lobe.reflected_width(), 1e-6), Vl.shape[:1]).astype(Vl.dtype)
        L, q = capquad.cap_nodes(R, Cl, radius, sigma, normal=N, n_radial=n_radial, n_azimuth=n_azimuth)
        nodes = lobe.terms(jnp.moveaxis(L, 0, 2), Vl)  # (A, Q, P): the pixel axis last, as the lobe's parameters
        qt = jnp.moveaxis(q, 0, 2).astype(Vl.dtype)
        for (a, _), (_, c) in zip(nodes, lobe.terms(Cl, Vl)):
            out.append((weight * jnp.sum(qt * a, axis=(0, 1)), c))
    return out


def _per_part(rule: str, n: int) -> list[str]:
    """``rule`` (one name, or one per lobe part, comma-separated) as ``n`` names."""
    rules = rule.split(",")
    if len(rules) == 1:
        rules = rules * n
    if len(rules) != n or any(r not in ("nodes", "stroud") for r in rules):
        raise ValueError(f"cap rule {rule!r}: 'nodes', 'stroud' or one of those for each of the {n} lobe parts")
    return rules


def _tabulated_norms(plan: Plan, mat: Material, px: Pixels, n: int = 128):
    """:func:`_norms` with the paper's normalisation N(μ) interpolated from ``n`` exact values.

    ``μ² N(μ)`` (:func:`~jkatana.models.microfacet.gaussian_normalisation`, a
    48-node quadrature per call) tends to ln2/π as μ → 0 and is a smooth function
    of μ² (its expansion in μ² starts ln2/π (1 + a μ² + …)), so it is evaluated at
    ``n`` nodes uniform in μ² over the pixels' range and interpolated linearly
    (relative error < 1e-5, ``tests/test_render_sun.py``): one interpolation per
    pixel instead of a quadrature. For the prefiltered mode, which otherwise
    evaluates no lobe, where the cap rule is the only user of N.
    """
    if plan.calibration is not None:
        return _norms(plan, mat, px)

    def table(mu):
        m = jnp.maximum(mu, 1e-8)
        s2 = m * m
        lo, hi = jnp.min(s2), jnp.max(s2)
        hi = jnp.maximum(hi, lo * (1 + 1e-6) + 1e-30)
        nodes = jnp.sqrt(jnp.linspace(lo, hi, n))
        g = gaussian_normalisation(nodes) * nodes * nodes
        t = (s2 - lo) / (hi - lo) * (n - 1)
        return jnp.interp(t, jnp.arange(n, dtype=t.dtype), g) / s2

    n0 = table(px.mu0) if (plan.hiraji and not plan.mirror) else None
    n1 = table(px.mu1) if plan.hamon else None
    return n0, n1


def cap_rule_for(plan: Plan, env: Environment, px: Pixels) -> str:
    """The cap rule the deterministic modes use for these pixels, per lobe part (:func:`_parts` order):
    ``"stroud"`` for a lobe at least :data:`~jkatana.light.capquad.STROUD_MIN_WIDTH` times wider than the
    largest cap at every pixel it weighs on, else ``"nodes"``; one name when all parts agree, else one per
    part, comma-separated. Each part keeps the error its rule states (:func:`_cap_rule_terms`): a frame's
    narrow hiraji lobe is integrated by the nodes, its wide hamon lobe by 4 directions. Host-side, on
    concrete pixels (a static choice, as ``Plan.fresnel_rank``)."""
    caps = _caps(env)
    if caps is None:
        return "nodes"
    widths = [np.asarray(jnp.where(weight > 0, lobe.reflected_width(), jnp.inf)).min(initial=np.inf)
              for lobe, weight, _ in _parts(_lobes(plan, px, (1.0, 1.0)))]
    if not widths:
        return "nodes"
    r_max = float(np.asarray(caps.radius).max())
    rules = ["stroud" if w >= capquad.STROUD_MIN_WIDTH * r_max else "nodes" for w in widths]
    return rules[0] if len(set(rules)) == 1 else ",".join(rules)


#: Widths past a cap's edge beyond which :func:`cap_pixels` leaves a pixel's cap term out: there the
#: lobes' facet term is at most ``exp(−CAP_REACH²/2)`` (1.5e-8) of its peak.
CAP_REACH = 6.0


def cap_pixels(plan: Plan, env: Environment, px: Pixels, reach: float = CAP_REACH) -> Bool[Array, "P"]:
    """The pixels whose cap term (:func:`_cap_rule_terms`, and a mirror hiraji's view of a cap) can matter:
    those whose mirror direction R lies within ``r_k + reach·σ`` of a cap's centre ``C_k``, σ the
    largest :meth:`~jkatana.models.lobes.Lobe.reflected_width` of the lobe parts the pixel weighs on.

    The bound, for the paper's lobes (:class:`~jkatana.models.lobes.Gaussian`,
    :class:`~jkatana.models.lobes.GaussianVCavity`), whose facet term is
    ``D = exp(−ln2 φ²/μ²)`` (Mochizuki et al., eq. 1) and σ = μ √(2/ln2): a light
    direction L is V turned half a turn about its half vector H (L = 2(V·H)H − V) and
    R is V turned half a turn about N; two half-turns, about H and about N, compose to
    a rotation through twice the angle between the axes, so ``∠(L, R) ≤ 2φ``.
    Every L of cap k has ``∠(L, R) ≥ ψ − r_k`` (ψ = ∠(R, C_k)), hence
    ``φ ≥ (ψ − r_k)/2`` and ``D ≤ exp(−(ψ − r_k)²/(2σ²))``: on a pixel left out,
    every cap direction's facet term is below ``exp(−reach²/2)`` of its peak (1.5e-8
    at the default 6), and so is the cap term, against what it would be with the
    facet term at its peak. For other lobes (GGX's and GTR's tails are not
    Gaussian) every pixel is kept. Pure JAX, exact in the chord form
    ``|R − C| ≤ 2 sin(min(ψ_max, π)/2)``.
    """
    caps = _caps(env)
    P = px.normal.shape[0]
    if caps is None:
        return jnp.zeros((P,), bool)
    parts = _parts(_lobes(plan, px, (1.0, 1.0)))
    if not all(isinstance(lobe, (Gaussian, GaussianVCavity)) for lobe, _, _ in parts):
        return jnp.ones((P,), bool)
    dtype = px.normal.dtype
    sigma = jnp.zeros((P,), dtype)
    for lobe, weight, _ in parts:
        s = jnp.broadcast_to(lobe.reflected_width(), (P,)).astype(dtype)
        sigma = jnp.maximum(sigma, jnp.where(jnp.broadcast_to(weight, (P,)) > 0, s, 0.0))
    R = reflect(px.view, px.normal)  # the mirror direction (world)
    Cw = caps.world(env.rotation).astype(dtype)  # (K, 3)
    chord = jnp.linalg.norm(R[:, None, :] - Cw[None], axis=-1)  # (P, K): 2 sin(ψ/2)
    psi_max = jnp.minimum(caps.radius.astype(dtype)[None] + reach * sigma[:, None], jnp.pi)
    return jnp.any(chord <= 2.0 * jnp.sin(0.5 * psi_max) + 1e-6, axis=-1)


def _cap_offsets(plan: Plan, key, P, dtype, ids, K, stream: int = 0x53554E):
    """Per cap, the random digital shifts of its cone samples: a stream of its own (``key`` folded with
    ``stream + k``), independent of the lobe and environment shifts (see :func:`mis_offset`)."""
    return [mis_offset(jax.random.fold_in(key, stream + k), P, dtype, plan, ids) for k in range(K)]


def _cap_ray(caps: Caps, Cw, k: int, u1, u2):
    """A direction uniform in solid angle in cap ``k`` (world): ``sin²(ψ/2) = u₁ sin²(r/2)``, φ = 2π u₂.

    The half-angle form keeps a sub-degree cone resolved in float32 (``1 − cos ψ``
    would not); density ``1/Ω_k`` (Pharr, Jakob & Humphreys, *PBRT* 4th ed., §A.5.6,
    uniform cone sampling).
    """
    c = Cw[k]
    t, b = tangent_frame(c)
    s = jnp.sqrt(u1) * jnp.sin(0.5 * caps.radius[k]).astype(u1.dtype)
    psi = 2.0 * jnp.arcsin(jnp.clip(s, 0.0, 1.0))
    phi = 2.0 * jnp.pi * u2
    sp = jnp.sin(psi)
    return (jnp.cos(psi)[:, None] * c + (sp * jnp.cos(phi))[:, None] * t + (sp * jnp.sin(phi))[:, None] * b)


