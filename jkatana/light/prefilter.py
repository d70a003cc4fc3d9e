"""Prefiltered environment maps (any reflection lobe) and the low-rank spectral basis of the Fresnel term.

## Lobe prefiltering

For the renderer's ``prefiltered`` mode and the interactive bake, the
environment is convolved with a reflection lobe under the split-sum
assumption N = V = R (Karis 2013, "Real Shading in Unreal Engine 4",
SIGGRAPH course): the kernel is the lobe's reflected-direction density at
normal incidence, made rotationally symmetric about the mirror direction R.

At V = N a reflected direction at angle ψ from N has its half vector at the
facet angle φ = ψ/2, with cos θH = cos(ψ/2), and dω_L = 4 cos θH dω_h
(Walter, Marschner, Li & Torrance 2007, "Microfacet models for refraction
through rough surfaces", eq. 14). The kernel is the lobe's own value
f_r cos θi there (:meth:`jkatana.models.lobes.Lobe.f_cos`, V = N):

- microfacet lobes (Beckmann, GGX, GTR): D(φ) G / 4, i.e. the half-vector
  density D cos θH times the Jacobian 1/(4 cos θH), times Smith shadowing;
- the paper's Gaussian lobe (Mochizuki et al., eq. 1): N(μ) D(ψ/2, μ)/(4 cos(ψ/2));
  the V-cavity lobe (eq. 2) adds its G;
- a :class:`~jkatana.models.lobes.Mixture`: the weighted sum.

It is zero below the horizon (ψ > π/2) and integrates to the lobe's albedo at
normal incidence; it is normalised here to ∫ K dω = 1 (numerically, per
output texel, so a constant map stays exactly constant), the lobe's energy
being carried separately (the split sum's second factor). The kernel is
tabulated once per lobe on x = sin²(ψ/2) ∈ [0, ½] (:func:`kernel_table`),
in which it is smooth at ψ = 0, and interpolated linearly (no arccos per pair).

Exact per-row algorithm: on an equirectangular grid the kernel between an
output row and a source row depends only on the column difference (rotation
about +Y), so each output row is a sum over the source rows within the
kernel's support of circular convolutions in longitude, done with real FFTs
(:func:`convolve`). The kernel is integrated over each source texel with
``sub × sub`` midpoint subsamples, so the result is the convolution of the
piecewise-constant map also when the lobe is comparable to a texel. Each μ
gets its own level whose texels are at most μ/``texels_per_mu`` rad high
(:func:`level_shape`; the renderer and the bake choose their own): the
source is box-downsampled (power-preserving) to it, or repeated (exact for
the piecewise-constant map) up to ``max_upsample`` times.

:meth:`PrefilteredEnv.lookup` is bilinear within a level and linear in log μ
between levels (an approximation between the tabulated μ; exact at them, up
to interpolation).

## Fresnel basis

:func:`jkatana.light.fresnel_basis.fresnel_basis` factorises F(cos θ, λ) ≈
Σ_r c_r(cos θ) b_r(λ) by a truncated SVD (Eckart & Young 1936) over a dense
cos θ table. For iron
(Johnson & Christy 1974) rank 3 reproduces F to a few 1e-6 (tests report the
measured value). With it, the spectral reflection of a prefiltered
environment needs only ``rank`` colour maps:

    XYZ(R, θ) = Σ_r c_r(cos θ) · P_r(R),   P_r(R) = Σ_λ L_μ(R, λ) b_r(λ) x̄ȳz̄(λ) Δλ,

(:func:`project_on_basis`), exact given the split sum and the rank-r F.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.fft as sfft
from jaxtyping import Array, ArrayLike, Float

from jkatana.errors import InputError
from jkatana.light.envmap import EnvMap, box_downsample  # noqa: F401 (box_downsample re-exported)
from jkatana.light.fresnel_basis import FresnelBasis, fresnel_basis  # noqa: F401 (the basis' home; re-exported)
from jkatana.light.fresnel_basis import project_on_basis as fresnel_basis_projection
from jkatana.models.lobes import Gaussian, Lobe
from jkatana.spectral.colorimetry import xyz_weights

#: A lobe of width μ: a lobe class whose first field is its width (``Gaussian``, ``GaussianVCavity``,
#: ``Beckmann``, ``GGX``) or any callable μ ↦ :class:`~jkatana.models.lobes.Lobe`
#: (``functools.partial(GTR, gamma=1.5)``, ``lambda m: Mixture(GGX(m), GTR(4 * m, 1.5), 0.8)``).
LobeFamily = Callable[..., Lobe]


def reflected_lobe(lobe: Lobe, sin2_half: Float[ArrayLike, "*n"]) -> Float[Array, "*n"]:
    """The prefilter kernel before normalisation: f_r cos θi of ``lobe`` at normal incidence (V = N = +z)
    toward a direction at angle ψ from N, given x = sin²(ψ/2) (module docstring; Walter et al. 2007,
    Karis 2013). Zero below the horizon (x > ½). Pure JAX; ``sin2_half`` must have the lobe's dtype;
    value and gradient finite at ψ = 0."""
    x = jnp.clip(jnp.asarray(sin2_half), 0.0, 1.0)
    sx = x * (1.0 - x)
    pos = sx > 0
    sin_psi = jnp.where(pos, 2.0 * jnp.sqrt(jnp.where(pos, sx, 1.0)), 0.0)
    zero = jnp.zeros_like(x)
    L = jnp.stack([sin_psi, zero, 1.0 - 2.0 * x], -1)
    V = jnp.stack([zero, zero, jnp.ones_like(x)], -1)
    return lobe.f_cos(L, V)


#: :func:`reflected_lobe` compiled once per lobe family, shape and dtype: the prefilter's kernel tables and the
#: interactive tail fit's kernel profiles (:func:`jkatana.interactive.taps.kernel_profiles`) share its programs.
reflected_kernel = eqx.filter_jit(reflected_lobe)


_build_jit = eqx.filter_jit(lambda family, mu: family(mu))  # one compilation per family, not one per operation


def lobe_of_width(lobe: LobeFamily, mu: float) -> Lobe:
    """``lobe(μ)`` with μ a JAX scalar of the default float dtype (float64 under x64)."""
    return _build_jit(lobe, jnp.asarray(mu, jnp.float64 if jax.config.jax_enable_x64 else jnp.float32))


def kernel_table(lobe: Lobe, rel: float = 1e-7, n: int = 8192) -> tuple[np.ndarray, np.ndarray]:
    """:func:`reflected_lobe` tabulated on ``n`` points over the kernel's support, uniform in
    sin(ψ/2) = √x (so a narrow peak with long tails is resolved too).

    The support ends at the horizon (x = ½) or where the kernel stays below ``rel`` of its peak; the
    table is refined until at least ``n/4`` points lie inside it, so narrow lobes are resolved. Beyond
    the last point the kernel is 0 (:func:`kernel_at`).

    **Returns:** ``(x, k)``, float64; ∫ K dω = 4π ∫ k dx (dω = 2π sin ψ dψ = 4π dx).
    """
    dt = jnp.result_type(*jax.tree.leaves(lobe))
    top = 0.5
    for _ in range(60):
        x = np.linspace(0.0, math.sqrt(top), n) ** 2
        # the horizon's node takes the value just above it: the kernel's cut there stays sharp
        k = np.asarray(reflected_kernel(lobe, jnp.asarray(np.minimum(x, 0.5 - 1e-12), dt)), np.float64)
        peak = float(np.max(k)) if k.size else 0.0
        if not (np.isfinite(peak) and peak > 0 and np.all(np.isfinite(k))):
            raise InputError(f"the lobe {lobe.to_params()} has no finite reflected kernel at normal incidence",
                             field="lobe")
        last = int(np.nonzero(k > rel * peak)[0][-1])
        if last >= n // 4:
            break
        top = float(x[last + 1])
    keep = min(last + 2, n)
    return x[:keep], k[:keep]


def kernel_at(x: np.ndarray, table: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The tabulated kernel at x = sin²(ψ/2): linear in sin(ψ/2) between the table's (uniform) nodes, 0
    beyond the last one (a direct index, no search: this is the convolution's inner loop)."""
    tx, tk = table
    n = tx.size
    u = np.sqrt(x) * (1.0 / math.sqrt(tx[1]))              # in node spacings
    i = np.minimum(u.astype(np.intp), n - 2)
    k = np.take(tk, i) + (u - i) * np.take(np.diff(tk), i)
    return np.where(u <= n - 1, k, 0.0)


def level_shape(mu: float, source_shape: tuple[int, int], texels_per_mu: float = 8.0,
                max_upsample: int = 1) -> tuple[int, int]:
    """Level resolution for μ: the source halved (both axes even, ≥ 4 rows) while a texel (π/h rad tall)
    stays ≤ μ/``texels_per_mu``, or doubled while it is larger, up to ``max_upsample`` × the source."""
    h, w = source_shape
    H = h
    while h % 2 == 0 and w % 2 == 0 and h // 2 >= 4 and math.pi / (h // 2) <= mu / texels_per_mu:
        h, w = h // 2, w // 2
    while math.pi / h > mu / texels_per_mu and 2 * h <= H * max_upsample:
        h, w = 2 * h, 2 * w
    return h, w


def convolve(image: Float[np.ndarray, "H W C"], table: tuple[np.ndarray, np.ndarray], *, sub: int = 3,
             chunk: int = 32) -> Float[np.ndarray, "H W C"]:
    """Convolve a piecewise-constant equirectangular image with the kernel ``table``
    (:func:`kernel_table`), normalised per output texel; output at texel centres, float64.

    Each output row is a sum over the source rows within the kernel's support of circular
    convolutions in longitude (real FFTs): exact on the grid. The kernel is integrated over each
    source texel with ``sub × sub`` midpoint subsamples (``sub = 1``: sampled at texel centres). Output
    rows go in chunks of ``chunk``, and only the columns within the support are evaluated, so memory and
    time scale with rows × support instead of rows² × width. The kernel is even in longitude (its
    subsamples are symmetric), so only offsets 0…W/2 are evaluated and its spectrum, real, is their
    type-I discrete cosine transform (Britanak, Yip & Rao 2007, "Discrete Cosine and Sine Transforms", §2.4).
    """
    L = np.asarray(image, np.float64)
    H, W = L.shape[:2]
    C = L.shape[2]
    tx, tk = table
    psi_max = 2.0 * math.asin(math.sqrt(min(float(tx[-1]), 1.0)))
    dth, dph = math.pi / H, 2.0 * math.pi / W
    theta = (np.arange(H) + 0.5) * dth
    edges = np.arange(H + 1) * dth
    t = (np.arange(sub) + 0.5) / sub
    th_sub = (np.arange(H)[:, None] + t[None, :]) * dth                                 # (H, sub)
    sin_sub = np.sin(th_sub)
    row_w = (np.cos(edges[:-1]) - np.cos(edges[1:])) / sin_sub.mean(axis=1)            # texel Ω / mean sin θ
    reach = int(math.ceil(psi_max / dth)) + 2
    half = W // 2 + 1                                                                   # offsets 0..W/2
    hav_p = np.sin(((np.arange(half)[:, None] + t[None, :]) - 0.5) * (dph / 2)) ** 2   # (half, sub)
    mult = np.full(half, 2.0)                                                           # offset ±Δ: twice
    mult[0] = 1.0
    if W % 2 == 0:
        mult[-1] = 1.0                                                                  # W/2 is its own mirror
    spec = sfft.rfft(L, axis=1, workers=-1).transpose(1, 0, 2)                          # (F, H, C)
    spec_ri = np.ascontiguousarray(np.concatenate([spec.real, spec.imag], axis=-1))     # (F, H, 2C)
    out = np.empty(L.shape, np.float64)
    for o0 in range(0, H, chunk):
        o1 = min(H, o0 + chunk)
        i0, i1 = max(0, o0 - reach), min(H, o1 + reach)
        K = np.zeros((half, o1 - o0, i1 - i0))                                         # (Δ, out, in)
        for j in range(o0, o1):
            r0, r1 = max(0, j - reach), min(H, j + reach + 1)
            # columns within reach: sin²(ψ/2) ≥ sin θ sin θ' sin²(Δφ/2)
            s2 = float(math.sin(theta[j]) * sin_sub[r0:r1].min())  # the subsamples are all that is evaluated
            ratio = math.sin(psi_max / 2) / math.sqrt(s2) if s2 > 0 else 2.0
            c = half if ratio >= 1.0 else min(int(math.ceil(2 * math.asin(ratio) / dph)) + 3, half)
            ti, si = th_sub[r0:r1], sin_sub[r0:r1]                                       # (r, sub)
            x = ((np.sin((theta[j] - ti) / 2) ** 2)[:, :, None, None]
                 + (math.sin(theta[j]) * si)[:, :, None, None] * hav_p[:c][None, None])  # (r, s, c, s)
            k = (kernel_at(x, table) * si[:, :, None, None]).sum(axis=(1, 3))
            K[:c, j - o0, r0 - i0:r1 - i0] = (k * row_w[r0:r1, None]).T
        K /= np.einsum("d,doi->o", mult, K)[None, :, None]
        # out[o, φ] = Σ_i Σ_Δ K[o, i, Δ] L[i, φ + Δ]  (circular correlation in longitude); K even in Δ, so its
        # spectrum is real: the DCT-I of offsets 0..W/2 (an odd W: the real FFT of the mirrored kernel)
        Kf = sfft.dct(K, type=1, axis=0, workers=-1) if W % 2 == 0 else \
            sfft.rfft(np.concatenate([K, K[:0:-1]], 0), axis=0, workers=-1).real           # (F, out, in)
        r = np.matmul(Kf, spec_ri[:, i0:i1])                                             # (F, out, 2C)
        out[o0:o1] = sfft.irfft((r[..., :C] + 1j * r[..., C:]).transpose(1, 0, 2), n=W, axis=1, workers=-1)
    return out


def prefilter_level(image: Float[np.ndarray, "H W C"], mu: float, *, lobe: LobeFamily = Gaussian,
                    texels_per_mu: float = 8.0, max_upsample: int = 1, sub: int = 3,
                    chunk: int = 32) -> Float[np.ndarray, "h w C"]:
    """Convolve an equirectangular image ``(H, W, C)`` with the normalised kernel of ``lobe(mu)``
    at :func:`level_shape`'s resolution (returned at that resolution, float64): the source is
    box-downsampled (:func:`box_downsample`) or repeated to it, then :func:`convolve`'d."""
    img = np.asarray(image, np.float64)
    H, W = img.shape[:2]
    h, w = level_shape(mu, (H, W), texels_per_mu, max_upsample)
    if h < H:
        img = box_downsample(img, H // h)
    elif h > H:
        f = h // H
        img = np.repeat(np.repeat(img, f, axis=0), f, axis=1)
    return convolve(img, kernel_table(lobe_of_width(lobe, mu)), sub=sub, chunk=chunk)


def blend_levels(vals, log_mus, mu):
    """The prefiltered radiance for width ``mu`` from the levels' lookups ``vals (m, *b, c)`` at widths
    ``exp(log_mus) (m,)`` (increasing): linear in log μ between the two levels around ``mu``, clamped to
    the tabulated range (μ ≤ 1e-12 counts as 1e-12, so μ = 0 takes the sharpest level). ``mu`` broadcasts
    against ``*b``. The renderer's lookup (:func:`jkatana.render.environment.lookup_prefiltered_many`)
    and :meth:`PrefilteredEnv.lookup` both blend with this function."""
    m = vals.shape[0]
    if m == 1:
        return vals[0]
    x = jnp.clip(jnp.log(jnp.maximum(mu, 1e-12)), log_mus[0], log_mus[-1])
    k0 = jnp.clip(jnp.searchsorted(log_mus, x, side="right") - 1, 0, m - 2)
    t = ((x - log_mus[k0]) / (log_mus[k0 + 1] - log_mus[k0]))[..., None]
    idx = jnp.broadcast_to(k0[..., None], vals.shape[1:])[None]
    lo = jnp.take_along_axis(vals, idx, axis=0)[0]
    hi = jnp.take_along_axis(vals, idx + 1, axis=0)[0]
    return lo * (1 - t) + hi * t


class PrefilteredEnv(eqx.Module):
    """A stack of lobe-prefiltered maps, one per μ (increasing). See the module docstring."""

    levels: tuple[EnvMap, ...]
    mus: tuple[float, ...] = eqx.field(static=True)

    def lookup(self, d: Float[ArrayLike, "*#b 3"], mu) -> Float[Array, "*#b wl"]:
        """Prefiltered radiance toward ``d`` for roughness ``mu`` (:func:`blend_levels`)."""
        vals = jnp.stack([lvl.lookup(d) for lvl in self.levels], axis=0)  # (m, *b, wl)
        return blend_levels(vals, jnp.log(jnp.asarray(self.mus, vals.dtype)), jnp.asarray(mu, vals.dtype))


def prefilter(env: EnvMap, mus: Sequence[float] = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3), *,
              lobe: LobeFamily = Gaussian, texels_per_mu: float = 8.0, max_upsample: int = 1, sub: int = 3,
              progress: bool = False) -> PrefilteredEnv:
    """Convolve ``env`` with the kernel of ``lobe`` for each width μ (:func:`prefilter_level`), see the
    module docstring.

    **Arguments:**

    - `mus`: lobe widths (the paper's μ in rad for the default lobe; α for microfacet lobes), positive.
    - `lobe`: the lobe family (:data:`LobeFamily`); default the paper's Gaussian lobe (eq. 1).
    - `texels_per_mu`: level texel height ≤ μ / this (default 8: the Gaussian kernel's
      FWHM, 4μ, spans ≥ 32 texels, unless capped by the source resolution).
    - `max_upsample`: allow levels finer than the source by up to this factor
      (nearest-neighbour repetition, which represents the piecewise-constant map
      exactly) when μ is small compared with a source texel: bilinear lookups of
      the result are then accurate near sharp features such as the sun.
    - `sub`: subsamples per texel side for the kernel's integral over a source texel.
    - `progress`: show a tqdm bar over μ.

    **Returns:** :class:`PrefilteredEnv` (levels in the dtype of ``env``).
    """
    mus = tuple(sorted(float(m) for m in mus))
    if not mus or mus[0] <= 0:
        raise InputError(f"mus must be positive, got {mus}", field="mus")
    it = mus
    if progress:
        from tqdm import tqdm

        it = tqdm(mus, desc="prefilter", unit="μ")
    src = np.asarray(env.radiance, np.float64)
    levels = []
    for mu in it:
        L = prefilter_level(src, mu, lobe=lobe, texels_per_mu=texels_per_mu, max_upsample=max_upsample, sub=sub)
        levels.append(EnvMap(jnp.asarray(L, env.radiance.dtype), env.grid))
    return PrefilteredEnv(tuple(levels), mus)


def brute_force_convolution(env: EnvMap, d, mu: float, sub: int = 8, lobe: LobeFamily = Gaussian) -> np.ndarray:
    """Reference: ``Σ_i L_i ∫_texel_i K dω / ∫ K dω`` over every source texel of ``env`` (piecewise-constant
    radiance) within the kernel's support, with ``sub × sub`` subsamples per texel, at any direction ``d``;
    the kernel is :func:`reflected_lobe` evaluated at each subsample (midpoint rule, rescaled to each
    texel's exact solid angle).

    Independent of :func:`prefilter`'s levels, kernel table, FFTs and interpolation; O(texels in the support).
    """
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d)
    H, W = env.height, env.width
    L = np.asarray(env.radiance, np.float64)
    lob = lobe_of_width(lobe, mu)
    dt = jnp.result_type(*jax.tree.leaves(lob))
    tx, _ = kernel_table(lob)
    psi_max = 2.0 * math.asin(math.sqrt(min(float(tx[-1]), 1.0)))
    theta_d = math.acos(max(-1.0, min(1.0, d[1])))
    phi_d = math.atan2(d[0], -d[2])
    theta_rows = (np.arange(H) + 0.5) * math.pi / H
    rows = np.nonzero(np.abs(theta_rows - theta_d) <= psi_max + 1.5 * math.pi / H)[0]
    t = (np.arange(sub) + 0.5) / sub
    th = (rows[:, None] + t[None, :]) * (math.pi / H)  # (r, s)
    ph = (np.arange(W)[:, None] + t[None, :]) * (2 * math.pi / W) - math.pi  # (W, s), absolute φ
    x = (np.sin((th - theta_d) / 2) ** 2)[:, None, :, None] \
        + math.sin(theta_d) * np.sin(th)[:, None, :, None] * (np.sin((ph - phi_d) / 2) ** 2)[None, :, None, :]
    k = np.asarray(reflected_kernel(lob, jnp.asarray(x, dt)), np.float64) * np.sin(th)[:, None, :, None]
    omega = np.cos(rows * math.pi / H) - np.cos((rows + 1) * math.pi / H)  # the texels' exact solid angles / Δφ
    K = k.mean(axis=(2, 3)) * (omega / np.sin(th).mean(axis=1))[:, None]  # ∝ ∫_texel K dω
    return np.einsum("rw,rwl->l", K, L[rows]) / K.sum()


# ---------------------------------------------------------------- Fresnel basis


def project_on_basis(env_or_level: EnvMap, basis: FresnelBasis) -> Float[Array, "H W rank 3"]:
    """``P_r = Σ_λ L(λ) b_r(λ) x̄ȳz̄(λ) Δλ``: the map projected on the Fresnel basis, XYZ per basis function.

    Shading then needs ``XYZ = Σ_r c_r(cos θ) P_r(R)`` (module docstring).
    """
    W = jnp.asarray(xyz_weights(env_or_level.grid), env_or_level.radiance.dtype)  # (wl, 3)
    B = jnp.asarray(basis.basis, env_or_level.radiance.dtype)  # (rank, wl)
    return fresnel_basis_projection(env_or_level.radiance, B, W)
