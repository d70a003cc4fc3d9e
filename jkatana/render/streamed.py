"""The renderer's :class:`~jkatana.render.environment.Environment` of a map too large to hold as full spectra.

:func:`~jkatana.render.environment.build_environment` takes the whole map's
spectra, ``(H, W, wl)``, and holds several float64 copies of them; a
6000 × 3000 map on 61 wavelengths would need some 50 GB.
:func:`build_streamed_environment` reads the map in row blocks
(:class:`jkatana.light.streaming.RowSource`) and keeps, per texel, only what
each mode reads:

- **lookups**: coefficients on a low-rank spectral basis (the environment is
  *factored*, radiance = ``channels @ basis``, as the renderer's low-rank mode).
  The basis is the leading right singular vectors (Eckart & Young 1936) of the
  exact spectra of a regular subsample of texels and of the map's brightest
  texels; its rank is the smallest that brings the subsample's texels'
  relative residuals (RMS) to :data:`STREAM_TOLERANCE`. The error of the kept coefficients is
  measured against exact spectra on a second, offset subsample, and returned
  (the renderer reports it as the environment's ``rank_residual``);
- **sampling**: one luminance per texel
  (:meth:`jkatana.light.sampling.EnvSampler.from_luminance`);
- **prefiltered levels**: the coefficients box-filtered to at most
  ``prefilter_resolution`` columns as they stream, then convolved as the full
  path convolves (:func:`~jkatana.render.environment.prefiltered_levels`);
- **a sun**: detected on the luminance and split off from the exact spectra of
  its texels and their ring (:func:`jkatana.light.sun.split_texels`).

The renderer takes this path only where the full one would not fit the memory
budget (:func:`jkatana.render.memory.environment_route`): a map that fits is
prepared, and rendered, exactly as before.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from jkatana.light.envmap import EnvMap, box_downsample
from jkatana.light.sampling import EnvSampler
from jkatana.light.sun import split_texels
from jkatana.render.environment import Environment, caps_on_basis, prefiltered_levels

#: Residual the streamed basis's rank is chosen to reach: each subsampled texel's relative residual, RMS.
STREAM_TOLERANCE = 5e-4
#: Largest rank of the streamed basis (4 bytes a texel per channel).
STREAM_MAX_RANK = 12
#: Texels per side of the regular subsample the basis is fitted on (and of the offset one that measures it).
STREAM_SUBSAMPLE = 128
#: The map's brightest texels added to the basis's subsample, so that a sun's spectrum is represented.
STREAM_BRIGHT = 256


def subsample(height: int, width: int, n: int = STREAM_SUBSAMPLE, offset: float = 0.25):
    """Flat ``(rows, cols)`` of an ``n × n`` regular grid of texels, at ``offset`` of a grid step."""
    rows = np.minimum(((np.arange(n) + offset) * height / n).astype(np.int64), height - 1)
    cols = np.minimum(((np.arange(n) + offset) * width / n).astype(np.int64), width - 1)
    R, C = np.meshgrid(np.unique(rows), np.unique(cols), indexing="ij")
    return R.ravel(), C.ravel()


def stream_basis(source, rank: int | None = None, tol: float = STREAM_TOLERANCE,
                 max_rank: int = STREAM_MAX_RANK) -> np.ndarray:
    """``(J, wl)`` orthonormal spectral basis of ``source`` (module docstring): ``rank`` rows, or where None
    the fewest (at most ``max_rank``) that leave the subsample's texels a relative residual of RMS ≤ ``tol``."""
    r, c = subsample(source.height, source.width)
    br, bc = source.bright(STREAM_BRIGHT)
    S = source.texels(np.concatenate([r, br]), np.concatenate([c, bc]))
    _, s, vt = np.linalg.svd(S, full_matrices=False)
    if rank is None:  # each texel's relative residual, RMS over the subsample (a sun would dominate a norm)
        norms = np.linalg.norm(S, axis=1)
        shapes = S[norms > 0] / norms[norms > 0, None]
        top = min(max_rank, s.size)
        rank = next((k for k in range(1, top + 1)
                     if np.sqrt(np.mean(np.sum((shapes - shapes @ vt[:k].T @ vt[:k]) ** 2, axis=1))) <= tol), top)
    basis = vt[:int(rank)]
    return -basis if basis[0].sum() < 0 else basis


def _project_pass(source, basis: np.ndarray):
    """Per texel: the coefficients ``(H, W, J)`` float32, the CIE Y and the sampler's luminance ``(H, W)``."""
    from jkatana.spectral.colorimetry import xyz_weights

    J = basis.shape[0]
    sampler_w = EnvSampler.weights(source.grid)
    P = np.concatenate([basis.T, xyz_weights(source.grid)[:, 1:2], sampler_w[:, None]], axis=1)
    coeffs, y, ys = source.project_all(P, (J, 0, 0))
    return coeffs, y, ys


def prefilter_factor(height: int, width: int, columns: int) -> int:
    """The box filter's factor: the smallest common divisor of the sides that leaves ≤ ``columns`` columns
    (else the largest common divisor)."""
    g = math.gcd(height, width)
    divisors = [f for f in range(1, g + 1) if g % f == 0]
    fits = [f for f in divisors if width // f <= columns]
    return min(fits) if fits else max(divisors)


def measured_residual(source, coeffs: np.ndarray, basis: np.ndarray, skip: np.ndarray | None = None) -> float:
    """``‖coeffs @ basis − L‖ / ‖L‖`` over the offset subsample's texels (exact spectra ``L``), leaving out
    those where ``skip`` (flat texel indices, e.g. a sun's, whose coefficients hold the remainder)."""
    r, c = subsample(source.height, source.width, offset=0.75)
    if skip is not None and len(skip):
        keep = ~np.isin(r * source.width + c, skip)
        r, c = r[keep], c[keep]
    exact = source.texels(r, c)
    approx = coeffs[r, c].astype(np.float64) @ basis
    return float(np.linalg.norm(approx - exact) / max(float(np.linalg.norm(exact)), 1e-300))


def build_streamed_environment(source, *, rank: int | None = None, rotation=None, prefilter_mus=(),
                               prefilter_resolution: int = 128, dtype=jnp.float32, env_density="max",
                               split_sun: bool = False, prefilter_lobes=(None, None), sampling: bool = True):
    """An :class:`~jkatana.render.environment.Environment` of a :class:`~jkatana.light.streaming.RowSource`,
    factored on a low-rank basis (module docstring); arguments as
    :func:`~jkatana.render.environment.build_environment`'s (``rank``: the basis's, None: chosen).

    **Returns:** ``(environment, True, rel_residual)``: the residual measured on exact spectra.
    """
    basis = stream_basis(source, rank)
    coeffs, y, ys = _project_pass(source, basis)
    caps, changed = None, np.zeros(0, np.int64)
    if split_sun:
        found, changes = split_texels(y.astype(np.float64), source.texels, source.grid, dtype=dtype)
        del y
        if found:
            caps = caps_on_basis(found, basis, dtype)
            flat_c, flat_y = coeffs.reshape(-1, basis.shape[0]), ys.reshape(-1)
            for texels, _, after in changes:
                flat_c[texels] = after @ basis.T
                flat_y[texels] = after @ EnvSampler.weights(source.grid)
            changed = np.concatenate([t for t, _, _ in changes])
    resid = measured_residual(source, coeffs, basis, changed)
    sampler = EnvSampler.from_luminance(ys, dtype, bilinear=env_density) if sampling else None
    del ys
    mus = tuple(sorted(float(m) for m in prefilter_mus))
    pre, lobe_pre = (), ()
    if mus:
        f = prefilter_factor(source.height, source.width, prefilter_resolution)
        small = box_downsample(coeffs, f, source.block_rows(f)) @ basis
        src = EnvMap(jnp.asarray(np.maximum(small, 0.0), jnp.float32), source.grid)
        pre, lobe_pre = prefiltered_levels(src, mus, basis, prefilter_lobes, dtype)
    rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    env = Environment(jnp.asarray(coeffs, dtype), jnp.asarray(basis, dtype), jnp.asarray(rot, dtype), sampler,
                      pre, jnp.asarray(np.asarray(mus, np.float64), dtype), caps, lobe_pre)
    return env, True, resid


def streams(scene, max_memory=None) -> bool:
    """Whether ``scene``'s environment is prepared by :func:`build_streamed_environment`: a map read from a
    file whose whole spectra would not fit the memory budget (:func:`jkatana.render.memory.environment_route`)."""
    from jkatana.render.memory import environment_route

    return environment_route(scene.environment, scene.spectral.grid.size, max_memory=max_memory) == "streamed"


def streamed_key(env_key: str | None) -> str | None:
    """The environment cache's key (:func:`jkatana.light.cache.environment_key`) for the streamed form of the
    same map: another entry, keyed by this path's source as well."""
    import hashlib
    import importlib
    import inspect

    if env_key is None:
        return None
    h = hashlib.sha256(env_key.encode())
    for m in ("jkatana.render.streamed", "jkatana.light.streaming", "jkatana.light.spectral_exr"):
        h.update(inspect.getsource(importlib.import_module(m)).encode())
    return "streamed-" + h.hexdigest()[:24]


def build_scene_streamed(scene, grid, **kw):
    """:func:`build_streamed_environment` of a scene's map file (its upsampling, scale and colourspace)."""
    from jkatana.light.streaming import row_source

    e = scene.environment
    return build_streamed_environment(row_source(e.path, grid, e.upsampling, e.scale, e.colourspace), **kw)


__all__ = ["build_streamed_environment", "build_scene_streamed", "streams", "streamed_key", "stream_basis",
           "subsample", "prefilter_factor", "measured_residual", "STREAM_TOLERANCE", "STREAM_MAX_RANK"]
