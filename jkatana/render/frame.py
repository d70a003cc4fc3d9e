"""One frame: G-buffer → per-pixel materials → jitted shading across local devices → XYZ image.

The pixel axis is split into fixed-size calls of ``devices × chunk`` pixels,
each call running :func:`jkatana.render.shading.shade` under
``jax.shard_map`` over a 1-D device mesh (on CPU, several host devices come
from ``XLA_FLAGS=--xla_force_host_platform_device_count=N``, which the CLI
sets to the core count). Fixed call shapes mean one compilation per
(plan, chunk) whatever the view's coverage (a frame whose pixels do not depend on
the call layout — prefiltered, or MIS with pixel ids — takes for its last call the
smallest of a finer ladder of sizes that holds the remaining pixels: one program
per size); JAX's asynchronous dispatch keeps both devices busy while Python queues
the next call. What frames of one view share (an immutable G-buffer's pixels, the
environment and material on every device) is sent once (:func:`derived`). A prefiltered frame's split caps (a sun) get a pass
of their own over the pixels they can reach (:func:`~jkatana.render.caps.cap_pixels`)
when those are few (:data:`CAP_PASS_MAX`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import time
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec as PS

from jkatana.render.camera import Camera
from jkatana.render.caps import _caps, cap_pixels, cap_rule_for
from jkatana.render.environment import Environment, background, xyz_environment
from jkatana.render.fresnel_fold import FRESNEL_RANK_TOL, FRESNEL_RANK_TOL_SAMPLED, Material, fold_fresnel, fresnel_rank_for
from jkatana.render.gbuffer import GBuffer, gbuffer_mesh, gbuffer_sphere
from jkatana.render.integrators import integrator_for
from jkatana.render.plan import Light, Pixels, Plan, Visibility
from jkatana.render.points import PixelIds
from jkatana.render.shading import ray_directions, shade, shade_caps

DEFAULT_CHUNK = 16384

#: Largest share of a prefiltered frame's pixels that :func:`~jkatana.render.caps.cap_pixels` may keep for the
#: split caps to get a pass of their own (:func:`shade_pixels`): a pass costs one more dispatch and repeats
#: the pixel's frame, while the cap rule's cost is per pixel.
CAP_PASS_MAX = 0.6

#: Per-device sizes of a prefiltered frame's last call (:func:`shade_pixels`): 1024 · 2^(k/2), rounded to 512.
_TAIL_LADDER = (1024, 1536, 2048, 3072, 4096, 6144, 8192, 12288)


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


def visibility(occluders, rays, position, normal) -> Visibility:
    """Host step: ray-cast every direction of ``rays`` (NumPy :class:`Rays`) from the pixels against ``occluders``.

    Origins are the G-buffer positions nudged along the normal (relative to the
    scene's scale) so that an occluder touching the surface does not shadow it
    through round-off.
    """
    pos = np.asarray(position, np.float64)
    eps = 1e-5 * max(1.0, float(np.abs(pos).max(initial=0.0)))
    origin = pos + eps * np.asarray(normal, np.float64)

    def cast(d, max_dist=None):
        P, K = d.shape[0], d.shape[1]
        if K == 0:
            return np.ones((P, 0), np.float32)
        o = np.broadcast_to(origin[:, None, :], d.shape)
        md = None if max_dist is None else np.asarray(max_dist).reshape(-1)
        return occluders.visible(o.reshape(-1, 3), np.asarray(d).reshape(-1, 3), md, eps).reshape(P, K)

    return Visibility(cast(np.asarray(rays.mirror)[:, None])[:, 0], cast(np.asarray(rays.lobe)),
                      cast(np.asarray(rays.env)), cast(np.asarray(rays.lights), np.asarray(rays.light_dist)))


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


def _digest(a) -> str:
    b = np.ascontiguousarray(np.asarray(a))
    return hashlib.blake2b(b.tobytes(), digest_size=16).hexdigest() + str(b.shape) + str(b.dtype)


def _env_sources(env: Environment) -> tuple:
    return ((env.channels, env.basis, *env.prefiltered, *(lvl for lv in env.lobe_prefiltered for lvl in lv))
            + (() if env.caps is None else (env.caps.channels,)))


def folded(rank: int, mat: Material, env: Environment, cmf, basis) -> tuple[Material, Environment]:
    """:func:`fold_with_caps` of ``(mat, env)``, computed once per (environment, material, CMFs, rank):
    only the environment's rotation and the material's scales are taken from the arguments each call."""
    def build():
        m2, e2 = _compiled_fold(rank)(mat, env, cmf, basis)
        return (m2.ftable, e2.channels, e2.prefiltered, e2.lobe_prefiltered,
                None if e2.caps is None else e2.caps.channels)

    a, ch, pre, lpre, capch = derived("fresnel-fold", (mat.ftable, *_env_sources(env)), (rank, _digest(cmf)), build)
    env2 = eqx.tree_at(lambda e: (e.channels, e.prefiltered), env, (ch, pre))
    if lpre:
        env2 = eqx.tree_at(lambda e: e.lobe_prefiltered, env2, lpre)
    if capch is not None:
        env2 = eqx.tree_at(lambda e: e.caps.channels, env2, capch)
    return Material(a, mat.chi, mat.beta), env2


def background_environment(env: Environment, cmf) -> Environment:
    """:func:`~jkatana.render.environment.xyz_environment` of ``env``, computed once per (environment, CMFs);
    the rotation is ``env``'s."""
    sources = (env.channels, env.basis) + (() if env.caps is None else (env.caps.channels,))
    xyz = derived("background-xyz", sources, _digest(cmf), lambda: xyz_environment(env, jnp.asarray(cmf)))
    return eqx.tree_at(lambda e: e.rotation, xyz, env.rotation)


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


@functools.lru_cache(maxsize=1)
def _compiled_background_spectral():
    """The background with its spectra (spectral output); XYZ-only frames use :func:`background_all`."""
    return jax.jit(lambda env, d, cmf: background(env, d, cmf, True))


@functools.lru_cache(maxsize=8)
def _compiled_background_xyz(n_dev: int):
    mesh = jax.make_mesh((n_dev,), ("d",), devices=jax.local_devices()[:n_dev])
    f = jax.shard_map(lambda env, d: background(env, d, jnp.eye(3, dtype=d.dtype))[0], mesh=mesh,
                      in_specs=(PS(), PS("d")), out_specs=PS("d"), check_vma=False)
    return jax.jit(f), mesh


def _camera_axes(camera: Camera, dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`Camera.pixel_axes` in ``dtype``: the devices make the rays from them (``tests/test_render_derived.py``
    holds those rays to :meth:`Camera.rays`' to float32 rounding)."""
    return tuple(a.astype(dtype) for a in camera.pixel_axes())


@functools.lru_cache(maxsize=8)
def _compiled_background_camera(n_dev: int, width: int, height: int):
    """The background along every camera ray, the rays made on the devices (each its own range of pixels)."""
    mesh = jax.make_mesh((n_dev,), ("d",), devices=jax.local_devices()[:n_dev])
    per = -(-width * height // n_dev)

    def per_device(env, fwd, x_right, y_up):
        i = jax.lax.axis_index("d").astype(jnp.int32) * per + jnp.arange(per, dtype=jnp.int32)
        row, col = jnp.divmod(jnp.minimum(i, width * height - 1), width)
        d = fwd + x_right[col] + y_up[row]
        d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
        return background(env, d, jnp.eye(3, dtype=d.dtype))[0]

    f = jax.shard_map(per_device, mesh=mesh, in_specs=(PS(), PS(), PS(), PS()), out_specs=PS("d"),
                      check_vma=False)
    return jax.jit(f), mesh


def background_camera(env: Environment, camera: Camera, cmf, dtype, n_devices: int | None = None) -> jax.Array:
    """:func:`background_all` along the camera's primary rays (:meth:`Camera.rays`), which the devices
    make themselves from the camera's per-column and per-row terms (same directions to float32
    rounding): the host neither builds nor sends the ``H × W`` rays."""
    n_dev = n_devices or len(jax.local_devices())
    f, mesh = _compiled_background_camera(n_dev, int(camera.width), int(camera.height))
    env3 = replicated(background_environment(env, np.asarray(cmf, dtype)), NamedSharding(mesh, PS()))
    return f(env3, *jax.device_put(_camera_axes(camera, dtype), NamedSharding(mesh, PS())))


def background_all(env: Environment, rays: np.ndarray, cmf, dtype, n_devices: int | None = None) -> jax.Array:
    """XYZ of the environment along camera ``rays (n, 3)`` (caps included), split across the local devices
    and dispatched asynchronously: a ``(n', 3)`` device array, ``n' ≥ n`` (padded to the devices).

    Looks up :func:`background_environment` (3 channels) instead of the spectral map.
    """
    n_dev = n_devices or len(jax.local_devices())
    f, mesh = _compiled_background_xyz(n_dev)
    n = rays.shape[0]
    pad = -n % n_dev
    d = np.asarray(rays, dtype)
    if pad:
        d = np.concatenate([d, np.tile(np.asarray([[0.0, 0.0, 1.0]], dtype), (pad, 1))])
    env3 = replicated(background_environment(env, np.asarray(cmf, dtype)), NamedSharding(mesh, PS()))
    return f(env3, jax.device_put(d, NamedSharding(mesh, PS("d"))))


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
    split across the devices; kept while ``px`` and ``ids`` live (:func:`derived`), so that frames of one
    view (:func:`_frame_pixels`) cut and send their pixels once."""
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
    if not all(_immutable(a) for a in sources):
        return build()
    where = (counts, tuple(d.id for d in split.mesh.devices.flat))
    return derived("call-inputs", sources, where, build, keep=4)


def _immutable(a) -> bool:
    """Whether ``a``'s values are fixed while it lives (a JAX array, or a read-only NumPy array that owns its
    data): what is derived from it may be keyed by its identity (:func:`derived`)."""
    if isinstance(a, jax.Array):
        return True
    return isinstance(a, np.ndarray) and not a.flags.writeable and a.flags.owndata


def _collect(outs: list, px: Pixels, P: int | None = None):
    """The first ``P`` (default: all of ``px``'s) rows of :func:`_dispatch`'s outputs as NumPy
    ``(xyz, spectra or None)``."""
    P = px.normal.shape[0] if P is None else P
    xyz = np.concatenate([np.asarray(o[0]) for o in outs])[:P]
    spec = None
    if outs[0][1] is not None:
        spec = np.concatenate([np.asarray(o[1]) for o in outs])[:P]
    return xyz, spec


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
    same pixels each frame for the same maps: they are kept (:func:`derived`, the maps by value unless a JAX
    array), so that a batch of frames of one view sends them to the devices once."""
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
    if not (keep.all() and all(_immutable(a) or a.base is not None and _immutable(a.base) for a in sources)):
        return build()
    if isinstance(maps, jax.Array):
        sources, maps_key = sources + (maps,), None
    else:
        maps_key = _digest(maps)
    return derived("frame-pixels", sources, (maps_key, np.dtype(dtype).str, ss), build, keep=4)


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
    plan = resolve_plan(plan, mat)
    ss = int(supersample)
    if ss < 1:
        raise ValueError(f"supersample must be ≥ 1, got {supersample}")
    plan = dataclasses.replace(plan, subpixels=ss * ss)
    spectral_out = plan.spectral and not plan.factored
    bg_all = None
    if not spectral_out:
        # every pixel's background, dispatched first: the devices look it up while the host casts the G-buffer
        if gb is not None:
            bg_all = background_all(env, gb.ray.reshape(-1, 3), cmf, dtype, n_devices)
        else:
            bg_all = background_camera(env, camera, cmf, dtype, n_devices)
    if gb is None:
        gb = gbuffer(geometry, camera)
    rays0, cast0 = (occluders.rays_cast, occluders.cast_s) if occluders is not None else (0, 0.0)
    H, W = gb.mask.shape
    if H % ss or W % ss:
        raise ValueError(f"supersample {ss}: the camera's {W}×{H} image is not a whole number of pixels")
    m = gb.mask.reshape(-1)
    keep = np.ones(len(gb.index), bool)  # the G-buffer's hits that are shaded
    blocked = np.zeros(H * W, bool)
    if plan.visibility and occluders is not None:
        # primary visibility: an occluder in front of the object (or of the sky) hides it
        origin, _ = camera.rays()
        d_occ = occluders.first_hit(np.broadcast_to(origin, (H * W, 3)), gb.ray.reshape(-1, 3))
        d_obj = np.full(H * W, np.inf)
        d_obj[gb.index] = np.linalg.norm(gb.hit_position - origin, axis=-1)
        blocked = d_occ < d_obj
        m = m & ~blocked
        keep = ~blocked[gb.index]
    t1, c1 = time.perf_counter(), time.process_time()
    sel = gb.index[keep]
    spectra = np.zeros((H * W, env.basis.shape[-1]), np.float32) if spectral_out else None
    key = jax.random.PRNGKey(seed)
    x = None
    if len(sel):
        px, ids = _frame_pixels(gb, keep, maps, dtype, ss)
        x, s = shade_pixels(plan, mat, env, lights, px, cmf, key, n_devices=n_devices, chunk=chunk,
                            occluders=occluders, ids=ids)
        if spectra is not None and s is not None:
            spectra[sel] = s
    t2, c2 = time.perf_counter(), time.process_time()
    bg = ~m & ~blocked
    if bg_all is not None:
        # every pixel's background, then the shaded pixels over it and the occluded ones black (the hit
        # pixels are the shaded and the occluded ones): one copy, not a gather and a scatter of the sky
        xyz = np.array(np.asarray(bg_all)[:H * W], np.float32)
        xyz[blocked] = 0.0
    else:
        xyz = np.zeros((H * W, 3), np.float32)
        if bg.any():
            bx, bs = _compiled_background_spectral()(env, jnp.asarray(gb.ray.reshape(-1, 3)[bg], dtype),
                                                      jnp.asarray(cmf, dtype))
            spectra[bg] = np.asarray(bs)
            xyz[bg] = np.asarray(bx)
    if x is not None:
        xyz[sel] = x
    t3, c3 = time.perf_counter(), time.process_time()
    # wall seconds per stage, and the process's CPU seconds over each (all threads: host and devices)
    timing = {"gbuffer_s": t1 - t0, "shade_s": t2 - t1, "background_s": t3 - t2, "total_s": t3 - t0,
              "gbuffer_cpu_s": c1 - c0, "shade_cpu_s": c2 - c1, "background_cpu_s": c3 - c2, "total_cpu_s": c3 - c0}
    if occluders is not None:
        timing["visibility_rays"] = occluders.rays_cast - rays0
        timing["visibility_cast_s"] = occluders.cast_s - cast0
    stats = {"pixels_shaded": int(len(sel)), "coverage": float(len(sel) / (H * W)),
             "occluded_pixels": int(blocked.sum()), "fresnel_rank": int(plan.fresnel_rank)}
    return Frame(xyz.reshape(H, W, 3), m.reshape(H, W), None if spectra is None else spectra.reshape(H, W, -1),
                 timing, stats)
