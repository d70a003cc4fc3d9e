"""On-disk cache of environments: loaded once, read back in well under a second.

Turning an HDR file into the renderer's environment is the slow part of
loading a scene: reading and spectrally upsampling the image
(:mod:`jkatana.light.upsampling`), then the sampling tables, the spectral
basis and, for the ``prefiltered`` mode, the lobe-convolved levels
(:func:`jkatana.render.environment.build_environment`). Both steps are pure
functions of their inputs, so their results are kept under a content key:

- :func:`radiance_key`: the file's bytes (SHA-256), or the sky's parameters,
  with the upsampling method, scale, colour space, the wavelength grid and the
  source of the modules that compute it (a code change invalidates the entry);
- :func:`environment_key`: the radiance key with the build options (basis
  rank, prefilter μ levels, precision) and the source of the building code;
- :func:`fresnel_key`: the optical constants on the grid (the conductor's
  Fresnel table is evaluated op by op, seconds of compilation per process).

Entries live in ``$JKATANA_CACHE`` (else ``~/.cache/jkatana``)/``environments``
as ``.npy`` (radiance) and folders of ``.npy`` + ``tree.json`` (an
:mod:`equinox` module tree, rebuilt field by field from classes of
``jkatana`` only), memory-mapped on read and written atomically (a
temporary file or folder renamed into place). The
environment's rotation is not part of the entry: it is set after loading.

## Size budget and eviction

The interactive bake (:mod:`jkatana.interactive.bake`) keeps its tables in the
sibling folder ``interactive``; both folders share one size budget,
:data:`DEFAULT_BUDGET_MB` (2048 MB, about eight 1k HDR environments), changed
by ``$JKATANA_CACHE_MAX_MB`` (:func:`cache_budget`). After each write,
:func:`evict` removes the least recently used entries until the total is
within the budget. An entry's last use is its modification time, set on every
read (:func:`acquire`; access times are unreliable on ``relatime``/``noatime``
mounts). An entry is *in use* while a process holds it with :func:`acquire`
(a shared ``flock`` on the entry's file, or on its ``tree.json``, kept until
:func:`release` or the process exits; memory-mapped entries are held for the
process's life): eviction takes an exclusive non-blocking lock first and
skips every entry it cannot lock, so an entry in use is never removed, and a
reader that finds its entry removed meanwhile builds it again. The entry just
written is held by its writer, so it survives its own eviction pass even when
it alone exceeds the budget. :func:`entries` lists the cache, :func:`clear`
empties it (but for entries in use).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import inspect
import json
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

#: bump when the stored layout changes
CACHE_VERSION = 1
#: default size budget of the cache folders (MB = 10⁶ bytes), see the module docstring
DEFAULT_BUDGET_MB = 2048.0
#: environment variable that sets the budget in MB
BUDGET_VARIABLE = "JKATANA_CACHE_MAX_MB"
#: the cache's sub-folders that share the budget: this module's entries and the interactive bake's
CACHE_FOLDERS = ("environments", "interactive")


def cache_base(cache_dir: str | Path | None = None) -> Path:
    """``cache_dir``, else ``$JKATANA_CACHE``, else ``~/.cache/jkatana``: the folder holding :data:`CACHE_FOLDERS`."""
    from jkatana.runtime import cache_home

    return Path(cache_dir) if cache_dir else cache_home()


def cache_root(cache_dir: str | Path | None = None) -> Path:
    """``cache_dir``, else ``$JKATANA_CACHE``, else ``~/.cache/jkatana``; its ``environments`` folder."""
    return cache_base(cache_dir) / "environments"


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _source_digest(*modules: str) -> bytes:
    return b"".join(inspect.getsource(importlib.import_module(m)).encode() for m in modules)


def _key(*parts) -> str:
    h = hashlib.sha256(repr((CACHE_VERSION,) + parts[:-1]).encode())
    h.update(parts[-1])
    return h.hexdigest()[:24]


def radiance_key(env, grid) -> str | None:
    """Content key of a scene environment's spectral radiance, or None when it is cheaper to build.

    `env` is a :class:`jkatana.render.scene.EnvironmentSpec`; the rotation is not part of the key.
    """
    g = (float(grid.start), float(grid.stop), int(grid.size))
    if env.type in ("exr", "hdr"):
        return _key("file", file_digest(env.path), env.upsampling, env.scale, env.colourspace, g,
                    _source_digest("jkatana.light.envmap", "jkatana.light.upsampling"))
    if env.type == "sky":
        return _key("sky", env.elevation_deg, env.azimuth_deg, env.turbidity, env.albedo, env.sun,
                    tuple(env.resolution), g, _source_digest("jkatana.light.sky"))
    return None


def environment_key(rad_key: str, *, rank, prefilter_mus, prefilter_resolution: int, dtype,
                    split_sun: bool = False, sampling: bool = True) -> str:
    """Key of :func:`jkatana.render.environment.build_environment`'s result for radiance ``rad_key``
    (``split_sun``: compact sources split off as caps, :mod:`jkatana.light.sun`; ``sampling``: with its
    sampling tables)."""
    mus = tuple(round(float(m), 12) for m in prefilter_mus)
    return _key("environment", rad_key, rank, mus, int(prefilter_resolution), np.dtype(dtype).name, bool(split_sun),
                *(() if sampling else ("no-sampler",)),
                _source_digest("jkatana.render.environment", "jkatana.render.streamed", "jkatana.light.sampling",
                               "jkatana.light.prefilter", "jkatana.light.sun", "jkatana.light.envmap",
                               "jkatana.light.streaming", "jkatana.models.lobes", "jkatana.models.lobe_id"))


def fresnel_key(n, k, dtype) -> str:
    """Key of :func:`jkatana.render.fresnel_fold.fresnel_table` for optical constants ``n``, ``k`` on a grid."""
    nk = np.concatenate([np.asarray(n, np.float64).ravel(), np.asarray(k, np.float64).ravel()]).tobytes()
    return _key("fresnel", np.dtype(dtype).name, hashlib.sha256(nk).hexdigest(),
                _source_digest("jkatana.render.fresnel_fold", "jkatana.models.fresnel"))


def cached_radiance(key: str | None, build: Callable[[], np.ndarray], cache_dir=None) -> np.ndarray:
    """``build()`` (a float32 ``(H, W, wl)`` array) through the cache; memory-mapped when read back."""
    if key is None:
        return build()
    from jkatana.io.atomic import atomic_path

    path = cache_root(cache_dir) / f"radiance-{key}.npy"
    if path.exists() and acquire(path):       # held for the process's life: the array is memory-mapped
        return np.load(path, mmap_mode="r")
    rad = np.ascontiguousarray(build(), np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, rad)
    after_write(path, cache_dir)
    return rad


def cached_tree(key: str | None, build: Callable[[], Any], cache_dir=None, kind: str = "environment") -> Any:
    """``build()`` (a tree of equinox modules, tuples, arrays and scalars) through the cache."""
    if key is None:
        return build()
    path = cache_root(cache_dir) / f"{kind}-{key}"
    if (path / "tree.json").exists() and acquire(path):    # held: the arrays are memory-mapped
        return load_tree(path)
    value = build()
    save_tree(path, value)
    after_write(path, cache_dir)
    return value


# ----------------------------------------------------------------------------- budget and eviction


def cache_budget() -> int:
    """The cache's size budget in bytes: ``$JKATANA_CACHE_MAX_MB`` (MB, a number ≥ 0), else
    :data:`DEFAULT_BUDGET_MB`. A malformed value is an :class:`~jkatana.errors.InputError` naming the variable."""
    raw = os.environ.get(BUDGET_VARIABLE)
    if raw is None or raw.strip() == "":
        return int(DEFAULT_BUDGET_MB * 1e6)
    try:
        mb = float(raw)
    except ValueError:
        mb = float("nan")
    if not mb >= 0 or mb == float("inf"):
        from jkatana.errors import InputError

        raise InputError(f"{BUDGET_VARIABLE} must be a size in MB (a number ≥ 0), got {raw!r}", field=BUDGET_VARIABLE)
    return int(mb * 1e6)


#: entries this process holds (:func:`acquire`): resolved path → open file descriptor with a shared flock
_HELD: dict[str, int] = {}


def _lock_file(entry: Path) -> Path:
    """The file whose flock marks ``entry`` in use: the entry itself, or a folder entry's ``tree.json``."""
    return entry / "tree.json" if entry.is_dir() else entry


def acquire(entry: str | Path) -> bool:
    """Mark ``entry`` (a cache file or folder) in use by this process and just used.

    Takes a shared ``flock`` on it (:func:`_lock_file`), kept until :func:`release`
    or the process exits, and sets its modification time to now (its last use, for
    :func:`evict`). Returns False when the entry is gone (evicted between the
    caller's check and the lock): the caller builds it again.
    """
    import fcntl

    entry = Path(entry)
    key = str(entry.resolve())
    if key in _HELD:
        os.utime(entry)
        return True
    lock = _lock_file(entry)
    try:
        fd = os.open(lock, os.O_RDONLY)
    except FileNotFoundError:
        return False
    fcntl.flock(fd, fcntl.LOCK_SH)
    try:                                  # removed while we waited for the lock: not this entry any more
        same = os.fstat(fd).st_ino == os.stat(lock).st_ino
    except FileNotFoundError:
        same = False
    if not same:
        os.close(fd)
        return False
    _HELD[key] = fd
    os.utime(entry)
    return True


def release(entry: str | Path) -> None:
    """Drop this process's hold on ``entry`` (:func:`acquire`); nothing if it holds none."""
    fd = _HELD.pop(str(Path(entry).resolve()), None)
    if fd is not None:
        os.close(fd)


@dataclasses.dataclass(frozen=True)
class Entry:
    """One cache entry: `path`, `size` (bytes; a folder's files summed), `last_used` (POSIX time)."""

    path: Path
    size: int
    last_used: float


def entries(cache_dir: str | Path | None = None) -> list[Entry]:
    """Every entry of :data:`CACHE_FOLDERS`, least recently used first (temporaries, whose names start
    with a dot, are not entries)."""
    out = []
    for sub in CACHE_FOLDERS:
        folder = cache_base(cache_dir) / sub
        if not folder.is_dir():
            continue
        for p in folder.iterdir():
            if p.name.startswith("."):
                continue
            try:
                st = p.stat()
                size = sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) if p.is_dir() else st.st_size
            except FileNotFoundError:         # removed by another process while listing
                continue
            out.append(Entry(p, int(size), float(st.st_mtime)))
    return sorted(out, key=lambda e: (e.last_used, e.path.name))


def _remove_unused(entry: Path) -> bool:
    """Remove ``entry`` if no process holds it (exclusive non-blocking flock); True when removed."""
    import fcntl
    import shutil
    import tempfile

    try:
        fd = os.open(_lock_file(entry), os.O_RDONLY)
    except FileNotFoundError:
        if entry.is_dir():                   # a folder without tree.json: an incomplete entry
            shutil.rmtree(entry, ignore_errors=True)
            return True
        return False
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        if entry.is_dir():                   # out of the way at once (readers see no entry), then deleted
            trash = Path(tempfile.mkdtemp(prefix=f".evicted-{entry.name}.", dir=entry.parent))
            os.rename(entry, trash / entry.name)
        else:
            entry.unlink()
            trash = None
    except FileNotFoundError:
        return False
    finally:
        os.close(fd)
    if trash is not None:
        shutil.rmtree(trash, ignore_errors=True)
    return True


def evict(cache_dir: str | Path | None = None, budget: int | None = None) -> list[Path]:
    """Remove least recently used entries not in use until the cache's total size is within ``budget``
    bytes (default :func:`cache_budget`). Returns the removed entries' paths."""
    budget = cache_budget() if budget is None else int(budget)
    listed = entries(cache_dir)
    total = sum(e.size for e in listed)
    removed = []
    for e in listed:
        if total <= budget:
            break
        if _remove_unused(e.path):
            total -= e.size
            removed.append(e.path)
    return removed


def after_write(entry: str | Path, cache_dir: str | Path | None = None) -> list[Path]:
    """A new entry was written: hold it (:func:`acquire`), then :func:`evict` to the budget."""
    acquire(entry)
    return evict(cache_dir)


def clear(cache_dir: str | Path | None = None) -> tuple[list[Path], list[Path]]:
    """Remove every entry no process holds. Returns ``(removed, kept_in_use)``."""
    removed, kept = [], []
    for e in entries(cache_dir):
        (removed if _remove_unused(e.path) else kept).append(e.path)
    return removed, kept


# ----------------------------------------------------------------------------- tree ↔ npz


def _encode(obj, arrays: dict) -> Any:
    import jax

    if isinstance(obj, (jax.Array, np.ndarray)):
        name = f"a{len(arrays)}"
        arrays[name] = np.asarray(obj)
        return {"array": name, "jax": isinstance(obj, jax.Array)}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        cls = type(obj)
        if not cls.__module__.startswith("jkatana."):
            raise TypeError(f"cannot cache a {cls.__module__}.{cls.__qualname__}")
        return {"class": f"{cls.__module__}:{cls.__qualname__}",
                "fields": {f.name: _encode(getattr(obj, f.name), arrays) for f in dataclasses.fields(obj)}}
    if isinstance(obj, (tuple, list)):
        return {"tuple": [_encode(v, arrays) for v in obj]}
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise TypeError(f"cannot cache a {type(obj).__name__}")


def _decode(node, arrays) -> Any:
    if isinstance(node, dict):
        if "array" in node:
            a = arrays[node["array"]]
            if node["jax"]:
                import jax.numpy as jnp

                return jnp.asarray(a)
            return a
        if "class" in node:
            mod, qual = node["class"].split(":")
            if not mod.startswith("jkatana."):
                raise ValueError(f"refusing to rebuild {node['class']}")
            cls = importlib.import_module(mod)
            for part in qual.split("."):
                cls = getattr(cls, part)
            obj = object.__new__(cls)
            for name, value in node["fields"].items():
                object.__setattr__(obj, name, _decode(value, arrays))
            return obj
        if "tuple" in node:
            return tuple(_decode(v, arrays) for v in node["tuple"])
    return node


def save_tree(path: str | Path, obj) -> Path:
    """Write ``obj`` as a folder: one ``.npy`` per array and ``tree.json`` describing the structure.

    Written into a temporary folder beside ``path`` and renamed into place, so a
    reader sees a whole entry or none.
    """
    import shutil
    import tempfile

    arrays: dict = {}
    tree = _encode(obj, arrays)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        for name, a in arrays.items():
            np.save(tmp / f"{name}.npy", np.ascontiguousarray(a))
        (tmp / "tree.json").write_text(json.dumps(tree))
        try:
            os.rename(tmp, path)
        except OSError:  # another process wrote the same entry first
            if not (path / "tree.json").exists():
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return path


def load_tree(path: str | Path):
    """Inverse of :func:`save_tree` (arrays memory-mapped until used)."""
    path = Path(path)
    tree = json.loads((path / "tree.json").read_text())
    arrays = {p.stem: np.load(p, mmap_mode="r") for p in path.glob("*.npy")}
    return _decode(tree, arrays)
