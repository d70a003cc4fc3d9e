"""Tables baked from the JAX models for the GLSL shaders (no model is re-derived in GLSL).

The interactive path evaluates, per pixel, the environment-lit radiance of the
paper's blend of hiraji (eq. 1) and hamon (eq. 2) lobes,

    L_o(λ) = ∫ f_r(L, V; λ) cos θi L_env(L, λ) dω_i,

integrated to CIE XYZ (eq. 6), as the split sum of Karis (2013), "Real Shading
in Unreal Engine 4", with the spectral dimension factored by a low-rank basis
of the Fresnel term:

    XYZ_c = Σ_r A_r(cos θv, μ) · P_{r,c}(R; μ)            (R = reflect(−V, N))

exact when the environment is constant over the lobe; the residual (lobe
stretching at grazing view, environment gradients inside the lobe) is what
the comparison with :mod:`jkatana.render` measures. :func:`bake` assembles,
one module per table:

1. the spectral basis b_r(λ) of iron's F(θ, λ) (SVD, rank 1–4;
   :func:`jkatana.interactive.tables.material_basis`);
2. the environment projected on it, P_{r,c}(ω) = Σ_λ b_r(λ) W_c(λ) L(ω, λ)
   with W_c the CIE 1931 weighting of eq. (6), prefiltered per μ level
   (:mod:`jkatana.interactive.levels`);
3. the lobe table A_r and the lobe's shape moments
   (:mod:`jkatana.interactive.lobe_tables`), and the tap pattern the shader
   reads the levels with (:mod:`jkatana.interactive.taps`); these do not depend
   on the environment and are cached and shipped
   (:mod:`jkatana.interactive.tables`); for a region holding a long-tailed lobe
   (not the paper's) up to two wider tail taps beside the three taps
   (:func:`jkatana.interactive.taps.tail_fit`);
4. compact bright sources (suns) split off the map as caps, each a shader
   uniform integrated against the lobe in closed form
   (:mod:`jkatana.interactive.caps`) — or, where a region holds a lobe other
   than the paper's, through the cap kernel table of
   :mod:`jkatana.interactive.captable`.

Plus the display transform: the XYZ → linear RGB matrix of
:func:`jkatana.spectral.xyz_to_rgb_matrix` (eq. 7) and a 1-D table of
:func:`jkatana.spectral.encode` (eq. 8) indexed by √x so that it is dense
near black (:func:`transfer_table`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.interactive.caps import MAX_CAPS as MAX_CAPS, sun_caps
from jkatana.interactive.captable import cap_kernel_table, needs_table
from jkatana.interactive.levels import MU_LEVELS, prefilter_level, upsample
from jkatana.interactive.lobe_tables import PAPER_LOBES, family_names
from jkatana.interactive.tables import MAX_RANK as MAX_RANK, cache_folder, load_entry, save_entry
from jkatana.interactive.tables import lobe_tables, material_basis_of
from jkatana.interactive.taps import resolved_taps
from jkatana.light.envmap import box_downsample
from jkatana.light.fresnel_basis import project_on_basis
from jkatana.models import Conductor
from jkatana.render.film import film_weights
from jkatana.spectral import DEFAULT_GRID, WavelengthGrid
from jkatana.spectral.colorimetry import encode, xyz_to_rgb_matrix

#: The modules whose source keys :func:`cached_bake`'s entries (a change to any of them re-bakes).
BAKE_MODULES = ("jkatana.interactive.bake", "jkatana.interactive.levels", "jkatana.interactive.lobe_tables",
                "jkatana.interactive.taps", "jkatana.interactive.tables", "jkatana.interactive.caps",
                "jkatana.light.prefilter", "jkatana.light.fresnel_basis", "jkatana.light.sun",
                "jkatana.interactive.captable", "jkatana.light.capquad")


@dataclasses.dataclass
class Baked:
    """Everything the shaders read, as NumPy arrays (float32 on upload).

    - ``env`` ``(n_mu, n, H, W, 3)``: P_{r,c}(ω; μ) (XYZ per basis function) of the first n ≤ rank basis
      functions (all of them unless the bake was asked for fewer: ``stack_rank`` of :func:`cached_bake`).
    - ``lut`` ``(2, n_mu, n_cos, rank)``: A_r for hiraji (0) and hamon (1).
    - ``spread`` ``(2, n_mu, n_cos, 3)``: lobe shape moments (:func:`~jkatana.interactive.lobe_tables.lobe_lut`).
    - ``taps`` ``(2, n_mu, n_cos, 1 + 2T)``: the tap pattern the shader reads, fitted where the map
      resolves it (:func:`~jkatana.interactive.taps.resolved_taps`); ``tap_l1`` the fit's L1 error and
      ``tap_ok`` the solver's convergence (see :func:`~jkatana.interactive.taps.tap_fit`).
    - ``mus``: the μ levels; ``b`` the spectral basis ``(rank, wl)``; ``fresnel_err``.
    - ``xyz_to_rgb`` 3×3; ``transfer`` 1-D table of encode(s²) for s uniform in [0, 1].
    - ``cap_dir`` ``(n, 3)``, ``cap_radius`` ``(n,)``, ``cap_q`` ``(n, rank, 3)``: the compact sources split
      off the map (:func:`~jkatana.interactive.caps.sun_caps`; ``n = 0``: none, ``env`` is the whole map).
    - ``cap_kernel`` ``(2, n_mu, n_cos, n_v, n_u)``: the caps' kernel table of the regions' lobes
      (:func:`~jkatana.interactive.captable.cap_kernel_table`) where a region holds a lobe other than the
      paper's and the map has a cap; ``(0,)`` otherwise (the shader's closed-form cap rule).
    - ``tail`` ``(2, n_mu, n_cos, N_TAIL, 3)``: the tail taps (s_t, o_t, w_t) of regions holding a lobe other
      than the paper's (:func:`~jkatana.interactive.taps.tail_fit`, read beside their three ``taps``); w_t = 0 elsewhere,
      and all zero for the paper's lobes (the shader has no tail code then).
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
    cap_kernel: np.ndarray
    tail: np.ndarray

    @property
    def rank(self) -> int:
        return self.b.shape[0]

    @property
    def n_caps(self) -> int:
        return int(self.cap_dir.shape[0])


def transfer_table(transfer="sRGB", n: int = 2048) -> np.ndarray:
    """encode(s²) for s uniform on [0, 1] (eq. 8 as a table, dense near black)."""
    s = np.linspace(0.0, 1.0, n)
    return np.asarray(encode(s ** 2, transfer), np.float64)


def cached_bake(radiance: np.ndarray, grid: WavelengthGrid = DEFAULT_GRID, *, rank: int = 3, mus=MU_LEVELS,
                colourspace: str = "sRGB", transfer=None, source: str = "Fe-Johnson", cache_dir=None,
                progress: bool = False, split_sun: bool = True, lobes: tuple = PAPER_LOBES,
                stack_rank: int | None = None) -> Baked:
    """:func:`bake` with an on-disk cache (``$JKATANA_CACHE`` or ``~/.cache/jkatana``/interactive).

    The key hashes every input (radiance bytes, grid, rank, μ levels, display
    transform, optical-constant source) and the source of :data:`BAKE_MODULES`,
    so a change to the baking code invalidates it. The entry keeps each prefiltered level
    at its own resolution (:func:`~jkatana.light.prefilter.level_shape`) in float16 scaled by the
    level's largest magnitude (relative precision 2⁻¹¹), resampled to the
    source's size on load: tens of MB for a 1k map instead of hundreds.
    `progress` shows a progress bar over the μ levels while baking; `split_sun` and `lobes` as :func:`bake`.
    `stack_rank`: how many basis functions' environment stacks ``Baked.env`` holds (default ``rank``): a shading
    at a lower rank reads no more (the cache entry keeps every level whatever it is).
    """
    import hashlib
    import importlib
    import inspect

    from jkatana.light.streaming import RowSource

    if isinstance(radiance, RowSource):
        return _cached_bake_rows(radiance, rank=rank, mus=mus, colourspace=colourspace, transfer=transfer,
                                 source=source, cache_dir=cache_dir, split_sun=split_sun, lobes=lobes,
                                 stack_rank=stack_rank)
    h = hashlib.sha256()
    for part in (np.ascontiguousarray(radiance, np.float64).tobytes(), repr((grid.start, grid.stop, grid.step,
                 rank, list(np.round(mus, 12)), colourspace, transfer, source, radiance.shape,
                 bool(split_sun), family_names(lobes))).encode(),
                 *(inspect.getsource(importlib.import_module(m)).encode() for m in BAKE_MODULES)):
        h.update(part)
    path = cache_folder(cache_dir) / f"baked-{h.hexdigest()[:24]}.npz"
    found = _load_baked(path, rank, stack_rank, radiance.shape[:2])
    if found is not None:
        return found
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    baked, levels = _bake(np.asarray(radiance, np.float64), grid,
                          conductor=Conductor.from_table(source, grid, dtype=dt), rank=rank, mus=mus,
                          colourspace=colourspace, transfer=transfer, cache_dir=cache_dir, progress=progress,
                          split_sun=split_sun, lobes=lobes, stack_rank=stack_rank)
    _save_baked(path, cache_dir, baked, levels)
    return baked


def _cached_bake_rows(rows, *, rank, mus, colourspace, transfer, source, cache_dir, split_sun, lobes,
                      stack_rank=None) -> Baked:
    """:func:`cached_bake` of a map read in row blocks (:class:`~jkatana.light.streaming.RowSource`, a map whose
    spectra do not fit in memory whole): :func:`_bake_rows`, keyed by the file's content and the same inputs."""
    import hashlib
    import importlib
    import inspect

    from jkatana.light.cache import file_digest

    h = hashlib.sha256()
    ident = (getattr(rows, "method", None), rows.scale, getattr(rows, "colourspace", None))
    for part in (file_digest(rows.path).encode(), repr((rows.grid.start, rows.grid.stop, rows.grid.step, rank,
                 list(np.round(mus, 12)), colourspace, transfer, source, ident, bool(split_sun),
                 family_names(lobes))).encode(),
                 *(inspect.getsource(importlib.import_module(m)).encode()
                   for m in (*BAKE_MODULES, "jkatana.light.streaming", "jkatana.render.streamed"))):
        h.update(part)
    path = cache_folder(cache_dir) / f"baked-rows-{h.hexdigest()[:24]}.npz"
    found = _load_baked(path, rank, stack_rank)
    if found is not None:
        return found
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    baked, levels = _bake_rows(rows, conductor=Conductor.from_table(source, rows.grid, dtype=dt), rank=rank,
                               mus=mus, colourspace=colourspace, transfer=transfer, cache_dir=cache_dir,
                               split_sun=split_sun, lobes=lobes, stack_rank=stack_rank)
    _save_baked(path, cache_dir, baked, levels, env_shape=np.asarray(baked.env.shape[2:4]))
    return baked


def _save_baked(path, cache_dir, baked: Baked, levels, **extra) -> None:
    """Write ``baked``'s cache entry: the prefiltered ``levels`` at their own resolutions as float16 (each scaled
    to its maximum), ``extra`` and every other field of ``baked`` but ``env`` (rebuilt from the levels by
    :func:`_level_stack`). The fields are read one by one: ``dataclasses.asdict`` would deep-copy every field, the
    environment stack too, only for it to be dropped."""
    scale = np.array([max(float(np.abs(lv).max()), 1e-30) / 60000.0 for lv in levels])
    small = {f"level{k}": (lv / scale[k]).astype(np.float16) for k, lv in enumerate(levels)}
    fields = {f.name: np.asarray(getattr(baked, f.name)) for f in dataclasses.fields(Baked) if f.name != "env"}
    save_entry(path, cache_dir, level_scale=scale, **extra, **small, **fields)


def _load_baked(path, rank: int, stack_rank: int | None, shape=None) -> Baked | None:
    """The :class:`Baked` of a cache entry written by :func:`_save_baked` (None when there is none): its levels
    read back to float32 and stacked at ``shape`` ``(H, W)`` (default the entry's ``env_shape``) by
    :func:`_level_stack`, its other fields as stored."""
    def read(z):
        levels = [z[f"level{k}"].astype(np.float32) * np.float32(z["level_scale"][k]) for k in range(len(z["mus"]))]
        fields = {f.name: z[f.name] for f in dataclasses.fields(Baked) if f.name != "env"}
        return fields, levels, (z["env_shape"] if shape is None else shape)

    found = load_entry(path, read)
    if found is None:
        return None
    fields, levels, (H, W) = found
    return Baked(**{**fields, "env": _level_stack(levels, int(H), int(W), rank, stack_rank),
                    "fresnel_err": float(fields["fresnel_err"]), "colourspace": str(fields["colourspace"])})


def _level_stack(levels, height: int, width: int, rank: int, stack_rank: int | None = None) -> np.ndarray:
    """``(n_mu, n, height, width, 3)`` float32: the levels ``(h_k, w_k, rank·3)`` resampled to one size
    (:func:`upsample`), as `Baked.env`, for the first n = ``stack_rank`` (default all ``rank``) basis functions:
    a shading at a lower rank than the bake's reads only those, and each stack is n_mu × height × width texels.

    Laid out rank-major in memory (a view of a C-ordered ``(rank, n_mu, height, width, 3)``): each basis
    function's stack is then the one contiguous block its 3-D texture is uploaded from, as it is. Each level is
    written into its place, so no full-size intermediate is made: the stack is hundreds of MB (a 1k map's finest
    level is 512 × 1024), and every byte of fresh memory is paid for in page faults."""
    n = rank if stack_rank is None else min(int(stack_rank), rank)
    out = np.empty((n, len(levels), int(height), int(width), 3), np.float32)
    for k, lv in enumerate(levels):
        lv = np.asarray(lv, np.float32)
        lv = lv.reshape(lv.shape[:2] + (rank, 3))
        for r in range(n):
            out[r, k] = upsample(lv[:, :, r], int(height), int(width))
    return out.transpose(1, 0, 2, 3, 4)


def _bake_rows(rows, *, conductor, rank, mus, colourspace, transfer, cache_dir, split_sun, lobes, stack_rank=None):
    """:func:`_bake` of a :class:`~jkatana.light.streaming.RowSource`: the map projected on the Fresnel basis
    × CIE weights as it streams (a linear projection per texel,
    :func:`~jkatana.light.fresnel_basis.projection_matrix`),
    its sun split from the exact spectra of its texels (:func:`jkatana.light.sun.split_texels`), box-filtered to
    the finest level's resolution (:func:`jkatana.light.prefilter.level_shape`), which is also the size of the
    texture the shaders read (not the map's: the finest level holds no more detail). The environment-independent
    tables (:func:`~jkatana.interactive.tables.lobe_tables`: seconds of JAX compilation for a lobe family met for
    the first time) are built on a second thread meanwhile."""
    from concurrent.futures import ThreadPoolExecutor

    b = material_basis_of(conductor, rank, mus, cache_dir)
    with ThreadPoolExecutor(1) as pool:  # the lobe tables compile and run on the other core meanwhile
        tables = pool.submit(lobe_tables, conductor, rank, mus, cache_dir, lobes)
        baked_env = _rows_environment(rows, b, rows.grid, mus, split_sun)
        b, err, lut, spread, taps, tap_l1, tap_ok, tail = tables.result()
    levels, h, w, cap_dir, cap_radius, cap_q = baked_env
    taps, tail = resolved_taps(taps, spread, mus, h, tail)
    cap_kernel = np.zeros((0,))
    if len(cap_radius) and needs_table(lobes):
        cap_kernel = cap_kernel_table(tuple(lobes), mus, float(np.max(cap_radius)), conductor)
    return Baked(env=_level_stack(levels, h, w, rank, stack_rank), lut=lut, spread=spread, taps=taps, tap_l1=tap_l1,
                 tap_ok=tap_ok, mus=np.asarray(mus, np.float64), b=b, fresnel_err=err,
                 xyz_to_rgb=xyz_to_rgb_matrix(colourspace),
                 transfer=transfer_table(colourspace if transfer is None else transfer), colourspace=colourspace,
                 cap_dir=cap_dir, cap_radius=cap_radius, cap_q=cap_q, cap_kernel=cap_kernel, tail=tail), levels


def _rows_environment(rows, b, grid, mus, split_sun):
    """:func:`_bake_rows`'s environment: the prefiltered levels at the finest level's size, that size, and the
    sun's caps ``(cap_dir, cap_radius, cap_q)``."""
    from jkatana.interactive.levels import TEXELS_PER_MU
    from jkatana.light.fresnel_basis import projection_matrix
    from jkatana.light.prefilter import level_shape
    from jkatana.light.sun import split_texels
    from jkatana.spectral.colorimetry import xyz_weights

    H, Wd, rank = rows.height, rows.width, b.shape[0]
    M = projection_matrix(b, film_weights(grid), None, np).reshape(grid.size, rank * 3)
    proj, y = rows.project_all(np.concatenate([M, xyz_weights(grid)[:, 1:2]], axis=1), (rank * 3, 0))
    cap_dir, cap_radius, cap_q = np.zeros((0, 3)), np.zeros((0,)), np.zeros((0, rank, 3))
    if split_sun:
        caps, changes = split_texels(y.astype(np.float64), rows.texels, grid, max_sources=MAX_CAPS)
        for texels, _, after in changes:
            proj.reshape(-1, rank * 3)[texels] = after @ M
        if caps:
            cap_dir = np.stack([np.asarray(c.direction, np.float64) for c in caps])
            cap_radius = np.array([float(c.radius) for c in caps])
            cap_q = np.stack([float(c.solid_angle) * project_on_basis(np.asarray(c.radiance, np.float64), b,
                                                                      film_weights(grid), xp=np) for c in caps])
    del y
    h, w = level_shape(float(np.min(mus)), (H, Wd), TEXELS_PER_MU)
    small = box_downsample(proj, H // h, rows.block_rows(H // h))
    del proj
    return [prefilter_level(small, float(mu)) for mu in mus], h, w, cap_dir, cap_radius, cap_q


def bake(radiance: np.ndarray, grid: WavelengthGrid = DEFAULT_GRID, *, conductor: Conductor | None = None,
         rank: int = 3, mus=MU_LEVELS, colourspace: str = "sRGB", transfer=None, cache_dir=None,
         split_sun: bool = True, lobes: tuple = PAPER_LOBES) -> Baked:
    """Bake all shader tables for an environment ``radiance (H, W, wl)`` on ``grid``.

    **Arguments:**

    - `radiance`: equirectangular spectral radiance (Y up, see :func:`jkatana.light.envmap.texel_directions_np`).
    - `conductor`: n, k (default iron, Johnson & Christy 1974).
    - `rank`: spectral basis rank (1–4); `mus`: prefilter levels.
    - `colourspace`, `transfer`: the display transform (as :func:`jkatana.spectral.to_display`).
    - `cache_dir`: where the environment-independent tables (:mod:`jkatana.interactive.tables`) are cached.
    - `split_sun`: split compact bright sources off as caps (:func:`~jkatana.interactive.caps.sun_caps`;
      default); False: prefilter the whole map.
    - `lobes`: the regions' lobes (hiraji, hamon) as families width ↦ lobe: the paper's (default) or those
      of parameter files (:func:`jkatana.interactive.lobe_tables.region_lobes`); the lobe table and the taps
      are computed for them (and cached per family), the environment levels are the same.

    **Returns:** a :class:`Baked`.
    """
    radiance = np.asarray(radiance, np.float64)
    if radiance.ndim != 3 or radiance.shape[-1] != grid.size:
        raise ValueError(f"radiance must be (H, W, {grid.size}), got {radiance.shape}")
    if conductor is None:
        conductor = Conductor.from_table("Fe-Johnson", grid, dtype=jnp.float64 if jax.config.jax_enable_x64
                                         else jnp.float32)
    baked, _ = _bake(radiance, grid, conductor=conductor, rank=rank, mus=mus, colourspace=colourspace,
                     transfer=transfer, cache_dir=cache_dir, split_sun=split_sun, lobes=lobes)
    return baked


def _bake(radiance, grid, *, conductor, rank, mus, colourspace, transfer, cache_dir, progress: bool = False,
          split_sun: bool = True, lobes: tuple = PAPER_LOBES, stack_rank: int | None = None):
    """:func:`bake`, also returning the prefiltered levels at their own resolutions (what the cache keeps)."""
    from tqdm import tqdm

    b, err, lut, spread, taps, tap_l1, tap_ok, tail = lobe_tables(conductor, rank, mus, cache_dir, lobes)
    W = film_weights(grid)            # (wl, 3); k = 1/∫ȳ dλ as jkatana.render: flat radiance 1 → Y = 1
    H, Wd = radiance.shape[:2]
    if split_sun:
        radiance, cap_dir, cap_radius, cap_q = sun_caps(radiance, grid, b, W)
    else:
        cap_dir, cap_radius, cap_q = np.zeros((0, 3)), np.zeros((0,)), np.zeros((0, rank, 3))
    proj = project_on_basis(radiance, b, W, xp=np).reshape(H, Wd, rank * 3)
    bar = tqdm(mus, desc="baking the environment (μ levels)", unit="level", disable=not progress,
               file=__import__("sys").stderr)
    levels = [prefilter_level(proj, float(mu)) for mu in bar]
    env = _level_stack(levels, H, Wd, rank, stack_rank)
    taps, tail = resolved_taps(taps, spread, mus, radiance.shape[0], tail)
    cap_kernel = np.zeros((0,))
    if len(cap_radius) and needs_table(lobes):
        cap_kernel = cap_kernel_table(tuple(lobes), mus, float(np.max(cap_radius)), conductor)
    return Baked(env=env, lut=lut, spread=spread, taps=taps, tap_l1=tap_l1, tap_ok=tap_ok,
                 mus=np.asarray(mus, np.float64), b=b, fresnel_err=err,
                 xyz_to_rgb=xyz_to_rgb_matrix(colourspace),
                 transfer=transfer_table(colourspace if transfer is None else transfer),
                 colourspace=colourspace, cap_dir=cap_dir, cap_radius=cap_radius, cap_q=cap_q,
                cap_kernel=cap_kernel, tail=tail), levels
