"""One well-stratified sample set per pixel across its subpixels (``Plan.subpixels``, ``PixelIds``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.models import Conductor
from jkatana.render.camera import Camera
from jkatana.render.film import film_weights
from jkatana.render.frame import render_frame
from jkatana.render.environment import build_environment
from jkatana.render.fresnel_fold import Material, fresnel_table
from jkatana.render.plan import Pixels, Plan
from jkatana.render.points import PixelIds, sample_points
from jkatana.render.shading import shade
from jkatana.spectral import DEFAULT_GRID

GRID = DEFAULT_GRID
CMF = film_weights(GRID)
S = 4  # subpixels per pixel (2 × 2)


def _is_net(pts: np.ndarray) -> bool:
    """Whether ``n = 2^m`` points in [0, 1)² form a (0, m, 2)-net: one point in every 2^a × 2^(m−a) box."""
    n = len(pts)
    m = int(round(np.log2(n)))
    assert 2**m == n
    for a in range(m + 1):
        ix = np.floor(pts[:, 0] * 2**a).astype(int)
        iy = np.floor(pts[:, 1] * 2 ** (m - a)).astype(int)
        counts = np.bincount(ix * 2 ** (m - a) + iy, minlength=n)
        if not np.all(counts == 1):
            return False
    return True


def _ids(n_pixels: int) -> PixelIds:
    return PixelIds(jnp.repeat(jnp.arange(n_pixels, dtype=jnp.uint32) * 7 + 3, S),
                    jnp.tile(jnp.arange(S, dtype=jnp.int32), n_pixels))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_union_of_a_pixels_subpixel_points_is_a_net(seed):
    """Lobe (u1, u2) and environment (u1, u2) points of a pixel's 4 subpixels × 16 samples are one (0, 6, 2)-net;
    each subpixel's 16 points a (0, 4, 2)-net. Independently shifted subpixel sets (the old scheme) are not."""
    key = jax.random.PRNGKey(seed)
    n_pix = 5
    new = np.asarray(sample_points(Plan(samples=16, subpixels=S), key, n_pix * S, _ids(n_pix), jnp.float64))
    old = np.asarray(sample_points(Plan(samples=16), key, n_pix * S, None, jnp.float64))
    for cols in ((1, 2), (3, 4)):
        for p in range(n_pix):
            union = new[p * S:(p + 1) * S][..., cols].reshape(-1, 2)
            assert _is_net(union)
            assert all(_is_net(new[p * S + s][:, cols]) for s in range(S))
        # the old scheme: each subpixel alone is a net, the union almost never is
        assert all(_is_net(old[i][:, cols]) for i in range(n_pix * S))
        assert sum(_is_net(old[p * S:(p + 1) * S][..., cols].reshape(-1, 2)) for p in range(n_pix)) == 0
    # the scramble is per pixel: subpixels of one pixel share it, different pixels differ
    assert not np.allclose(new[0], new[S])


def _scene(n_pix: int, rng):
    c = Conductor.from_table("Fe-Johnson", GRID, dtype=jnp.float64)
    mat = Material(fresnel_table(c.n, c.k), jnp.asarray(79000.0), jnp.asarray(43000.0))
    from jkatana.light.sky import hosek_wilkie_sky

    sky = np.asarray(hosek_wilkie_sky(35.0, 160.0, 3.0, 0.1, (32, 64), GRID, sun_supersampling=4).radiance)
    env, _, _ = build_environment(sky, dtype=jnp.float64)  # the precision of mat and px
    # per pixel a normal tilted towards the sun side; its 4 subpixels differ slightly (a footprint)
    base = rng.normal(size=(n_pix, 1, 3)) * np.array([0.3, 0.3, 0.0]) + np.array([0.0, 0.0, 1.0])
    n = base + rng.normal(size=(n_pix, S, 3)) * np.array([0.02, 0.02, 0.0])
    n = (n / np.linalg.norm(n, axis=-1, keepdims=True)).reshape(-1, 3)
    P = n.shape[0]
    px = Pixels(jnp.zeros((P, 3)), jnp.asarray(n), jnp.tile(jnp.array([[0.0, 0.0, 1.0]]), (P, 1)),
                jnp.full((P,), 0.5), jnp.full((P,), 0.05), jnp.full((P,), 0.1))
    return mat, env, px


def _shader(plan, mat, env, px, ids):
    return jax.jit(jax.vmap(lambda k: shade(plan, mat, env, None, px, jnp.asarray(CMF), k, None, ids)[0]))


@pytest.mark.slow
def test_pixel_estimate_is_unbiased_and_less_noisy():
    """Over many seeds each subpixel's and each pixel's mean matches a converged estimate (z-scores), and the
    pixel estimate's variance is lower than with independently shifted subpixel sets."""
    rng = np.random.default_rng(3)
    n_pix, N, seeds = 6, 4, 256
    mat, env, px = _scene(n_pix, rng)
    ids = _ids(n_pix)
    keys = jax.random.split(jax.random.PRNGKey(11), seeds)
    new = np.asarray(_shader(Plan(samples=N, subpixels=S, fresnel_rank=0), mat, env, px, ids)(keys))[..., 1]
    old = np.asarray(_shader(Plan(samples=N, fresnel_rank=0), mat, env, px, None)(keys))[..., 1]
    ref = np.asarray(_shader(Plan(samples=4096, fresnel_rank=0), mat, env, px, None)(keys[:2])).mean(0)[..., 1]
    assert np.all(ref > 0)

    def z(samples, truth):
        return (samples.mean(0) - truth) / (samples.std(0, ddof=1) / np.sqrt(seeds) + 1e-3 * truth)

    pix = lambda a: a.reshape(a.shape[:-1] + (n_pix, S)).mean(-1)  # noqa: E731
    for est in (new, pix(new)):  # per subpixel and per pixel
        zz = z(est, ref if est is new else pix(ref))
        assert np.all(np.abs(zz) < 5.0), zz
        assert np.mean(zz**2) < 3.0, zz
    # variance of the pixel estimate: one stratified set vs independent shifts (same samples, same cost)
    v_new, v_old = pix(new).var(0, ddof=1), pix(old).var(0, ddof=1)
    assert np.median(v_new / v_old) < 0.7, v_new / v_old


@pytest.mark.parametrize("n_env", [pytest.param(0, marks=pytest.mark.slow), 1,
                                   pytest.param(12, marks=pytest.mark.slow)])
@pytest.mark.slow
def test_estimate_is_unbiased_for_any_number_of_environment_samples(n_env):
    """The balance heuristic with sample counts: 4 lobe samples beside 0, 1 or 12 environment samples per
    subpixel all have the converged mean (z-scores over seeds); ``env_samples=None`` is one per lobe sample."""
    rng = np.random.default_rng(5)
    n_pix, seeds = 4, 192
    mat, env, px = _scene(n_pix, rng)
    ids = _ids(n_pix)
    keys = jax.random.split(jax.random.PRNGKey(7), seeds)
    est = np.asarray(_shader(Plan(samples=4, env_samples=n_env, subpixels=S, fresnel_rank=0), mat, env, px, ids)(
        keys))[..., 1]
    ref = np.asarray(_shader(Plan(samples=4096, fresnel_rank=0), mat, env, px, None)(keys[:2])).mean(0)[..., 1]
    zz = (est.mean(0) - ref) / (est.std(0, ddof=1) / np.sqrt(seeds) + 1e-3 * ref)
    assert np.all(np.abs(zz) < 5.0), zz
    assert np.mean(zz**2) < 3.0, zz
    if n_env == 1:  # a different count is a different estimator: it must not be the default's
        same = np.asarray(_shader(Plan(samples=4, subpixels=S, fresnel_rank=0), mat, env, px, ids)(keys[:4]))
        explicit = np.asarray(_shader(Plan(samples=4, env_samples=4, subpixels=S, fresnel_rank=0), mat, env, px,
                                      ids)(keys[:4]))
        np.testing.assert_array_equal(same, explicit)
        assert not np.allclose(est[:4], same[..., 1], rtol=1e-6)


@pytest.mark.slow
def test_frame_is_independent_of_chunking_and_devices():
    """With pixel ids the scramble depends on the frame seed and the pixel only: chunk size and device
    count do not change the frame; the seed does."""
    c = Conductor.from_table("Fe-Johnson", GRID, dtype=jnp.float32)
    mat = Material(fresnel_table(c.n, c.k), jnp.asarray(79000.0, jnp.float32), jnp.asarray(43000.0, jnp.float32))
    from jkatana.light.sky import hosek_wilkie_sky

    sky = np.asarray(hosek_wilkie_sky(35.0, 160.0, 3.0, 0.1, (32, 64), GRID, sun_supersampling=4).radiance)
    env, _, _ = build_environment(sky)
    cam = Camera(position=(0.0, 0.0, 4.0), fov_deg=32.0, width=48, height=48)
    maps = np.array([[[0.3, 0.05, 0.15]]], np.float32).repeat(2, 0).repeat(2, 1)
    sphere = ("sphere", (0.0, 0.0, 0.0), 1.0)
    plan = Plan(samples=4)
    a = render_frame(plan, mat, env, None, sphere, cam, maps, CMF, supersample=2, chunk=256, n_devices=1)
    b = render_frame(plan, mat, env, None, sphere, cam, maps, CMF, supersample=2, n_devices=len(jax.local_devices()))
    c2 = render_frame(plan, mat, env, None, sphere, cam, maps, CMF, supersample=2, seed=1)
    m = a.mask
    assert m.sum() > 500
    np.testing.assert_allclose(a.xyz[m], b.xyz[m], rtol=1e-5, atol=1e-6 * a.xyz[m].max())
    assert not np.allclose(a.xyz[m], c2.xyz[m], rtol=1e-3)
    with pytest.raises(ValueError, match="supersample"):
        render_frame(plan, mat, env, None, sphere, Camera(position=(0.0, 0.0, 4.0), fov_deg=32.0, width=47,
                                                          height=48), maps, CMF, supersample=2)


@pytest.mark.slow
def test_render_view_supersample_box_averages_a_shared_set():
    """``render_view(supersample=2)``: the camera's resolution, each pixel the mean of its 4 subpixels shaded
    with one per-pixel set (equal to averaging ``render_frame(supersample=2)`` by hand), close to the
    1-subpixel frame where the image is smooth."""
    from jkatana.render.renderer import camera_for, prepare, render_view
    from jkatana.render.scenefile import scene_from_dict

    raw = {"geometry": {"sphere": {"radius": 1.0}}, "material": {"w": 0.0, "mu0": 0.05, "mu1": 0.2},
           "environment": {"type": "sky", "resolution": [16, 32]}, "camera": {"type": "lookat",
           "position": [0, 0, 4], "look_at": [0, 0, 0], "resolution": [24, 16]},
           "render": {"mode": "reference", "samples": 8}}
    p = prepare(scene_from_dict(raw))
    one = render_view(p, seed=3)
    two = render_view(p, seed=3, supersample=2)
    assert two.xyz.shape == one.xyz.shape == (16, 24, 3) and two.stats["supersample"] == 2
    cam = camera_for(p.scene)
    import dataclasses

    big = render_frame(p.plan, p.material, p.env, p.lights, p.geometry,
                       dataclasses.replace(cam, width=48, height=32), p.maps, p.cmf, seed=3, dtype=p.dtype,
                       supersample=2)
    np.testing.assert_allclose(two.xyz, big.xyz.reshape(16, 2, 24, 2, 3).mean((1, 3)), rtol=1e-5, atol=1e-7)
    assert np.array_equal(two.mask, big.mask.reshape(16, 2, 24, 2).all((1, 3)))
    m = two.mask & one.mask
    assert m.sum() > 50
    rel = np.abs(two.xyz[m, 1] - one.xyz[m, 1]) / one.xyz[m, 1].max()
    assert np.median(rel) < 0.1
