"""The bake's environment-independent tables, cached and shipped: Fresnel basis, lobe tables, tap fit.

What depends on the conductor and the μ levels but not on the environment —
the spectral basis of F (:func:`material_basis`), the lobe tables
(:func:`jkatana.interactive.lobe_tables.lobe_lut`) and the tap fit
(:func:`jkatana.interactive.taps.tap_fit`, minutes) — is computed once and
kept: for iron at the default grid and levels in the package
(``jkatana/data/interactive``, written by :func:`write_shipped_tap_table`),
else in the user cache (:mod:`jkatana.light.cache`'s budget and eviction).
Each entry's name is a key that hashes its inputs and the source text of the
functions that compute it, so a change to that code leaves a stale entry
unused (and the shipped-table tests fail until it is regenerated).
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.interactive.levels import MU_LEVELS
from jkatana.interactive.lobe_tables import LUT_SOURCES, PAPER_LOBES, family_names, lobe_lut
from jkatana.interactive.taps import FIT_SOURCES, N_TAPS, TAIL_SOURCES, tail_fit, tap_fit
from jkatana.light.fresnel_basis import basis_of_table, fresnel_basis
from jkatana.models import Conductor
from jkatana.spectral import DEFAULT_GRID, WavelengthGrid

#: Largest rank the shaders support (one RGBA texel holds 4 coefficients).
MAX_RANK = 4
#: Cosines the Fresnel basis is fitted on: uniform on [0, 1], the lobe table's axis.
BASIS_COS = np.linspace(0.0, 1.0, 256)


def material_basis(conductor: Conductor, rank: int) -> tuple[np.ndarray, float]:
    """The spectral basis of the conductor's F (:func:`jkatana.light.fresnel_basis.fresnel_basis` on
    :data:`BASIS_COS`), rank 1–:data:`MAX_RANK`.

    **Returns:** ``(b (rank, wl), rel_err)``: the orthonormal spectral basis (the first row with a positive
    sum) and the max relative error of the rank-``rank`` F over the table.
    """
    if not 1 <= rank <= MAX_RANK:
        raise ValueError(f"rank must be 1..{MAX_RANK}, got {rank}")
    fb = fresnel_basis(conductor, rank, cos=BASIS_COS)
    F = np.asarray(conductor.fresnel(jnp.asarray(BASIS_COS, conductor.n.dtype)), np.float64)
    b = np.asarray(fb.basis, np.float64)
    return b, float(np.max(np.abs(np.asarray(fb.coefficients, np.float64) @ b - F) / F))


def cache_folder(cache_dir=None) -> Path:
    """``cache_dir``, else ``$JKATANA_CACHE``, else ``~/.cache/jkatana``; its ``interactive`` folder (under the
    size budget and eviction of :mod:`jkatana.light.cache`)."""
    from jkatana.light.cache import cache_base

    return cache_base(cache_dir) / "interactive"


def load_entry(path: Path, read):
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


def save_entry(path: Path, cache_dir, **arrays) -> None:
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


#: Folder of tap tables shipped with the package (see :func:`cached_tap_fit`).
SHIPPED_TAPS = Path(__file__).resolve().parent.parent / "data" / "interactive"


def tap_fit_key(conductor: Conductor, mus=MU_LEVELS, n_cos: int = 64, lobes: tuple = PAPER_LOBES) -> str:
    """Cache key of :func:`tap_fit`: n, k (rounded to float32, so float32 and float64 runs share it), μ
    levels, n_cos, the tap count, the regions' lobe families (:func:`~jkatana.interactive.lobe_tables.family_names`)
    and the source of the fitting code (a code change invalidates it)."""
    import hashlib
    import inspect

    h = hashlib.sha256()
    for part in (np.asarray(conductor.n, np.float32).astype(np.float64).tobytes(),
                 np.asarray(conductor.k, np.float32).astype(np.float64).tobytes(),
                 np.asarray(mus, np.float64).round(12).tobytes(), repr((n_cos, N_TAPS)).encode(),
                 repr(family_names(lobes)).encode(),
                 *(inspect.getsource(f).encode() for f in FIT_SOURCES)):
        h.update(part)
    return h.hexdigest()[:24]


def cached_tap_fit(conductor: Conductor, mus, n_cos: int, cache_dir=None, lobes: tuple = PAPER_LOBES):
    """:func:`tap_fit` (≈ 1–5 min on 2 CPU cores) cached: it depends on the conductor and the μ levels,
    not on the environment. Looked up first among the tables shipped in ``jkatana/data/interactive``
    (iron, Johnson & Christy 1974, at the default levels: computed by this code with
    :func:`write_shipped_tap_table`; a test checks the shipped key is current), then in the user cache
    beside :func:`jkatana.interactive.bake.cached_bake`'s tables; else fitted and cached, once per conductor,
    levels and pair of lobe families (``lobes``). Key: :func:`tap_fit_key`."""
    key = tap_fit_key(conductor, mus, n_cos, lobes)
    for path in (SHIPPED_TAPS / f"taps-{key}.npz", cache_folder(cache_dir) / f"taps-{key}.npz"):
        if path.exists():
            found = load_entry(path, lambda z: (z["taps"], z["l1"], z["ok"]))
            if found is not None:
                return found
    _, taps, l1, ok = tap_fit(conductor, mus, n_cos=n_cos, lobes=lobes)
    save_entry(path, cache_dir, taps=taps, l1=l1, ok=ok)
    return taps, l1, ok


def cached_tail_fit(conductor: Conductor, mus, n_cos: int, cache_dir=None, lobes: tuple = PAPER_LOBES):
    """``(taps, tail, l1)``: :func:`~jkatana.interactive.taps.tail_fit` (a tail tap for the regions holding a
    lobe other than the paper's, beside :func:`cached_tap_fit`'s three taps), cached in the user cache. Key:
    :func:`tap_fit_key`'s and the source of :data:`~jkatana.interactive.taps.TAIL_SOURCES`. Regions holding the paper's lobes keep the three-tap table
    (w_t = 0); with the paper's lobes in both regions nothing is fitted."""
    import hashlib
    import inspect

    taps, _, _ = cached_tap_fit(conductor, mus, n_cos, cache_dir, lobes)
    if all(family in PAPER_LOBES for family in lobes):
        return tail_fit(conductor, taps, mus, n_cos, lobes)
    h = hashlib.sha256(tap_fit_key(conductor, mus, n_cos, lobes).encode())
    for f in TAIL_SOURCES:
        h.update(inspect.getsource(f).encode())
    path = cache_folder(cache_dir) / f"tail-{h.hexdigest()[:24]}.npz"
    found = load_entry(path, lambda z: (z["taps"], z["tail"], z["l1"]))
    if found is not None:
        return found
    taps, tail, l1 = tail_fit(conductor, taps, mus, n_cos, lobes)
    save_entry(path, cache_dir, taps=taps, tail=tail, l1=l1)
    return taps, tail, l1


def cached_material_tables(conductor: Conductor, rank: int, mus, cache_dir=None, lobes: tuple = PAPER_LOBES):
    """``(b, fresnel_err, lut, spread)``: :func:`material_basis` and :func:`lobe_lut`, which depend on the
    conductor, the rank and the μ levels but not on the environment, cached beside the tap fit (seconds of
    JAX compilation that a new environment need not pay again). Looked up first among the tables shipped
    with the package (iron at the default grid, rank 3 and levels: :func:`write_shipped_tap_table`), then in
    the user cache; ``lobes`` as :func:`cached_tap_fit`. Key: :func:`tap_fit_key`'s inputs, the rank and the
    source of the two functions."""
    import hashlib
    import inspect

    h = hashlib.sha256(tap_fit_key(conductor, mus, 64, lobes).encode() + repr(rank).encode())
    for f in (material_basis, fresnel_basis, basis_of_table, *LUT_SOURCES):
        h.update(inspect.getsource(f).encode())
    name = f"material-{h.hexdigest()[:24]}.npz"
    for path in (SHIPPED_TAPS / name, cache_folder(cache_dir) / name):
        if path.exists():
            found = load_entry(path, lambda z: (z["b"], float(z["err"]), z["lut"], z["spread"]))
            if found is not None:
                return found
    b, err = material_basis(conductor, rank)
    _, lut, spread = lobe_lut(conductor, b, mus, lobes=lobes)
    save_entry(path, cache_dir, b=b, err=np.float64(err), lut=lut, spread=spread)
    return b, err, lut, spread


def write_shipped_tap_table(source: str = "Fe-Johnson", grid: WavelengthGrid = DEFAULT_GRID) -> Path:
    """Fit the taps for ``source`` at the default μ levels and write them to the package's data folder
    (run after changing the fitting code: ``python -c "from jkatana.interactive.tables import
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
    """Compute :func:`cached_material_tables` for ``source`` at the default levels into the package's
    data folder (float64, as the shipped tap table)."""
    jax.config.update("jax_enable_x64", True)
    conductor = Conductor.from_table(source, grid, dtype=jnp.float64)
    for old in SHIPPED_TAPS.glob("material-*.npz"):
        old.unlink()
    with __import__("tempfile").TemporaryDirectory() as tmp:
        cached_material_tables(conductor, rank, MU_LEVELS, tmp)
        made = next((Path(tmp) / "interactive").glob("material-*.npz"))
        target = SHIPPED_TAPS / made.name
        _save_npz(target, **dict(np.load(made)))
    return target
