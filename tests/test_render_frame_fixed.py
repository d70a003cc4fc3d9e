"""A frame's fixed part: the sphere's G-buffer kept per view, pixels and tables sent to the devices once per
view, and the pixel-id frames' last call from the fine tail ladder — each giving the frame it replaces."""

from __future__ import annotations

import gc

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import NamedSharding, PartitionSpec as PS

from jkatana.models import Conductor
from jkatana.render import derived as D, dispatch, frame as F
from jkatana.render.camera import Camera
from jkatana.render.film import film_weights
from jkatana.render.gbuffer import gbuffer_sphere
from jkatana.render.environment import build_environment
from jkatana.render.fresnel_fold import Material, fresnel_table
from jkatana.render.plan import Plan
from jkatana.render.points import PixelIds
from jkatana.spectral import DEFAULT_GRID

GRID = DEFAULT_GRID
CMF = film_weights(GRID)
SPHERE = ("sphere", (0.0, 0.0, 0.0), 1.0)


def _scene():
    c = Conductor.from_table("Fe-Johnson", GRID, dtype=jnp.float32)
    mat = Material(fresnel_table(c.n, c.k), jnp.asarray(79000.0, jnp.float32), jnp.asarray(43000.0, jnp.float32))
    from jkatana.light.sky import hosek_wilkie_sky

    sky = np.asarray(hosek_wilkie_sky(35.0, 160.0, 3.0, 0.1, (32, 64), GRID, sun_supersampling=4).radiance)
    env, _, _ = build_environment(sky)
    return mat, env


def _dense_sphere(cam: Camera, center, radius):
    """The sphere's G-buffer written densely over the whole image (the test's oracle)."""
    origin, dirs = cam.rays()
    oc = origin - np.asarray(center)
    b = dirs @ oc
    disc = b * b - (oc @ oc - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    mask = (disc > 0) & (t > 0)
    pos = origin + t[..., None] * dirs
    n = (pos - np.asarray(center)) / radius
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    uv = np.stack([0.5 + np.arctan2(n[..., 0], n[..., 2]) / (2 * np.pi), np.arccos(np.clip(n[..., 1], -1, 1)) / np.pi], -1)
    return mask, pos[mask], n[mask], uv[mask], -dirs[mask]


@pytest.mark.parametrize("cam,center,radius", [
    (Camera(position=(0.0, 0.3, 3.2), fov_deg=38.0, width=96, height=96), (0.0, 0.0, 0.0), 1.0),
    (Camera(position=(0.4, 1.3, 2.2), look_at=(0.1, 0.0, 0.0), fov_deg=50.0, width=64, height=40), (0.1, 0.2, -0.3), 0.7),
])
def test_sphere_gbuffer_is_the_dense_one_kept_per_view_and_read_only(cam, center, radius):
    g = gbuffer_sphere(cam, center, radius)
    mask, pos, n, uv, view = _dense_sphere(cam, center, radius)
    assert mask.sum() > 300
    np.testing.assert_array_equal(g.mask, mask)
    np.testing.assert_array_equal(g.index, np.flatnonzero(mask))
    for got, want in ((g.hit_position, pos), (g.hit_normal, n), (g.hit_uv, uv), (g.hit_view, view)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(np.linalg.norm(g.hit_position - center, axis=-1), radius, rtol=1e-12)
    np.testing.assert_allclose(np.sum(g.hit_tangent * g.hit_normal, -1), 0.0, atol=1e-12)
    np.testing.assert_array_equal(g.ray, cam.rays()[1])
    assert gbuffer_sphere(cam, list(center), radius) is g  # one per (camera, centre, radius)
    other = Camera(position=cam.position, look_at=cam.look_at, fov_deg=cam.fov_deg + 1.0, width=cam.width,
                   height=cam.height)
    assert gbuffer_sphere(other, center, radius) is not g
    for a in (g.mask, g.index, g.hit_position, g.hit_normal, g.hit_tangent, g.hit_uv, g.hit_view, g.ray):
        assert not a.flags.writeable
    with pytest.raises(ValueError):
        g.hit_normal[0, 0] = 2.0


def test_fine_tail_only_where_the_points_follow_the_pixel():
    ids = PixelIds(np.zeros(4, np.uint32), np.zeros(4, np.int32))
    for mode, with_ids, sub, free in (("prefiltered", False, 1, True), ("reference", True, 4, True),
                                      ("lowrank", True, 4, True), ("reference", False, 4, False),
                                      ("reference", True, 1, False), ("paper", True, 4, False)):
        got = dispatch._layout_free(Plan(mode=mode, subpixels=sub), ids if with_ids else None)
        assert got is free, (mode, with_ids, sub)
    # 186 104 pixels over 2 devices in calls of 16 384 per device: 6 whole calls, or a last call of 12 288
    assert dispatch._call_sizes(Plan(), 186104, 2, 16384, False) == (16384, [16384] * 6)
    assert dispatch._call_sizes(Plan(), 186104, 2, 16384, True) == (16384, [16384] * 5 + [12288])


@pytest.mark.slow
def test_pixel_id_frame_with_the_fine_tail_equals_whole_calls(monkeypatch):
    """Reference mode with 2×2 subpixels: the last call cut from the tail ladder gives the frame of whole calls
    (the points depend on the pixel ids only; programs of another size may round differently in the last
    float32 bits)."""
    mat, env = _scene()
    cam = Camera(position=(0.0, 0.0, 4.0), fov_deg=32.0, width=96, height=96)
    maps = np.array([[[0.3, 0.05, 0.15]]], np.float32).repeat(2, 0).repeat(2, 1)
    plan = Plan(samples=4)
    n_dev = len(jax.local_devices())
    P = int(gbuffer_sphere(cam).mask.sum())
    whole = dispatch._call_sizes(plan, P, n_dev, 4096, False)[1]
    fine = dispatch._call_sizes(plan, P, n_dev, 4096, True)[1]
    assert sum(fine) < sum(whole)  # the fine tail pads less here
    a = F.render_frame(plan, mat, env, None, SPHERE, cam, maps, CMF, supersample=2, chunk=4096)
    monkeypatch.setattr(dispatch, "_layout_free", lambda plan, ids: False)
    b = F.render_frame(plan, mat, env, None, SPHERE, cam, maps, CMF, supersample=2, chunk=4096)
    m = a.mask
    assert m.sum() == P
    np.testing.assert_allclose(a.xyz[m], b.xyz[m], rtol=1e-5, atol=1e-6 * a.xyz[m].max())
    np.testing.assert_array_equal(a.xyz[~m], b.xyz[~m])


def test_frames_of_one_view_reuse_its_pixels_and_follow_the_maps():
    """A second frame of a view reuses the pixels sent for the first (same frame); maps changed in place give
    the new maps' frame, as a fresh G-buffer does."""
    mat, env = _scene()
    cam = Camera(position=(0.0, 0.0, 4.0), fov_deg=32.0, width=40, height=40)
    maps = np.array([[[0.3, 0.05, 0.15]]], np.float32).repeat(2, 0).repeat(2, 1)
    plan = Plan(samples=2)
    a = F.render_frame(plan, mat, env, None, SPHERE, cam, maps, CMF, supersample=2, seed=3)
    n_entries = len(D._DERIVED)
    b = F.render_frame(plan, mat, env, None, SPHERE, cam, maps, CMF, supersample=2, seed=3)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    assert len(D._DERIVED) == n_entries  # nothing new derived: pixels, call inputs and tables were kept
    maps[..., 2] = 0.3  # a wider hamon lobe, same array
    c = F.render_frame(plan, mat, env, None, SPHERE, cam, maps, CMF, supersample=2, seed=3)
    g = gbuffer_sphere(cam)
    fresh = F.GBuffer(g.mask, g.index.copy(), g.hit_position.copy(), g.hit_normal.copy(), g.hit_tangent.copy(),
                      g.hit_uv.copy(), g.hit_view.copy(), cam)  # writable: not kept
    d = F.render_frame(plan, mat, env, None, SPHERE, cam, maps, CMF, supersample=2, seed=3, gb=fresh)
    keep = np.ones(len(g.index), bool)
    px, ids = F._frame_pixels(g, keep, maps, jnp.float32, 2)
    assert F._frame_pixels(g, keep, maps.copy(), jnp.float32, 2)[0] is px  # kept per (G-buffer, maps' values)
    assert F._frame_pixels(fresh, keep, maps, jnp.float32, 2)[0] is not px  # a writable G-buffer: built anew
    assert dispatch._call_inputs(px, ids, (len(g.index),), NamedSharding(jax.make_mesh((1,), ("d",)), PS("d")))[0] is \
        dispatch._call_inputs(px, ids, (len(g.index),), NamedSharding(jax.make_mesh((1,), ("d",)), PS("d")))[0]
    m = a.mask
    assert not np.allclose(a.xyz[m], c.xyz[m], rtol=1e-3)
    np.testing.assert_array_equal(c.xyz[m], d.xyz[m])  # (d's background comes from host-made rays)


def test_replicated_puts_a_leaf_once_while_it_lives():
    mesh = jax.make_mesh((len(jax.local_devices()),), ("d",))
    rep = NamedSharding(mesh, PS())
    a = jnp.arange(6.0, dtype=jnp.float32) + 1.0  # a fresh single-device array
    host = np.arange(3.0, dtype=np.float32)
    t1 = D.replicated((a, host), rep)
    t2 = D.replicated((a, host), rep)
    assert t2[0] is t1[0] and t1[0].sharding == rep
    np.testing.assert_array_equal(np.asarray(t1[0]), np.asarray(a))
    assert t2[1] is not t1[1]  # NumPy leaves may change in place: put each time
    host[0] = 9.0
    assert float(D.replicated((a, host), rep)[1][0]) == 9.0
    n = len(D._DERIVED)
    del a, t1, t2
    gc.collect()
    assert len(D._DERIVED) == n - 1  # the copy leaves with its source
