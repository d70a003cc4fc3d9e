"""Environment lighting as the shader sees it: spectral channels (optionally on a spectral basis), its
rotation, its importance sampler and its prefiltered levels; bilinear lookups and the background.

The sampler is the light stage's :class:`jkatana.light.sampling.EnvSampler`
(piecewise-constant density ∝ luminance × solid angle, Pharr, Jakob &
Humphreys, *PBRT* 4th ed., §A.5 and §12.5); prefiltered levels come from
:func:`jkatana.light.prefilter.prefilter` (split sum, Karis 2013); the spectral
basis of a low-rank environment is its leading principal spectra (SVD,
Eckart & Young 1936).

Compact bright sources (a sun) can be split off the map first
(:func:`jkatana.light.sun.split_compact_sources`): the *remainder* is what is
sampled, prefiltered and looked up, and the sources ride along as spherical-cap
lights (:class:`Caps`) that the shader integrates on their own — a
deterministic cap rule in the prefiltered and paper modes, a third sampling
strategy under multiple importance sampling in the Monte Carlo modes.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.light.envmap import EnvMap, direction_to_uv
from jkatana.light.prefilter import blend_levels
from jkatana.light.envmap import bilinear_uv as bilinear_equirect_uv  # the one bilinear lookup, under the render name
from jkatana.light.sampling import EnvSampler
from jkatana.light.sun import SunSplit, cap_solid_angle, split_compact_sources
from jkatana.render.integrators import INTEGRATORS


#: Render modes that split compact sources off the map by default (where one exists): the integrators of
#: :data:`~jkatana.render.integrators.INTEGRATORS` marked ``splits_sun``, the fast deterministic and low-rank
#: modes. The reference mode keeps the whole map (the yardstick) unless asked.
SPLIT_MODES = tuple(name for name, integrator in INTEGRATORS.items() if integrator.splits_sun)


class Caps(eqx.Module):
    """Spherical-cap lights split off an environment, stacked (K caps), in the environment's channel space.

    The shader's form of :class:`jkatana.light.sun.SunCap` (uniform spectral
    radiance over a cone of half-angle ``radius`` about ``direction``).

    **Fields:**

    - `direction`: ``(K, 3)`` unit cap centres in *map* coordinates (world =
      ``direction @ rotation`` of the :class:`Environment`, so rotating the
      environment rotates its caps).
    - `radius`: ``(K,)`` angular radii (rad).
    - `channels`: ``(K, C)`` radiance over each cap on the environment's
      spectral basis (as a texel of `Environment.channels`).
    """

    direction: Float[Array, "K 3"]
    radius: Float[Array, "K"]
    channels: Float[Array, "K C"]

    @property
    def count(self) -> int:
        """K (static: the shapes decide what the shader traces)."""
        return int(self.radius.shape[0])

    def sin2_half(self) -> Float[Array, "K"]:
        """``sin²(r/2)``: a unit direction d is inside cap k iff ``|d − c_k|² < 4 sin²(r_k/2)`` (chord test)."""
        return jnp.sin(0.5 * self.radius) ** 2

    def solid_angle(self) -> Float[Array, "K"]:
        """Solid angle per cap (:func:`jkatana.light.sun.cap_solid_angle`)."""
        return cap_solid_angle(self.radius)

    def world(self, rotation: Float[Array, "3 3"]) -> Float[Array, "K 3"]:
        """Cap centres in world coordinates for a world → map ``rotation``."""
        return self.direction @ rotation

    def inside(self, d_world, rotation) -> Array:
        """``(..., K)`` boolean: world directions ``d_world (..., 3)`` inside each cap (chord test)."""
        c = self.world(rotation)
        diff = d_world[..., None, :] - c
        return jnp.sum(diff * diff, -1) < 4.0 * self.sin2_half()


def caps_from_split(split: SunSplit, basis: np.ndarray, dtype=jnp.float32) -> Caps | None:
    """The :class:`Caps` of a :class:`~jkatana.light.sun.SunSplit` projected on a ``(J, wl)`` spectral basis
    (rows orthonormal, as :func:`env_basis` returns), or None when nothing was split."""
    return caps_on_basis(split.caps, basis, dtype)


def caps_on_basis(caps: tuple, basis: np.ndarray, dtype=jnp.float32) -> Caps | None:
    """:func:`caps_from_split` of the split's :class:`~jkatana.light.sun.SunCap` lights alone."""
    if not caps:
        return None
    b = np.asarray(basis, np.float64)
    direction = np.stack([np.asarray(c.direction, np.float64) for c in caps])
    radius = np.asarray([float(c.radius) for c in caps])
    radiance = np.stack([np.asarray(c.radiance, np.float64) for c in caps])
    return Caps(jnp.asarray(direction, dtype), jnp.asarray(radius, dtype), jnp.asarray(radiance @ b.T, dtype))


class Environment(eqx.Module):
    """Environment lighting as the shader sees it.

    **Fields:**

    - `channels`: ``(H, W, J)``: spectral radiance (J = wavelengths, `basis`
      unused) or coefficients on a spectral basis.
    - `basis`: ``(J, wl)`` spectra such that radiance = channels @ basis.
    - `rotation`: ``(3, 3)`` world → map rotation applied to every lookup.
    - `sampler`: :class:`jkatana.light.sampling.EnvSampler` of the map (luminance ×
      solid angle, bilinear-safe), in map coordinates; None where the environment was built for a mode that
      does not sample it (:attr:`Integrator.sampled <jkatana.render.integrators.Integrator.sampled>`).
    - `prefiltered`: ``M`` lobe-convolved maps ``(H_m, W_m, J)`` for ``prefilter_mus``
      (:func:`jkatana.light.prefilter.prefilter`, projected on ``basis``), or ``()``.
    - `prefilter_mus`: ``(M,)`` μ of each prefiltered level (increasing).
    - `caps`: compact sources split off the map (:class:`Caps`), or None: nothing
      split, and the shader traces no cap code. With caps, every other field
      describes the *remainder* of the map.
    - `lobe_prefiltered`: per region (hiraji, hamon) ``()`` — the region renders the
      paper's lobe and reads `prefiltered` — or the ``M`` levels of the region's own
      lobe at ``prefilter_mus`` (:func:`build_environment`'s ``prefilter_lobes``),
      each scaled by the lobe's albedo at normal incidence; ``()`` when no region
      holds another lobe.
    """

    channels: Float[Array, "H W J"]
    basis: Float[Array, "J wl"]
    rotation: Float[Array, "3 3"]
    sampler: EnvSampler | None
    prefiltered: tuple
    prefilter_mus: Float[Array, "M"]
    caps: Caps | None = None
    lobe_prefiltered: tuple = ()


def bilinear_equirect(image: Float[Array, "H W C"], d: Float[Array, "*b 3"]) -> Float[Array, "*b C"]:
    """Bilinear lookup of an equirectangular ``(H, W, C)`` image in direction ``d``.

    Same convention and filtering as :meth:`jkatana.light.envmap.EnvMap.lookup`
    (wrap in u, clamp in v), for any number of channels (spectral bands or
    basis coefficients).
    """
    u, v = direction_to_uv(d)
    return bilinear_equirect_uv(image, u, v)  # jkatana.light.envmap.bilinear_uv


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
                      env_density="max", split_sun: bool | SunSplit = False, prefilter_lobes=(None, None),
                      sampling: bool = True):
    """An :class:`Environment` (sampling tables, optional basis and prefiltering) from ``(H, W, wl)`` radiance.

    Environment sampling is :class:`jkatana.light.sampling.EnvSampler` (the light
    stage's): a piecewise-constant density ∝ luminance × solid angle per texel,
    the texel's luminance being the integral of the *bilinear* radiance the
    lookups return (so ``radiance / pdf`` stays bounded next to a one-texel
    sun), uniform in solid angle inside a texel — Pharr, Jakob & Humphreys,
    *PBRT* 4th ed., §A.5 and §12.5. ``env_density`` is the texel weight
    (:meth:`~jkatana.light.sampling.EnvSampler.build`'s ``bilinear``): ``"max"``
    (3×3 neighbourhood maximum) or ``True`` (exact bilinear integral).

    ``split_sun``: ``True`` splits the map's compact bright sources off as
    spherical caps (:func:`jkatana.light.sun.split_compact_sources`, its default
    criterion), a :class:`~jkatana.light.sun.SunSplit` of this radiance uses that
    split (e.g. the built-in sky's exact solar disc,
    :func:`~jkatana.light.sun.split_sky_sun`); the sampler, the prefiltered levels
    and the channels are then the remainder's and the caps go to
    :attr:`Environment.caps`. The spectral basis is the whole map's (the sun's
    spectrum included), so a low-rank basis represents the caps as well as the
    sky. Where no compact source exists nothing changes: the environment is the
    one ``split_sun=False`` builds, array for array.

    ``prefilter_lobes``: per region (hiraji, hamon) ``None`` (the paper's lobe: the
    levels of `Environment.prefiltered`) or a :class:`~jkatana.models.lobe_id.LobeId`
    at unit width, the lobe the shader renders that region with (the normalised form in the
    normalised convention); such a region gets levels of its own
    (`Environment.lobe_prefiltered`): the map convolved with that lobe's kernel at
    each μ of ``prefilter_mus`` as its primary width (:func:`jkatana.light.prefilter.prefilter`,
    any lobe), times the lobe's albedo at normal incidence
    (:func:`~jkatana.light.prefilter.kernel_table`'s ``4π ∫ k dx``), so that the
    split sum carries the lobe's energy (Karis 2013) as the normalised paper's lobe
    carries 1.

    ``sampling``: build the sampling tables (False: `Environment.sampler` is None, for a mode that never samples
    the map; they are a few floats per texel and a pass over the map).

    **Returns:** ``(environment, factored, rel_residual)``.
    """
    from jkatana.spectral import DEFAULT_GRID

    radiance = np.asarray(radiance, np.float64)
    H, W, nwl = radiance.shape
    coeffs, basis, factored, resid = env_basis(radiance, rank)
    if grid is None:  # the density only steers sampling: an unknown grid borrows the default range
        grid = DEFAULT_GRID if nwl == DEFAULT_GRID.size else type(DEFAULT_GRID).with_count(DEFAULT_GRID.start, DEFAULT_GRID.stop, nwl)
    caps = None
    if split_sun is not False:
        split = split_sun if isinstance(split_sun, SunSplit) else \
            split_compact_sources(EnvMap(jnp.asarray(radiance, dtype), grid))
        caps = caps_from_split(split, basis, dtype)
        if caps is not None:
            radiance = np.asarray(split.remainder.radiance, np.float64)
            if factored:
                coeffs = (radiance.reshape(-1, nwl) @ basis.T.astype(np.float64)).reshape(H, W, -1).astype(np.float32)
            else:
                coeffs = radiance.astype(np.float32)
    sampler = EnvSampler.build(EnvMap(jnp.asarray(radiance, dtype), grid), bilinear=env_density) if sampling else None
    rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    mus = tuple(sorted(float(m) for m in prefilter_mus))
    pre, lobe_pre = (), ()
    if mus:
        # the light stage's exact convolution with the lobe kernel, on the source box-downsampled to
        # at most `prefilter_resolution` columns, then projected on the environment's spectral basis
        src = EnvMap(jnp.asarray(radiance, jnp.float32), grid)
        while src.width > prefilter_resolution and src.height % 2 == 0 and src.width % 2 == 0:
            src = src.downsample(2)
        pre, lobe_pre = prefiltered_levels(src, mus, basis, prefilter_lobes, dtype)
    env = Environment(jnp.asarray(coeffs, dtype), jnp.asarray(basis, dtype), jnp.asarray(rot, dtype), sampler,
                      pre, jnp.asarray(np.asarray(mus, np.float64), dtype), caps, lobe_pre)
    return env, factored, resid


def prefiltered_levels(src: EnvMap, mus: tuple, basis: np.ndarray, prefilter_lobes, dtype) -> tuple[tuple, tuple]:
    """`Environment.prefiltered` and `Environment.lobe_prefiltered` of a map ``src`` already at the levels'
    source resolution: :func:`jkatana.light.prefilter.prefilter` with the paper's lobe and with each region's
    lobe (times its albedo, :func:`lobe_albedo`), projected on the environment's ``basis``."""
    from jkatana.light.prefilter import prefilter as light_prefilter

    def project(levels, scales=None):
        scales = scales or [1.0] * len(levels)
        return tuple(jnp.asarray(k * (np.asarray(lvl.radiance, np.float64) @ basis.T.astype(np.float64)), dtype)
                     for lvl, k in zip(levels, scales))

    pre = project(light_prefilter(src, mus).levels)
    lobe_pre = ()
    if any(key is not None for key in prefilter_lobes):
        lobe_pre = tuple(() if key is None else project(light_prefilter(src, mus, lobe=key).levels,
                                                        [lobe_albedo(key, m) for m in mus])
                         for key in prefilter_lobes)
    return pre, lobe_pre


def lobe_albedo(key, mu: float) -> float:
    """``∫ f_r cos θi dω`` at normal incidence of the lobe of ``key`` at primary width ``mu``: ``4π ∫ k dx`` over
    :func:`jkatana.light.prefilter.kernel_table` (the prefilter's own tabulated kernel, x = sin²(ψ/2), trapezoid
    on its nodes, which resolve the peak)."""
    from jkatana.light.prefilter import kernel_table, lobe_of_width

    x, k = kernel_table(lobe_of_width(key, mu))
    return float(4.0 * np.pi * np.trapezoid(k, x))


def env_lookup(env: Environment, d_world):
    """Environment channels in world direction ``d_world`` (rotation applied)."""
    return bilinear_equirect(env.channels, to_map(env, d_world))


def _rotate(d, M):
    """``d @ M`` for ``(*b, 3)`` directions and a 3×3 matrix, as a sum of broadcast products (XLA's CPU
    backend runs the ``(n, 3) × (3, 3)`` dot product much slower than this elementwise form)."""
    return d[..., 0:1] * M[0] + d[..., 1:2] * M[1] + d[..., 2:3] * M[2]


def to_map(env: Environment, d_world):
    """World directions in the map's frame: ``d_world @ env.rotation.T``."""
    return _rotate(d_world, env.rotation.T)


def from_map(env: Environment, d_map):
    """Map-frame directions in the world: ``d_map @ env.rotation``."""
    return _rotate(d_map, env.rotation)


def env_uv(env: Environment, d_world):
    """Map coordinates ``(u, v)`` of world direction ``d_world`` (one ``direction_to_uv`` for lookup and pdf)."""
    return direction_to_uv(to_map(env, d_world))


def lookup_prefiltered(env: Environment, mu, R_world):
    """Prefiltered channels toward ``R_world`` for per-pixel ``mu``: bilinear in each level, linear
    in log μ between levels, clamped to the tabulated range (:func:`jkatana.light.prefilter.blend_levels`,
    in the environment's channel space)."""
    return lookup_prefiltered_many(env, (mu,), R_world)[0]


def lookup_prefiltered_many(env: Environment, mus, R_world, level_sets=None) -> list:
    """:func:`lookup_prefiltered` toward one direction per pixel for several per-pixel widths ``mus``
    (the hiraji and hamon lobes share the mirror direction), width ``i`` in the levels ``level_sets[i]``
    (default `Environment.prefiltered` for every width). The map coordinates are computed once and,
    where every level shares a resolution, one bilinear lookup of the distinct levels side by side
    serves every level and width (the same arithmetic per channel as a lookup per level)."""
    sets = [env.prefiltered] * len(mus) if level_sets is None else list(level_sets)
    distinct = []
    for lv in sets:
        if not any(lv is d for d in distinct):
            distinct.append(lv)
    where = [next(i for i, d in enumerate(distinct) if lv is d) for lv in sets]
    d = to_map(env, R_world)
    M = len(env.prefiltered)
    flat = [lvl for lv in distinct for lvl in lv]
    if all(lvl.shape == flat[0].shape for lvl in flat):
        u, v = direction_to_uv(d)
        C = flat[0].shape[-1]
        stacked = jnp.concatenate(flat, axis=-1)  # (H, W, S·M·C)
        allv = jnp.moveaxis(bilinear_equirect_uv(stacked, u, v).reshape(-1, len(flat), C), 1, 0)  # (S·M, P, C)
    else:
        allv = jnp.stack([bilinear_equirect(lvl, d) for lvl in flat])
    log_mus = jnp.log(env.prefilter_mus)
    return [blend_levels(allv[j * M:(j + 1) * M], log_mus, mu) for mu, j in zip(mus, where)]  # (M, P, C) each


def unbasis(env: Environment):
    """Pseudo-inverse map from spectra to the accumulator's channels (identity in full mode)."""
    return env.basis.T


def xyz_environment(env: Environment, cmf) -> Environment:
    """``env`` with its channels and caps folded to CIE XYZ (``basis`` the 3 × 3 identity), for the background.

    A bilinear lookup commutes with a per-texel linear map, so looking up the
    folded map gives the XYZ of the spectral lookup up to float rounding, with 3
    channels instead of J per camera ray. The sampler and prefiltered levels are
    left as they are (the background does not read them).
    """
    M = env.basis @ cmf.astype(env.basis.dtype)  # (J, 3)
    caps = None if env.caps is None else Caps(env.caps.direction, env.caps.radius, env.caps.channels @ M)
    return Environment(env.channels @ M, jnp.eye(3, dtype=env.basis.dtype), env.rotation, env.sampler,
                       env.prefiltered, env.prefilter_mus, caps, env.lobe_prefiltered)


def background(env: Environment, directions, cmf, spectral: bool = False):
    """XYZ (and spectra) of the environment seen directly along camera rays (the caps included)."""
    C = env_lookup(env, directions)
    if env.caps is not None:  # a camera ray inside a cap sees its radiance (point-sampled disc)
        inside = env.caps.inside(directions, env.rotation).astype(C.dtype)
        C = C + inside @ env.caps.channels.astype(C.dtype)
    if not spectral:  # (J, 3) first: a (P, J) @ (J, wl) product per pixel would dominate large frames
        return C @ (env.basis @ cmf), None
    E = C @ env.basis
    return E @ cmf, E
