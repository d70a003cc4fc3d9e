"""On-disk cache of environments: loaded once, read back in well under a second.

Turning an HDR file into the renderer's environment is the slow part of
loading a scene: reading and spectrally upsampling the image
(:mod:`jkatana.light.upsampling`), then the sampling tables, the spectral
basis and, for the ``prefiltered`` mode, the lobe-convolved levels
(:func:`jkatana.render.shading.build_environment`). Both steps are pure
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


def cache_root(cache_dir: str | Path | None = None) -> Path:
    """``cache_dir``, else ``$JKATANA_CACHE``, else ``~/.cache/jkatana``; its ``environments`` folder."""
    base = cache_dir or os.environ.get("JKATANA_CACHE") or Path.home() / ".cache" / "jkatana"
    return Path(base) / "environments"


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

    `env` is a :class:`jkatana.render.scene.Environment`; the rotation is not part of the key.
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
                    split_sun: bool = False) -> str:
    """Key of :func:`jkatana.render.shading.build_environment`'s result for radiance ``rad_key``
    (``split_sun``: compact sources split off as caps, :mod:`jkatana.light.sun`)."""
    mus = tuple(round(float(m), 12) for m in prefilter_mus)
    return _key("environment", rad_key, rank, mus, int(prefilter_resolution), np.dtype(dtype).name, bool(split_sun),
                _source_digest("jkatana.render.shading", "jkatana.render.environment", "jkatana.light.sampling",
                               "jkatana.light.prefilter", "jkatana.light.sun"))


def fresnel_key(n, k, dtype) -> str:
    """Key of :func:`jkatana.render.shading.fresnel_table` for optical constants ``n``, ``k`` on a grid."""
    nk = np.concatenate([np.asarray(n, np.float64).ravel(), np.asarray(k, np.float64).ravel()]).tobytes()
    return _key("fresnel", np.dtype(dtype).name, hashlib.sha256(nk).hexdigest(),
                _source_digest("jkatana.render.shading", "jkatana.models.fresnel"))


def cached_radiance(key: str | None, build: Callable[[], np.ndarray], cache_dir=None) -> np.ndarray:
    """``build()`` (a float32 ``(H, W, wl)`` array) through the cache; memory-mapped when read back."""
    if key is None:
        return build()
    from jkatana.io.atomic import atomic_path

    path = cache_root(cache_dir) / f"radiance-{key}.npy"
    if path.exists():
        return np.load(path, mmap_mode="r")
    rad = np.ascontiguousarray(build(), np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, rad)
    return rad


def cached_tree(key: str | None, build: Callable[[], Any], cache_dir=None, kind: str = "environment") -> Any:
    """``build()`` (a tree of equinox modules, tuples, arrays and scalars) through the cache."""
    if key is None:
        return build()
    path = cache_root(cache_dir) / f"{kind}-{key}"
    if (path / "tree.json").exists():
        return load_tree(path)
    value = build()
    save_tree(path, value)
    return value


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
