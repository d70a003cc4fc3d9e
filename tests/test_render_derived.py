"""What a frame derives from its environment once (XYZ background map, Fresnel fold) equals the per-frame
computation to float32 rounding, and the prefiltered levels looked up side by side equal one lookup per level."""

from __future__ import annotations

import gc
import math

import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.light.envmap import texel_directions_np
from jkatana.models import Conductor
from jkatana.render import background as B, derived as D, frame as F
from jkatana.render.camera import Camera
from jkatana.render.environment import bilinear_equirect, lookup_prefiltered, lookup_prefiltered_many
from jkatana.render.film import film_weights
from jkatana.render.environment import background, build_environment
from jkatana.render.fresnel_fold import Material, fresnel_rank_for, fresnel_table
from jkatana.render.plan import Plan
from jkatana.spectral.grid import WavelengthGrid
from tests._scenes import paste_disc

GRID = WavelengthGrid(400.0, 700.0, 20.0)
CMF = film_weights(GRID).astype(np.float32)
SUN = np.array([0.35, 0.45, 0.82]) / np.linalg.norm([0.35, 0.45, 0.82])


def _sun_map(H=64, W=128):
    d = texel_directions_np(H, W)
    shape = 1.0 + 0.5 * (700.0 - GRID.wavelengths) / 300.0
    L = (0.2 + 0.6 * np.maximum(d[..., 1], 0.0) + 0.05 * d[..., 0])[..., None] * shape
    return paste_disc(L, SUN, math.radians(1.0), 2.0e4 * (0.7 + 0.3 * (GRID.wavelengths - 400.0) / 300.0), sub=8)[0]


@pytest.fixture(scope="module")
def env():
    e, fac, _ = build_environment(_sun_map(), grid=GRID, prefilter_mus=(0.02, 0.05, 0.12, 0.3), split_sun=True)
    assert not fac and e.caps is not None
    return e


def _iron():
    c = Conductor.from_table("Fe-Johnson", GRID, dtype=jnp.float32)
    return Material(fresnel_table(c.n, c.k), jnp.asarray(79000.0, jnp.float32), jnp.asarray(43000.0, jnp.float32))


def _directions(n=4000, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d[:50] = SUN + 0.002 * d[:50]  # some rays inside the cap
    return jnp.asarray(d / np.linalg.norm(d, axis=-1, keepdims=True), jnp.float32)


def test_background_from_the_xyz_map_equals_the_spectral_lookup(env):
    d = _directions()
    want, _ = background(env, d, jnp.asarray(CMF))
    got, _ = background(B.background_environment(env, CMF), d, jnp.eye(3, dtype=jnp.float32))
    assert float(jnp.max(want[:50, 1])) > 1e3  # the cap is seen
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=2e-6, atol=1e-6)


def test_derived_maps_are_reused_per_environment_and_dropped_with_it(env):
    calls = []

    def build():
        calls.append(1)
        return object()

    a = jnp.ones((4, 4))
    v1 = D.derived("t", (a,), 1, build)
    assert D.derived("t", (a,), 1, build) is v1 and len(calls) == 1
    D.derived("t", (a,), 2, build)  # another extra key: built again
    b = jnp.ones((4, 4))  # equal values, another array: built again
    D.derived("t", (b,), 1, build)
    assert len(calls) == 3
    n = len(D._DERIVED)
    del a
    gc.collect()
    assert len(D._DERIVED) == n - 2
    # a rotation changes nothing that is derived: the same XYZ map serves any rotation
    rot = jnp.asarray(np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]), jnp.float32)
    e1 = B.background_environment(env, CMF)
    import equinox as eqx

    e2 = B.background_environment(eqx.tree_at(lambda e: e.rotation, env, rot), CMF)
    assert e2.channels is e1.channels and np.array_equal(np.asarray(e2.rotation), np.asarray(rot))


def test_cached_fresnel_fold_equals_the_fold(env):
    mat = _iron()
    R, vt = fresnel_rank_for(mat.ftable, _basis_too=True)
    basis = jnp.asarray(vt[:R], jnp.float32)
    m1, e1 = D.fold_with_caps(R, mat, env, jnp.asarray(CMF), basis)
    m2, e2 = D.folded(R, mat, env, jnp.asarray(CMF), basis)
    m3, e3 = D.folded(R, Material(mat.ftable, mat.chi * 2, mat.beta), env, jnp.asarray(CMF), basis)
    assert e3.channels is e2.channels and float(m3.chi) == 2 * float(mat.chi)  # reused; scales current
    for x, y in ((m1.ftable, m2.ftable), (e1.channels, e2.channels), (e1.caps.channels, e2.caps.channels),
                 *zip(e1.prefiltered, e2.prefiltered)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_prefiltered_levels_side_by_side_equal_one_lookup_per_level(env):
    R = _directions(2000, seed=1)
    rng = np.random.default_rng(2)
    mus = [jnp.asarray(rng.uniform(0.01, 0.4, 2000), jnp.float32) for _ in range(2)]
    got = lookup_prefiltered_many(env, mus, R)
    for mu, g in zip(mus, got):
        vals = [bilinear_equirect(lvl, R @ env.rotation.T) for lvl in env.prefiltered]
        logm = np.log(np.asarray(env.prefilter_mus, np.float64))
        x = np.clip(np.log(np.asarray(mu, np.float64)), logm[0], logm[-1])
        k = np.clip(np.searchsorted(logm, x, side="right") - 1, 0, len(logm) - 2)
        t = ((x - logm[k]) / (logm[k + 1] - logm[k]))[:, None]
        v = np.stack([np.asarray(a) for a in vals])
        want = v[k, np.arange(2000)] * (1 - t) + v[k + 1, np.arange(2000)] * t
        np.testing.assert_allclose(np.asarray(g), want, rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(np.asarray(lookup_prefiltered(env, mu, R)), np.asarray(g))


@pytest.mark.slow
def test_frame_is_the_frame_without_the_derived_maps(env):
    """A prefiltered frame rendered twice (derived maps built, then reused) and with the cache cleared is
    the same frame; its background equals the spectral background to float32 rounding."""
    mat = _iron()
    cam = Camera(position=(0.0, 0.0, 4.0), fov_deg=40.0, width=40, height=30)
    maps = np.array([[[0.5, 0.05, 0.12]]], np.float32).repeat(2, 0).repeat(2, 1)
    plan = Plan(mode="prefiltered", samples=1)
    sphere = ("sphere", (0.0, 0.0, 0.0), 1.0)
    f1 = F.render_frame(plan, mat, env, None, sphere, cam, maps, CMF)
    f2 = F.render_frame(plan, mat, env, None, sphere, cam, maps, CMF)
    D._DERIVED.clear()
    f3 = F.render_frame(plan, mat, env, None, sphere, cam, maps, CMF)
    np.testing.assert_array_equal(f1.xyz, f2.xyz)
    np.testing.assert_array_equal(f1.xyz, f3.xyz)
    bg = ~f1.mask
    want, _ = background(env, jnp.asarray(cam.rays()[1][bg], jnp.float32), jnp.asarray(CMF))
    np.testing.assert_allclose(f1.xyz[bg], np.asarray(want), rtol=2e-6, atol=1e-6)


def test_background_along_the_camera_rays_made_on_the_devices(env):
    """:func:`~jkatana.render.background.background_camera` (rays made on the devices from the camera's per-column
    and per-row terms) is :func:`~jkatana.render.background.background_all` of :meth:`Camera.rays` to float32
    rounding, for an image whose pixel count does not divide by the devices."""
    cam = Camera(position=(0.3, 0.2, 4.0), look_at=(0.0, 0.1, 0.0), fov_deg=55.0, width=37, height=23)
    fwd, xr, yu = B._camera_axes(cam, np.float64)
    d = fwd + xr[None, :, :] + yu[:, None, :]
    np.testing.assert_allclose(d / np.linalg.norm(d, axis=-1, keepdims=True), cam.rays()[1], rtol=0, atol=1e-15)
    got = np.asarray(B.background_camera(env, cam, CMF, jnp.float32))[:37 * 23]
    want = np.asarray(B.background_all(env, cam.rays()[1].reshape(-1, 3), CMF, jnp.float32))[:37 * 23]
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-6)
