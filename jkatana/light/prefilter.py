"""Prefiltered environment maps and the low-rank spectral basis of the Fresnel term.

## Lobe prefiltering

For the fast renderer modes and the interactive path, the environment is
convolved with the paper's Gaussian facet lobe, D(φ) = exp(−ln2 φ²/μ²)
(Mochizuki et al.), under the usual split-sum assumption N = V = R (Karis
2013, "Real Shading in Unreal Engine 4", SIGGRAPH course): a facet tilted by
φ reflects the direction R by ψ = 2φ, so the kernel on the sphere is

    K_μ(ω, R) = exp(−ln2 ψ²/(4μ²)) / Z,    ψ = ∠(ω, R),

normalised to ∫ K dω = 1 (numerically, per output texel, so a constant map
stays exactly constant). :func:`prefilter` computes it for a list of μ.

Exact per-row algorithm: on an equirectangular grid the kernel between an
output row and a source row depends only on the column difference (rotation
about +Y), so each output row is a sum over nearby source rows of circular
convolutions in φ, done with real FFTs. Each μ gets its own level whose
texels are at most μ/``texels_per_mu`` rad high (default 8) (capped at the source
resolution); the source is box-downsampled (power-preserving) to that level
first, and only source rows within the kernel's support (K > 1e-7 K(0)) enter.

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
from typing import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jkatana.errors import InputError
from jkatana.light.envmap import EnvMap
from jkatana.light.fresnel_basis import FresnelBasis, fresnel_basis  # noqa: F401 (the basis' home; re-exported)
from jkatana.spectral.colorimetry import xyz_weights

LN2 = math.log(2.0)


def lobe_kernel(psi, mu):
    """Un-normalised prefilter kernel ``exp(−ln2 ψ²/(4μ²))`` (ψ: angle from R, rad)."""
    return np.exp(-LN2 * np.square(psi) / (4.0 * mu * mu))


def kernel_support(mu: float, rel: float = 1e-7) -> float:
    """Angle ψ beyond which the kernel is below ``rel`` of its peak."""
    return min(math.pi, 2.0 * mu * math.sqrt(math.log(1.0 / rel) / LN2))


def level_shape(mu: float, source_shape: tuple[int, int], texels_per_mu: float = 8.0,
                max_upsample: int = 1) -> tuple[int, int]:
    """Level resolution for μ: the coarsest ``H_src · 2^k`` (k ≤ log2 max_upsample) whose texel
    height is ≤ μ/texels_per_mu (at least 4 rows)."""
    H, W = source_shape
    h = H
    while h % 2 == 0 and (math.pi / (h // 2)) <= mu / texels_per_mu and h // 2 >= 4:
        h //= 2
    while math.pi / h > mu / texels_per_mu and 2 * h <= H * max_upsample:
        h *= 2
    return h, W * h // H


def _column_reach(theta_out: float, rows: np.ndarray, H: int, W: int, psi_max: float) -> int:
    """Largest column offset that can lie within ψ_max: from sin²(ψ/2) ≥ sin θ sin θ' sin²(Δφ/2)."""
    edges_sin = np.minimum(np.sin(rows * math.pi / H), np.sin((rows + 1) * math.pi / H))
    s = math.sqrt(max(math.sin(theta_out) * float(edges_sin.min()), 0.0))
    ratio = math.sin(psi_max / 2) / s if s > 0 else 2.0
    if ratio >= 1.0:
        return W
    return min(W, int(math.ceil(2 * math.asin(ratio) / (2 * math.pi / W))) + 2)


def _texel_kernel(theta_out: float, rows: np.ndarray, H: int, W: int, mu: float, sub: int,
                  psi_max: float) -> np.ndarray:
    """∫ K_μ dω over source texels ``(rows, all columns)`` for an output direction at polar angle
    ``theta_out`` and azimuth at the centre of column 0; ``sub × sub`` midpoint subsamples per texel,
    rescaled to the texel's exact solid angle. Only columns within reach of ψ_max are evaluated.
    Shape ``(len(rows), W)``."""
    c = _column_reach(theta_out, rows, H, W, psi_max)
    cols = np.arange(W) if 2 * c + 1 >= W else np.arange(-c, c + 1)
    t = (np.arange(sub) + 0.5) / sub
    th = (rows[:, None] + t[None, :]) * (math.pi / H)  # (r, s)
    dph = ((cols[:, None] + t[None, :]) - 0.5) * (2 * math.pi / W)  # (C, s): source φ − output φ
    ct, st = np.cos(th), np.sin(th)
    cos_psi = (math.cos(theta_out) * ct[:, None, :, None]
               + math.sin(theta_out) * st[:, None, :, None] * np.cos(dph)[None, :, None, :])  # (r, C, s, s)
    psi = np.arccos(np.clip(cos_psi, -1.0, 1.0))
    k = lobe_kernel(psi, mu) * st[:, None, :, None]
    omega_rows = (np.cos(rows * math.pi / H) - np.cos((rows + 1) * math.pi / H)) * (2 * math.pi / W)
    vals = k.mean(axis=(2, 3)) * (omega_rows / st.mean(axis=1))[:, None]
    if cols.size == W:
        return vals
    out = np.zeros((rows.size, W))
    out[:, np.mod(cols, W)] = vals
    return out


def convolve_level(L: np.ndarray, mu: float, rel: float = 1e-7, sub: int = 3) -> np.ndarray:
    """Convolve a piecewise-constant equirect map ``(H, W, n)`` with the normalised K_μ.

    Output at texel centres; the kernel is integrated over each source texel
    with ``sub × sub`` subsamples, so the result is the convolution of the
    piecewise-constant map even when μ is comparable to a texel. Per output
    row: a sum over source rows within the support of circular correlations in
    φ (real FFTs).
    """
    H, W, n = L.shape
    theta = (np.arange(H) + 0.5) * math.pi / H
    psi_max = kernel_support(mu, rel)
    L_hat = np.fft.rfft(L, axis=1)  # (H, W/2+1, n)
    out = np.empty((H, W, n), np.float64)
    for j in range(H):
        rows = np.nonzero(np.abs(theta - theta[j]) <= psi_max + 1.5 * math.pi / H)[0]
        K = _texel_kernel(theta[j], rows, H, W, mu, sub, psi_max)  # (r, W)
        K /= K.sum()
        # out[j, i] = Σ_{j', Δ} K[j', Δ] L[j', i + Δ]  (circular correlation)
        K_hat = np.conj(np.fft.rfft(K, axis=1))
        acc = np.einsum("rk,rkl->kl", K_hat, L_hat[rows])
        out[j] = np.fft.irfft(acc, n=W, axis=0)
    return out


class PrefilteredEnv(eqx.Module):
    """A stack of lobe-prefiltered maps, one per μ (increasing). See the module docstring."""

    levels: tuple[EnvMap, ...]
    mus: tuple[float, ...] = eqx.field(static=True)

    def lookup(self, d: Float[ArrayLike, "*#b 3"], mu) -> Float[Array, "*#b wl"]:
        """Prefiltered radiance toward ``d`` for roughness ``mu`` (clamped to the stack's range)."""
        vals = jnp.stack([lvl.lookup(d) for lvl in self.levels], axis=0)  # (m, *b, wl)
        if len(self.mus) == 1:
            return vals[0]
        logm = jnp.log(jnp.asarray(self.mus, vals.dtype))
        x = jnp.clip(jnp.log(jnp.asarray(mu, vals.dtype)), logm[0], logm[-1])
        idx = jnp.clip(jnp.searchsorted(logm, x, side="right") - 1, 0, len(self.mus) - 2)
        t = (x - logm[idx]) / (logm[idx + 1] - logm[idx])
        t = t[..., None]
        lo = jnp.take_along_axis(vals, idx[None, ..., None] * jnp.ones_like(vals[:1], jnp.int32), axis=0)[0] \
            if jnp.ndim(idx) else vals[idx]
        hi = jnp.take_along_axis(vals, (idx + 1)[None, ..., None] * jnp.ones_like(vals[:1], jnp.int32), axis=0)[0] \
            if jnp.ndim(idx) else vals[idx + 1]
        return lo * (1 - t) + hi * t


def prefilter(env: EnvMap, mus: Sequence[float] = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3), *,
              texels_per_mu: float = 8.0, max_upsample: int = 1, progress: bool = False) -> PrefilteredEnv:
    """Convolve ``env`` with the Gaussian-lobe kernel for each μ (rad), see the module docstring.

    **Arguments:**

    - `mus`: roughness values (the paper's μ, rad), positive.
    - `texels_per_mu`: level texel height ≤ μ / this (default 8: the kernel's
      FWHM, 4μ, spans ≥ 32 texels, unless capped by the source resolution).
    - `max_upsample`: allow levels finer than the source by up to this factor
      (nearest-neighbour repetition, which represents the piecewise-constant map
      exactly) when μ is small compared with a source texel: bilinear lookups of
      the result are then accurate near sharp features such as the sun.
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
    levels = []
    for mu in it:
        h, w = level_shape(mu, (env.height, env.width), texels_per_mu, max_upsample)
        if h < env.height:
            L = np.asarray(env.downsample(env.height // h).radiance, np.float64)
        else:
            f = h // env.height
            L = np.asarray(env.radiance, np.float64)
            if f > 1:
                L = np.repeat(np.repeat(L, f, axis=0), f, axis=1)
        L = convolve_level(L, mu)
        levels.append(EnvMap(jnp.asarray(L, env.radiance.dtype), env.grid))
    return PrefilteredEnv(tuple(levels), mus)


def brute_force_convolution(env: EnvMap, d, mu: float, sub: int = 8) -> np.ndarray:
    """Reference: ``Σ_i L_i ∫_texel_i K_μ(ω, d) dω / ∫ K_μ dω`` over every source texel of ``env``
    (piecewise-constant radiance), with ``sub × sub`` subsamples per texel, at any direction ``d``.

    Independent of :func:`prefilter`'s levels, FFTs and interpolation; O(texels in the support).
    """
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d)
    H, W = env.height, env.width
    L = np.asarray(env.radiance, np.float64)
    theta_d = math.acos(max(-1.0, min(1.0, d[1])))
    phi_d = math.atan2(d[0], -d[2])
    psi_max = kernel_support(mu)
    theta_rows = (np.arange(H) + 0.5) * math.pi / H
    rows = np.nonzero(np.abs(theta_rows - theta_d) <= psi_max + 1.5 * math.pi / H)[0]
    t = (np.arange(sub) + 0.5) / sub
    th = (rows[:, None] + t[None, :]) * (math.pi / H)  # (r, s)
    ph = (np.arange(W)[:, None] + t[None, :]) * (2 * math.pi / W) - math.pi  # (W, s), absolute φ
    cos_psi = (math.cos(theta_d) * np.cos(th)[:, None, :, None]
               + math.sin(theta_d) * np.sin(th)[:, None, :, None] * np.cos(ph - phi_d)[None, :, None, :])
    k = lobe_kernel(np.arccos(np.clip(cos_psi, -1, 1)), mu) * np.sin(th)[:, None, :, None]
    K = k.mean(axis=(2, 3))  # ∝ ∫_texel K dω (row factor cancels only within a row: keep sin θ weights)
    return np.einsum("rw,rwl->l", K, L[rows]) / K.sum()


# ---------------------------------------------------------------- Fresnel basis


def project_on_basis(env_or_level: EnvMap, basis: FresnelBasis) -> Float[Array, "H W rank 3"]:
    """``P_r = Σ_λ L(λ) b_r(λ) x̄ȳz̄(λ) Δλ``: the map projected on the Fresnel basis, XYZ per basis function.

    Shading then needs ``XYZ = Σ_r c_r(cos θ) P_r(R)`` (module docstring).
    """
    W = jnp.asarray(xyz_weights(env_or_level.grid), env_or_level.radiance.dtype)  # (wl, 3)
    B = jnp.asarray(basis.basis, env_or_level.radiance.dtype)  # (rank, wl)
    return jnp.einsum("hwl,rl,lc->hwrc", env_or_level.radiance, B, W)
