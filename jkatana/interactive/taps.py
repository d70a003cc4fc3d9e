"""The shader's tap pattern: the reflected lobe approximated by a few reads of the prefiltered environment.

Per (lobe, μ, cos θv) the shader reads the environment levels (prefiltered
with :func:`prefilter_kernel`, the kernel of
:func:`jkatana.light.prefilter.prefilter_level`) at T = :data:`N_TAPS`
directions rotated from the mirror direction R in the plane of incidence,
each at a fitted level width, with fitted weights (:func:`tap_fit`): filtered
importance sampling (Křivánek & Colbert 2008) with a pattern fitted to the
lobe instead of drawn from it. Where the map cannot resolve a fitted level
the moment-matched pattern is used instead (:func:`resolved_taps`). For a
region holding a long-tailed lobe (GGX, GTR, …: not the paper's) up to two
wider reads — the tail taps (:func:`tail_fit`) — put the light of the lobe's
tails, which the three taps miss, back where the lobe has it.
"""

from __future__ import annotations

import functools
import math
import types

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from jkatana.interactive.levels import MU_LEVELS
from jkatana.interactive.lobe_tables import PAPER_LOBES, lobe_lut, moment_taps
from jkatana.light.fresnel_basis import fresnel_basis
from jkatana.light.prefilter import LobeFamily, lobe_of_width, reflected_kernel, reflected_lobe
from jkatana.models import Conductor
from jkatana.models.lobes import Gaussian

#: Taps of the fitted lobe kernel (:func:`tap_fit`), read by the shader when ``JK_TAP_FIT`` is set.
N_TAPS = 3


def prefilter_kernel(sin2_half, mu_e, family: LobeFamily = Gaussian, n_quad: int = 1024):
    """The kernel the environment levels are prefiltered with, normalised to 1 over the sphere, at the
    direction x = sin²(ψ/2) from its centre: :func:`jkatana.light.prefilter.reflected_lobe` of
    ``family(mu_e)`` (the lobe's f_r cos θi at normal incidence, zero below the horizon; Walter et al.
    2007, Karis 2013), as the prefilter tabulates it. The normalisation 2π ∫ k sin ψ dψ is a trapezoid
    rule on ψ = (π/2) t², t uniform (nodes dense at the peak), so a JAX function with finite gradients
    in ``mu_e`` and in the direction; ``mu_e`` may be an array (broadcast against ``sin2_half``)."""
    mu_e = jnp.asarray(mu_e)
    lobe = family(mu_e)
    t = jnp.linspace(0.0, 1.0, n_quad, dtype=mu_e.dtype).reshape((n_quad,) + (1,) * mu_e.ndim)
    psi = 0.5 * jnp.pi * t * t
    k = reflected_lobe(lobe, jnp.sin(0.5 * psi) ** 2)
    norm = jnp.trapezoid(k * 2.0 * jnp.pi * jnp.sin(psi) * (jnp.pi * t), t, axis=0)
    return reflected_lobe(lobe, jnp.asarray(sin2_half, mu_e.dtype)) / norm


def view_frame(cos_v, xp=jnp):
    """The frame the lobe kernels and the cap table are tabulated in, for views at ``cos_v`` (any shape) in
    the x–z plane, N = z: ``(V, R, t, y)``, each ``(*cos_v.shape, 3)``, with V = (sin θv, 0, cos θv), R its
    mirror direction about N, t the unit vector in the plane of incidence orthogonal to R, towards N (the
    direction of positive ``a_par``; x at normal incidence, where N = R), and y = R × t across the plane.
    ``xp``: ``jax.numpy`` (differentiable) or ``numpy``."""
    cv = xp.asarray(cos_v)
    sv = xp.sqrt(xp.maximum(1.0 - cv ** 2, 0.0))
    zero = xp.zeros_like(sv)
    V = xp.stack([sv, zero, cv], axis=-1)
    R = xp.stack([-sv, zero, cv], axis=-1)
    tt = xp.asarray([0.0, 0.0, 1.0], cv.dtype) - cv[..., None] * R
    tn = xp.linalg.norm(tt, axis=-1, keepdims=True)
    t = xp.where(tn > 1e-9, tt / xp.maximum(tn, 1e-12), xp.asarray([1.0, 0.0, 0.0], cv.dtype))
    return V, R, t, xp.cross(R, t)


def lobe_kernel(model, conductor: Conductor, cos_v, n: int = 64, width=None):
    """The reflected lobe of ``model`` as a normalised kernel around the mirror direction R, on a grid.

    Angles from R: ``a_par`` along the plane of incidence (positive towards N) and ``a_perp`` across
    it, L = cos a_perp (cos a_par R + sin a_par t) + sin a_perp y, dω = cos a_perp da_par da_perp.
    The kernel is the lobe's own f_r cos θi (``model.brdf_cos``, summed over λ) at V = (sin θv, 0, cos θv),
    normalised so that Σ K dω = 1. With μ = ``width`` (default ``model.mu``) the grid spans ±min(14 μ, π)
    along the plane and ±min(14 μ max(cos θv, 0.15), π/2) across (the lobe narrows across the plane by
    ≈ cos θv).

    **Returns** ``(K (n, n), a_par (n, n), a_perp (n, n), dω (n, n))``.
    """
    dt = conductor.n.dtype
    mu = jnp.asarray(model.mu if width is None else width, dt)
    cv = jnp.asarray(cos_v, dt)
    V, R, t, y = view_frame(cv)
    lim_par = jnp.minimum(14.0 * mu, jnp.pi)
    lim_perp = jnp.minimum(14.0 * mu * jnp.maximum(cv, 0.15), jnp.pi / 2)
    u = (jnp.arange(n, dtype=dt) + 0.5) / n * 2 - 1
    ap, aq = jnp.meshgrid(u * lim_par, u * lim_perp, indexing="ij")
    L = ((jnp.cos(aq) * jnp.cos(ap))[..., None] * R + (jnp.cos(aq) * jnp.sin(ap))[..., None] * t
         + jnp.sin(aq)[..., None] * y)
    f = model.brdf_cos(L, jnp.broadcast_to(V, L.shape), conductor).sum(-1)
    dw = jnp.cos(aq) * (2 * lim_par / n) * (2 * lim_perp / n)
    K = f / jnp.maximum(jnp.sum(f * dw), 1e-30)
    return K, ap, aq, dw


def tap_kernel(params, mu, ap, aq, mu_min: Float[ArrayLike, ""] = 0.0):
    """The shader's kernel for tap parameters ``(s, o_1..o_T, l_1..l_T)``: T taps at angles o_j from R
    along the plane of incidence, weights softmax(l), each the prefilter kernel at width
    μ_e = max(μ e^s, mu_min) (the environment level the shader reads)."""
    T = (params.shape[-1] - 1) // 2
    s, o, l = params[0], params[1:1 + T], params[1 + T:]
    w = jax.nn.softmax(l)
    mu_e = jnp.maximum(mu * jnp.exp(s), mu_min)
    # sin²(α/2) for the angle α between L and tap j: 1 − cos α = 2 sin²(a_perp/2) + 2 cos a_perp sin²(d/2)
    x = jnp.sin(aq / 2)[None] ** 2 + jnp.cos(aq)[None] * jnp.sin((ap[None] - o[:, None, None]) / 2) ** 2
    return jnp.einsum("j,jab->ab", w, prefilter_kernel(x, mu_e))


@functools.partial(jax.jit, static_argnames=("family", "n"))
def _lobe_kernels(family, mu, conductor, cos_v, n: int):
    model = family(mu)
    return jax.vmap(lambda cv: lobe_kernel(model, conductor, cv, n, width=mu))(cos_v)


@jax.jit
def _fit_scan(K, ap, aq, dw, moments, mu, mu_min):
    """Least-squares tap fits for a batch of lobes ``K (B, C, n, n)`` (widths ``mu (B,)``), along
    decreasing cos θv (axis C), each warm-started from the previous one so that the tables are
    continuous in cos θv and bilinear lookups between entries stay meaningful. ``moments (B, C, 1 + 2T)``:
    the moment-matched pattern in the same layout, kept where the fit does not beat it."""
    import optimistix as optx

    solver = optx.LevenbergMarquardt(rtol=1e-5, atol=1e-7)
    spread = jnp.linspace(-0.25, 0.25, N_TAPS).astype(mu.dtype)

    def one(prev, m, Kc, apc, aqc, dwc, pm):
        sq = jnp.sqrt(dwc)
        # warm start, taps pulled apart by ±μ/4: coincident taps (the optimum at normal incidence) are a
        # saddle the solver cannot leave (their Jacobian columns are equal)
        p0 = prev.at[1:1 + N_TAPS].add(m * spread)

        def resid(p, _):
            r = (tap_kernel(p, m, apc, aqc, mu_min) - Kc) * sq
            return jnp.concatenate([r.ravel(), 1e-3 * p[1 + N_TAPS:]])   # keeps the softmax logits bounded
        sol = optx.least_squares(resid, solver, p0, max_steps=64, throw=False)
        p = sol.value
        err = jnp.sum(jnp.abs(tap_kernel(p, m, apc, aqc, mu_min) - Kc) * dwc)
        # never worse than the moment-matched binomial pattern (lobe_lut's), which is also the fallback
        err_m = jnp.sum(jnp.abs(tap_kernel(pm, m, apc, aqc, mu_min) - Kc) * dwc)
        better = jnp.isfinite(err) & jnp.all(jnp.isfinite(p)) & (err <= err_m)
        p, err = jnp.where(better, p, pm), jnp.where(better, err, err_m)
        idx = jnp.argsort(p[1:1 + N_TAPS])                                 # taps ordered by offset
        p = jnp.concatenate([p[:1], p[1:1 + N_TAPS][idx], p[1 + N_TAPS:][idx]])
        return p, err, (sol.result == optx.RESULTS.successful) & better

    def step(prev, xs):
        p, err, ok = jax.vmap(one)(prev, mu, *xs)
        return p, (p, err, ok)
    p0 = jnp.zeros((mu.shape[0], 1 + 2 * N_TAPS), mu.dtype)
    xs = tuple(jnp.moveaxis(x, 1, 0) for x in (K, ap, aq, dw, moments))
    _, (ps, errs, ok) = jax.lax.scan(step, p0, xs)
    return ps, errs, ok                                                      # (C, B, ...)


def tap_fit(conductor: Conductor, mus=MU_LEVELS, n_cos: int = 64, n: int = 32, lobes: tuple = PAPER_LOBES):
    """Filtered importance sampling pattern of the lobe, fitted per (cos θv, μ) for hiraji and hamon, whose
    lobes are ``lobes`` (families width ↦ lobe, :func:`jkatana.interactive.lobe_tables.region_lobes`).

    The shader approximates ∫ K(ω) L_env(ω) dω, K the reflected lobe normalised (:func:`lobe_kernel`),
    by Σ_j w_j L̃_{μ_e}(ω_j): T = :data:`N_TAPS` reads of the environment prefiltered at width μ_e,
    at directions ω_j rotated from R by o_j in the plane of incidence. This is filtered importance
    sampling (Křivánek & Colbert 2008, "Real-time Shading with Filtered Importance Sampling"), with the
    taps, weights and filter width not drawn from the lobe but fitted to it: least squares
    ∫ (K − Σ_j w_j K_{μ_e}(·, ω_j))² dω (optimistix Levenberg–Marquardt), so the sum has the lobe's
    skew (off normal incidence the lobe's peak stays near R while its mean moves towards N) and a small
    bright source inside the lobe (a sun; a softbox edge) receives the lobe's own weight. The
    moment-matched pattern (:func:`~jkatana.interactive.lobe_tables.moment_taps`) has the lobe's mean and
    variance but not its skew: too little weight near the peak at oblique view (θv = 55–65°).

    **Returns** ``(cos, taps (2, n_mu, n_cos, 1 + 2T), l1 (2, n_mu, n_cos), ok (2, n_mu, n_cos))``:
    per model (0 hiraji, 1 hamon), ``taps`` = (s, o_1..o_T, w_1..w_T) with s = log(μ_e/μ), offsets in
    radians towards N, weights summing to 1; ``l1`` = ∫ |K − fit| dω (0: exact, 2: disjoint), and
    whether the solver converged.
    """
    cos = np.linspace(0.0, 1.0, n_cos)
    cos_c = np.maximum(cos, 1e-3)[::-1]                     # fit from normal incidence towards grazing
    dt = conductor.n.dtype
    mu_min = float(np.min(mus))
    kern = [_lobe_kernels(family, jnp.asarray(mu, dt), conductor, jnp.asarray(cos_c, dt), n)
            for family in lobes for mu in mus]
    K, ap, aq, dw = (jnp.stack([k[i] for k in kern]) for i in range(4))     # (2·n_mu, n_cos, n, n)
    mu_b = jnp.asarray(np.tile(np.asarray(mus, np.float64), 2), dt)
    # the moment-matched binomial pattern (1/4, 1/2, 1/4 at mean, mean ± √2 spread; lobe_lut) as logits
    b = np.asarray(fresnel_basis(conductor, 1).basis)                      # the moments do not depend on it
    _, _, shape = lobe_lut(conductor, b, mus, n_cos=n_cos, lobes=lobes)     # (2, n_mu, n_cos, 3)
    moments = moment_taps(shape[:, :, ::-1].reshape(2 * len(mus), n_cos, 3))
    moments[..., 1 + N_TAPS:] = np.log(moments[..., 1 + N_TAPS:])                # weights as logits
    ps, errs, good = _fit_scan(K, ap, aq, dw, jnp.asarray(moments, dt), mu_b, jnp.asarray(mu_min, dt))
    ps = np.asarray(ps, np.float64)[::-1].transpose(1, 0, 2).reshape(2, len(mus), n_cos, -1)
    w = np.exp(ps[..., 1 + N_TAPS:] - ps[..., 1 + N_TAPS:].max(-1, keepdims=True))
    taps = np.concatenate([ps[..., :1 + N_TAPS], w / w.sum(-1, keepdims=True)], -1)
    l1 = np.asarray(errs, np.float64)[::-1].T.reshape(2, len(mus), n_cos)
    ok = np.asarray(good)[::-1].T.reshape(2, len(mus), n_cos)
    return cos, taps, l1, ok


#: Reach of :func:`polar_lobe_kernel`'s grid in widths μ: GGX keeps 1/(1 + 24²) ≈ 0.2 % of its facet
#: distribution's mass beyond a half-angle of 24 α (Walter et al. 2007, eq. 33).
TAIL_REACH = 48.0
#: Tail taps a region may read (:func:`tail_fit`): a nearer and a farther part of a long-tailed lobe's tails.
N_TAIL = 2
#: Radius (in μ) beyond which :func:`tail_fit` puts the lobe's energy back with the tail taps.
TAIL_FROM = 4.0
#: Edges (in μ) of the rings around R whose energies :func:`tail_fit`'s choice of levels matches.
TAIL_RINGS = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 48.0)
#: Largest fraction of a tail tap's read that may lie below the surface's horizon (:func:`tail_fit` turns the
#: tap towards N until it does: :func:`horizon_clearance`).
TAIL_BELOW = 0.05


#: Nodes of the prefilter kernels' radial profiles (:func:`kernel_profiles`), uniform in u = x^{1/4}, x = sin²(ψ/2),
#: from the centre to the horizon (x = ½, where the kernel drops to zero): dense at the peak (the narrowest level,
#: 0.0125 rad, falls to half its peak near node 1090). As many as the prefilter's kernel tables
#: (:func:`jkatana.light.prefilter.kernel_table`), whose compiled program they share.
N_PROFILE = 8192
#: u at the kernel's horizon, the profiles' last node.
_U_HORIZON = 0.5 ** 0.25


def profile_nodes() -> np.ndarray:
    """The nodes u = x^{1/4} of :func:`kernel_profiles`."""
    return np.linspace(0.0, _U_HORIZON, N_PROFILE)


def kernel_profiles(mu_e) -> np.ndarray:
    """The prefilter kernels of widths ``mu_e`` (any shape) as radial profiles ``(*mu_e.shape, N_PROFILE)``: their
    values at x = sin²(ψ/2) = u⁴ for the nodes u of :func:`profile_nodes`, zero beyond the last (the horizon), read
    back anywhere by :func:`profile_read`. Each is the paper's Gaussian lobe's :func:`reflected_lobe` (through
    :func:`~jkatana.light.prefilter.reflected_kernel`, the program that prefilters the environment: no compilation
    of its own) normalised to 1 over the sphere, where dω = 16π u³ du (trapezoid rule): :func:`prefilter_kernel`."""
    mu_e = np.asarray(mu_e, np.float64)
    u = profile_nodes()
    x, dw = np.minimum(u ** 4, 0.5), 16.0 * np.pi * u ** 3              # the last node on the horizon
    widths, which = np.unique(mu_e.ravel(), return_inverse=True)
    if widths.size == 0:
        return np.zeros(mu_e.shape + (N_PROFILE,))
    lobes = [lobe_of_width(Gaussian, float(m)) for m in widths]
    xs = jnp.asarray(x, jnp.result_type(*jax.tree.leaves(lobes[0])))
    out = np.asarray([np.asarray(k) for k in [reflected_kernel(lobe, xs) for lobe in lobes]], np.float64)
    out /= np.trapezoid(out * dw, u, axis=-1)[:, None]
    return out[which].reshape(mu_e.shape + (N_PROFILE,))


def profile_read(prof: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Kernels tabulated by :func:`kernel_profiles`, ``prof (*P, N_PROFILE)``, at directions ``x (*lead, m)`` (sin² of
    half the angle from each kernel's centre; ``P`` broadcasts against ``lead``, as a level's profile serves every
    view): linear in u = x^{1/4} up to the horizon, zero beyond it; ``(*lead, m)``."""
    P = prof.shape[:-1]
    pos = np.sqrt(np.sqrt(np.clip(x, 0.0, 1.0))) * ((N_PROFILE - 1) / _U_HORIZON)
    i0 = np.minimum(pos.astype(np.int32), N_PROFILE - 2)
    f = pos - i0
    at = i0 + (np.arange(math.prod(P), dtype=np.int32) * N_PROFILE).reshape(P + (1,))
    flat = np.ascontiguousarray(prof).reshape(-1)
    return np.where(x <= 0.5, flat[at] * (1.0 - f) + flat[at + 1] * f, 0.0)


def below_fraction(mu_e, h) -> np.ndarray:
    """The fraction of the prefilter kernel of width ``mu_e`` (:func:`prefilter_kernel`; a scalar, or ``(L,)`` for a
    leading axis of levels) that lies beyond a great circle at angular distance ``h`` (radians, 0 ≤ h < π/2, any
    shape) from its centre: the part of a read centred at elevation h above a surface's horizon that comes from
    below it. The ring of radius ψ about the centre lies beyond the circle over acos(tan h / tan ψ)/π of its length
    (0 for ψ ≤ h, all of it for ψ ≥ π − h); the rings are summed with the kernel's weight k(ψ) dω = 16π u³ k du on
    its profile's nodes (:func:`kernel_profiles`, trapezoid rule)."""
    mu_e, h = np.asarray(mu_e, np.float64), np.asarray(h, np.float64)
    u = profile_nodes()
    w = kernel_profiles(np.atleast_1d(mu_e)) * (16.0 * np.pi * u ** 3)                # (L, n)
    psi = (2.0 * np.arcsin(u * u)).reshape((N_PROFILE,) + (1,) * h.ndim)
    b = np.sin(h) * np.cos(psi) / np.maximum(np.cos(h) * np.sin(psi), 1e-30)
    part = np.arccos(np.clip(b, -1.0, 1.0)) / np.pi                                # (n, *h.shape)
    lead = (-1,) + (1,) * h.ndim
    out = np.trapezoid(w.reshape(w.shape + (1,) * h.ndim) * part, u, axis=1) / np.trapezoid(w, u, axis=1).reshape(lead)
    return out.reshape(mu_e.shape + h.shape)


def horizon_clearance(mu_e, below: float = TAIL_BELOW, n_h: int = 128) -> np.ndarray:
    """The elevation above a surface's horizon (radians) at which a read of the level of width ``mu_e`` (a scalar or
    ``(L,)``) takes at most ``below`` of its light from beneath it (:func:`below_fraction`, which falls with the
    elevation; π/2 where no elevation does)."""
    mu_e = np.asarray(mu_e, np.float64)
    hs = np.linspace(0.0, 0.5 * np.pi, n_h, endpoint=False)
    f = below_fraction(mu_e, hs).reshape(-1, n_h)
    return np.asarray([np.interp(-below, -fl, hs, right=0.5 * np.pi) for fl in f]).reshape(mu_e.shape)


def _spectral_sum(conductor: Conductor, n: int = 1025):
    """A conductor's Fresnel factor summed over its wavelengths, Σ_λ F(cos θ, λ), as a one-band conductor that a
    lobe's ``brdf_cos`` takes (an object with its ``fresnel``): the sum tabulated on ``n`` cosines and read linearly
    (F is smooth in cos θ: the polar kernels agree with the full spectral sum to 1e-5 of their peak, at a
    sixty-first of the Fresnel work). A function, not a class: the tail table's key reads its source, and
    :func:`inspect.getsource` of a class parses the whole module, which CPython 3.11 cannot do on two threads at
    once."""
    cos = jnp.linspace(0.0, 1.0, n, dtype=conductor.n.dtype)
    total = jnp.sum(conductor.fresnel(cos), -1)
    return types.SimpleNamespace(fresnel=lambda c: jnp.interp(jnp.clip(c, 0.0, 1.0), cos, total)[..., None])


def polar_lobe_kernel(model, conductor: Conductor, cos_v, n_psi: int = 48, n_chi: int = 32, width=None):
    """The reflected lobe of ``model`` as a normalised kernel around R on a polar grid reaching its tails.

    Angle ψ from R (ψ = ψ_max u², u uniform: nodes dense at the peak; ψ_max = min(:data:`TAIL_REACH` μ, π))
    and azimuth χ from the plane of incidence (χ = 0 towards N), so that L = cos ψ R + sin ψ (cos χ t +
    sin χ y) with t, y as :func:`lobe_kernel`'s, dω = sin ψ dψ dχ. The kernel is the lobe's f_r cos θi
    (``model.brdf_cos`` summed over λ, :func:`_spectral_sum`) at V = (sin θv, 0, cos θv), normalised so that
    Σ K dω = 1: unlike :func:`lobe_kernel`'s ±14 μ box it holds a long-tailed lobe's far tails (GGX, GTR), whose
    light the lobe table's energy (:func:`~jkatana.interactive.lobe_tables.lobe_integral` with ``tails``) counts.

    **Returns** ``(K, a_par, a_perp, dω, ψ)``, each ``(n_psi, n_chi)``; a_par, a_perp as :func:`lobe_kernel`'s.
    """
    dt = conductor.n.dtype
    mu = jnp.asarray(model.mu if width is None else width, dt)
    cv = jnp.asarray(cos_v, dt)
    V, R, t, y = view_frame(cv)
    top = jnp.minimum(TAIL_REACH * mu, jnp.pi)
    u = (jnp.arange(n_psi, dtype=dt) + 0.5) / n_psi
    chi = (jnp.arange(n_chi, dtype=dt) + 0.5) / n_chi * 2 * jnp.pi
    psi, ch = jnp.meshgrid(top * u * u, chi, indexing="ij")
    st, ct = jnp.sin(psi), jnp.cos(psi)
    L = ct[..., None] * R + (st * jnp.cos(ch))[..., None] * t + (st * jnp.sin(ch))[..., None] * y
    f = model.brdf_cos(L, jnp.broadcast_to(V, L.shape), _spectral_sum(conductor))[..., 0]
    dw = st * (2 * top * u / n_psi)[:, None] * (2 * jnp.pi / n_chi)
    K = f / jnp.maximum(jnp.sum(f * dw), 1e-30)
    a_par = jnp.arctan2(st * jnp.cos(ch), ct)
    a_perp = jnp.arcsin(jnp.clip(st * jnp.sin(ch), -1.0, 1.0))
    return K, a_par, a_perp, dw, psi


def weighted_tap_kernel(taps, mu, ap, aq, mu_min: Float[ArrayLike, ""] = 0.0):
    """:func:`tap_kernel` of a pattern in :func:`tap_fit`'s returned layout ``(s, o_1..o_T, w_1..w_T)``: weights,
    not logits (floored at 1e-30 before their logarithm, so that a zero weight stays finite in float32)."""
    T = (taps.shape[-1] - 1) // 2
    return tap_kernel(jnp.concatenate([taps[:1 + T], jnp.log(jnp.maximum(taps[1 + T:], 1e-30))]), mu, ap, aq, mu_min)


def tail_kernel(taps, tail, mu, ap, aq, mu_min: Float[ArrayLike, ""], mu_max: Float[ArrayLike, ""]):
    """The shader's kernel with tail taps: the three taps ``taps (1 + 2T)`` (:func:`tap_fit`'s layout, width
    μ e^s, offsets o_j, weights w_j summing to 1) and the tail taps ``tail (N, 3)`` (:func:`tail_fit`'s rows
    (s_t, o_t, w_t)), each read at its own width μ e^{s_t} clamped to [mu_min, mu_max] (the widest prefiltered
    level) at offset o_t: (1 − Σ_t w_t) Σ_j w_j K_j + Σ_t w_t K_t."""
    out = (1.0 - jnp.sum(tail[:, 2])) * weighted_tap_kernel(taps, mu, ap, aq, mu_min)
    for s_t, o_t, w_t in tail:
        x = jnp.sin(aq / 2) ** 2 + jnp.cos(aq) * jnp.sin((ap - o_t) / 2) ** 2
        out = out + w_t * prefilter_kernel(x, jnp.clip(mu * jnp.exp(s_t), mu_min, mu_max))
    return out


@functools.partial(jax.jit, static_argnames=("family", "n_psi", "n_chi"))
def _polar_kernels(family, mu, conductor, cos_v, n_psi: int, n_chi: int):
    """:func:`polar_lobe_kernel` of ``family(mu)`` at each of ``cos_v (C,)``: ``(K, a_par, a_perp, dω, ψ)``, each
    ``(C, n_psi, n_chi)`` (the only part of the tail fit that evaluates the lobe: one compilation per family)."""
    return jax.vmap(lambda cv: polar_lobe_kernel(family(mu), conductor, cv, n_psi, n_chi, width=mu))(cos_v)


def _tail_rows(family, mu, conductor, cos_v, taps, levels, clear, mu_min, n_psi: int, n_chi: int,
               level_profiles: np.ndarray | None = None) -> np.ndarray:
    """The tail taps per cos θv for the lobe ``family(mu)`` read by the three taps ``taps (C, 1 + 2T)``
    (weights, not logits), candidates the prefiltered ``levels`` and the height above the horizon each needs
    (``clear``, :func:`horizon_clearance`); see :func:`tail_fit`. Rows ``(C, 3 N_TAIL + 1)``:
    ``(s, o, w)`` of each tail tap, narrower first, then ∫ |K − mix| dω.

    The lobe's kernel comes from JAX (:func:`_polar_kernels`); the reads of the levels and of the three taps are
    the prefilter kernel's profiles (:func:`kernel_profiles`, ``level_profiles`` those of ``levels`` when the
    caller has them) and the choice among them runs in NumPy, float64: no compilation beyond the lobe's own."""
    mu, mu_min = float(mu), float(mu_min)
    levels, clear = np.asarray(levels, np.float64), np.asarray(clear, np.float64)
    taps, cos_v = np.asarray(taps, np.float64), np.asarray(cos_v, np.float64)
    dt = conductor.n.dtype
    C, n_lv = len(cos_v), len(levels)
    K, ap, aq, dw, psi = (np.asarray(a, np.float64).reshape(C, -1) for a in
                          _polar_kernels(family, jnp.asarray(mu, dt), conductor, jnp.asarray(cos_v, dt), n_psi, n_chi))
    prof = kernel_profiles(levels) if level_profiles is None else level_profiles
    # sin²(α/2) of the angle α between a grid direction and a read at angle o from R in the plane of incidence:
    # sin²(a_perp/2) + cos a_perp sin²((a_par − o)/2), with sin((a − o)/2) expanded (one sine per node, not per read)
    s2, sa, ca, cq = np.sin(aq / 2) ** 2, np.sin(ap / 2), np.cos(ap / 2), np.cos(aq)

    def reads(o):                                                                  # o (C, n) → (C, n, nodes)
        d = sa[:, None] * np.cos(o / 2)[..., None] - ca[:, None] * np.sin(o / 2)[..., None]
        return s2[:, None] + cq[:, None] * d * d
    T = (taps.shape[-1] - 1) // 2
    mu_e = np.maximum(mu * np.exp(taps[:, 0]), mu_min)                             # the three taps' level
    F3 = np.einsum("ct,ctp->cp", taps[:, 1 + T:], profile_read(kernel_profiles(mu_e)[:, None], reads(taps[:, 1:1 + T])))
    far = psi > TAIL_FROM * mu
    Kd = K * dw
    e_lobe = np.sum(np.where(far, Kd, 0.0), -1)
    o_t = np.sum(np.where(far, Kd * ap, 0.0), -1) / np.maximum(e_lobe, 1e-30)
    # each level read at o_t, or turned further towards N until its centre (at θv − o from N) is as high above the
    # horizon as the level's width needs (horizon_clearance), never past N
    th = np.arccos(np.clip(cos_v, -1.0, 1.0))
    o_l = np.clip(th[:, None] - 0.5 * np.pi + clear, o_t[:, None], np.maximum(o_t, th)[:, None])      # (C, L)
    Ft = profile_read(prof, reads(o_l))                                            # (C, L, nodes)
    # the cells whose energies the mix matches: the rings around R, and below the horizon (L·N ≤ 0, N = z), where
    # the lobe has none but a wide read, symmetric about its direction, reaches (a bright floor seen through the
    # surface); the mix (1 − Σw) F3 + Σ w_l F_l has cell energies r3 + Σ w_l D_l, linear in w
    _, R, tv, yv = view_frame(cos_v, np)
    below = cq * (np.cos(ap) * R[:, 2:] + np.sin(ap) * tv[:, 2:]) + np.sin(aq) * yv[:, 2:] <= 0.0
    ring = np.searchsorted(np.asarray(TAIL_RINGS[1:-1]), psi / mu)
    cells = np.concatenate([ring[..., None] == np.arange(len(TAIL_RINGS) - 1), below[..., None]], -1) * dw[..., None]
    r3 = np.matmul(F3[:, None], cells)[:, 0]                                       # (C, cells)
    D = np.matmul(Ft, cells) - r3[:, None]                                         # (C, L, cells)
    b = np.matmul(K[:, None], cells)[:, 0] - r3                                    # the lobe: 0 below
    # the weights put the lobe's energy beyond TAIL_FROM μ back exactly (Σ_t w_t d_t = e, d_t the energy there
    # that level t's read adds over the three taps'; weights ≥ 0, Σ ≤ 0.9). Along that line a pair's cell residuals
    # are v − w_i u, and their L1 norm (what the mix misplaces, bounding its error under any environment of bounded
    # radiance) is convex and piecewise linear in w_i: its minimum lies where a residual vanishes (w_i = v_c/u_c) or
    # at an end of the feasible interval (either level alone)
    e_far = (e_lobe - np.sum(np.where(far, F3 * dw, 0.0), -1))[:, None]           # (C, 1)
    d = np.matmul(Ft, np.where(far, dw, 0.0)[..., None])[..., 0] - (e_lobe[:, None] - e_far)    # (C, L)
    i, j = np.triu_indices(n_lv)                                                   # level pairs, i ≤ j (i = j: one)
    di, dj = d[:, i], d[:, j]
    ok = (di > 1e-6) & (dj > 1e-6) & (levels[i] > mu) & (levels[j] > mu)
    dj_ = np.where(ok, dj, 1.0)
    u = D[:, i] - (di / dj_)[..., None] * D[:, j]                                  # (C, pairs, cells)
    v = b[:, None] - (e_far / dj_)[..., None] * D[:, j]
    # feasible w_i: w_j = (e − w_i d_i)/d_j ≥ 0, w_i ≥ 0, w_i + w_j ≤ 0.9
    wider = dj > di
    hi = np.minimum(e_far / np.where(ok, di, 1.0),
                    np.where(wider, (0.9 - e_far / dj_) / np.where(wider, 1.0 - di / dj_, 1.0), np.inf))
    lo = np.where(wider, 0.0, np.maximum(0.0, (0.9 - e_far / dj_) / np.where(dj < di, 1.0 - di / dj_, -1.0)))
    ok &= hi >= lo
    cand = np.concatenate([v / np.where(np.abs(u) > 1e-30, u, 1e-30), lo[..., None], hi[..., None]], -1)
    cand = np.clip(cand, lo[..., None], hi[..., None])                             # (C, pairs, cells + 2)
    l1c = np.sum(np.abs(v[:, :, None, :] - cand[..., None] * u[:, :, None, :]), -1)
    best = np.argmin(l1c, -1)[..., None]
    wi = np.take_along_axis(cand, best, -1)[..., 0]
    wj = np.maximum((e_far - wi * di) / dj_, 0.0)                                   # ≥ 0 but for rounding
    err = np.where(ok, np.take_along_axis(l1c, best, -1)[..., 0], np.inf)
    pair = i != j
    wi, wj = np.where(pair, wi, np.minimum(e_far / np.where(ok, di, 1.0), 0.9)), np.where(pair, wj, 0.0)
    c, k = np.arange(C), np.argmin(err, -1)
    usable = np.isfinite(err[c, k]) & (e_far[:, 0] > 1e-6)
    wi, wj = np.where(usable, wi[c, k], 0.0), np.where(usable, wj[c, k], 0.0)
    mix = (1.0 - wi - wj)[:, None] * F3 + wi[:, None] * Ft[c, i[k]] + wj[:, None] * Ft[c, j[k]]
    l1 = np.sum(np.abs(mix - K) * dw, -1)
    s_i = np.where(wi > 0, np.log(levels[i[k]] / mu), 0.0)
    s_j = np.where(wj > 0, np.log(levels[j[k]] / mu), 0.0)
    return np.stack([s_i, o_l[c, i[k]], wi, s_j, o_l[c, j[k]], wj, l1], -1)


def tail_fit(conductor: Conductor, taps: np.ndarray, mus=MU_LEVELS, n_cos: int = 64, lobes: tuple = PAPER_LOBES,
             n_psi: int = 48, n_chi: int = 32):
    """Tail taps per (cos θv, μ) for the regions' lobes ``lobes`` that are not the paper's.

    Three taps prefiltered with the paper's Gaussian (:func:`tap_fit`) hold a long-tailed lobe's core but not
    its tails: GGX (Walter et al. 2007) keeps 1/(1 + k²) of its facet mass beyond a half-angle of k α, so
    12–21 % of the reflected light lies beyond 4 μ from R, where the taps' Gaussian kernels hold almost
    nothing, and an environment brighter there than near R (the sky around a sun, a softbox) comes out too
    dark. GTR at γ < 2 (Burley 2012) and a two-lobe mixture's haze reach further still: a power law spans
    more radii than one prefiltered level holds. The tail taps are up to :data:`N_TAIL` further reads of the
    environment at wider prefiltered levels: the shader reads (1 − Σ_t w_t) Σ_j w_j L̃_j + Σ_t w_t L̃_t. On the
    polar grid of :func:`polar_lobe_kernel` (which reaches the tails) their offset is the in-plane mean angle of the
    lobe's light beyond :data:`TAIL_FROM` μ from R, or, for a level too wide for that direction's height above the
    surface's horizon, the offset that lifts it to the height where at most :data:`TAIL_BELOW` of its read lies
    below the horizon (:func:`horizon_clearance`): off normal view the lobe's far light is cut off by the horizon on
    R's side and lies towards N, and a read reaching under the horizon shows what the surface hides (under a studio
    light its bright floor, up to a fifth of a facet's light); their weights (≥ 0, Σ ≤ 0.9) put the lobe's energy
    beyond that radius back; their levels (a pair among the prefiltered levels wider than μ, ``mus``, or one) and
    the split between them are those whose mix misplaces the least light (L1) over the rings :data:`TAIL_RINGS`
    around R and one more cell, below the horizon: the lobe has no light there, but a wide read, symmetric about its
    direction, reaches across it (a bright floor seen through the surface). No iteration: each pair's optimum is at
    one of a few breakpoints, a choice among the levels the shader can read.

    **Returns** ``(taps, tail (2, n_mu, n_cos, N_TAIL, 3), l1 (2, n_mu, n_cos))``: ``taps`` unchanged
    (:func:`tap_fit`'s layout), the tail taps (s_t = log(μ_t/μ), offset o_t towards N, weight w_t; narrower
    first, s_t = 0 where w_t = 0) and ∫ |K − mix| dω on the polar grid; regions holding the paper's lobe get
    w_t = 0 (and l1 0: not evaluated there).
    """
    taps = np.array(taps, np.float64)
    tail = np.zeros(taps.shape[:3] + (N_TAIL, 3))
    l1 = np.zeros(taps.shape[:3])
    cos_c = np.maximum(np.linspace(0.0, 1.0, n_cos), 1e-3)
    levels = np.asarray(mus, np.float64)
    clear, prof = horizon_clearance(levels), kernel_profiles(levels)
    for m, family in enumerate(lobes):
        if family in PAPER_LOBES:
            continue
        for k, mu in enumerate(levels):
            rows = _tail_rows(family, mu, conductor, cos_c, taps[m, k], levels, clear, levels.min(), n_psi, n_chi, prof)
            tail[m, k], l1[m, k] = rows[:, :3 * N_TAIL].reshape(-1, N_TAIL, 3), rows[:, -1]
    return taps, tail, l1


def core_taps(base: np.ndarray, mus, c: float) -> tuple[np.ndarray, np.ndarray]:
    """Three taps for a lobe whose core is that of the base family at c times its width
    (:func:`~jkatana.interactive.lobe_tables.family_core`), from the base's fitted taps ``base (n_mu, n_cos,
    1 + 2T)`` (:func:`tap_fit`'s layout): at level μ_k, the base's pattern fitted at the level μ_j nearest to
    c μ_k (in log μ), scaled by c μ_k / μ_j — offsets times that ratio, filter width μ_e = c μ_k e^{s_j}, so
    s = s_j + ln c, weights kept. Exact where the base lobe's kernel is self-similar in its width (a narrow
    lobe: f_r depends on the facet slope over the width, Walter et al. 2007, eqs. 33, 35); the tail tap
    (:func:`tail_fit`, run on the lobe itself) puts back what the core's pattern misses.

    **Returns** ``(taps (n_mu, n_cos, 1 + 2T), j (n_mu,))``: the taps and the base level each is read from."""
    mus = np.asarray(mus, np.float64)
    log_mu = np.log(mus)
    target = np.log(c * mus)
    j = np.abs(target[:, None] - log_mu[None, :]).argmin(-1)
    ratio = c * mus / mus[j]
    out = np.array(base[j], np.float64)
    out[..., 0] += math.log(c)
    out[..., 1:1 + N_TAPS] *= ratio[:, None, None]
    return out, j


#: The functions whose source text keys the tail table (:func:`jkatana.interactive.tables.cached_tail_fit`).
TAIL_SOURCES = (view_frame, _spectral_sum, polar_lobe_kernel, kernel_profiles, profile_read,
                below_fraction, horizon_clearance, _polar_kernels, _tail_rows, tail_fit)


#: The fitted pattern is used where its filter width μ_e spans at least this many texels of the map.
MIN_FIT_TEXELS = 2.0


def resolved_taps(taps: np.ndarray, spread: np.ndarray, mus, height: int, tail: np.ndarray | None = None):
    """The fitted taps where the map resolves them, the moment-matched ones elsewhere.

    The fit (:func:`tap_fit`) models each tap as the continuous prefilter kernel of width μ_e; the
    shader reads a prefiltered equirectangular map of ``height`` rows, bilinearly. Where μ_e is below
    :data:`MIN_FIT_TEXELS` texels (π/height rad each) the map does not resolve the fitted kernel's
    shape, and a small bright source (a sun of ~2 texels) lands on whichever texel the fitted offsets
    happen to hit; the moment pattern, wider, averages over it (the sun-glint view of
    ``experiments/interactive_agreement.py`` compares both). So per table entry: fitted if
    μ e^s ≥ MIN_FIT_TEXELS·π/height, else moments.

    With a ``tail`` table (:func:`tail_fit`'s ``(2, n_mu, n_cos, N_TAIL, 3)``) also returns it. A region whose
    tail taps are in use (a long-tailed lobe, not the paper's) falls back to the moment pattern of its own three
    taps (their mean, spread and filter width: :func:`fitted_moments`) and keeps its tail taps: the lobe's
    moments (``spread``) count its tails, which the tail taps read, so their pattern with the tail taps would
    count them twice, and without them spreads the tails' light evenly over the core's reach.
    """
    mu_e = np.asarray(mus, np.float64)[None, :, None] * np.exp(taps[..., 0])
    use = mu_e >= MIN_FIT_TEXELS * np.pi / height
    fallback = moment_taps(spread)
    if tail is None:
        return np.where(use[..., None], taps, fallback)
    long_tailed = np.any(tail[..., 2] > 0, axis=(1, 2, 3))[:, None, None, None]
    fallback = np.where(long_tailed, moment_taps(fitted_moments(taps)), fallback)
    keep_tail = (use[..., None] | long_tailed)[..., None]
    return np.where(use[..., None], taps, fallback), np.where(keep_tail, tail, 0.0)


def fitted_moments(taps: np.ndarray) -> np.ndarray:
    """The moments of a tap pattern ``(..., 1 + 2T)`` (:func:`tap_fit`'s layout, weights summing to 1) in
    :func:`~jkatana.interactive.lobe_tables.lobe_lut`'s ``spread`` layout ``(..., 3)``: its filter width's
    log ratio s, the spread √(Σ w (o − m)²) of its offsets about their mean m = Σ w o, and m, so that
    :func:`~jkatana.interactive.lobe_tables.moment_taps` of them has the pattern's first and second moments."""
    o, w = taps[..., 1:1 + N_TAPS], taps[..., 1 + N_TAPS:]
    mean = np.sum(w * o, -1)
    sd = np.sqrt(np.maximum(np.sum(w * (o - mean[..., None]) ** 2, -1), 0.0))
    return np.stack([taps[..., 0], sd, mean], -1)


#: The functions whose source text keys the tap table (:func:`jkatana.interactive.tables.tap_fit_key`).
FIT_SOURCES = (reflected_lobe, prefilter_kernel, view_frame, lobe_kernel, tap_kernel, _lobe_kernels, _fit_scan, tap_fit)
