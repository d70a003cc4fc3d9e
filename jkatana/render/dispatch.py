"""Shading a frame's pixels across the local devices: compiled programs, call sizes, dispatch.

The pixel axis is split into fixed-size calls of ``devices × chunk`` pixels,
each call running :func:`jkatana.render.shading.shade` under
``jax.shard_map`` over a 1-D device mesh (on CPU, several host devices come
from ``XLA_FLAGS=--xla_force_host_platform_device_count=N``, which the CLI
sets to the core count). Fixed call shapes mean one compilation per
(plan, chunk) whatever the view's coverage (a frame whose pixels do not depend on
the call layout — a deterministic integrator's, or MIS with pixel ids — takes for its last call the
smallest of a finer ladder of sizes that holds the remaining pixels: one program
per size); JAX's asynchronous dispatch keeps both devices busy while Python queues
the next call. What calls share (the environment and material on every device, a view's pixels cut
into calls) is sent once (:mod:`jkatana.render.derived`). A prefiltered frame's split caps (a sun) get a
pass of their own over the pixels they can reach (:func:`~jkatana.render.caps.cap_pixels`)
when those are few (:data:`CAP_PASS_MAX`). With occluders, each call's traced directions are
ray-cast on the host first (:func:`~jkatana.render.occlusion.visibility`).
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec as PS

from jkatana.render.caps import _caps, cap_pixels, cap_rule_for
from jkatana.render.derived import derived, folded, immutable, replicated
from jkatana.render.environment import Environment
from jkatana.render.fresnel_fold import FRESNEL_RANK_TOL, FRESNEL_RANK_TOL_SAMPLED, Material, fresnel_rank_for
from jkatana.render.integrators import integrator_for
from jkatana.render.occlusion import visibility
from jkatana.render.plan import Light, Pixels, Plan
from jkatana.render.points import PixelIds
from jkatana.render.shading import ray_directions, shade, shade_caps

DEFAULT_CHUNK = 16384


#: Largest share of a prefiltered frame's pixels that :func:`~jkatana.render.caps.cap_pixels` may keep for the
#: split caps to get a pass of their own (:func:`shade_pixels`): a pass costs one more dispatch and repeats
#: the pixel's frame, while the cap rule's cost is per pixel.
CAP_PASS_MAX = 0.6


#: Per-device sizes of a prefiltered frame's last call (:func:`shade_pixels`): 1024 · 2^(k/2), rounded to 512.
_TAIL_LADDER = (1024, 1536, 2048, 3072, 4096, 6144, 8192, 12288)


def devices():
    return jax.local_devices()


@functools.lru_cache(maxsize=32)
def _compiled(plan: Plan, n_dev: int, chunk: int, caps_only: bool = False):
    """:func:`~jkatana.render.shading.shade` (or, ``caps_only``, :func:`~jkatana.render.shading.shade_caps`)
    jitted over ``n_dev`` devices, ``chunk`` pixels each: ``(function, mesh)``."""
    mesh = jax.make_mesh((n_dev,), ("d",), devices=jax.local_devices()[:n_dev])

    def per_device(mat, env, lights, px, vis, cmf, key, ids):
        if caps_only:
            return shade_caps(plan, mat, env, px, cmf, vis)
        if ids is None:  # with pixel ids the scramble comes from the frame key and the pixel index
            key = jax.random.fold_in(key, jax.lax.axis_index("d"))
        return shade(plan, mat, env, lights, px, cmf, key, vis, ids)

    f = jax.shard_map(per_device, mesh=mesh,
                      in_specs=(PS(), PS(), PS(), PS("d"), PS("d"), PS(), PS(), PS("d")),
                      out_specs=(PS("d"), PS("d") if plan.spectral and not plan.factored else PS()),
                      check_vma=False)
    return jax.jit(f), mesh


@functools.lru_cache(maxsize=32)
def _compiled_rays(plan: Plan, n_dev: int, chunk: int):
    """The directions :func:`shade` will trace, with the same per-device key (visibility pass)."""
    mesh = jax.make_mesh((n_dev,), ("d",), devices=jax.local_devices()[:n_dev])

    def per_device(env, lights, px, key, ids):
        if ids is None:
            key = jax.random.fold_in(key, jax.lax.axis_index("d"))
        return ray_directions(plan, env, lights, px, key, ids)

    f = jax.shard_map(per_device, mesh=mesh, in_specs=(PS(), PS(), PS("d"), PS(), PS("d")), out_specs=PS("d"),
                      check_vma=False)
    return jax.jit(f)


def resolve_plan(plan: Plan, mat: Material) -> Plan:
    """``plan`` with ``fresnel_rank=None`` decided on the host: the smallest rank of the material's
    Fresnel table within :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL_SAMPLED` in the sampled modes
    (:data:`~jkatana.render.plan.SAMPLED_MODES`, whose Monte Carlo noise dwarfs that bias) and
    :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL` in the others, where the plan allows folding
    (no spectral output, no lights, not ``factored``, a lobe or mirror to shade), else 0 (full spectra).
    An explicit ``fresnel_rank`` (0: full spectra) is kept."""
    if plan.fresnel_rank is not None:
        return plan
    ok = not (plan.spectral or plan.lights or plan.factored)
    tol = FRESNEL_RANK_TOL_SAMPLED if integrator_for(plan.mode).sampled else FRESNEL_RANK_TOL
    return dataclasses.replace(plan, fresnel_rank=fresnel_rank_for(mat.ftable, tol) if ok else 0)


#: The values padding pixels take (a lit, upward-facing, mid-width pixel: finite everywhere, then discarded).
_PAD_PIXEL = ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, 1.0), 1.0, 0.05, 0.05)


@functools.partial(jax.jit, static_argnums=1)
def _split_calls(px: Pixels, counts: tuple):
    """``px`` padded with :data:`_PAD_PIXEL` to ``sum(counts)`` rows and cut into calls of ``counts`` rows:
    one dispatch for what would otherwise be a dozen eager operations per call."""
    pad = sum(counts) - px.normal.shape[0]
    full = Pixels(*(jnp.concatenate([a, jnp.broadcast_to(jnp.asarray(fill, a.dtype), (pad,) + a.shape[1:])])
                    for a, fill in zip(px, _PAD_PIXEL)))
    starts = np.cumsum((0,) + counts)
    return [jax.tree.map(lambda a, s=s, n=n: a[s:s + n], full) for s, n in zip(starts[:-1], counts)]


def shade_pixels(plan: Plan, mat: Material, env: Environment, lights: Light | None, px: Pixels,
                 cmf, key, *, n_devices: int | None = None, chunk: int = DEFAULT_CHUNK, occluders=None,
                 ids: PixelIds | None = None):
    """Shade ``P`` pixels in fixed-size sharded calls; returns ``(xyz (P, 3), spectra or None)`` as NumPy.

    ``ids`` (:class:`~jkatana.render.shading.PixelIds`, with ``plan.subpixels > 1``): the output pixel and
    subpixel of each G-buffer sample; their points then come from one per-pixel sequence whose scramble
    depends on ``key`` and the pixel index only (not on the chunk or device).

    With ``plan.visibility`` each call first computes the directions it will
    trace (:func:`~jkatana.render.shading.ray_directions`, jitted), ray-casts
    them on the host against ``occluders`` (:class:`~jkatana.render.gbuffer.Occluders`)
    and passes the :class:`~jkatana.render.shading.Visibility` to the jitted
    shader. Without it there is no visibility step at all.
    """
    if plan.visibility and occluders is None:
        raise ValueError("plan.visibility needs occluders")
    plan = resolve_plan(plan, mat)
    split_caps = integrator_for(plan.mode).deterministic and _caps(env) is not None and not plan.visibility
    # the pixels the caps can reach (cap_pixels), dispatched first: computed while the host picks the rule
    near = _compiled_cap_pixels(dataclasses.replace(plan, cap_rule=None))(env, px) if split_caps else None
    if plan.cap_rule is None and env.caps is not None and integrator_for(plan.mode).cap_rule:
        plan = dataclasses.replace(plan, cap_rule=cap_rule_for(plan, env, px))
    if plan.fresnel_rank and not plan.factored:  # once per frame: F·E·CMF folded into a 3R-channel map
        _, vt = fresnel_rank_for(mat.ftable, _basis_too=True)  # cached host SVD
        mat, env = folded(plan.fresnel_rank, mat, env, jnp.asarray(cmf, px.normal.dtype),
                          jnp.asarray(vt[:plan.fresnel_rank], px.normal.dtype))
    n_dev = n_devices or len(jax.local_devices())
    # the caps on their own pass over the pixels where they can matter, when those are few enough to pay
    # for the pass; else in the one pass, as every other term
    near = np.flatnonzero(np.asarray(near)) if split_caps else None
    if near is None or len(near) > CAP_PASS_MAX * px.normal.shape[0]:
        return _collect(_dispatch(plan, mat, env, lights, px, cmf, key, n_dev, chunk, occluders, ids), px)
    no_caps = eqx.tree_at(lambda e: e.caps, env, None)
    rest = _dispatch(plan, mat, no_caps, lights, px, cmf, key, n_dev, chunk, occluders, ids)
    on_caps = None
    if len(near):
        take = np.full(_bucket(plan, len(near), n_dev, chunk), near[-1])
        take[:len(near)] = near
        on_caps = _dispatch(plan, mat, env, lights, _take(px, jnp.asarray(take, jnp.int32)), cmf, key, n_dev, chunk,
                            occluders, None, caps_only=True)
    xyz, spec = _collect(rest, px)
    if on_caps is not None:
        cx, cs = _collect(on_caps, px, len(near))
        xyz[near] += cx
        if spec is not None and cs is not None:
            spec[near] += cs
    return xyz, spec


@functools.lru_cache(maxsize=32)
def _compiled_cap_pixels(plan: Plan):
    """:func:`~jkatana.render.caps.cap_pixels` of ``plan``, jitted."""
    return jax.jit(lambda env, px: cap_pixels(plan, env, px))


@jax.jit
def _take(px: Pixels, idx: jax.Array) -> Pixels:
    """The pixels ``idx`` of ``px`` (one dispatch)."""
    return jax.tree.map(lambda a: a[idx], px)


def _call_sizes(plan: Plan, P: int, n_dev: int, chunk: int, fine_tail: bool | None = None) -> tuple[int, list[int]]:
    """``(chunk, per-device pixels of each call)`` for ``P`` pixels: calls of ``chunk`` from a fixed ladder
    (1024 · 4^k, capped at ``chunk``), so that views with different coverage reuse one compiled program
    instead of compiling per pixel count; with ``fine_tail`` (default: a prefiltered ``plan``) the last call
    from the finer :data:`_TAIL_LADDER` (steps ≤ 1.5×), padding the remainder instead of a whole call.

    A frame may take the fine tail when its pixels' values do not depend on the call layout
    (:func:`_layout_free`); else the calls stay whole, as the streams follow them."""
    fine_tail = integrator_for(plan.mode).deterministic if fine_tail is None else fine_tail
    need = -(-P // n_dev)
    size = 1024
    while size < need and size < chunk:
        size *= 4
    chunk = int(min(size, chunk))
    call = n_dev * chunk
    n_calls = max(1, -(-P // call))
    sizes = [chunk] * n_calls
    if fine_tail:
        rest = -(-(P - (n_calls - 1) * call) // n_dev)
        sizes[-1] = min(s for s in _TAIL_LADDER + (chunk,) if s >= min(rest, chunk))
    return chunk, sizes


def _layout_free(plan: Plan, ids: PixelIds | None) -> bool:
    """Whether a pixel's value is independent of the call and device that shade it: the prefiltered mode
    (deterministic), and the MIS modes (``"reference"``, ``"lowrank"``) with :class:`PixelIds` and
    ``plan.subpixels > 1`` (their points come from the pixel index and the frame key:
    :func:`~jkatana.render.points.mis_offset`). The paper's jittered rays and the MIS modes without pixel ids
    draw per call."""
    integrator = integrator_for(plan.mode)
    return integrator.deterministic or (integrator.sampled and ids is not None and plan.subpixels > 1)


def _bucket(plan: Plan, n: int, n_dev: int, chunk: int) -> int:
    """The pixel count :func:`_call_sizes` pads ``n`` pixels of a prefiltered ``plan`` to: a subset gathered at
    that size adds no padding of its own, and its programs are one per size of the ladder."""
    return n_dev * sum(_call_sizes(plan, n, n_dev, chunk)[1])


def _dispatch(plan: Plan, mat: Material, env: Environment, lights: Light | None, px: Pixels, cmf, key, n_dev: int,
              chunk: int, occluders, ids: PixelIds | None, caps_only: bool = False) -> list:
    """:func:`shade_pixels`' sharded calls over ``px``, dispatched (asynchronous): their outputs."""
    P = px.normal.shape[0]
    chunk, sizes = _call_sizes(plan, P, n_dev, chunk, _layout_free(plan, ids))
    n_calls = len(sizes)
    dtype = px.normal.dtype
    ids = ids if ids is not None and plan.subpixels > 1 else None
    f, mesh = _compiled(plan, n_dev, chunk, caps_only)
    rep = NamedSharding(mesh, PS())
    split = NamedSharding(mesh, PS("d"))
    calls, call_ids = _call_inputs(px, ids, tuple(n_dev * s for s in sizes), split)
    mat, env, lights = replicated((mat, env, lights), rep)
    cmf = jax.device_put(jnp.asarray(cmf, dtype), rep)
    outs = []
    rays_f = _compiled_rays(plan, n_dev, chunk) if plan.visibility else None
    # with pixel ids every call takes the frame's key (the scramble comes from the pixel index): sent once
    frame_key = jax.device_put(key, rep) if ids is not None else None
    for i in range(n_calls):
        if sizes[i] != chunk:
            f = _compiled(plan, n_dev, sizes[i], caps_only)[0]
        chunk_px, chunk_ids = calls[i], call_ids[i]
        ckey = frame_key if ids is not None else jax.device_put(jax.random.fold_in(key, i), rep)
        vis = None
        if rays_f is not None:
            rays = jax.tree.map(np.asarray, rays_f(env, lights, chunk_px, ckey, chunk_ids))
            vis = jax.device_put(jax.tree.map(lambda a: jnp.asarray(a, dtype),
                                              visibility(occluders, rays, np.asarray(chunk_px.position),
                                                         np.asarray(chunk_px.normal))), split)
        outs.append(f(mat, env, lights, chunk_px, vis, cmf, ckey, chunk_ids))
    return outs


def _call_inputs(px: Pixels, ids: PixelIds | None, counts: tuple, split: NamedSharding) -> tuple[list, list]:
    """``(pixels, pixel ids or None)`` of each of :func:`_dispatch`'s calls (``counts`` rows each), padded and
    split across the devices; kept while ``px`` and ``ids`` live (:func:`~jkatana.render.derived.derived`), so
    that frames of one view (:func:`~jkatana.render.frame._frame_pixels`) cut and send their pixels once."""
    def build():
        calls = jax.device_put(_split_calls(px, counts), split)
        if ids is None:
            return calls, [None] * len(counts)
        pad = sum(counts) - px.normal.shape[0]
        pid = np.concatenate([np.asarray(ids.pixel, np.uint32), np.zeros(pad, np.uint32)])
        sub = np.concatenate([np.asarray(ids.subpixel, np.int32), np.zeros(pad, np.int32)])
        starts = np.cumsum((0,) + counts)
        return calls, jax.device_put([PixelIds(pid[a:b], sub[a:b]) for a, b in zip(starts[:-1], starts[1:])], split)

    sources = tuple(px) + (() if ids is None else tuple(ids))
    if not all(immutable(a) for a in sources):
        return build()
    where = (counts, tuple(d.id for d in split.mesh.devices.flat))
    return derived("call-inputs", sources, where, build, keep=4)


def _collect(outs: list, px: Pixels, P: int | None = None):
    """The first ``P`` (default: all of ``px``'s) rows of :func:`_dispatch`'s outputs as NumPy
    ``(xyz, spectra or None)``."""
    P = px.normal.shape[0] if P is None else P
    xyz = np.concatenate([np.asarray(o[0]) for o in outs])[:P]
    spec = None
    if outs[0][1] is not None:
        spec = np.concatenate([np.asarray(o[1]) for o in outs])[:P]
    return xyz, spec
