"""In-process A/B of the reference shader on the peer sphere's pixels: ``python ab_shade.py VARIANTS ROUNDS [S]``.

``VARIANTS``: comma-separated names from :data:`PATCHES` (``base`` = the checkout as it is). The pixels are
captured from one peer-sphere frame (``prof.capture``); per round each variant is patched in, every jit cache
cleared, ``shade`` compiled and called once, then timed over 3 calls (process CPU s per call, median);
the order of the variants alternates per round. Also prints each variant's XYZ difference to the first.
"""
from __future__ import annotations

import dataclasses
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
import prof  # noqa: E402


def _sum_written(x):
    """A short last axis summed as written-out additions (tried in ``_safe.norm``; not kept)."""
    out = x[..., 0]
    for k in range(1, x.shape[-1]):
        out = out + x[..., k]
    return out


def _old_to_local(v, t, b, n):
    """``geometry.to_local`` before 7846511 (jnp.stack of jnp.sum)."""
    import jax.numpy as jnp
    return jnp.stack([jnp.sum(v * t, -1), jnp.sum(v * b, -1), jnp.sum(v * n, -1)], -1)


def _arctan2():
    import jax.numpy as jnp
    return jnp.arctan2


def _matmul_rotate(d, M):
    return d @ M


def _old_equirect():
    """``envmap.equirect_direction`` before 7846511 (jnp.stack)."""
    import jax.numpy as jnp
    import numpy as np

    def equirect_direction(u, cos_theta, sin_theta):
        phi = (u - 0.5) * 2 * np.pi
        return jnp.stack(jnp.broadcast_arrays(sin_theta * jnp.sin(phi), cos_theta, -sin_theta * jnp.cos(phi)), -1)
    return equirect_direction


def _einsum_fold():
    """``shading._fold_xyz`` as the batched einsum it replaced."""
    import jax.numpy as jnp

    def fold(F, E):
        return jnp.einsum("pr,prc->pc", F, E.reshape(E.shape[0], -1, 3))
    return fold


#: name → list of (module, attribute, replacement factory); the ``old-*`` ones undo one part of 7846511
PATCHES = {
    "base": [],
    "sum-written": [("jkatana.models._safe", "sum_last", lambda: _sum_written)],
    "old-atan2": [("jkatana.light.envmap", "atan2", _arctan2), ("jkatana.light.sampling", "atan2", _arctan2)],
    "old-to_local": [("jkatana.models.geometry", "to_local", lambda: _old_to_local),
                     ("jkatana.render.shading", "to_local", lambda: _old_to_local)],
    "old-rotate": [("jkatana.render.environment", "_rotate", lambda: _matmul_rotate)],
    # needs the (reverted, not committed) shading._fold_xyz: the Fresnel fold by broadcast products
    "old-fold": [("jkatana.render.shading", "_fold_xyz", _einsum_fold)],
    "old-equirect": [("jkatana.light.sampling", "equirect_direction", _old_equirect)],
}
PATCHES["old-all"] = (PATCHES["old-atan2"] + PATCHES["old-to_local"] + PATCHES["old-rotate"]
                      + PATCHES["old-equirect"])


def apply(name):
    import importlib
    saved = []
    for mod, attr, make in PATCHES[name]:
        m = importlib.import_module(mod)
        saved.append((m, attr, getattr(m, attr)))
        setattr(m, attr, make())
    return saved


def restore(saved):
    for m, attr, v in reversed(saved):
        setattr(m, attr, v)


def main(names, rounds, S):
    import jax
    import jax.numpy as jnp

    from jkatana.render import shading as sh

    b = prof.capture()
    plan, mat, env, px, cmf, key, ids = (b[k] for k in ("plan", "mat", "env", "px", "cmf", "key", "ids"))
    px = jax.tree.map(lambda a: jnp.asarray(np.asarray(a)), px)
    ids = None if ids is None else jax.tree.map(lambda a: jnp.asarray(np.asarray(a)), ids)
    P = px.normal.shape[0]
    pl = dataclasses.replace(plan, samples=S)
    print(f"P {P}, S {S}, variants {names}, rounds {rounds}; load {os.getloadavg()[0]:.2f}", flush=True)
    res = {n: [] for n in names}
    first = None
    for r in range(rounds):
        for name in (names if r % 2 == 0 else names[::-1]):
            saved = apply(name)
            try:
                jax.clear_caches()
                f = jax.jit(lambda mat, env, px, cmf, key, ids: sh.shade(pl, mat, env, None, px, cmf, key, None, ids))
                out = np.asarray(f(mat, env, px, cmf, key, ids)[0])
                ts = []
                for _ in range(3):
                    c0 = time.process_time()
                    jax.block_until_ready(f(mat, env, px, cmf, key, ids))
                    ts.append(time.process_time() - c0)
            finally:
                restore(saved)
            if first is None:
                first = out
            t = float(np.median(ts))
            res[name].append(t)
            print(f"round {r} {name:16s} CPU {t:.3f} s/call ({t / (P * S) * 1e9:.0f} ns per sample pair), "
                  f"max |ΔXYZ|/max XYZ {np.abs(out - first).max() / np.abs(first).max():.1e}  "
                  f"load {os.getloadavg()[0]:.2f}", flush=True)
    base = names[0]
    for n in names:
        v = np.array(res[n])
        ratio = v / np.array(res[base])
        print(f"{n:16s} median {np.median(v):.3f} [{v.min():.3f}, {v.max():.3f}] s; per-round ratio to {base} "
              f"median {np.median(ratio):.3f} [{ratio.min():.3f}, {ratio.max():.3f}]")


if __name__ == "__main__":
    main(sys.argv[1].split(","), int(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) > 3 else 8)
