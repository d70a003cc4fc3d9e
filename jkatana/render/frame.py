"""One frame: G-buffer → per-pixel materials → shading across the local devices → XYZ image.

:func:`render_frame` casts the camera's G-buffer (:mod:`jkatana.render.gbuffer`), hides what
occluders cover (:mod:`jkatana.render.occlusion`), looks the reflectance maps up at the hit
pixels' UVs, shades them in sharded calls (:func:`jkatana.render.dispatch.shade_pixels`) and
lays them over the environment seen directly (:mod:`jkatana.render.background`). What frames of
one view share (an immutable G-buffer's pixels) is derived once (:mod:`jkatana.render.derived`).
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.render.background import background_all, background_camera, background_spectral
from jkatana.render.camera import Camera
from jkatana.render.derived import derived, digest, immutable
from jkatana.render.dispatch import DEFAULT_CHUNK, resolve_plan, shade_pixels
from jkatana.render.environment import Environment
from jkatana.render.fresnel_fold import Material
from jkatana.render.gbuffer import GBuffer, gbuffer_mesh, gbuffer_sphere
from jkatana.render.occlusion import primary_blocked
from jkatana.render.plan import Light, Pixels, Plan
from jkatana.render.points import PixelIds


def sample_map(maps: jax.Array, uv: jax.Array) -> jax.Array:
    """Bilinear lookup of a ``(H, W, C)`` reflectance map at UVs ``(P, 2)`` (clamped at the borders).

    Convention (as :mod:`jkatana.maps`): column ↔ u (along the blade), row ↔ v
    (across; row 0 at v = 0, the mune). Differentiable in ``maps``.
    """
    H, W = maps.shape[0], maps.shape[1]
    x = jnp.clip(uv[:, 0] * W - 0.5, 0.0, W - 1.0)
    y = jnp.clip(uv[:, 1] * H - 0.5, 0.0, H - 1.0)
    x0 = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, max(W - 2, 0))
    y0 = jnp.clip(jnp.floor(y).astype(jnp.int32), 0, max(H - 2, 0))
    x1 = jnp.minimum(x0 + 1, W - 1)
    y1 = jnp.minimum(y0 + 1, H - 1)
    fx = (x - x0.astype(x.dtype)).astype(maps.dtype)[:, None]
    fy = (y - y0.astype(y.dtype)).astype(maps.dtype)[:, None]
    top = maps[y0, x0] * (1 - fx) + maps[y0, x1] * fx
    bot = maps[y1, x0] * (1 - fx) + maps[y1, x1] * fx
    return top * (1 - fy) + bot * fy


_sample_map = jax.jit(sample_map)


@dataclasses.dataclass
class Frame:
    """A rendered frame: ``xyz (H, W, 3)`` linear, ``mask``, optional spectra, timings (s) and stats."""

    xyz: np.ndarray
    mask: np.ndarray
    spectra: np.ndarray | None
    timing: dict
    stats: dict


def gbuffer(geometry, camera: Camera) -> GBuffer:
    """G-buffer of a trimesh mesh or of ``("sphere", center, radius)``."""
    if isinstance(geometry, tuple) and geometry[0] == "sphere":
        return gbuffer_sphere(camera, geometry[1], geometry[2])
    return gbuffer_mesh(geometry, camera)


def pixel_blocks(a: np.ndarray, s: int) -> np.ndarray:
    """``(H·s, W·s, …)`` subpixels viewed as ``(H, s, W, s, …)``: reduce axes (1, 3) to get pixels
    (``.mean`` for radiance, ``.all`` for the mask) of a frame rendered with ``supersample=s``."""
    return a.reshape(a.shape[0] // s, s, a.shape[1] // s, s, *a.shape[2:])


def _frame_pixels(gb: GBuffer, keep: np.ndarray, maps, dtype, ss: int) -> tuple[Pixels, PixelIds | None]:
    """The shaded pixels of ``gb`` (its hits where ``keep``) as :class:`Pixels` on the device, the reflectance
    ``maps`` looked up at their UVs, and with ``ss > 1`` their :class:`PixelIds` (output pixel, subpixel).

    An immutable G-buffer (:func:`~jkatana.render.gbuffer.gbuffer_sphere`'s) with every hit kept gives the
    same pixels each frame for the same maps: they are kept (:func:`~jkatana.render.derived.derived`, the maps
    by value unless a JAX array), so that a batch of frames of one view sends them to the devices once."""
    def build():
        uv = jnp.asarray(gb.hit_uv[keep], dtype)
        mp = _sample_map(jnp.asarray(maps, dtype), uv)
        px = Pixels(jnp.asarray(gb.hit_position[keep], dtype), jnp.asarray(gb.hit_normal[keep], dtype),
                    jnp.asarray(gb.hit_view[keep], dtype), mp[:, 0], mp[:, 1], mp[:, 2])
        if ss == 1:
            return px, None
        W = gb.mask.shape[1]
        row, col = np.divmod(gb.index[keep], W)
        ids = PixelIds(((row // ss) * (W // ss) + col // ss).astype(np.uint32),
                       ((row % ss) * ss + col % ss).astype(np.int32))
        for a in ids:
            a.flags.writeable = False
        return px, ids

    sources = (gb.index, gb.hit_position, gb.hit_normal, gb.hit_view, gb.hit_uv)
    if not (keep.all() and all(immutable(a) or a.base is not None and immutable(a.base) for a in sources)):
        return build()
    if isinstance(maps, jax.Array):
        sources, maps_key = sources + (maps,), None
    else:
        maps_key = digest(maps)
    return derived("frame-pixels", sources, (maps_key, np.dtype(dtype).str, ss), build, keep=4)


def _frame_plan(plan: Plan, mat: Material, supersample) -> tuple[Plan, int]:
    """``(plan, s)``: the plan as the frame shades it (:func:`~jkatana.render.dispatch.resolve_plan`, ``s²``
    subpixels per pixel) and the supersampling factor ``s``."""
    plan = resolve_plan(plan, mat)
    ss = int(supersample)
    if ss < 1:
        raise ValueError(f"supersample must be ≥ 1, got {supersample}")
    return dataclasses.replace(plan, subpixels=ss * ss), ss


def _background_first(env: Environment, camera: Camera, gb: GBuffer | None, cmf, dtype, n_devices):
    """Every pixel's background in XYZ, dispatched (asynchronous): along the given G-buffer's rays, or the
    camera's made on the devices."""
    if gb is not None:
        return background_all(env, gb.ray.reshape(-1, 3), cmf, dtype, n_devices)
    return background_camera(env, camera, cmf, dtype, n_devices)


def _visible(plan: Plan, gb: GBuffer, camera: Camera, occluders, ss: int):
    """``(mask (H·W,), keep (hits,), blocked (H·W,))``: the pixels that see the object unoccluded, the G-buffer's
    hits that are shaded, and the pixels an occluder hides (primary visibility, with ``plan.visibility``)."""
    H, W = gb.mask.shape
    if H % ss or W % ss:
        raise ValueError(f"supersample {ss}: the camera's {W}×{H} image is not a whole number of pixels")
    if not (plan.visibility and occluders is not None):
        return gb.mask.reshape(-1), np.ones(len(gb.index), bool), np.zeros(H * W, bool)
    blocked = primary_blocked(gb, camera, occluders)
    return gb.mask.reshape(-1) & ~blocked, ~blocked[gb.index], blocked


def _shade_hits(plan: Plan, mat: Material, env: Environment, lights: Light | None, gb: GBuffer, keep, maps, cmf,
                key, dtype, ss: int, how: dict):
    """``(XYZ of the kept hits or None, the frame's spectra (H·W, wl) or None)``: the kept hits shaded
    (:func:`~jkatana.render.dispatch.shade_pixels` with the keywords ``how``), their spectra in place."""
    H, W = gb.mask.shape
    sel = gb.index[keep]
    spectra = np.zeros((H * W, env.basis.shape[-1]), np.float32) if plan.spectral and not plan.factored else None
    if not len(sel):
        return None, spectra
    px, ids = _frame_pixels(gb, keep, maps, dtype, ss)
    x, s = shade_pixels(plan, mat, env, lights, px, cmf, key, ids=ids, **how)
    if spectra is not None and s is not None:
        spectra[sel] = s
    return x, spectra


def _compose(env: Environment, gb: GBuffer, cmf, dtype, bg_all, bg, blocked, spectra) -> np.ndarray:
    """The frame's ``(H·W, 3)`` XYZ before the shaded pixels go in: the background where ``bg``, black where
    ``blocked``. From the dispatched XYZ background ``bg_all`` (every pixel's: one copy, not a gather and a
    scatter of the sky), else looked up with its spectra (written into ``spectra``)."""
    H, W = gb.mask.shape
    if bg_all is not None:
        xyz = np.array(np.asarray(bg_all)[:H * W], np.float32)
        xyz[blocked] = 0.0
        return xyz
    xyz = np.zeros((H * W, 3), np.float32)
    if bg.any():
        bx, bs = background_spectral()(env, jnp.asarray(gb.ray.reshape(-1, 3)[bg], dtype), jnp.asarray(cmf, dtype))
        spectra[bg] = np.asarray(bs)
        xyz[bg] = np.asarray(bx)
    return xyz


def render_frame(plan: Plan, mat: Material, env: Environment, lights: Light | None, geometry,
                 camera: Camera, maps, cmf, *, seed: int = 0, dtype=jnp.float32,
                 n_devices: int | None = None, chunk: int = DEFAULT_CHUNK, gb: GBuffer | None = None,
                 occluders=None, supersample: int = 1) -> Frame:
    """Render one frame.

    **Arguments:**

    - `plan`, `mat`, `env`, `lights`: see :mod:`jkatana.render.shading`.
    - `geometry`: a ``trimesh.Trimesh`` with UVs, or ``("sphere", center, radius)``.
    - `camera`: :class:`~jkatana.render.camera.Camera`.
    - `maps`: ``(H, W, 3)`` array of (w, μ0, μ1) sampled at the pixels' UV.
    - `cmf`: ``(wl, 3)`` film weights (:func:`jkatana.render.film.film_weights`).
    - `occluders`: :class:`~jkatana.render.gbuffer.Occluders` when ``plan.visibility``:
      they hide what lies behind them from the camera (black pixels) and shadow
      the traced directions.
    - `supersample`: ``s > 1``: the camera's image is ``s × s`` subpixels per output
      pixel (its size divisible by ``s``); the caller box-averages the returned
      frame. Each pixel's ``s²`` subpixels share one sample sequence of
      ``s² × plan.samples`` points (``Plan.subpixels``, :class:`~jkatana.render.shading.PixelIds`),
      so the pixel's samples are stratified as a whole, not per subpixel.

    **Returns:** a :class:`Frame` at the camera's (subpixel) resolution.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    plan, ss = _frame_plan(plan, mat, supersample)
    spectral_out = plan.spectral and not plan.factored
    # every pixel's background, dispatched first: the devices look it up while the host casts the G-buffer
    bg_all = None if spectral_out else _background_first(env, camera, gb, cmf, dtype, n_devices)
    gb = gbuffer(geometry, camera) if gb is None else gb
    rays0, cast0 = (occluders.rays_cast, occluders.cast_s) if occluders is not None else (0, 0.0)
    mask, keep, blocked = _visible(plan, gb, camera, occluders, ss)
    t1, c1 = time.perf_counter(), time.process_time()
    sel = gb.index[keep]
    x, spectra = _shade_hits(plan, mat, env, lights, gb, keep, maps, cmf, jax.random.PRNGKey(seed), dtype, ss,
                             dict(n_devices=n_devices, chunk=chunk, occluders=occluders))
    t2, c2 = time.perf_counter(), time.process_time()
    xyz = _compose(env, gb, cmf, dtype, bg_all, ~mask & ~blocked, blocked, spectra)
    if x is not None:
        xyz[sel] = x
    t3, c3 = time.perf_counter(), time.process_time()
    # wall seconds per stage, and the process's CPU seconds over each (all threads: host and devices)
    timing = {"gbuffer_s": t1 - t0, "shade_s": t2 - t1, "background_s": t3 - t2, "total_s": t3 - t0,
              "gbuffer_cpu_s": c1 - c0, "shade_cpu_s": c2 - c1, "background_cpu_s": c3 - c2, "total_cpu_s": c3 - c0}
    if occluders is not None:
        timing["visibility_rays"] = occluders.rays_cast - rays0
        timing["visibility_cast_s"] = occluders.cast_s - cast0
    H, W = gb.mask.shape
    stats = {"pixels_shaded": int(len(sel)), "coverage": float(len(sel) / (H * W)),
             "occluded_pixels": int(blocked.sum()), "fresnel_rank": int(plan.fresnel_rank)}
    return Frame(xyz.reshape(H, W, 3), mask.reshape(H, W), None if spectra is None else spectra.reshape(H, W, -1),
                 timing, stats)
