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
from jkatana.interactive.lobe_tables import FITTED_FAMILIES, LUT_SOURCES, PAPER_LOBES, family_core, family_names
from jkatana.interactive.lobe_tables import gtr_core_factor, lobe_lut
from jkatana.interactive.taps import FIT_SOURCES, N_TAIL, N_TAPS, TAIL_SOURCES, core_taps, tail_fit, tap_fit
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
    """``(taps, l1, ok)`` of :func:`tap_fit` for the regions' lobes ``lobes``, per region.

    The paper's pair (≈ 1–5 min on 2 CPU cores) is looked up first among the tables shipped in
    ``jkatana/data/interactive`` (iron, Johnson & Christy 1974, at the default levels: computed by this code
    with :func:`write_shipped_tap_table`; a test checks the shipped key is current), then in the user cache
    beside :func:`jkatana.interactive.bake.cached_bake`'s tables; else fitted and cached once per conductor and
    levels. A region holding another lobe takes its row from :func:`family_tables` (shipped for
    :data:`~jkatana.interactive.lobe_tables.FITTED_FAMILIES`, else built from their taps without a fit). Key of
    the paper's pair: :func:`tap_fit_key`."""
    taps, l1, ok = (np.array(a) for a in _paper_tap_fit(conductor, mus, n_cos, cache_dir))
    for i, family in enumerate(lobes):
        if family is not PAPER_LOBES[i]:
            taps[i], l1[i], ok[i] = (family_tables(conductor, mus, n_cos, family, cache_dir)[k]
                                     for k in ("taps", "l1", "ok"))
    return taps, l1, ok


def _paper_tap_fit(conductor: Conductor, mus, n_cos: int, cache_dir=None):
    """:func:`tap_fit` of the paper's lobes, shipped or cached (:func:`cached_tap_fit`)."""
    key = tap_fit_key(conductor, mus, n_cos)
    for path in (SHIPPED_TAPS / f"taps-{key}.npz", cache_folder(cache_dir) / f"taps-{key}.npz"):
        if path.exists():
            found = load_entry(path, lambda z: (z["taps"], z["l1"], z["ok"]))
            if found is not None:
                return found
    _, taps, l1, ok = tap_fit(conductor, mus, n_cos=n_cos)
    save_entry(path, cache_dir, taps=taps, l1=l1, ok=ok)
    return taps, l1, ok


def cached_tail_fit(conductor: Conductor, mus, n_cos: int, cache_dir=None, lobes: tuple = PAPER_LOBES):
    """``(taps, tail, l1)``: :func:`cached_tap_fit`'s taps and, for the regions holding a lobe other than the
    paper's, the tail taps of :func:`~jkatana.interactive.taps.tail_fit` and their ∫ |K − mix| dω, from
    :func:`family_tables`; regions holding the paper's lobes keep the three-tap table (w_t = 0, l1 0)."""
    taps, _, _ = cached_tap_fit(conductor, mus, n_cos, cache_dir, lobes)
    tail, l1 = np.zeros(taps.shape[:3] + (N_TAIL, 3)), np.zeros(taps.shape[:3])
    for i, family in enumerate(lobes):
        if family is not PAPER_LOBES[i]:
            entry = family_tables(conductor, mus, n_cos, family, cache_dir)
            tail[i], l1[i] = entry["tail"], entry["tail_l1"]
    return taps, tail, l1


def cached_material_tables(conductor: Conductor, rank: int, mus, cache_dir=None, lobes: tuple = PAPER_LOBES):
    """``(b, fresnel_err, lut, spread)``: :func:`material_basis` and :func:`lobe_lut`, which depend on the
    conductor, the rank and the μ levels but not on the environment, cached beside the tap fit (seconds of
    JAX compilation that a new environment need not pay again). Looked up first among the tables shipped
    with the package (iron at the default grid, rank 3 and levels: :func:`write_shipped_tap_table`), then in
    the user cache. A region holding a lobe other than the paper's takes its rows from
    :func:`family_material_tables`. Key: :func:`tap_fit_key`'s inputs, the rank and the source of the two
    functions."""
    b, err, lut, spread = _paper_material_tables(conductor, rank, mus, cache_dir)
    lut, spread = np.array(lut), np.array(spread)
    for i, family in enumerate(lobes):
        if family is not PAPER_LOBES[i]:
            lut[i], spread[i] = family_material_tables(conductor, rank, mus, family, cache_dir, b)
    return b, err, lut, spread


def material_basis_of(conductor: Conductor, rank: int, mus, cache_dir=None) -> np.ndarray:
    """The conductor's ``(rank, wl)`` Fresnel basis of :func:`cached_material_tables` (shipped or cached)."""
    return _paper_material_tables(conductor, rank, mus, cache_dir)[0]


def lobe_tables(conductor: Conductor, rank: int, mus, cache_dir=None, lobes: tuple = PAPER_LOBES, n_cos: int = 64):
    """Every table of the bake that depends on the material but not on the environment:
    ``(b, fresnel_err, lut, spread)`` of :func:`cached_material_tables` and ``(taps, tap_l1, tap_ok, tail)`` of
    :func:`tap_tables`, the two built side by side (each is a JAX compilation for a lobe family met for the
    first time, and XLA compiles on one core)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:
        tap_rows = pool.submit(tap_tables, conductor, mus, n_cos, cache_dir, lobes)
        b, err, lut, spread = cached_material_tables(conductor, rank, mus, cache_dir, lobes)
        taps, tap_l1, tap_ok, tail = tap_rows.result()
    if lut.shape[2] != n_cos:
        raise ValueError(f"the lobe table has {lut.shape[2]} cos θv rows, the taps {n_cos}")
    return b, err, lut, spread, taps, tap_l1, tap_ok, tail


def tap_tables(conductor: Conductor, mus, n_cos: int = 64, cache_dir=None, lobes: tuple = PAPER_LOBES):
    """``(taps, tap_l1, tap_ok, tail)``: the taps of :func:`cached_tap_fit` and, where a region holds a lobe
    other than the paper's, its tail taps (:func:`cached_tail_fit`; zeros otherwise)."""
    taps, tap_l1, tap_ok = cached_tap_fit(conductor, mus, n_cos, cache_dir, lobes)
    tail = np.zeros(taps.shape[:3] + (N_TAIL, 3))
    if any(family not in PAPER_LOBES for family in lobes):
        taps, tail, _ = cached_tail_fit(conductor, mus, n_cos, cache_dir, lobes)
    return taps, tap_l1, tap_ok, tail


def _material_key(conductor: Conductor, rank: int, mus, lobes: tuple) -> str:
    import hashlib
    import inspect

    h = hashlib.sha256(tap_fit_key(conductor, mus, 64, lobes).encode() + repr(rank).encode())
    for f in (material_basis, fresnel_basis, basis_of_table, *LUT_SOURCES):
        h.update(inspect.getsource(f).encode())
    return h.hexdigest()[:24]


def _paper_material_tables(conductor: Conductor, rank: int, mus, cache_dir=None):
    """:func:`cached_material_tables` of the paper's lobes."""
    name = f"material-{_material_key(conductor, rank, mus, PAPER_LOBES)}.npz"
    for path in (SHIPPED_TAPS / name, cache_folder(cache_dir) / name):
        if path.exists():
            found = load_entry(path, lambda z: (z["b"], float(z["err"]), z["lut"], z["spread"]))
            if found is not None:
                return found
    b, err = material_basis(conductor, rank)
    _, lut, spread = lobe_lut(conductor, b, mus)
    save_entry(path, cache_dir, b=b, err=np.float64(err), lut=lut, spread=spread)
    return b, err, lut, spread


def family_material_tables(conductor: Conductor, rank: int, mus, family, cache_dir=None, b=None):
    """``(lut, spread)`` of one region's lobe family (:func:`lobe_lut`'s rows, ``(n_mu, 64, ·)``): shipped for
    iron at rank 3 and the default levels (:data:`~jkatana.interactive.lobe_tables.FITTED_FAMILIES`,
    :func:`write_shipped_family_tables`), else cached, else computed (seconds: one JAX compilation). ``b``:
    the conductor's basis (:func:`material_basis`) when the caller has it."""
    name = f"family-material-{_material_key(conductor, rank, mus, (family,))}.npz"
    for path in (SHIPPED_TAPS / name, cache_folder(cache_dir) / name):
        if path.exists():
            found = load_entry(path, lambda z: (z["lut"], z["spread"]))
            if found is not None:
                return found
    b = material_basis(conductor, rank)[0] if b is None else b
    _, lut, spread = lobe_lut(conductor, b, mus, lobes=(family,))
    save_entry(path, cache_dir, lut=lut[0], spread=spread[0])
    return lut[0], spread[0]


def family_key(conductor: Conductor, mus, n_cos: int, family) -> str:
    """Key of :func:`family_tables`: :func:`tap_fit_key` of the family alone and the source of the tail fit
    and of the core's construction (a code change invalidates it)."""
    import hashlib
    import inspect

    h = hashlib.sha256(tap_fit_key(conductor, mus, n_cos, (family,)).encode())
    for f in (*TAIL_SOURCES, core_taps, family_core, gtr_core_factor, family_tables):
        h.update(inspect.getsource(f).encode())
    return h.hexdigest()[:24]


def family_tables(conductor: Conductor, mus, n_cos: int, family, cache_dir=None, fitted=None) -> dict:
    """One region's tap rows for a lobe family other than the paper's: ``taps, l1, ok (n_mu, n_cos, ·)`` as
    :func:`tap_fit`'s rows, ``tail, tail_l1`` as :func:`~jkatana.interactive.taps.tail_fit`'s.

    Looked up among the tables shipped with the package, then in the user cache. Else built: the three
    taps of :data:`~jkatana.interactive.lobe_tables.FITTED_FAMILIES` (GGX, Beckmann) are fitted
    (:func:`tap_fit`, minutes: shipped for iron at the default levels, so only another conductor or other
    levels pay it; ``fitted``: that fit's ``(taps, l1, ok)`` rows when the caller has them); every other
    family's are its core's (:func:`~jkatana.interactive.lobe_tables.family_core`: GTR's equal-half-maximum
    GGX, a mixture's narrower part) scaled to its width (:func:`~jkatana.interactive.taps.core_taps`, no fit;
    ``l1``/``ok`` those of the core's fit at the level it is read from). The tail taps are then fitted to the
    family's own lobe (:func:`~jkatana.interactive.taps.tail_fit`, no iteration: seconds)."""
    name = f"family-{family_key(conductor, mus, n_cos, family)}.npz"
    for path in (SHIPPED_TAPS / name, cache_folder(cache_dir) / name):
        if path.exists():
            found = load_entry(path, lambda z: {k: z[k] for k in z.files})
            if found is not None:
                return found
    base, c = family_core(family)
    if fitted is not None:
        taps, l1, ok = fitted
    elif base == family:
        _, taps, l1, ok = tap_fit(conductor, mus, n_cos=n_cos, lobes=(family, family))
        taps, l1, ok = taps[0], l1[0], ok[0]
    else:
        if base in PAPER_LOBES:
            rows = [a[PAPER_LOBES.index(base)] for a in _paper_tap_fit(conductor, mus, n_cos, cache_dir)]
        else:
            rows = [family_tables(conductor, mus, n_cos, base, cache_dir)[k] for k in ("taps", "l1", "ok")]
        taps, j = core_taps(rows[0], mus, c)
        l1, ok = rows[1][j], rows[2][j]
    _, tail, tail_l1 = tail_fit(conductor, np.asarray(taps)[None], mus, n_cos, (family,))
    entry = {"taps": np.asarray(taps, np.float64), "l1": np.asarray(l1, np.float64), "ok": np.asarray(ok),
             "tail": tail[0], "tail_l1": tail_l1[0]}
    save_entry(path, cache_dir, **entry)
    return entry


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


def write_shipped_family_tables(source: str = "Fe-Johnson", grid: WavelengthGrid = DEFAULT_GRID, rank: int = 3,
                                 fitted: dict | None = None) -> list[Path]:
    """:func:`family_tables` and :func:`family_material_tables` of
    :data:`~jkatana.interactive.lobe_tables.FITTED_FAMILIES` for ``source`` at the default levels and rank 3,
    float64, into the package's data folder (stale ``family-*`` tables removed): one tap fit of the pair
    (minutes), unless ``fitted`` gives ``{family: (taps, l1, ok)}`` rows of a fit by this code."""
    jax.config.update("jax_enable_x64", True)
    conductor = Conductor.from_table(source, grid, dtype=jnp.float64)
    if fitted is None:
        _, taps, l1, ok = tap_fit(conductor, MU_LEVELS, n_cos=64, lobes=FITTED_FAMILIES)
        fitted = {f: (taps[i], l1[i], ok[i]) for i, f in enumerate(FITTED_FAMILIES)}
    for old in SHIPPED_TAPS.glob("family-*.npz"):
        old.unlink()
    written = []
    with __import__("tempfile").TemporaryDirectory() as tmp:
        for family in FITTED_FAMILIES:
            family_tables(conductor, MU_LEVELS, 64, family, tmp, fitted=fitted[family])
            family_material_tables(conductor, rank, MU_LEVELS, family, tmp)
        for made in sorted((Path(tmp) / "interactive").glob("family-*.npz")):
            _save_npz(SHIPPED_TAPS / made.name, **dict(np.load(made)))
            written.append(SHIPPED_TAPS / made.name)
    return written


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
