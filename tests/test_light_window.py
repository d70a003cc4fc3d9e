"""Environment sampling inside a texel window (``EnvSampler.window`` / ``sample_window`` / ``pdf_window``): the
density is normalised over the window and is the one the samples follow, the window holds its cone, and the
reference frame does not change with the window (MIS with the lobe strategy keeps it unbiased)."""

import math
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.light import hosek_wilkie_sky
from jkatana.light.envmap import (direction_to_uv, texel_directions_np, texel_index, texel_solid_angles_np,
                                  uv_to_direction)
from jkatana.light.sampling import WINDOW_TOTAL, EnvSampler
from jkatana.render.plan import ENV_WINDOW
from jkatana.shared import shared_data
from jkatana.spectral import WavelengthGrid

G7 = WavelengthGrid(400, 700, 50)
H, W = 32, 64


@pytest.fixture(scope="module")
def sampler():
    env = hosek_wilkie_sky(25.0, 100.0, 3.0, 0.1, (H, W), G7, dtype=jnp.float32)  # a sun and a dark ground
    return EnvSampler.build(env)


def _unit(theta, phi):
    return uv_to_direction(jnp.asarray([phi / (2 * math.pi) + 0.5]), jnp.asarray([theta / math.pi]))


# (polar angle, azimuth, half-angle): mid-latitude; a window that wraps past u = 1; one holding the zenith;
# one holding the nadir; a half-angle past 90° (the whole width); a narrow one
WINDOWS = [(1.2, 0.3, 0.5), (1.0, math.pi - 0.05, 0.4), (0.2, 1.0, 0.5), (2.9, -2.0, 0.4), (1.5, 0.0, 2.0),
           (1.7, -1.0, 0.08)]


@pytest.mark.parametrize("theta,phi,half", WINDOWS)
@pytest.mark.slow
def test_window_density_normalised_followed_by_samples_and_holding_the_cone(sampler, theta, phi, half):
    d = _unit(theta, phi)
    win = sampler.window(d, jnp.asarray([half], jnp.float32))
    r0, r1, c0, c1, Q = (np.asarray(x)[0] for x in win[:5])
    assert 0 <= r0 < r1 <= H and 0 <= c0 < W and c0 < c1 <= c0 + W and Q > 0
    # every direction of the cone falls in the window
    key = jax.random.PRNGKey(3)
    z = jax.random.normal(key, (20000, 3))
    z = z / jnp.linalg.norm(z, axis=-1, keepdims=True)
    in_cone = np.asarray(z @ d[0]) >= math.cos(half) + 1e-4
    u, v = direction_to_uv(z)
    p = np.asarray(sampler.pdf_window(tuple(jnp.broadcast_to(x, (20000,)) for x in win), u, v))
    assert in_cone.sum() > 10 and (p[in_cone] > 0).all()
    # the density integrates to 1 over the sphere (texel centres: piecewise constant per texel)
    tu, tv = ((np.arange(W) + 0.5) / W)[None, :].repeat(H, 0), ((np.arange(H) + 0.5) / H)[:, None].repeat(W, 1)
    wb = tuple(jnp.broadcast_to(x, (H * W,)) for x in win)
    pt = np.asarray(sampler.pdf_window(wb, jnp.asarray(tu.ravel(), jnp.float32), jnp.asarray(tv.ravel(), jnp.float32)))
    assert float((pt.reshape(H, W) * texel_solid_angles_np(H, W)).sum()) == pytest.approx(1.0, rel=1e-5)
    # samples: inside, with the density pdf_window gives, and in each texel as often as it says
    n = 200_000
    us = jax.random.uniform(jax.random.PRNGKey(5), (n, 2), jnp.float32)
    wn = tuple(jnp.broadcast_to(x, (n,)) for x in win)
    ds, ps, su, sv = sampler.sample_window(wn, us)
    ps, su, sv = np.asarray(ps), np.asarray(su), np.asarray(sv)
    assert np.isfinite(np.asarray(ds)).all() and (ps > 0).all()
    np.testing.assert_allclose(np.linalg.norm(np.asarray(ds), axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(sampler.pdf_window(wn, jnp.asarray(su), jnp.asarray(sv))), ps, rtol=1e-6)
    su2, sv2 = direction_to_uv(ds)  # the direction and its map coordinates agree
    np.testing.assert_allclose(np.asarray(sampler.pdf_window(wn, su2, sv2)), ps, rtol=1e-6)
    j, i = (np.asarray(x) for x in texel_index(jnp.asarray(su), jnp.asarray(sv), H, W))
    counts = np.bincount(j * W + i, minlength=H * W).reshape(H, W)
    expected = n * pt.reshape(H, W) * texel_solid_angles_np(H, W)
    big = expected > 50
    assert big.sum() >= 3
    assert np.all(np.abs(counts - expected)[big] < 5 * np.sqrt(expected[big]) + 2), np.max(
        np.abs(counts - expected)[big] / np.sqrt(expected[big]))
    assert counts[expected == 0].sum() == 0


@pytest.mark.slow
def test_window_estimates_the_windows_power_without_bias(sampler):
    """E[L(d)/p] over the window's samples = the radiance integral over its weighted texels (the sun included)."""
    env = hosek_wilkie_sky(25.0, 100.0, 3.0, 0.1, (H, W), G7, dtype=jnp.float32)
    sun = np.unravel_index(np.argmax(np.asarray(env.luminance())), (H, W))
    c = jnp.asarray(texel_directions_np(H, W)[sun][None], jnp.float32)
    win = sampler.window(c, jnp.asarray([0.6], jnp.float32))
    n = 400_000
    wn = tuple(jnp.broadcast_to(x, (n,)) for x in win)
    d, p, _, _ = sampler.sample_window(wn, jax.random.uniform(jax.random.PRNGKey(9), (n, 2), jnp.float32))
    est = np.asarray(jnp.mean(env.lookup_nearest(d) / p[:, None], axis=0), np.float64)
    r0, r1, c0, c1 = (int(np.asarray(x)[0]) for x in win[:4])
    cols = np.arange(c0, c1) % W
    q = np.asarray(sampler.window_q)[r0:r1][:, cols]
    L = np.asarray(env.radiance, np.float64)[r0:r1][:, cols]
    om = texel_solid_angles_np(H, W)[r0:r1][:, cols]
    exact = np.einsum("hw,hwl->l", om * (q > 0), L)
    np.testing.assert_allclose(est, exact, rtol=1e-2)


def test_window_tables_are_exact_integers_in_float32(sampler):
    tab = np.asarray(sampler.window_table, np.float64)
    q = np.asarray(sampler.window_q, np.float64)
    assert np.all(q == np.round(q)) and q.sum() <= WINDOW_TOTAL and tab.max() <= 2.0 ** 24
    ref = np.zeros((H + 1, 2 * W + 1))
    ref[1:, 1:] = np.cumsum(np.cumsum(np.concatenate([q, q], 1), 0), 1)
    np.testing.assert_array_equal(tab, ref)


@pytest.mark.slow
def test_reference_frame_unchanged_by_the_window():
    """The peer study's rough sphere, converged with and without the window: equal within the noise."""
    from validation import mitsuba as mc

    with tempfile.TemporaryDirectory() as t:
        envp = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(t) / "env.exr", 128)
        kw = dict(alpha=0.2, size=24, samples=256, supersample=2, same_upsampling=False, env_nodes=None)
        a, mask, _ = mc.render_jkatana(envp, seed=1, env_window=None, **kw)
        b, _, _ = mc.render_jkatana(envp, seed=2, env_window=ENV_WINDOW, **kw)
        b2, _, _ = mc.render_jkatana(envp, seed=3, env_window=ENV_WINDOW, **kw)
    m = mask
    ratio = b[m].mean(0) / a[m].mean(0)
    np.testing.assert_allclose(ratio, 1.0, atol=2e-3)
    between = mc.compare(a, b, m)["dE2000_mean"]
    within = mc.compare(b, b2, m)["dE2000_mean"]  # two windowed frames: the noise scale
    assert between < 1.5 * within + 0.02, (between, within)
