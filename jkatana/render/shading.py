"""Spectral shading of G-buffer pixels under an environment (JAX, jitted).

Every visible pixel carries a normal N, a view direction V (towards the
camera) and the reflectance-map parameters at its UV (w, μ0, μ1). The
outgoing radiance is the rendering equation with the paper's blended BRDF
(Mochizuki et al., eq. 5)::

    L_o(λ) = ∫ [w f_hiraji + (1 − w) f_hamon](L, V, λ) cos θi L_env(L, λ) dL
             + Σ_lights f(L_j, V, λ) cos θi E_j(λ) / r_j²

with f·cos θi from :meth:`jkatana.models.Hiraji.brdf_cos` /
:meth:`jkatana.models.Hamon.brdf_cos` (normalised convention unless a
calibration is given). The integral is estimated by one of four modes, all
static (trace-time) choices recorded in a :class:`Plan`:

- ``"reference"`` — importance sampling of the lobe mixture (Gaussian facet
  normals, exact pdf) and of the environment (piecewise-constant luminance
  density), combined with multiple importance sampling, balance heuristic
  (Veach & Guibas 1995). Unbiased; its error is measured against a converged
  frame by ``benchmarks/bench_render.py``.
- ``"paper"`` — the paper's method (§5): a fixed number of jittered reflection
  rays around the mirror direction (stratified facet normals in a disk of
  radius 2.5 μ), averaged with Gaussian weights D(φ, μ). Biased (truncated,
  self-normalised) but cheap; 30 rays in the paper.
- ``"prefiltered"`` — split-sum: the environment pre-convolved with the
  reflection lobe for a few μ, looked up at the mirror direction and
  multiplied by the Fresnel factor (Karis 2013, "Real Shading in Unreal
  Engine 4"). No noise, an approximation whose error is measured.
- ``"lowrank"`` — ``"reference"`` sampling, but with the environment
  projected on its first ``rank`` principal spectra (SVD over texels), so that
  per sample only ``rank`` channels are looked up and the Fresnel factor is
  folded into a (cos θ, rank, XYZ) table. A grey environment is exactly rank 1:
  the renderer detects it and always runs one band (:func:`env_basis`).

Sampling design of the MIS modes:

- the lobes are the objects of :mod:`jkatana.models.lobes` (value, sampler
  and pdf together): hiraji :class:`~jkatana.models.lobes.Gaussian`, hamon
  :class:`~jkatana.models.lobes.GaussianVCavity` (or
  :class:`~jkatana.models.lobes.Beckmann` for the Mitsuba comparison), blended
  and sampled as a :class:`~jkatana.models.lobes.Mixture` with weights w, 1 − w;
- the Fresnel factor is folded into the environment (:func:`fold_fresnel`,
  ``Plan.fresnel_rank``): per sample a ``3R``-channel lookup instead of one per
  wavelength, exact up to the rank of F(cos θ, λ);
- per-pixel points are a 3D Sobol sequence (Joe & Kuo 2008) with random
  digital shifts (Owen 2003), the environment warp taking 2 of them
  (:meth:`~jkatana.light.sampling.EnvSampler.sample_uniform2`), so that each
  strategy sees a well-stratified 2D set;
- one point set per output pixel across its subpixels (``Plan.subpixels``,
  :class:`PixelIds`): subpixel ``q`` of ``S`` takes points ``q·N … q·N + N − 1``
  of the pixel's ``S·N``-point sequence, so the union is one (0, m, 2)-net.

Effects on demand (all decided on the host before tracing, so a switched-off
effect is absent from the compiled program): no hamon pixels → no
Torrance–Sparrow term; all hiraji μ0 below ``MIRROR_MU`` → a mirror lookup,
no lobe sampling; no point lights → none evaluated.

Spectra leave the jitted function as CIE XYZ with ``k = 1/∫ȳ dλ`` (a flat
spectrum of 1 has Y = 1; Mitsuba 3's film uses the same normalisation), and
optionally as spectra.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.light.envmap import EnvMap, direction_to_uv, uv_to_direction
from jkatana.light.fresnel_basis import svd_of_table
from jkatana.light.sampling import EnvSampler
from jkatana.models.fresnel import fresnel_conductor
from jkatana.models.geometry import tangent_frame, to_local, to_world
from jkatana.models.lobes import Beckmann, Gaussian, GaussianVCavity, Mixture, reflect
from jkatana.models.microfacet import gaussian_facet, gaussian_normalisation



@functools.lru_cache(maxsize=64)
def _sobol_table(n: int) -> np.ndarray:
    """First ``n`` points of the 3D Sobol sequence (Joe & Kuo 2008 directions, scipy.stats.qmc) as uint32.

    Dimensions 0 and 1 form a (0, 2)-sequence: every power-of-two prefix is a
    (0, m, 2)-net, i.e. one point in every elementary interval of the unit
    square. The renderer XORs each pixel's points with random bits (a random
    digital shift, which keeps the net property; Owen 2003, "Quasi-Monte Carlo
    sampling", SIGGRAPH course notes) — independently for the lobe and the
    environment strategies, so each gets its own well-stratified 2D set.
    """
    from scipy.stats import qmc

    m = 1 << max(n - 1, 0).bit_length()  # a power-of-two prefix (scipy warns otherwise), then the first n
    pts = qmc.Sobol(d=3, scramble=False).random(m)[:n]
    return np.asarray(np.round(pts * 2.0**32), np.uint64).astype(np.uint32)
#: Below this μ0 (radians) the hiraji lobe is treated as a perfect mirror (one lookup).
MIRROR_MU = 1e-4
#: Cosine samples of the Fresnel table (linear interpolation error < 1e-6 for iron).
FRESNEL_TABLE = 1024
MODES = ("reference", "paper", "prefiltered", "lowrank")
#: Largest |F − F_R| (absolute reflectance) accepted for a rank-R Fresnel table (:func:`fresnel_rank_for`).
FRESNEL_RANK_TOL = 1e-5


@dataclasses.dataclass(frozen=True)
class Plan:
    """Static (trace-time) choices of what the shader computes.

    **Fields:**

    - `mode`: one of :data:`MODES`.
    - `samples`: lobe samples per pixel (``"reference"``/``"lowrank"``: pairs of
      one lobe sample and one environment sample; ``"paper"``: jittered rays).
    - `hiraji`, `hamon`: whether any pixel has w > 0 / w < 1.
    - `mirror`: hiraji treated as a perfect mirror (μ0 < MIRROR_MU everywhere).
    - `env_sampling`: importance-sample the environment too (MIS).
    - `factored`: shade in the environment's spectral basis (rank = its channels).
    - `fresnel_rank`: ``R > 0``: shade with the Fresnel factor folded into the
      environment (:func:`fold_fresnel`: per sample a ``3R``-channel lookup and
      ``R`` Fresnel coefficients instead of ``wl`` bands; the caller passes the
      folded material and environment). ``0``: full spectra. ``None`` (default):
      :func:`jkatana.render.frame.shade_pixels` picks the smallest ``R`` whose
      Fresnel table residual is below :data:`FRESNEL_RANK_TOL` when the plan
      allows it (no spectral output, no lights, not ``factored``), else 0;
      :func:`shade` called directly treats ``None`` as 0.
    - `lights`: number of point/directional lights (0: none evaluated).
    - `calibration`: ``None`` for the normalised convention, else K (see models).
    - `rough_model`: ``"paper"`` (hamon = eq. 2, Gaussian D, V-cavity G) or
      ``"beckmann"`` (hamon = Cook–Torrance with the normalised Beckmann D, α = μ1,
      and separable Smith G with Walter et al.'s 2007 rational G1 — the model
      Mitsuba 3's ``roughconductor`` uses; for validation against it).
    - `spectral`: also return spectra (full mode only).
    - `visibility`: the scene has occluders: every traced light direction is
      weighted by a host-computed visibility (:class:`Visibility`). ``False``
      (no occluders) compiles no visibility input at all.
    - `subpixels`: ``S`` G-buffer samples (subpixels) per output pixel. With
      ``S > 1`` and :class:`PixelIds` passed to :func:`shade`, the MIS modes draw
      ONE per-pixel point set of ``S × samples`` points and give each subpixel
      its share (subpixel ``q`` takes points ``q·N … q·N + N − 1`` of the pixel's
      ``S·N``-point Sobol sequence under the pixel's digital shift), so that the union over a pixel's
      subpixels is one well-stratified set instead of ``S`` independently
      shifted ones. Without ids (or ``S = 1``) every G-buffer sample is its own pixel.
    """

    mode: str = "reference"
    samples: int = 64
    hiraji: bool = True
    hamon: bool = True
    mirror: bool = False
    env_sampling: bool = True
    factored: bool = False
    fresnel_rank: int | None = None
    lights: int = 0
    rough_model: str = "paper"
    calibration: float | None = None
    spectral: bool = False
    visibility: bool = False
    subpixels: int = 1


class Environment(eqx.Module):
    """Environment lighting as the shader sees it.

    **Fields:**

    - `channels`: ``(H, W, J)``: spectral radiance (J = wavelengths, `basis`
      unused) or coefficients on a spectral basis.
    - `basis`: ``(J, wl)`` spectra such that radiance = channels @ basis.
    - `rotation`: ``(3, 3)`` world → map rotation applied to every lookup.
    - `sampler`: :class:`jkatana.light.sampling.EnvSampler` of the map (luminance ×
      solid angle, bilinear-safe), in map coordinates.
    - `prefiltered`: ``M`` lobe-convolved maps ``(H_m, W_m, J)`` for ``prefilter_mus``
      (:func:`jkatana.light.prefilter.prefilter`, projected on ``basis``), or ``()``.
    - `prefilter_mus`: ``(M,)`` μ of each prefiltered level (increasing).
    """

    channels: Float[Array, "H W J"]
    basis: Float[Array, "J wl"]
    rotation: Float[Array, "3 3"]
    sampler: EnvSampler
    prefiltered: tuple
    prefilter_mus: Float[Array, "M"]


class Light(NamedTuple):
    """Point (``kind`` 0: position, intensity W sr⁻¹ nm⁻¹) or directional (1: direction to light, irradiance)."""

    vector: Float[Array, "n 3"]
    kind: Float[Array, "n"]
    spectrum: Float[Array, "n wl"]


class Pixels(NamedTuple):
    """G-buffer pixels (flattened, padded): world position, normal, view direction, per-pixel material."""

    position: Float[Array, "P 3"]
    normal: Float[Array, "P 3"]
    view: Float[Array, "P 3"]
    w: Float[Array, "P"]
    mu0: Float[Array, "P"]
    mu1: Float[Array, "P"]


class PixelIds(NamedTuple):
    """Which output pixel and which of its subpixels each G-buffer sample is (see ``Plan.subpixels``).

    ``pixel (P,)`` uint32: a frame-wide pixel index (the scramble of the pixel's
    point set is ``jax.random.bits(fold_in(key, pixel))``, so it does not depend on
    the chunk or device that shades it); ``subpixel (P,)`` int32 in ``[0, S)``.
    """

    pixel: Array
    subpixel: Array


class Rays(NamedTuple):
    """World directions the shader will trace for given pixels and key (see :func:`ray_directions`).

    Pixel axis first everywhere (so one sharding splits them): ``mirror (P, 3)``
    (mirror direction: the mirror hiraji and the prefiltered lookups),
    ``lobe (P, S, 3)`` (lobe-sampled or the paper's jittered rays), ``env (P, S, 3)``
    (environment samples of MIS; empty ``S = 0`` otherwise), ``lights (P, n, 3)`` and
    ``light_dist (P, n)`` (distance to a point light, ``inf`` for directional ones).
    """

    mirror: Float[Array, "P 3"]
    lobe: Float[Array, "P S 3"]
    env: Float[Array, "P S2 3"]
    lights: Float[Array, "P n 3"]
    light_dist: Float[Array, "P n"]


class Visibility(NamedTuple):
    """1 where the direction of the matching :class:`Rays` entry reaches the environment/light, else 0."""

    mirror: Float[Array, "P"]
    lobe: Float[Array, "P S"]
    env: Float[Array, "P S2"]
    lights: Float[Array, "P n"]


# ---------------------------------------------------------------- environment


def bilinear_equirect(image: Float[Array, "H W C"], d: Float[Array, "*b 3"]) -> Float[Array, "*b C"]:
    """Bilinear lookup of an equirectangular ``(H, W, C)`` image in direction ``d``.

    Same convention and filtering as :meth:`jkatana.light.envmap.EnvMap.lookup`
    (wrap in u, clamp in v), for any number of channels (spectral bands or
    basis coefficients).
    """
    u, v = direction_to_uv(d)
    return bilinear_equirect_uv(image, u, v)


def bilinear_equirect_uv(image: Float[Array, "H W C"], u, v) -> Float[Array, "*b C"]:
    """:func:`bilinear_equirect` at given equirectangular coordinates ``(u, v)`` (no ``atan2``)."""
    H, W = image.shape[0], image.shape[1]
    x = u * W - 0.5
    y = jnp.clip(v * H - 0.5, 0.0, H - 1.0)
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx = (x - x0).astype(image.dtype)[..., None]
    fy = (y - y0).astype(image.dtype)[..., None]
    i0 = jnp.mod(x0.astype(jnp.int32), W)
    i1 = jnp.mod(i0 + 1, W)
    j0 = jnp.clip(y0.astype(jnp.int32), 0, H - 1)
    j1 = jnp.minimum(j0 + 1, H - 1)
    top = image[j0, i0] * (1 - fx) + image[j0, i1] * fx
    bottom = image[j1, i0] * (1 - fx) + image[j1, i1] * fx
    return top * (1 - fy) + bottom * fy


def env_basis(radiance: np.ndarray, rank: int | None, *, grey_rtol: float = 1e-5):
    """Spectral factorisation of an environment: ``radiance ≈ coeffs @ basis``.

    ``rank=None`` keeps the full spectra (identity basis) unless the map is grey
    (every texel a multiple of one spectrum to ``grey_rtol``), which is exactly
    rank 1. Otherwise the first ``rank`` right singular vectors of the
    ``(H·W, wl)`` radiance matrix (principal spectra, Eckart–Young optimal in
    the least-squares sense).

    **Returns:** ``(coeffs (H, W, J), basis (J, wl), factored: bool, rel_residual)``.
    """
    L = np.asarray(radiance, np.float64)
    H, W, nwl = L.shape
    flat = L.reshape(-1, nwl)
    # rank-1 test on a subsample (cheap): the leading singular value carries all the energy
    step = max(1, flat.shape[0] // 20000)
    _, s, vt = np.linalg.svd(flat[::step], full_matrices=False)
    energy = np.sqrt(np.sum(s[1:] ** 2)) / max(s[0], 1e-300)
    if rank is None and energy > grey_rtol:
        return L.astype(np.float32), np.eye(nwl, dtype=np.float32), False, 0.0
    r = 1 if rank is None else int(rank)
    basis = vt[:r]
    if basis[0].sum() < 0:
        basis = -basis
    coeffs = flat @ basis.T
    resid = np.linalg.norm(flat - coeffs @ basis) / max(np.linalg.norm(flat), 1e-300)
    return (coeffs.reshape(H, W, r).astype(np.float32), basis.astype(np.float32), True, float(resid))


def build_environment(radiance: np.ndarray, *, rank: int | None = None, rotation=None,
                      prefilter_mus=(), prefilter_resolution: int = 128, dtype=jnp.float32, grid=None,
                      env_density="max"):
    """An :class:`Environment` (sampling tables, optional basis and prefiltering) from ``(H, W, wl)`` radiance.

    Environment sampling is :class:`jkatana.light.sampling.EnvSampler` (the light
    stage's): a piecewise-constant density ∝ luminance × solid angle per texel,
    the texel's luminance being the integral of the *bilinear* radiance the
    lookups return (so ``radiance / pdf`` stays bounded next to a one-texel
    sun), uniform in solid angle inside a texel — Pharr, Jakob & Humphreys,
    *PBRT* 4th ed., §A.5 and §12.5. ``env_density`` is the texel weight
    (:meth:`~jkatana.light.sampling.EnvSampler.build`'s ``bilinear``): ``"max"``
    (3×3 neighbourhood maximum) or ``True`` (exact bilinear integral).

    **Returns:** ``(environment, factored, rel_residual)``.
    """
    from jkatana.spectral import DEFAULT_GRID

    radiance = np.asarray(radiance, np.float64)
    H, W, nwl = radiance.shape
    coeffs, basis, factored, resid = env_basis(radiance, rank)
    if grid is None:  # the density only steers sampling: an unknown grid borrows the default range
        grid = DEFAULT_GRID if nwl == DEFAULT_GRID.size else type(DEFAULT_GRID).with_count(DEFAULT_GRID.start, DEFAULT_GRID.stop, nwl)
    sampler = EnvSampler.build(EnvMap(jnp.asarray(radiance, dtype), grid), bilinear=env_density)
    rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    mus = tuple(sorted(float(m) for m in prefilter_mus))
    pre = ()
    if mus:
        # the light stage's exact convolution with the lobe kernel, on the source box-downsampled to
        # at most `prefilter_resolution` columns, then projected on the environment's spectral basis
        from jkatana.light.prefilter import prefilter as light_prefilter

        src = EnvMap(jnp.asarray(radiance, jnp.float32), grid)
        while src.width > prefilter_resolution and src.height % 2 == 0 and src.width % 2 == 0:
            src = src.downsample(2)
        levels = light_prefilter(src, mus).levels
        pre = tuple(jnp.asarray(np.asarray(lvl.radiance, np.float64) @ basis.T.astype(np.float64), dtype)
                    for lvl in levels)
    env = Environment(jnp.asarray(coeffs, dtype), jnp.asarray(basis, dtype), jnp.asarray(rot, dtype), sampler,
                      pre, jnp.asarray(np.asarray(mus, np.float64), dtype))
    return env, factored, resid


def env_lookup(env: Environment, d_world):
    """Environment channels in world direction ``d_world`` (rotation applied)."""
    return bilinear_equirect(env.channels, d_world @ env.rotation.T)


def env_uv(env: Environment, d_world):
    """Map coordinates ``(u, v)`` of world direction ``d_world`` (one ``direction_to_uv`` for lookup and pdf)."""
    return direction_to_uv(d_world @ env.rotation.T)


def _lookup_prefiltered(env: Environment, mu, R_world):
    """Prefiltered channels toward ``R_world`` for per-pixel ``mu``: bilinear in each level, linear
    in log μ between levels, clamped to the tabulated range (as
    :meth:`jkatana.light.prefilter.PrefilteredEnv.lookup`, in the environment's channel space)."""
    d = R_world @ env.rotation.T
    vals = jnp.stack([bilinear_equirect(lvl, d) for lvl in env.prefiltered])  # (M, P, J)
    M = vals.shape[0]
    if M == 1:
        return vals[0]
    logm = jnp.log(env.prefilter_mus)
    x = jnp.clip(jnp.log(jnp.maximum(mu, 1e-12)), logm[0], logm[-1])
    k0 = jnp.clip(jnp.searchsorted(logm, x, side="right") - 1, 0, M - 2)
    t = ((x - logm[k0]) / (logm[k0 + 1] - logm[k0]))[:, None]
    P = R_world.shape[0]
    return vals[k0, jnp.arange(P)] * (1 - t) + vals[k0 + 1, jnp.arange(P)] * t


# ---------------------------------------------------------------- geometry helpers


def fresnel_table(n, k, size: int = FRESNEL_TABLE):
    """F(cos θ, λ) on ``size`` cosines uniformly in [0, 1] (exact conductor Fresnel, differentiable in n, k)."""
    c = jnp.linspace(0.0, 1.0, size, dtype=n.dtype)
    return fresnel_conductor(c[:, None], n, k)


def _table_lookup(table, cos):
    """Linear interpolation of a ``(T, ...)`` table at cosines in [0, 1]."""
    T = table.shape[0]
    x = jnp.clip(cos, 0.0, 1.0) * (T - 1)
    i0 = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, T - 2)
    f = (x - i0).astype(table.dtype)
    f = f.reshape(f.shape + (1,) * (table.ndim - 1))
    return table[i0] * (1 - f) + table[i0 + 1] * f


# ---------------------------------------------------------------- BRDF (f·cos θi) per region


class Material(eqx.Module):
    """Differentiable material inputs: Fresnel table and the fitted scales (calibrated convention)."""

    ftable: Float[Array, "T wl"]
    chi: Float[Array, ""]
    beta: Float[Array, ""]


def _norms(plan: Plan, mat: Material, px: Pixels):
    """Per-pixel lobe scales: N(μ) (normalised convention) or χ/K, β/K (calibrated). Hoisted out of the sample loop."""
    if plan.calibration is None:
        n0 = gaussian_normalisation(px.mu0) if (plan.hiraji and not plan.mirror) else None
        n1 = gaussian_normalisation(px.mu1) if plan.hamon else None
        return n0, n1
    return mat.chi / plan.calibration, mat.beta / plan.calibration


def _lobes(plan: Plan, px: Pixels, norms):
    """The sampled lobes of the pixels with their blend weights: ``[(lobe, weight), ...]``.

    Hiraji: :class:`~jkatana.models.lobes.Gaussian` (μ0, weight w) unless it is a
    perfect mirror; hamon: :class:`~jkatana.models.lobes.GaussianVCavity` (μ1) or,
    with ``plan.rough_model == "beckmann"``, :class:`~jkatana.models.lobes.Beckmann`
    (α = μ1), weight 1 − w (Mochizuki et al., eq. 5).
    """
    normalised = plan.calibration is None
    out = []
    if plan.hiraji and not plan.mirror:
        out.append((Gaussian(px.mu0, norms[0], normalised=normalised), px.w))
    if plan.hamon:
        rough = (Beckmann(px.mu1) if plan.rough_model == "beckmann"
                 else GaussianVCavity(px.mu1, norms[1], normalised=normalised))
        out.append((rough, 1.0 - px.w))
    return out


def _sampler(lobes):
    """One lobe, or the blend of two sampled by its weights (:class:`~jkatana.models.lobes.Mixture`)."""
    if len(lobes) == 1:
        return lobes[0][0]
    (a, w), (b, _) = lobes
    return Mixture(a, b, w)


def _mix_w(plan: Plan, px: Pixels):
    """Probability of sampling the hiraji lobe."""
    if plan.mirror or not plan.hiraji:
        return jnp.zeros_like(px.w)
    if not plan.hamon:
        return jnp.ones_like(px.w)
    return px.w


def _fcos_terms(lobes, L, V):
    """f·cos θi without Fresnel per lobe term, weighted by the blend: ``[(a, Fresnel cosine), ...]``."""
    return [(w * a, c) for lobe, w in lobes for a, c in lobe.terms(L, V)]


# ---------------------------------------------------------------- Fresnel folded into the environment


def fresnel_rank_for(ftable, tol: float = FRESNEL_RANK_TOL, max_rank: int = 8, *, _basis_too: bool = False) -> int:
    """Smallest R with max |F − F_R| ≤ ``tol`` over the table (truncated SVD in λ), 0 if none ≤ ``max_rank``.

    F(cos θ, λ) of a conductor is smooth in both arguments (see DESIGN.md); the
    SVD is :func:`jkatana.light.fresnel_basis.svd_of_table`'s. Host-side
    (NumPy float64) on a concrete table.
    """
    import hashlib

    F = np.ascontiguousarray(np.asarray(ftable))
    key = (hashlib.blake2b(F.tobytes(), digest_size=16).hexdigest(), F.shape, str(F.dtype), tol, max_rank)
    if key not in _RANK_CACHE:  # a per-frame host SVD costs ~1 s on a loaded machine: once per table
        F = F.astype(np.float64)
        u, s, vt = svd_of_table(F)
        _RANK_CACHE[key] = (0, vt)
        for r in range(1, min(max_rank, len(s)) + 1):
            if np.max(np.abs(F - (u[:, :r] * s[:r]) @ vt[:r])) <= tol:
                _RANK_CACHE[key] = (r, vt)
                break
    return _RANK_CACHE[key][0] if not _basis_too else _RANK_CACHE[key]


_RANK_CACHE: dict = {}


def fold_fresnel(rank: int, mat: Material, env: Environment, cmf, basis=None) -> tuple[Material, Environment]:
    """Fold a rank-``R`` Fresnel factorisation and the CMFs into the environment (exact up to that rank).

    With ``F(c, λ) ≈ Σ_r a_r(c) b_r(λ)`` (``b`` the leading right singular
    vectors of the table, held fixed — no gradient through the SVD; ``a = F bᵀ``
    is differentiable in the table) the XYZ radiance of one sample is
    ``Σ_r a_r(cos θ) G_r(L)`` with ``G_r = Σ_λ b_r(λ) E(L, λ) x̄ȳz̄(λ)``: a
    ``3R``-channel map. Bilinear lookups commute with this per-texel linear map,
    so the only approximation is the Fresnel rank. Per sample a ``3R``-channel
    lookup replaces a ``wl``-band one — the issue's "9-channel bilinear lookup"
    for R = 3. **Returns:** ``(material with ftable (T, R), environment with
    channels (H, W, 3R) and folded prefiltered levels)``; pass both to
    :func:`shade` with ``Plan(fresnel_rank=R)``. ``basis``: the ``(R, wl)`` spectra
    if already known (the frame passes the host SVD of :func:`fresnel_rank_for`),
    else the SVD runs here.
    """
    F = mat.ftable
    if basis is None:
        _, _, vt = jnp.linalg.svd(jax.lax.stop_gradient(F), full_matrices=False)
        basis = vt[:rank]
    b = jnp.asarray(basis, F.dtype)  # (R, wl)
    a = F @ b.T  # (T, R)
    M = jnp.einsum("jl,rl,lc->jrc", env.basis, b, cmf.astype(F.dtype))  # (J, R, 3)

    def fold(img):
        return jnp.einsum("hwj,jrc->hwrc", img, M).reshape(img.shape[:2] + (3 * rank,))

    env2 = eqx.tree_at(lambda e: (e.channels, e.prefiltered), env,
                       (fold(env.channels), tuple(fold(lvl) for lvl in env.prefiltered)))
    return Material(a, mat.chi, mat.beta), env2


def _folded(plan: Plan) -> bool:
    return bool(plan.fresnel_rank) and not plan.factored


# ---------------------------------------------------------------- the shader


def _frame(px: Pixels):
    """Per-pixel tangent frame and the view direction in it."""
    N = px.normal
    t, b = tangent_frame(N)
    return (t, b, N), to_local(px.view, t, b, N)


def _mirror_ray(Vl, fr):
    Rl = jnp.stack([-Vl[:, 0], -Vl[:, 1], Vl[:, 2]], -1)
    return Rl, to_world(Rl, *fr)


def _paper_grid(S: int):
    nu = max(1, int(round(math.sqrt(S))))
    return nu, -(-S // nu)


def _paper_ray(plan: Plan, px: Pixels, Vl, fr, key, k):
    """The k-th of the paper's jittered rays: ``(L_local, L_world, φ, μ)``."""
    nu, nv = _paper_grid(plan.samples)
    P = Vl.shape[0]
    kk = jax.random.fold_in(key, k)
    j = jax.random.uniform(kk, (P, 3), Vl.dtype)
    su = ((k // nv) + j[:, 0]) / nu
    sv = ((k % nv) + j[:, 1]) / nv
    # lobe choice per sample (mixture), then a stratified point in the disk φ ≤ 2.5 μ
    use0 = j[:, 2] < _mix_w(plan, px)
    mu = jnp.where(use0, px.mu0, px.mu1)
    phi = 2.5 * mu * jnp.sqrt(su)
    psi = 2 * jnp.pi * sv
    s = jnp.sin(phi)
    h = jnp.stack([s * jnp.cos(psi), s * jnp.sin(psi), jnp.cos(phi)], -1)
    Ll = reflect(Vl, h)
    return Ll, to_world(Ll, *fr), phi, mu


def _per_pixel(plan: Plan, ids: PixelIds | None) -> bool:
    return ids is not None and plan.subpixels > 1


def _mis_offset(key, P, dtype, plan: Plan | None = None, ids: PixelIds | None = None):
    """Per-pixel randomisation of the Sobol sample sequence: random digital shifts ``(P, 5)`` (uint32).

    With :class:`PixelIds` (and ``plan.subpixels > 1``) the randomisation is drawn per output
    pixel from ``fold_in(key, pixel)``, so all subpixels of a pixel share it wherever they are shaded."""
    if plan is not None and _per_pixel(plan, ids):
        def one(p):
            kp = jax.random.fold_in(key, p)
            return jax.random.bits(kp, (5,), jnp.uint32)

        return jax.vmap(one)(ids.pixel)
    return jax.random.bits(key, (P, 5), jnp.uint32)


def _sample_index(plan: Plan, ids: PixelIds | None, k):
    """Index of the k-th sample of each G-buffer sample in its pixel's sequence: ``k`` (scalar), or
    ``(P,)`` per subpixel (subpixel ``s`` takes indices ``s·N … s·N + N − 1``: for ``N`` a power of two each
    block is a (0, m, 2)-net and their union the full prefix)."""
    if not _per_pixel(plan, ids):
        return k
    sub = ids.subpixel.astype(jnp.int32)
    return sub * plan.samples + k


def _uniforms(plan: Plan, offset, k, dtype, ids: PixelIds | None = None):
    """The k-th point per pixel: ``(mix, lobe u1, lobe u2, env (P, 2))``."""
    idx = _sample_index(plan, ids, k)
    n = plan.samples * (plan.subpixels if _per_pixel(plan, ids) else 1)
    t = jnp.asarray(_sobol_table(n))[idx]  # (3,) the same point for every pixel, or (P, 3) per subpixel
    t = jnp.broadcast_to(t, offset.shape[:1] + (3,))

    def unit(x):  # top 24 bits → [0, 1) exactly representable in float32
        return (x >> 8).astype(dtype) * jnp.asarray(2.0**-24, dtype)

    return (unit(t[:, 2] ^ offset[:, 4]), unit(t[:, 0] ^ offset[:, 0]), unit(t[:, 1] ^ offset[:, 1]),
            jnp.stack([unit(t[:, 0] ^ offset[:, 2]), unit(t[:, 1] ^ offset[:, 3])], -1))


def sample_points(plan: Plan, key, n: int, ids: PixelIds | None = None, dtype=jnp.float32):
    """The unit-cube points the MIS modes use: ``(n, plan.samples, 5)`` = (mixture choice, lobe u1, lobe u2,
    environment u1, u2) per G-buffer sample (Sobol), for inspection and tests.

    Same construction as :func:`shade` with the same ``key`` and ``ids``.
    """
    offset = _mis_offset(key, n, dtype, plan, ids)

    def one(k):
        r0, r1, r2, re = _uniforms(plan, offset, k, dtype, ids)
        return jnp.concatenate([jnp.stack([r0, r1, r2], -1), re], -1)

    return jax.vmap(one, out_axes=1)(jnp.arange(plan.samples))


def _mis_rays(plan: Plan, env: Environment, sampler, Vl, fr, offset, k, ids: PixelIds | None = None):
    """The k-th MIS pair: ``(Ll, Lw, pdf)`` from the lobe mixture ``sampler``, ``(Ll2, Lw2, pe2, uv2)`` from the
    environment (``None`` without environment sampling; ``uv2`` the map coordinates of ``Lw2``, or ``None``)."""
    dtype = Vl.dtype
    r0, r1, r2, re = _uniforms(plan, offset, k, dtype, ids)
    Ll, pb = sampler.sample(Vl, jnp.stack([r1, r2], -1), r0)
    Lw = to_world(Ll, *fr)
    if not plan.env_sampling:
        return Ll, Lw, pb, None, None, None, None
    d_map, pe2, u2, v2 = env.sampler.sample_uniform2(re)
    Lw2, uv2 = d_map @ env.rotation, (u2, v2)
    return Ll, Lw, pb, to_local(Lw2, *fr), Lw2, pe2, uv2


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


def _has_lobe(plan: Plan) -> bool:
    return (plan.hiraji and not plan.mirror) or plan.hamon


def ray_directions(plan: Plan, env: Environment, lights: Light | None, px: Pixels, key,
                   ids: PixelIds | None = None) -> Rays:
    """Every direction :func:`shade` will look up for these pixels and this key, as :class:`Rays`.

    Built from the same sampling helpers as :func:`shade` (same key → same
    directions), so a host step can ray-cast them against occluders and hand
    the result back to :func:`shade` as a :class:`Visibility`. Pure JAX.
    """
    fr, Vl = _frame(px)
    P, dtype = Vl.shape[0], Vl.dtype
    _, mirror = _mirror_ray(Vl, fr)
    empty = jnp.zeros((P, 0, 3), dtype)
    lobe, envd = empty, empty
    ks = jnp.arange(plan.samples)
    if plan.mode == "paper" and _has_lobe(plan):
        lobe = jax.vmap(lambda k: _paper_ray(plan, px, Vl, fr, key, k)[1], out_axes=1)(ks)
    elif plan.mode in ("reference", "lowrank") and _has_lobe(plan):
        offset = _mis_offset(key, P, dtype, plan, ids)
        sampler = _sampler(_lobes(plan, px, (1.0, 1.0)))  # sampling needs the widths only

        def one(k):
            _, Lw, _, _, Lw2, _, _ = _mis_rays(plan, env, sampler, Vl, fr, offset, k, ids)
            return Lw, (Lw2 if Lw2 is not None else jnp.zeros((P, 3), dtype))

        lobe, envd = jax.vmap(one, out_axes=1)(ks)
        if not plan.env_sampling:
            envd = empty
    n = plan.lights if lights is not None else 0
    if n:
        ls = [_light_ray(lights, j, px) for j in range(n)]
        ldir = jnp.stack([x[0] for x in ls], 1)
        ldist = jnp.stack([jnp.broadcast_to(x[2], (P,)) for x in ls], 1)
    else:
        ldir, ldist = empty, jnp.zeros((P, 0), dtype)
    return Rays(mirror, lobe, envd, ldir, ldist)


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
    vis = vis if plan.visibility else None
    dtype = px.normal.dtype
    P = px.normal.shape[0]
    fr, Vl = _frame(px)
    factored = plan.factored
    folded = _folded(plan)
    norms = _norms(plan, mat, px)
    lobes = _lobes(plan, px, norms)
    sampler = _sampler(lobes) if lobes else None
    if folded:
        R = plan.fresnel_rank
        if plan.lights or plan.spectral or mat.ftable.shape[-1] != R or env.channels.shape[-1] != 3 * R:
            raise ValueError("Plan(fresnel_rank=R) needs fold_fresnel's material and environment, "
                             "and no lights or spectral output")
        acc = jnp.zeros((P, 3), dtype)
    elif factored:
        # (T, J, 3): Fresnel folded with the basis spectra and the CMFs
        xtable = jnp.einsum("tl,jl,lc->tjc", mat.ftable, env.basis, cmf)
        acc = jnp.zeros((P, 3), dtype)
    else:
        acc = jnp.zeros((P, env.channels.shape[-1]), dtype)

    def combine(cos, E):
        """F(cos)·E in the accumulator's space."""
        if folded:
            return jnp.einsum("pr,prc->pc", _table_lookup(mat.ftable, cos), E.reshape(E.shape[0], -1, 3))
        if factored:
            return jnp.einsum("pjc,pj->pc", _table_lookup(xtable, cos), E)
        return _table_lookup(mat.ftable, cos) * E

    def radiance_terms(Ll, Lw, weight, uv=None):
        """Σ_lobes scalar·F(cos)·E(L) · weight, in the accumulator's space (``uv``: map coordinates of Lw)."""
        terms = _fcos_terms(lobes, Ll, Vl)
        E = env_lookup(env, Lw) if uv is None else bilinear_equirect_uv(env.channels, *uv)  # (P, J)
        total = 0.0
        for a, c in terms:
            total = total + (a * weight)[:, None] * combine(c, E)
        return total

    def add_mirror_like(acc, weight, E, cos):
        wv = jnp.where(Vl[:, 2] > 0, weight, 0.0)
        if vis is not None:
            wv = wv * vis.mirror
        return acc + wv[:, None] * combine(cos, E)

    # --- mirror hiraji: one deterministic lookup
    if plan.hiraji and plan.mirror:
        _, Rw = _mirror_ray(Vl, fr)
        acc = add_mirror_like(acc, px.w, env_lookup(env, Rw), jnp.clip(Vl[:, 2], 0.0, 1.0))

    S = plan.samples
    ks = jnp.arange(S)
    if plan.mode == "prefiltered" and _has_lobe(plan):
        # split sum: F(cos θv) × prefiltered env at the mirror direction, per lobe
        _, Rw = _mirror_ray(Vl, fr)
        cos = jnp.clip(Vl[:, 2], 0.0, 1.0)
        for on, weight, mu in ((plan.hiraji and not plan.mirror, px.w, px.mu0), (plan.hamon, 1.0 - px.w, px.mu1)):
            if on:
                acc = add_mirror_like(acc, weight, _lookup_prefiltered(env, mu, Rw), cos)
    elif plan.mode == "paper" and _has_lobe(plan):
        def body(carry, xs):
            acc_, wsum = carry
            k, v = xs
            Ll, Lw, phi, mu = _paper_ray(plan, px, Vl, fr, key, k)
            gauss = gaussian_facet(phi, jnp.maximum(mu, 1e-7))
            pdf = sampler.pdf(Ll, Vl)
            ok = (Ll[:, 2] > 0) & (pdf > 0)
            g = jnp.where(ok, gauss / jnp.where(ok, pdf, 1.0), 0.0)  # Gaussian weight × 1/pdf → throughput
            if v is not None:
                g = g * v
            return (acc_ + radiance_terms(Ll, Lw, g), wsum + gauss), None

        xs = (ks, None if vis is None else vis.lobe.T)
        (lob, wsum), _ = jax.lax.scan(body, (jnp.zeros_like(acc), jnp.zeros((P,), dtype)), xs)
        acc = acc + lob / jnp.maximum(wsum, 1e-30)[:, None]
    elif _has_lobe(plan):  # reference / lowrank: MIS of lobe and environment sampling
        offset = _mis_offset(key, P, dtype, plan, ids)

        def body(acc_, xs):
            k, v1, v2 = xs
            Ll, Lw, pb, Ll2, Lw2, pe2, uv2 = _mis_rays(plan, env, sampler, Vl, fr, offset, k, ids)
            uv = env_uv(env, Lw)  # one atan2 pair serves the density and the lookup
            pe = env.sampler.pdf_uv(*uv) if plan.env_sampling else 0.0
            ok = (Ll[:, 2] > 0) & (pb > 0)
            wgt = jnp.where(ok, 1.0 / jnp.where(ok, pb + pe, 1.0), 0.0)
            if v1 is not None:
                wgt = wgt * v1
            acc_ = acc_ + radiance_terms(Ll, Lw, wgt, uv)
            if plan.env_sampling:
                pb2 = sampler.pdf(Ll2, Vl)
                ok2 = (Ll2[:, 2] > 0) & (pe2 > 0)
                wgt2 = jnp.where(ok2, 1.0 / jnp.where(ok2, pb2 + pe2, 1.0), 0.0)
                if v2 is not None:
                    wgt2 = wgt2 * v2
                acc_ = acc_ + radiance_terms(Ll2, Lw2, wgt2, uv2)
            return acc_, None

        xs = (ks, None, None) if vis is None else (ks, vis.lobe.T, vis.env.T if plan.env_sampling else None)
        lob, _ = jax.lax.scan(body, jnp.zeros_like(acc), xs)
        acc = acc + lob / S

    # --- analytic lights (point: kind 0, directional: kind 1); a delta hiraji lobe never sees one
    if plan.lights and lights is not None:
        for j in range(plan.lights):
            Lw, falloff, _ = _light_ray(lights, j, px)
            if vis is not None:
                falloff = falloff * vis.lights[:, j]
            Ll = to_local(Lw, *fr)
            spec = lights.spectrum[j]
            for a, c in _fcos_terms(lobes, Ll, Vl):
                Fs = _table_lookup(mat.ftable, c) * spec[None, :]
                if factored:
                    acc = acc + (a * falloff)[:, None] * (Fs @ cmf)
                else:
                    acc = acc + (a * falloff)[:, None] * Fs @ _unbasis(env)
    if factored or folded:
        return acc, None
    spectra = acc @ env.basis  # identity when not factored
    return spectra @ cmf, (spectra if plan.spectral else None)


def _unbasis(env: Environment):
    """Pseudo-inverse map from spectra to the accumulator's channels (identity in full mode)."""
    return env.basis.T


def background(env: Environment, directions, cmf, spectral: bool = False):
    """XYZ (and spectra) of the environment seen directly along camera rays."""
    C = env_lookup(env, directions)
    if not spectral:  # (J, 3) first: a (P, J) @ (J, wl) product per pixel would dominate large frames
        return C @ (env.basis @ cmf), None
    E = C @ env.basis
    return E @ cmf, E
