"""Values derived once from arrays that frames share, kept while those arrays live.

JAX arrays are immutable, so an array alive under the same identity holds the same values: what
is derived from it (the environment folded to XYZ for the background, the Fresnel fold, a
replicated copy on the devices, a frame's pixels cut into calls) need not be recomputed per frame.
:func:`derived` keys a value by the identity of its source arrays and drops it with them (weak
references); :func:`folded` is the Fresnel fold of an environment and material
(:func:`~jkatana.render.fresnel_fold.fold_fresnel`, the split caps folded too) so kept.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import weakref

import equinox as eqx
import jax
import numpy as np
from jax.sharding import NamedSharding

from jkatana.render.environment import Environment
from jkatana.render.fresnel_fold import Material, fold_fresnel


#: Maps derived from an environment (and material) once and reused by every frame that renders it:
#: ``key → (weak references to the source arrays, value)``; an entry leaves when a source array does.
_DERIVED: dict = {}


def derived(kind: str, sources: tuple, extra, build, keep: int | None = None):
    """``build()``, computed once per identity of the ``sources`` arrays (and the hashable ``extra``).

    JAX arrays are immutable, so an array alive under the same identity holds the
    same values: what is derived from it (the environment folded to XYZ for the
    background, the Fresnel fold) need not be recomputed per frame. The cache holds
    weak references only; an entry is dropped when any source array is collected.
    ``keep``: at most that many entries of this ``kind`` are held (the least recently used leaves first),
    for values that are large beside their sources.
    """
    key = (kind, tuple(id(a) for a in sources), extra)
    hit = _DERIVED.get(key)
    if hit is not None and all(r() is a for r, a in zip(hit[0], sources)):
        if keep is not None:  # most recently used last
            _DERIVED[key] = _DERIVED.pop(key)
        return hit[1]
    value = build()

    def drop(_, k=key, cache=_DERIVED):  # the dict bound here: at interpreter exit the module's globals are gone
        cache.pop(k, None)

    _DERIVED[key] = (tuple(weakref.ref(a, drop) for a in sources), value)
    if keep is not None:
        same = [k for k in _DERIVED if k[0] == kind]
        for k in same[:max(0, len(same) - keep)]:
            _DERIVED.pop(k, None)
    return value


def replicated(tree, sharding: NamedSharding):
    """``jax.device_put(tree, sharding)`` with each JAX-array leaf's copy kept while the leaf lives
    (:func:`derived`): an environment or material that frames share is put on every device once, not per
    frame. Other leaves (NumPy arrays, which may change in place) are put on every call."""
    leaves, treedef = jax.tree.flatten(tree)
    where = (tuple(d.id for d in sharding.mesh.devices.flat), sharding.spec)
    out, todo = list(leaves), []
    for i, a in enumerate(leaves):
        hit = _DERIVED.get(("replicated", (id(a),), where)) if isinstance(a, jax.Array) else None
        if hit is not None and hit[0][0]() is a:
            out[i] = hit[1]
        else:
            todo.append(i)
    if todo:
        put = jax.device_put([leaves[i] for i in todo], sharding)
        for i, b in zip(todo, put):
            out[i] = b
            if isinstance(leaves[i], jax.Array) and b is not leaves[i]:  # (a copy: it holds no reference to its source)
                derived("replicated", (leaves[i],), where, lambda b=b: b)
    return jax.tree.unflatten(treedef, out)


def digest(a) -> str:
    """A content key of ``a`` (BLAKE2b of its bytes, with its shape and dtype): for values keyed by an array's
    contents rather than its identity (NumPy arrays, which may change in place)."""
    b = np.ascontiguousarray(np.asarray(a))
    return hashlib.blake2b(b.tobytes(), digest_size=16).hexdigest() + str(b.shape) + str(b.dtype)


def immutable(a) -> bool:
    """Whether ``a``'s values are fixed while it lives (a JAX array, or a read-only NumPy array that owns its
    data): what is derived from it may be keyed by its identity (:func:`derived`)."""
    if isinstance(a, jax.Array):
        return True
    return isinstance(a, np.ndarray) and not a.flags.writeable and a.flags.owndata


def _env_sources(env: Environment) -> tuple:
    return ((env.channels, env.basis, *env.prefiltered, *(lvl for lv in env.lobe_prefiltered for lvl in lv))
            + (() if env.caps is None else (env.caps.channels,)))


def fold_with_caps(rank: int, mat: Material, env: Environment, cmf, basis=None) -> tuple[Material, Environment]:
    """:func:`~jkatana.render.shading.fold_fresnel`, the environment's split caps folded too.

    A cap's radiance is one more texel for the fold (a per-texel linear map), so
    its channels are folded as a row of texels through the same function.
    """
    mat2, env2 = fold_fresnel(rank, mat, env, cmf, basis)
    if env.caps is None:
        return mat2, env2
    row = dataclasses.replace(env, channels=env.caps.channels[None], prefiltered=(), caps=None, lobe_prefiltered=())
    _, folded = fold_fresnel(rank, mat, row, cmf, basis)
    return mat2, eqx.tree_at(lambda e: e.caps.channels, env2, folded.channels[0])


@functools.lru_cache(maxsize=8)
def _compiled_fold(rank: int):
    return jax.jit(lambda mat, env, cmf, basis: fold_with_caps(rank, mat, env, cmf, basis))


def folded(rank: int, mat: Material, env: Environment, cmf, basis) -> tuple[Material, Environment]:
    """:func:`fold_with_caps` of ``(mat, env)``, computed once per (environment, material, CMFs, rank):
    only the environment's rotation and the material's scales are taken from the arguments each call."""
    def build():
        m2, e2 = _compiled_fold(rank)(mat, env, cmf, basis)
        return (m2.ftable, e2.channels, e2.prefiltered, e2.lobe_prefiltered,
                None if e2.caps is None else e2.caps.channels)

    a, ch, pre, lpre, capch = derived("fresnel-fold", (mat.ftable, *_env_sources(env)), (rank, digest(cmf)), build)
    env2 = eqx.tree_at(lambda e: (e.channels, e.prefiltered), env, (ch, pre))
    if lpre:
        env2 = eqx.tree_at(lambda e: e.lobe_prefiltered, env2, lpre)
    if capch is not None:
        env2 = eqx.tree_at(lambda e: e.caps.channels, env2, capch)
    return Material(a, mat.chi, mat.beta), env2
