"""Tables baked from the JAX models for the GLSL shaders (no model is re-derived in GLSL).

The interactive path evaluates, per pixel, the environment-lit radiance of the
paper's blend of hiraji (eq. 1) and hamon (eq. 2) lobes,

    L_o(λ) = ∫ f_r(L, V; λ) cos θi L_env(L, λ) dω_i,

integrated to CIE XYZ (eq. 6), with three textures that are all computed here
from :mod:`jkatana.models` and :mod:`jkatana.spectral`:

1. **Low-rank spectral basis of the Fresnel term.** The SVD of iron's
   F(θ, λ) on a cos θ × λ grid gives F ≈ Σ_r a_r(θ) b_r(λ) (rank 3 is exact
   to ~1e-6 for iron; the benchmark measures ranks 1–4).
2. **Environment projected on the basis and prefiltered per roughness.**
   P_{r,c}(ω; μ) = Σ_λ b_r(λ) W_c(λ) L̃_μ(ω, λ), where W_c is the CIE 1931
   weighting of eq. (6) and L̃_μ the environment convolved with the
   paper's Gaussian lobe at normal incidence, K(α) ∝ D(α/2, μ)/cos(α/2)
   up to the horizon, α ≤ 90° (:mod:`jkatana.light.prefilter`, exact on an
   equirectangular grid), for
   each μ level on the source box-downsampled to ≥ :data:`TEXELS_PER_MU`
   texels per μ (:func:`level_shape`) and resampled bilinearly to the
   source's size for the shader. One layer per μ level, log-spaced.
3. **Lobe lookup table** A_r(cos θv, μ) = Σ_λ b_r(λ) ∫ f_r cos θi dω_i for
   the hiraji and hamon models exactly as :meth:`Hiraji.brdf_cos` and
   :meth:`Hamon.brdf_cos` define them (normalised, uncalibrated convention),
   by quadrature in half-vector space. It carries the Fresnel variation over
   the lobe, the V-cavity G of eq. (2) and the lobe's energy, so that per pixel

       XYZ_c = Σ_r A_r(cos θv, μ) · P_{r,c}(R; μ)            (R = reflect(−V, N))

   which is exact when the environment is constant over the lobe; the
   residual (lobe stretching at grazing view, environment gradients inside
   the lobe) is what the comparison with :mod:`jkatana.render` measures. This is
   the split-sum approximation of Karis (2013), "Real Shading in Unreal
   Engine 4", with the spectral dimension factored by the SVD.

4. **Compact bright sources split off.** A sun holds most of an outdoor
   map's power in a few texels, which no prefiltered level of a 128-row
   map resolves. :func:`jkatana.light.sun.split_compact_sources` splits such
   sources off as spherical caps (direction C, angular radius r, spectral
   radiance L_cap); the *remainder* is what is projected and prefiltered,
   and each cap (at most :data:`MAX_CAPS`) becomes shader uniforms: C, r
   and Q_{r,c} = Ω_cap Σ_λ b_r(λ) W_c(λ) L_cap(λ) (:func:`sun_caps`). The
   shader adds, over a tap pattern j (direction R_j, weight w_j, level
   width μ_j),

       XYZ_c += Σ_r A_r Q_{r,c} Σ_j w_j k̂(∠(R_j, C); μ_j, r),

   the lobe integrated against the cap instead of the map. The pattern is
   the moment-matched one (:func:`moment_taps`) even where the map is read
   with the fitted taps (:func:`tap_fit`): those match the lobe in L1 over
   the sphere, not point by point, and a cap samples the kernel at about
   one point (the agreement test of the sun-glint view under
   ``sunrise.exr`` measures the difference).
   k̂ is the normalised prefilter kernel
   D(α/2, μ)/cos(α/2) (the paper's Gaussian lobe in reflected directions, as
   :func:`jkatana.light.prefilter.kernel_table` tabulates it) in closed form, exp(−c h²)/cos h
   with h = α/2, c = ln2/μ², normalised by
   8π ∫₀^{π/2} e^{−c h²} sin h dh ≈ (4π/c)(1 − 1/(6c) + 1/(60c²)) (sin h to
   its fifth-order Taylor term), convolved with the cap's uniform disc as a
   Gaussian of the same mass whose value at the cap's centre is the exact
   one: the kernel is a Gaussian of variance σ² = 2/c per axis in α, a disc
   of radius r about its centre holds 1 − e^{−r²/2σ²} = 1 − e^{−x} of it,
   x = c r²/4, so c → c' = 4 (1 − e^{−x})/r² (→ c (1 − x/2), the moment-matched
   1/c + r²/8, for a small cap; a peak of 1, a mirror's, for a large one)
   (:func:`cap_kernel`; tested against the kernel integrated over the cap by
   :func:`jkatana.light.capquad.cap_nodes`' rule). Without a compact source
   nothing is split and the shader has no cap code (``JK_CAPS`` 0).

Plus the display transform: the XYZ → linear RGB matrix of
:func:`jkatana.spectral.xyz_to_rgb_matrix` (eq. 7) and a 1-D table of
:func:`jkatana.spectral.encode` (eq. 8) indexed by √x so that it is dense
near black.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.light.fresnel_basis import basis_of_table
from jkatana.light.prefilter import level_shape  # noqa: F401 (the levels' resolution, for readers)
from jkatana.light.prefilter import prefilter_level as _light_prefilter_level
from jkatana.models import Conductor, Hamon, Hiraji, gaussian_facet
from jkatana.spectral import DEFAULT_GRID, WavelengthGrid
from jkatana.render.film import film_weights
from jkatana.spectral.colorimetry import encode, xyz_to_rgb_matrix

#: μ levels of the prefiltered environment (radians, log-spaced, ratio √2; 0.05 is a level).
MU_LEVELS = 0.0125 * np.sqrt(2.0) ** np.arange(11)
#: Largest rank the shaders support (one RGBA texel holds 4 coefficients).
MAX_RANK = 4
#: Most compact sources (sun caps) the shaders take as uniforms (:func:`jkatana.light.sun.find_compact_sources`'s
#: default ``max_sources``).
MAX_CAPS = 4


def fresnel_basis(conductor: Conductor, rank: int, n_cos: int = 256):
    """The bake's view of :func:`jkatana.light.fresnel_basis.basis_of_table`: F on ``n_cos`` cosines uniform
    on [0, 1] (the shaders' texture coordinate), rank 1–4.

    **Returns:** ``(cos, a, b, rel_err)``: the cos grid, coefficients, orthonormal spectral
    basis (rows, the first with a positive sum), and the max relative error of the reconstruction.
    """
    if not 1 <= rank <= MAX_RANK:
        raise ValueError(f"rank must be 1..{MAX_RANK}, got {rank}")
    cos = np.linspace(0.0, 1.0, n_cos)
    F = np.asarray(conductor.fresnel(jnp.asarray(cos, conductor.n.dtype)), np.float64)
    fb = basis_of_table(cos, F, rank)
    a, b = np.asarray(fb.coefficients), np.asarray(fb.basis)
    rel_err = float(np.max(np.abs(a @ b - F) / F))
    return cos, a, b, rel_err


#: Level resolution of the bake: texel height ≤ μ / this (the Gaussian kernel's FWHM, 4μ, spans ≥ 8 texels).
TEXELS_PER_MU = 2.0


def prefilter_level(image: np.ndarray, mu: float, *, texels_per_mu: float = TEXELS_PER_MU,
                    chunk: int = 32) -> np.ndarray:
    """An equirectangular image ``(H, W, C)`` convolved with the paper's Gaussian lobe of width ``mu``
    (:func:`jkatana.light.prefilter.prefilter_level`, kernel sampled at texel centres), at
    :func:`level_shape`'s resolution for ``texels_per_mu``."""
    return _light_prefilter_level(image, mu, texels_per_mu=texels_per_mu, sub=1, chunk=chunk)


def upsample(level: np.ndarray, height: int, width: int) -> np.ndarray:
    """Bilinear resampling of an equirectangular ``(h, w, C)`` level to ``(height, width, C)``
    (texel centres; longitude wraps, latitude clamps at the poles)."""
    h, w = level.shape[:2]
    if (h, w) == (height, width):
        return np.asarray(level)
    y = np.clip((np.arange(height) + 0.5) * h / height - 0.5, 0.0, h - 1.0)
    j0 = np.minimum(np.floor(y).astype(int), max(h - 2, 0))
    fy = (y - j0)[:, None, None].astype(level.dtype)
    rows = level[j0] * (1 - fy) + level[np.minimum(j0 + 1, h - 1)] * fy                # (height, w, C)
    x = (np.arange(width) + 0.5) * w / width - 0.5
    i0 = np.floor(x).astype(int)
    fx = (x - i0)[None, :, None].astype(level.dtype)
    return rows[:, i0 % w] * (1 - fx) + rows[:, (i0 + 1) % w] * fx


def prefilter(image: np.ndarray, mu: float) -> np.ndarray:
    """:func:`prefilter_level` resampled to the image's resolution (:func:`upsample`)."""
    H, W = image.shape[:2]
    return upsample(prefilter_level(image, mu), H, W)


def halfvector_quadrature(mu, n_phi: int = 32, n_psi: int = 48, extent: float = 4.5):
    """Quadrature of the half-vector hemisphere around N = +z for a lobe of width μ.

    Gauss–Legendre in the facet angle φ ∈ [0, min(extent·μ, π/2)] (D < 1e-6
    beyond 4.5 μ), uniform in azimuth; ``mu`` may be a traced JAX scalar.
    **Returns** ``(H (Q, 3), dω_h (Q,))``.
    """
    x, wx = np.polynomial.legendre.leggauss(n_phi)
    top = jnp.minimum(extent * mu, jnp.pi / 2)
    phi = (jnp.asarray(x) + 1) / 2 * top
    wphi = jnp.asarray(wx) / 2 * top
    psi = (np.arange(n_psi) + 0.5) / n_psi * 2 * np.pi
    P, S = jnp.meshgrid(phi, jnp.asarray(psi), indexing="ij")
    Hh = jnp.stack([jnp.sin(P) * jnp.cos(S), jnp.sin(P) * jnp.sin(S), jnp.cos(P)], -1).reshape(-1, 3)
    w = (wphi[:, None] * jnp.sin(P) * (2 * np.pi / n_psi)).reshape(-1)
    return Hh, w


def lobe_integral(model, conductor: Conductor, V_local, n_phi=32, n_psi=48, moments: bool = False):
    """∫ f_r cos θi dω_i (spectral) of ``model`` (Hiraji or Hamon) for local view directions ``V (..., 3)``.

    Quadrature in half-vector space (:func:`halfvector_quadrature` scaled to
    ``model.mu``), dω_i = 4 (V·H) dω_h (Walter et al. 2007, eq. 14). With
    ``moments=True`` also returns the lobe's mean squared angle from the mirror
    direction (weights summed over λ).
    """
    dt = conductor.n.dtype
    Hh, wh = halfvector_quadrature(jnp.asarray(model.mu, dt), n_phi, n_psi)
    V = jnp.asarray(V_local, dt)[..., None, :]
    Hj = Hh.astype(dt)
    vh = jnp.sum(V * Hj, -1, keepdims=True)
    L = 2 * vh * Hj - V
    f = model.brdf_cos(L, V, conductor)                                             # (..., Q, wl)
    dw = 4.0 * jnp.maximum(vh, 0.0) * wh.astype(dt)[:, None]
    total = jnp.sum(f * dw, axis=-2)
    if not moments:
        return total
    # angles of L from the mirror direction R, along the plane of incidence (t, towards N) and across it (y)
    R = V * jnp.asarray([-1.0, -1.0, 1.0], dt)
    nt = jnp.asarray([0.0, 0.0, 1.0], dt) - R[..., 2:3] * R
    t = nt / jnp.maximum(jnp.linalg.norm(nt, axis=-1, keepdims=True), 1e-12)
    t = jnp.where(jnp.linalg.norm(nt, axis=-1, keepdims=True) > 1e-9, t, jnp.asarray([1.0, 0.0, 0.0], dt))
    y = jnp.cross(R, t)
    lr = jnp.sum(L * R, -1)
    a_par = jnp.arctan2(jnp.sum(L * t, -1), lr)
    a_perp = jnp.arctan2(jnp.sum(L * y, -1), lr)
    wsum = jnp.sum(f * dw, axis=-1)
    norm = jnp.maximum(jnp.sum(wsum, -1), 1e-30)
    mean = jnp.sum(wsum * a_par, -1) / norm
    var_par = jnp.sum(wsum * (a_par - mean[..., None]) ** 2, -1) / norm
    var_perp = jnp.sum(wsum * a_perp ** 2, -1) / norm
    return total, (mean, var_par, var_perp)


@jax.jit
def _lut_column(mu, conductor, V, b):
    out, shape = [], []
    for cls in (Hiraji, Hamon):
        model = cls(jnp.ones((), mu.dtype), mu)
        total, (mean, var_par, var_perp) = lobe_integral(model, conductor, V, moments=True)
        out.append(total @ b.T)
        iso = 0.5 * (var_par[-1] + var_perp[-1])                  # V[-1] is normal incidence: isotropic
        shape.append(jnp.stack([0.5 * jnp.log(var_perp / iso),       # across-plane width → prefilter level
                                jnp.sqrt(jnp.maximum(var_par - var_perp, 0.0)),   # ± tap offset (rad)
                                mean], -1))                          # lobe centre offset towards N (rad)
    return jnp.stack(out), jnp.stack(shape)


def lobe_lut(conductor: Conductor, b: np.ndarray, mus=MU_LEVELS, n_cos: int = 64):
    """A_r(cos θv, μ) for hiraji and hamon: ``(2, n_mu, n_cos, rank)``, cos grid uniform on [0, 1].

    Also returns ``shape (2, n_mu, n_cos, 3)``, the reflected lobe's moments
    from the same quadrature, in angles from the mirror direction R: (0) half
    the log of its variance across the plane of incidence relative to normal
    incidence, (1) the extra spread along the plane, √(var_par − var_perp),
    (2) the mean offset along the plane towards N. Off normal incidence the
    lobe narrows across the plane (by ≈ cos θ) but not along it; the shader
    reads the environment prefiltered for the across-plane width at three
    taps, R rotated in the plane by mean and mean ± √2·spread with weights
    ¼, ½, ¼ — a kernel with the lobe's first and second moments that keeps
    the peak of a small bright source (a sun) within ~10 %.
    """
    cos = np.linspace(0.0, 1.0, n_cos)
    cos_c = np.maximum(cos, 1e-3)
    V = np.stack([np.sqrt(1 - cos_c ** 2), np.zeros_like(cos_c), cos_c], -1)
    dt = conductor.n.dtype
    cols = [_lut_column(jnp.asarray(mu, dt), conductor, jnp.asarray(V, dt), jnp.asarray(b, dt)) for mu in mus]
    out = np.stack([np.asarray(c[0], np.float64) for c in cols], axis=1)
    shape = np.stack([np.asarray(c[1], np.float64) for c in cols], axis=1)
    return cos, out, shape


#: Taps of the fitted lobe kernel (:func:`tap_fit`), read by the shader when ``JK_TAP_FIT`` is set.
N_TAPS = 3


def _prefilter_kernel_normalised(sin2_half, mu_e, n_quad: int = 1024):
    """The prefilter kernel of :func:`_kernel`, D(α/2, μ_e)/cos(α/2), as a JAX function of
    sin²(α/2) (smooth where α → 0, unlike arccos), normalised to 1 over the sphere (trapezoid rule in α
    on [0, min(12 μ_e, π)]); finite gradients in ``mu_e`` and in the direction."""
    def k(x):
        x = jnp.clip(x, 0.0, 1.0 - 1e-6)           # α = π (x = 1): arcsin and √(1 − x) have infinite slopes
        pos = x > 0
        half = jnp.where(pos, jnp.arcsin(jnp.sqrt(jnp.where(pos, x, 1.0))), 0.0)
        return gaussian_facet(half, mu_e) / jnp.maximum(jnp.sqrt(1.0 - x), 1e-6)
    top = jnp.minimum(12.0 * mu_e, jnp.pi)
    a = jnp.linspace(0.0, 1.0, n_quad) * top
    norm = jnp.trapezoid(k(jnp.sin(a / 2) ** 2) * 2 * jnp.pi * jnp.sin(a), a)
    return k(sin2_half) / norm


def lobe_kernel(model, conductor: Conductor, cos_v, n: int = 64):
    """The reflected lobe of ``model`` as a normalised kernel around the mirror direction R, on a grid.

    Angles from R: ``a_par`` along the plane of incidence (positive towards N) and ``a_perp`` across
    it, L = cos a_perp (cos a_par R + sin a_par t) + sin a_perp y, dω = cos a_perp da_par da_perp.
    The kernel is f_r cos θi (summed over λ) from :meth:`Hiraji.brdf_cos` / :meth:`Hamon.brdf_cos`
    at V = (sin θv, 0, cos θv), normalised so that Σ K dω = 1. The grid spans ±min(14 μ, π) along the
    plane and ±min(14 μ max(cos θv, 0.15), π/2) across (the lobe narrows across the plane by ≈ cos θv).

    **Returns** ``(K (n, n), a_par (n, n), a_perp (n, n), dω (n, n))``.
    """
    dt = conductor.n.dtype
    mu = jnp.asarray(model.mu, dt)
    cv = jnp.asarray(cos_v, dt)
    sv = jnp.sqrt(jnp.maximum(1.0 - cv ** 2, 0.0))
    V = jnp.stack([sv, jnp.zeros_like(sv), cv])
    R = jnp.stack([-sv, jnp.zeros_like(sv), cv])
    tt = jnp.asarray([0.0, 0.0, 1.0], dt) - cv * R
    tn = jnp.linalg.norm(tt)
    t = jnp.where(tn > 1e-9, tt / jnp.maximum(tn, 1e-12), jnp.asarray([1.0, 0.0, 0.0], dt))
    y = jnp.cross(R, t)
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


def tap_kernel(params, mu, ap, aq, mu_min: float = 0.0):
    """The shader's kernel for tap parameters ``(s, o_1..o_T, l_1..l_T)``: T taps at angles o_j from R
    along the plane of incidence, weights softmax(l), each the prefilter kernel at width
    μ_e = max(μ e^s, mu_min) (the environment level the shader reads)."""
    T = (params.shape[-1] - 1) // 2
    s, o, l = params[0], params[1:1 + T], params[1 + T:]
    w = jax.nn.softmax(l)
    mu_e = jnp.maximum(mu * jnp.exp(s), mu_min)
    # sin²(α/2) for the angle α between L and tap j: 1 − cos α = 2 sin²(a_perp/2) + 2 cos a_perp sin²(d/2)
    x = jnp.sin(aq / 2)[None] ** 2 + jnp.cos(aq)[None] * jnp.sin((ap[None] - o[:, None, None]) / 2) ** 2
    return jnp.einsum("j,jab->ab", w, _prefilter_kernel_normalised(x, mu_e))


@functools.partial(jax.jit, static_argnames=("cls", "n"))
def _lobe_kernels(cls, mu, conductor, cos_v, n: int):
    model = cls(jnp.ones((), mu.dtype), mu)
    return jax.vmap(lambda cv: lobe_kernel(model, conductor, cv, n))(cos_v)


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


def tap_fit(conductor: Conductor, mus=MU_LEVELS, n_cos: int = 64, n: int = 32):
    """Filtered importance sampling pattern of the lobe, fitted per (cos θv, μ) for hiraji and hamon.

    The shader approximates ∫ K(ω) L_env(ω) dω, K the reflected lobe normalised (:func:`lobe_kernel`),
    by Σ_j w_j L̃_{μ_e}(ω_j): T = :data:`N_TAPS` reads of the environment prefiltered at width μ_e,
    at directions ω_j rotated from R by o_j in the plane of incidence. This is filtered importance
    sampling (Křivánek & Colbert 2008, "Real-time Shading with Filtered Importance Sampling"), with the
    taps, weights and filter width not drawn from the lobe but fitted to it: least squares
    ∫ (K − Σ_j w_j K_{μ_e}(·, ω_j))² dω (optimistix Levenberg–Marquardt), so the sum has the lobe's
    skew (off normal incidence the lobe's peak stays near R while its mean moves towards N) and a small
    bright source inside the lobe (a sun; a softbox edge) receives the lobe's own weight. The earlier
    moment-matched pattern (:func:`lobe_lut`'s ``shape``) has the lobe's mean and variance but not its
    skew: ~5–10 % too little weight near the peak at θv = 55–65° for the hamon (μ = 0.2).

    **Returns** ``(cos, taps (2, n_mu, n_cos, 1 + 2T), l1 (2, n_mu, n_cos), ok (2, n_mu, n_cos))``:
    per model (0 hiraji, 1 hamon), ``taps`` = (s, o_1..o_T, w_1..w_T) with s = log(μ_e/μ), offsets in
    radians towards N, weights summing to 1; ``l1`` = ∫ |K − fit| dω (0: exact, 2: disjoint), and
    whether the solver converged.
    """
    cos = np.linspace(0.0, 1.0, n_cos)
    cos_c = np.maximum(cos, 1e-3)[::-1]                     # fit from normal incidence towards grazing
    dt = conductor.n.dtype
    mu_min = float(np.min(mus))
    kern = [_lobe_kernels(cls, jnp.asarray(mu, dt), conductor, jnp.asarray(cos_c, dt), n)
            for cls in (Hiraji, Hamon) for mu in mus]
    K, ap, aq, dw = (jnp.stack([k[i] for k in kern]) for i in range(4))     # (2·n_mu, n_cos, n, n)
    mu_b = jnp.asarray(np.tile(np.asarray(mus, np.float64), 2), dt)
    # the moment-matched binomial pattern (1/4, 1/2, 1/4 at mean, mean ± √2 spread; lobe_lut) as logits
    _, _, shape = lobe_lut(conductor, fresnel_basis(conductor, 1)[2], mus, n_cos=n_cos)  # (2, n_mu, n_cos, 3)
    moments = moment_taps(shape[:, :, ::-1].reshape(2 * len(mus), n_cos, 3))
    moments[..., 1 + N_TAPS:] = np.log(moments[..., 1 + N_TAPS:])                # weights as logits
    ps, errs, good = _fit_scan(K, ap, aq, dw, jnp.asarray(moments, dt), mu_b, jnp.asarray(mu_min, dt))
    ps = np.asarray(ps, np.float64)[::-1].transpose(1, 0, 2).reshape(2, len(mus), n_cos, -1)
    w = np.exp(ps[..., 1 + N_TAPS:] - ps[..., 1 + N_TAPS:].max(-1, keepdims=True))
    taps = np.concatenate([ps[..., :1 + N_TAPS], w / w.sum(-1, keepdims=True)], -1)
    l1 = np.asarray(errs, np.float64)[::-1].T.reshape(2, len(mus), n_cos)
    ok = np.asarray(good)[::-1].T.reshape(2, len(mus), n_cos)
    return cos, taps, l1, ok


@dataclasses.dataclass
class Baked:
    """Everything the shaders read, as NumPy arrays (float32 on upload).

    - ``env`` ``(n_mu, rank, H, W, 3)``: P_{r,c}(ω; μ) (XYZ per basis function).
    - ``lut`` ``(2, n_mu, n_cos, rank)``: A_r for hiraji (0) and hamon (1).
    - ``spread`` ``(2, n_mu, n_cos, 3)``: lobe shape moments (see :func:`lobe_lut`).
    - ``taps`` ``(2, n_mu, n_cos, 1 + 2T)``: the tap pattern the shader reads, fitted where the map
      resolves it (:func:`resolved_taps`); ``tap_l1`` the fit's L1 error and ``tap_ok`` the solver's
      convergence (see :func:`tap_fit`).
    - ``mus``: the μ levels; ``b`` the spectral basis ``(rank, wl)``; ``fresnel_err``.
    - ``xyz_to_rgb`` 3×3; ``transfer`` 1-D table of encode(s²) for s uniform in [0, 1].
    - ``cap_dir`` ``(n, 3)``, ``cap_radius`` ``(n,)``, ``cap_q`` ``(n, rank, 3)``: the compact sources split
      off the map (:func:`sun_caps`; ``n = 0``: none, ``env`` is the whole map).
    """

    env: np.ndarray
    lut: np.ndarray
    spread: np.ndarray
    taps: np.ndarray
    tap_l1: np.ndarray
    tap_ok: np.ndarray
    mus: np.ndarray
    b: np.ndarray
    fresnel_err: float
    xyz_to_rgb: np.ndarray
    transfer: np.ndarray
    colourspace: str
    cap_dir: np.ndarray
    cap_radius: np.ndarray
    cap_q: np.ndarray

    @property
    def rank(self) -> int:
        return self.b.shape[0]

    @property
    def n_caps(self) -> int:
        return int(self.cap_dir.shape[0])


def sun_caps(radiance: np.ndarray, grid: WavelengthGrid, b: np.ndarray, weights: np.ndarray):
    """Split the compact bright sources off ``radiance (H, W, wl)`` for the shaders.

    :func:`jkatana.light.sun.split_compact_sources` (its default criterion, at most :data:`MAX_CAPS`
    sources) finds them; each cap's spectral radiance is projected as the map is, on the Fresnel basis
    ``b (rank, wl)`` and the CIE weights ``weights (wl, 3)`` of eq. (6), times the cap's solid angle:
    ``Q_{r,c} = Ω_cap Σ_λ b_r(λ) W_c(λ) L_cap(λ)``.

    **Returns** ``(remainder (H, W, wl) float64, cap_dir (n, 3), cap_radius (n,), cap_q (n, rank, 3))``;
    ``n = 0`` and the map itself when nothing is compact.
    """
    from jkatana.light.envmap import EnvMap
    from jkatana.light.sun import split_compact_sources

    rank = b.shape[0]
    split = split_compact_sources(EnvMap(jnp.asarray(radiance, jnp.float32), grid), max_sources=MAX_CAPS)
    if not split.caps:
        return radiance, np.zeros((0, 3)), np.zeros((0,)), np.zeros((0, rank, 3))
    caps = split.caps
    direction = np.stack([np.asarray(c.direction, np.float64) for c in caps])
    radius = np.array([float(c.radius) for c in caps])
    q = np.stack([float(c.solid_angle) * np.einsum("l,rl,lc->rc", np.asarray(c.radiance, np.float64), b, weights)
                  for c in caps])
    return np.asarray(split.remainder.radiance, np.float64), direction, radius, q


def cap_kernel(tap_dir: np.ndarray, mu: np.ndarray, cap_dir: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The shader's cap response (``shade.glsl``'s ``jk_cap_kernel``), in NumPy for tests.

    The normalised prefilter kernel of width ``mu`` (D(α/2, μ)/cos(α/2), :func:`_kernel`) about the tap
    direction, integrated over a cap of angular ``radius`` about ``cap_dir`` and divided by the cap's solid
    angle (see the module docstring): ``exp(−c' h²)/cos h / N(c')`` with h half the angle between the two
    directions, c = ln2/μ², x = c r²/4, c' = 4 (1 − e^{−x})/r² (c (1 − x/2) below x = 1e-3),
    N(c) = (4π/c)(1 − 1/(6c) + 1/(60c²)). Broadcasts.
    """
    tap_dir, cap_dir = np.asarray(tap_dir, np.float64), np.asarray(cap_dir, np.float64)
    c0 = np.log(2.0) / np.asarray(mu, np.float64) ** 2
    r2 = np.asarray(radius, np.float64) ** 2
    x = 0.25 * c0 * r2
    c = np.where(x < 1e-3, c0 * (1.0 - 0.5 * x), 4.0 * -np.expm1(-x) / np.maximum(r2, 1e-30))
    s = np.minimum(0.5 * np.linalg.norm(tap_dir - cap_dir, axis=-1), 1.0)   # sin h
    h = np.arcsin(s)
    norm = 4.0 * np.pi / c * (1.0 - 1.0 / (6.0 * c) + 1.0 / (60.0 * c * c))
    return np.exp(-c * h * h) / np.sqrt(np.maximum(1.0 - s * s, 1e-6)) / norm


def moment_taps(spread: np.ndarray) -> np.ndarray:
    """The moment-matched binomial pattern of :func:`lobe_lut` (weights ¼, ½, ¼ at mean, mean ± √2·spread,
    filter width from the across-plane variance) in :func:`tap_fit`'s layout ``(..., 1 + 2T)``."""
    off = np.sqrt(2.0) * spread[..., 1:2] * np.array([-1.0, 0.0, 1.0])
    w = np.broadcast_to(np.array([0.25, 0.5, 0.25]), off.shape)
    return np.concatenate([spread[..., :1], spread[..., 2:3] + off, w], -1)


#: The fitted pattern is used where its filter width μ_e spans at least this many texels of the map.
MIN_FIT_TEXELS = 2.0


def resolved_taps(taps: np.ndarray, spread: np.ndarray, mus, height: int) -> np.ndarray:
    """The fitted taps where the map resolves them, the moment-matched ones elsewhere.

    The fit (:func:`tap_fit`) models each tap as the continuous prefilter kernel of width μ_e; the
    shader reads a prefiltered equirectangular map of ``height`` rows, bilinearly. Where μ_e is below
    :data:`MIN_FIT_TEXELS` texels (π/height rad each) the map does not resolve the fitted kernel's
    shape: measured on the sun-glint view (a 1.5° sun, ~2 texels of a 128-row map, in the hiraji's
    μ0 = 0.05 lobe, μ_e ≈ 0.026 rad ≈ 1 texel), the fitted pattern there gave ΔE p95 4.7 on the hiraji
    pixels against 2.6 with the moment pattern, while on the hamon (μ_e ≈ 0.11 rad) it gave 1.9
    against 3.6. So per table entry: fitted if μ e^s ≥ MIN_FIT_TEXELS·π/height, else moments.
    """
    mu_e = np.asarray(mus, np.float64)[None, :, None] * np.exp(taps[..., 0])
    use = mu_e >= MIN_FIT_TEXELS * np.pi / height
    return np.where(use[..., None], taps, moment_taps(spread))


def _cache_root(cache_dir=None) -> Path:
    """``cache_dir``, else ``$JKATANA_CACHE``, else ``~/.cache/jkatana``; its ``interactive`` folder (under the
    size budget and eviction of :mod:`jkatana.light.cache`)."""
    from jkatana.light.cache import cache_base

    return cache_base(cache_dir) / "interactive"


def _load_entry(path: Path, read):
    """``read(npz)`` of a cache entry, held in use while it is read (:func:`jkatana.light.cache.acquire`; the
    arrays are copied, so the hold ends with the read); None when the entry is absent or was evicted."""
    from jkatana.light import cache

    if path.parent == SHIPPED_TAPS:
        with np.load(path) as z:
            return read(z)
    if not path.exists() or not cache.acquire(path):
        return None
    try:
        with np.load(path) as z:
            return read(z)
    finally:
        cache.release(path)


def _save_entry(path: Path, cache_dir, **arrays) -> None:
    """:func:`_save_npz` into the cache, then the cache's eviction to its budget
    (:func:`jkatana.light.cache.after_write`)."""
    from jkatana.light import cache

    _save_npz(path, **arrays)
    cache.after_write(path, cache_dir)
    cache.release(path)


def _save_npz(path: Path, **arrays) -> None:
    """``np.savez`` written atomically (temporary file beside ``path``, then rename)."""
    from jkatana.io.atomic import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)


#: Folder of tap tables shipped with the package (see :func:`_cached_tap_fit`).
SHIPPED_TAPS = Path(__file__).resolve().parent.parent / "data" / "interactive"


def tap_fit_key(conductor: Conductor, mus=MU_LEVELS, n_cos: int = 64) -> str:
    """Cache key of :func:`tap_fit`: n, k (rounded to float32, so float32 and float64 runs share it), μ
    levels, n_cos, the tap count and the source of the fitting code (a code change invalidates it)."""
    import hashlib
    import inspect

    h = hashlib.sha256()
    for part in (np.asarray(conductor.n, np.float32).astype(np.float64).tobytes(),
                 np.asarray(conductor.k, np.float32).astype(np.float64).tobytes(),
                 np.asarray(mus, np.float64).round(12).tobytes(), repr((n_cos, N_TAPS)).encode(),
                 *(inspect.getsource(f).encode() for f in (_prefilter_kernel_normalised, lobe_kernel, tap_kernel,
                                                           _lobe_kernels, _fit_scan, tap_fit))):
        h.update(part)
    return h.hexdigest()[:24]


def _cached_tap_fit(conductor: Conductor, mus, n_cos: int, cache_dir=None):
    """:func:`tap_fit` (≈ 1–5 min on 2 CPU cores) cached: it depends on the conductor and the μ levels,
    not on the environment. Looked up first among the tables shipped in ``jkatana/data/interactive``
    (iron, Johnson & Christy 1974, at the default levels: computed by this code with
    :func:`write_shipped_tap_table`; a test checks the shipped key is current), then in the user cache
    beside :func:`cached_bake`'s tables; else fitted and cached. Key: :func:`tap_fit_key`."""
    key = tap_fit_key(conductor, mus, n_cos)
    for path in (SHIPPED_TAPS / f"taps-{key}.npz", _cache_root(cache_dir) / f"taps-{key}.npz"):
        if path.exists():
            found = _load_entry(path, lambda z: (z["taps"], z["l1"], z["ok"]))
            if found is not None:
                return found
    _, taps, l1, ok = tap_fit(conductor, mus, n_cos=n_cos)
    _save_entry(path, cache_dir, taps=taps, l1=l1, ok=ok)
    return taps, l1, ok


def _cached_material_tables(conductor: Conductor, rank: int, mus, cache_dir=None):
    """``(b, fresnel_err, lut, spread)``: :func:`fresnel_basis` and :func:`lobe_lut`, which depend on the
    conductor, the rank and the μ levels but not on the environment, cached beside the tap fit (seconds of
    JAX compilation that a new environment need not pay again). Looked up first among the tables shipped
    with the package (iron at the default grid, rank 3 and levels: :func:`write_shipped_tap_table`), then in
    the user cache. Key: :func:`tap_fit_key`'s inputs, the rank and the source of the two functions."""
    import hashlib
    import inspect

    h = hashlib.sha256(tap_fit_key(conductor, mus, 64).encode() + repr(rank).encode())
    for f in (fresnel_basis, lobe_lut, _lut_column, lobe_integral, halfvector_quadrature):
        h.update(inspect.getsource(f).encode())
    name = f"material-{h.hexdigest()[:24]}.npz"
    for path in (SHIPPED_TAPS / name, _cache_root(cache_dir) / name):
        if path.exists():
            found = _load_entry(path, lambda z: (z["b"], float(z["err"]), z["lut"], z["spread"]))
            if found is not None:
                return found
    _, _, b, err = fresnel_basis(conductor, rank)
    _, lut, spread = lobe_lut(conductor, b, mus)
    _save_entry(path, cache_dir, b=b, err=np.float64(err), lut=lut, spread=spread)
    return b, err, lut, spread


def write_shipped_tap_table(source: str = "Fe-Johnson", grid: WavelengthGrid = DEFAULT_GRID) -> Path:
    """Fit the taps for ``source`` at the default μ levels and write them to the package's data folder
    (run after changing the fitting code: ``python -c "from jkatana.interactive.bake import
    write_shipped_tap_table as w; print(w())"``); stale tables of older keys are removed. Turns on
    ``jax_enable_x64`` for the process: the shipped fit is the float64 one."""
    # the shipped table is the float64 fit (float32 runs share its key and use it: the LM fit in float32
    # converges on fewer entries)
    jax.config.update("jax_enable_x64", True)
    conductor = Conductor.from_table(source, grid, dtype=jnp.float64)
    key = tap_fit_key(conductor, MU_LEVELS, 64)
    _, taps, l1, ok = tap_fit(conductor, MU_LEVELS, n_cos=64)
    for old in [*SHIPPED_TAPS.glob("taps-*.npz"), *SHIPPED_TAPS.glob("material-*.npz")]:
        old.unlink()
    path = SHIPPED_TAPS / f"taps-{key}.npz"
    _save_npz(path, taps=taps, l1=l1, ok=ok)
    write_shipped_material_table(source, grid)
    return path


def write_shipped_material_table(source: str = "Fe-Johnson", grid: WavelengthGrid = DEFAULT_GRID,
                                 rank: int = 3) -> Path:
    """Compute :func:`_cached_material_tables` for ``source`` at the default levels into the package's
    data folder (float64, as the shipped tap table)."""
    jax.config.update("jax_enable_x64", True)
    conductor = Conductor.from_table(source, grid, dtype=jnp.float64)
    for old in SHIPPED_TAPS.glob("material-*.npz"):
        old.unlink()
    with __import__("tempfile").TemporaryDirectory() as tmp:
        _cached_material_tables(conductor, rank, MU_LEVELS, tmp)
        made = next((Path(tmp) / "interactive").glob("material-*.npz"))
        target = SHIPPED_TAPS / made.name
        _save_npz(target, **dict(np.load(made)))
    return target


def transfer_table(transfer="sRGB", n: int = 2048) -> np.ndarray:
    """encode(s²) for s uniform on [0, 1] (eq. 8 as a table, dense near black)."""
    s = np.linspace(0.0, 1.0, n)
    return np.asarray(encode(s ** 2, transfer), np.float64)


def cached_bake(radiance: np.ndarray, grid: WavelengthGrid = DEFAULT_GRID, *, rank: int = 3, mus=MU_LEVELS,
                colourspace: str = "sRGB", transfer=None, source: str = "Fe-Johnson", cache_dir=None,
                progress: bool = False, split_sun: bool = True) -> Baked:
    """:func:`bake` with an on-disk cache (``$JKATANA_CACHE`` or ``~/.cache/jkatana``/interactive).

    The key hashes every input (radiance bytes, grid, rank, μ levels, display
    transform, optical-constant source) and this module's source, so a change
    to the baking code invalidates it. The entry keeps each prefiltered level
    at its own resolution (:func:`level_shape`) in float16 scaled by the
    level's largest magnitude (relative precision 2⁻¹¹), resampled to the
    source's size on load: tens of MB for a 1k map instead of hundreds.
    `progress` shows a progress bar over the μ levels while baking; `split_sun` as :func:`bake`.
    """
    import hashlib

    h = hashlib.sha256()
    for part in (np.ascontiguousarray(radiance, np.float64).tobytes(), repr((grid.start, grid.stop, grid.step,
                 rank, list(np.round(mus, 12)), colourspace, transfer, source, radiance.shape,
                 bool(split_sun))).encode(),
                 Path(__file__).read_bytes()):
        h.update(part)
    path = _cache_root(cache_dir) / f"baked-{h.hexdigest()[:24]}.npz"
    H, W = radiance.shape[:2]

    def read(z):
        return ({f.name: z[f.name] for f in dataclasses.fields(Baked) if f.name != "env"},
                [z[f"level{k}"].astype(np.float32) * np.float32(z["level_scale"][k]) for k in range(len(mus))])

    found = _load_entry(path, read)
    if found is not None:
        fields, levels = found
        env = np.stack([upsample(lv, H, W) for lv in levels]).reshape(len(mus), H, W, rank, 3)
        return Baked(**{**fields, "env": env.transpose(0, 3, 1, 2, 4), "fresnel_err": float(fields["fresnel_err"]),
                        "colourspace": str(fields["colourspace"])})
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    baked, levels = _bake(np.asarray(radiance, np.float64), grid,
                          conductor=Conductor.from_table(source, grid, dtype=dt), rank=rank, mus=mus,
                          colourspace=colourspace, transfer=transfer, cache_dir=cache_dir, progress=progress,
                          split_sun=split_sun)
    scale = np.array([max(float(np.abs(lv).max()), 1e-30) / 60000.0 for lv in levels])
    small = {f"level{k}": (lv / scale[k]).astype(np.float16) for k, lv in enumerate(levels)}
    _save_entry(path, cache_dir, level_scale=scale, **small,
                **{k: np.asarray(v) for k, v in dataclasses.asdict(baked).items() if k != "env"})
    return baked


def bake(radiance: np.ndarray, grid: WavelengthGrid = DEFAULT_GRID, *, conductor: Conductor | None = None,
         rank: int = 3, mus=MU_LEVELS, colourspace: str = "sRGB", transfer=None, cache_dir=None,
         split_sun: bool = True) -> Baked:
    """Bake all shader tables for an environment ``radiance (H, W, wl)`` on ``grid``.

    **Arguments:**

    - `radiance`: equirectangular spectral radiance (Y up, see :func:`jkatana.light.envmap.texel_directions_np`).
    - `conductor`: n, k (default iron, Johnson & Christy 1974).
    - `rank`: spectral basis rank (1–4); `mus`: prefilter levels.
    - `colourspace`, `transfer`: the display transform (as :func:`jkatana.spectral.to_display`).
    - `cache_dir`: where the environment-independent tap fit (:func:`tap_fit`) is cached.
    - `split_sun`: split compact bright sources off as caps (:func:`sun_caps`; default); False: prefilter
      the whole map.

    **Returns:** a :class:`Baked`.
    """
    radiance = np.asarray(radiance, np.float64)
    if radiance.ndim != 3 or radiance.shape[-1] != grid.size:
        raise ValueError(f"radiance must be (H, W, {grid.size}), got {radiance.shape}")
    if conductor is None:
        conductor = Conductor.from_table("Fe-Johnson", grid, dtype=jnp.float64 if jax.config.jax_enable_x64
                                         else jnp.float32)
    baked, _ = _bake(radiance, grid, conductor=conductor, rank=rank, mus=mus, colourspace=colourspace,
                     transfer=transfer, cache_dir=cache_dir, split_sun=split_sun)
    return baked


def _bake(radiance, grid, *, conductor, rank, mus, colourspace, transfer, cache_dir, progress: bool = False,
          split_sun: bool = True):
    """:func:`bake`, also returning the prefiltered levels at their own resolutions (what the cache keeps)."""
    from tqdm import tqdm

    b, err, lut, spread = _cached_material_tables(conductor, rank, mus, cache_dir)
    W = film_weights(grid)            # (wl, 3); k = 1/∫ȳ dλ as jkatana.render: flat radiance 1 → Y = 1
    H, Wd = radiance.shape[:2]
    if split_sun:
        radiance, cap_dir, cap_radius, cap_q = sun_caps(radiance, grid, b, W)
    else:
        cap_dir, cap_radius, cap_q = np.zeros((0, 3)), np.zeros((0,)), np.zeros((0, rank, 3))
    proj = np.einsum("hwl,rl,lc->hwrc", radiance, b, W, optimize=True).reshape(H, Wd, rank * 3)
    bar = tqdm(mus, desc="baking the environment (μ levels)", unit="level", disable=not progress,
               file=__import__("sys").stderr)
    levels = [prefilter_level(proj, float(mu)) for mu in bar]
    env = np.stack([upsample(lv.astype(np.float32), H, Wd) for lv in levels])        # (n_mu, H, W, r*3)
    env = env.reshape(len(mus), H, Wd, rank, 3).transpose(0, 3, 1, 2, 4)
    taps, tap_l1, tap_ok = _cached_tap_fit(conductor, mus, lut.shape[2], cache_dir)
    taps = resolved_taps(taps, spread, mus, radiance.shape[0])
    return Baked(env=env, lut=lut, spread=spread, taps=taps, tap_l1=tap_l1, tap_ok=tap_ok, mus=np.asarray(mus, np.float64), b=b, fresnel_err=err,
                 xyz_to_rgb=xyz_to_rgb_matrix(colourspace),
                 transfer=transfer_table(colourspace if transfer is None else transfer),
                 colourspace=colourspace, cap_dir=cap_dir, cap_radius=cap_radius, cap_q=cap_q), levels
