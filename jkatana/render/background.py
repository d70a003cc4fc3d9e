"""The environment seen directly: each camera ray's background, in XYZ or as spectra.

A frame's pixels that see no object show the environment along their camera ray (caps
included). XYZ-only frames look up the environment folded to three channels
(:func:`background_environment`, kept per environment: :mod:`jkatana.render.derived`) across the
local devices, the rays made on the devices from the camera's per-column and per-row terms
(:func:`background_camera`) or sent (:func:`background_all`); a spectral frame looks up the
spectral map (:func:`background_spectral`).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec as PS

from jkatana.render.camera import Camera
from jkatana.render.derived import derived, digest, replicated
from jkatana.render.environment import Environment, background, xyz_environment


def background_environment(env: Environment, cmf) -> Environment:
    """:func:`~jkatana.render.environment.xyz_environment` of ``env``, computed once per (environment, CMFs);
    the rotation is ``env``'s."""
    sources = (env.channels, env.basis) + (() if env.caps is None else (env.caps.channels,))
    xyz = derived("background-xyz", sources, digest(cmf), lambda: xyz_environment(env, jnp.asarray(cmf)))
    return eqx.tree_at(lambda e: e.rotation, xyz, env.rotation)


@functools.lru_cache(maxsize=1)
def background_spectral():
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
