"""Sampling: environment densities, the lobes' samplers seen from the light stage, unbiased reflected radiance,
MIS variance (the lobes' own property tests are in tests/test_models_lobes.py)."""

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.light import EnvMap, hosek_wilkie_sky, load_envmap
from jkatana.light.sampling import (
    EnvSampler, frame_from_normal, mis_weight, reflected_radiance, reflected_radiance_quadrature, to_local,
)
from jkatana.models import Beckmann, Conductor, Gaussian, Hiraji
from jkatana.spectral import WavelengthGrid
from jkatana.shared import shared_data

G7 = WavelengthGrid(400, 700, 50)
ENVMAPS = shared_data("envmaps")


def _sky():
    return hosek_wilkie_sky(35.0, 180.0, 3.0, 0.1, (64, 128), G7, dtype=jnp.float64)


def _photo(name):
    env = load_envmap(ENVMAPS / name, G7, upsampling="Mallett 2019", dtype=np.float64)
    return env.downsample(8)  # 64 × 128, power-preserving


def test_env_sampler_pdf_consistent_and_normalised():
    env = hosek_wilkie_sky(35.0, 180.0, 3.0, 0.1, (64, 128), G7, ground=False, dtype=jnp.float64)
    s = EnvSampler.build(env)
    d, p = s.sample(jax.random.PRNGKey(0), 100_000)
    np.testing.assert_allclose(np.asarray(s.pdf(d)), np.asarray(p), rtol=1e-12)
    assert float(jnp.sum(s.texel_pdf * env.solid_angles())) == pytest.approx(1.0, rel=1e-12)
    # unbiased for the map's power, sun included (sun texels: 3e-4 of the sphere, most of the power)
    power = jnp.einsum("hw,hwl->l", env.solid_angles(), env.radiance)
    est = jnp.mean(env.lookup_nearest(d) / p[:, None], axis=0)
    np.testing.assert_allclose(np.asarray(est), np.asarray(power), rtol=5e-3)
    # the sun is sampled in proportion to its luminous power: never missed
    no_sun = hosek_wilkie_sky(35.0, 180.0, 3.0, 0.1, (64, 128), G7, sun=False, ground=False, dtype=jnp.float64)
    sun_share = 1 - float(jnp.sum(no_sun.luminance() * env.solid_angles()) / jnp.sum(env.luminance() * env.solid_angles()))
    sun_dir = jnp.asarray(np.asarray(env.directions())[np.unravel_index(np.argmax(env.luminance()), (64, 128))])
    frac = float(jnp.mean(d @ sun_dir > math.cos(math.radians(6.0))))  # texels are 2.8°
    assert sun_share > 0.2 and frac >= 0.98 * sun_share, (frac, sun_share)


def test_env_sampler_uniform_warp_and_max_density():
    """``sample_uniform`` is the warp behind ``sample``; ``bilinear="max"`` bounds f/p by the texel's own weight."""
    env = _sky()
    s = EnvSampler.build(env)
    u = jax.random.uniform(jax.random.PRNGKey(1), (4096, 4), jnp.float64)
    d, p = s.sample_uniform(u.reshape(64, 64, 4))
    assert d.shape == (64, 64, 3) and p.shape == (64, 64)
    d0, p0 = s.sample(jax.random.PRNGKey(1), 4096)
    np.testing.assert_array_equal(np.asarray(d).reshape(-1, 3), np.asarray(d0))
    np.testing.assert_array_equal(np.asarray(p).reshape(-1), np.asarray(p0))
    m = EnvSampler.build(env, bilinear="max")
    dm, pm = m.sample(jax.random.PRNGKey(2), 100_000)
    np.testing.assert_allclose(np.asarray(m.pdf(dm)), np.asarray(pm), rtol=1e-12)
    assert float(jnp.sum(m.texel_pdf * env.solid_angles())) == pytest.approx(1.0, rel=1e-12)
    # bilinear radiance over pdf at random directions: bounded for "max" (no sun fireflies) and
    # heavier-tailed for the exact bilinear integral, which lets the sun spill 4x its texel weight
    q = jax.random.normal(jax.random.PRNGKey(3), (200_000, 3), jnp.float64)
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    y = env.lookup(q) @ jnp.ones(env.grid.size)
    ratio_max = float(jnp.max(y / m.pdf(q)))
    ratio_lin = float(jnp.max(y / s.pdf(q)))
    assert ratio_max < ratio_lin


def test_env_sampler_positive_where_radiance_is():
    L = np.zeros((8, 16, G7.size))
    L[2, 3, 0] = 1.0  # radiance only at 400 nm, where ȳ ≈ 0
    s = EnvSampler.build(EnvMap(jnp.asarray(L), G7))
    assert float(s.texel_pdf[2, 3]) > 0.5 / float(EnvMap(jnp.asarray(L), G7).solid_angles()[2, 3])
    assert float(s.texel_pdf.min()) > 0


def _sample(lobe, key, n, V):
    V = jnp.broadcast_to(V, (n, 3))
    return lobe.sample(V, jax.random.uniform(key, (n, 2), V.dtype))


def _cap_check(lobe, V, extent, n=50_000):
    """E[1_cap / p] = Ω_cap for a cap of half-angle `extent` around the mirror direction."""
    L, p = _sample(lobe, jax.random.PRNGKey(3), n, V)
    np.testing.assert_allclose(np.asarray(lobe.pdf(L, V)), np.asarray(p), rtol=1e-10)
    R = jnp.array([-V[0], -V[1], V[2]])
    inside = ((L @ R) > math.cos(extent)) & (p > 0)
    est = float(jnp.mean(jnp.where(inside, 1 / jnp.where(inside, p, 1.0), 0.0)))
    return est, 2 * math.pi * (1 - math.cos(extent))


@pytest.mark.parametrize("mu", [pytest.param(0.005, marks=pytest.mark.slow), 0.05, 0.3])
def test_gaussian_lobe_pdf_matches_sampler(mu):
    V = jnp.array([math.sin(0.7), 0.0, math.cos(0.7)])
    lobe = Gaussian(jnp.asarray(mu))
    est, omega = _cap_check(lobe, V, 2 * mu)
    assert est == pytest.approx(omega, rel=0.03)
    # normalised over the sphere (quadrature); at normal view no half vector has V·H ≤ 0
    fr = frame_from_normal(jnp.array([0.0, 0.0, 1.0]))
    N = jnp.array([0.0, 0.0, 1.0])
    total = reflected_radiance_quadrature(EnvMap(jnp.ones((4, 8, 1)), WavelengthGrid(550, 550, 1)),
                                          lambda L, V_: lobe.pdf(L, V_)[..., None], N, fr,
                                          min(16 * mu, math.pi))
    assert float(total[0]) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("alpha", [0.02, 0.2])
def test_beckmann_pdf_matches_sampler(alpha):
    V = jnp.array([math.sin(0.4), 0.0, math.cos(0.4)])
    est, omega = _cap_check(Beckmann(jnp.asarray(alpha)), V, 2 * alpha)
    assert est == pytest.approx(omega, rel=0.03)


def test_lobe_sampling_finite_at_tiny_mu_and_normal_view():
    N = jnp.array([0.0, 0.0, 1.0], jnp.float32)
    L, p = _sample(Gaussian(jnp.float32(1e-4)), jax.random.PRNGKey(0), 1000, N)
    assert np.isfinite(np.asarray(L)).all() and np.isfinite(np.asarray(p)).all() and float(p.min()) > 0
    g = jax.grad(lambda m: jnp.sum(jnp.log(Gaussian(m).pdf(L, N))))(jnp.float32(1e-4))
    assert np.isfinite(float(g))


def test_mis_weights_sum_to_one():
    p1 = jnp.array([0.0, 1.0, 2.0, 1e-30])
    p2 = jnp.array([0.0, 3.0, 2.0, 5.0])
    for h in ("balance", "power"):
        w = mis_weight(p1, p2, 2, 3, h) + mis_weight(p2, p1, 3, 2, h)
        np.testing.assert_allclose(np.asarray(w[1:]), 1.0, rtol=1e-12)
        assert float(w[0]) == 0.0


def test_mis_weight_per_density_is_the_weight_over_n_p():
    """The form the renderer's strategies use: w / (n p), 0 where the sample does not count."""
    p1 = jnp.array([0.0, 1.0, 2.0, 0.5, 4.0])
    p2 = jnp.array([0.0, 3.0, 2.0, 0.0, 1.0])
    valid = jnp.array([False, True, True, True, False])  # 0: both densities 0 (the renderer passes ok = p > 0)
    for h in ("balance", "power"):
        w = mis_weight(p1, p2, 2, 3, h)
        q = mis_weight(p1, p2, 2, 3, h, valid=valid, per_density=True)
        np.testing.assert_allclose(np.asarray(q[1:4] * 2 * p1[1:4]), np.asarray(w[1:4]), rtol=1e-12)
        assert float(q[0]) == 0.0 and float(q[4]) == 0.0
    # the balance heuristic's 1 / Σ n p, also where this strategy's own density is 0
    q = mis_weight(jnp.array([0.0]), jnp.array([0.25]), 4, 2, valid=jnp.array([True]), per_density=True)
    assert float(q[0]) == 2.0


def _estimates(env, mu, n_w, V_w, N=8, M=128, seed=11):
    """Luminance of M independent estimates per strategy: env alone (N samples, luminance sampler),
    lobe alone (N), MIS (N + N, balance heuristic, with the MIS-compensated environment sampler)."""
    from jkatana.spectral import xyz_weights

    cond = Conductor.from_table("Fe-Johnson", G7, jnp.float64)
    model = Hiraji(mu=jnp.asarray(mu))  # array μ: a Python float is concretised by models (fails under jit)
    brdf = lambda L, V: model.brdf_cos(L, V, cond)  # noqa: E731
    fr = frame_from_normal(n_w)
    Vl = to_local(fr, V_w)
    ybar = np.asarray(xyz_weights(G7))[:, 1]
    Y_ref = float(np.asarray(reflected_radiance_quadrature(env, brdf, Vl, fr, min(16 * mu, math.pi))) @ ybar)
    plain, comp = EnvSampler.build(env), EnvSampler.build(env, compensate=True)
    lobe = Gaussian(jnp.asarray(mu))
    keys = jax.random.split(jax.random.PRNGKey(seed), M)
    out = {}
    for strategy, sampler in (("env", plain), ("lobe", plain), ("mis", comp)):
        f = jax.jit(jax.vmap(lambda k: reflected_radiance(k, env, sampler, brdf, Vl, fr, lobe, N, N,
                                                          strategy=strategy)))
        out[strategy] = np.asarray(f(keys)) @ ybar
    return Y_ref, out


def _check(Y_ref, out, strict=True):
    for k, Y in out.items():
        se = Y.std() / math.sqrt(Y.size)
        assert abs(Y.mean() - Y_ref) < 4 * se + 1e-9 * abs(Y_ref), (k, Y.mean(), Y_ref, se)
    # the bias check has power where it matters: for MIS, and for the better single strategy
    # (environment sampling alone under a sharp lobe over smooth sky is hopelessly noisy, se ≈ 0.4–0.7 Y)
    se = {k: Y.std() / math.sqrt(Y.size) for k, Y in out.items()}
    assert se["mis"] < 0.2 * abs(Y_ref) and min(se["env"], se["lobe"]) < 0.2 * abs(Y_ref), (se, Y_ref)
    v = {k: Y.var() for k, Y in out.items()}
    # MIS (N of each strategy) vs each strategy alone with N samples. Where a bright sun is in the
    # lobe both strategies matter and MIS is strictly below both. Where the lobe sees no dominant peak
    # the compensated environment sampler adds little and MIS stays within Veach's bound of the lobe
    # strategy: measured 1.00× (built-in sky), 1.06× and 1.29× (pedestrian overpass, whose clipped sun
    # holds 0.6 % of the power); the test allows 1.35×.
    assert v["mis"] < v["env"], v
    assert (v["mis"] < v["lobe"]) if strict else (v["mis"] <= 1.35 * v["lobe"]), v


def _configs(env):
    lum = np.asarray(env.luminance())
    j, i = np.unravel_index(np.argmax(lum), lum.shape)
    s = jnp.asarray(np.asarray(env.directions())[j, i])
    V = jnp.array([0.3, 0.2, 0.9])
    V = V / jnp.linalg.norm(V)
    n_sun = (V + s) / jnp.linalg.norm(V + s)
    n_sky = jnp.array([0.0, 1.0, 0.3]) / jnp.linalg.norm(jnp.array([0.0, 1.0, 0.3]))
    return V, n_sun, n_sky


@pytest.mark.slow  # the all-maps test below checks this configuration too (sky, μ = 0.05, sun), with 256 estimates
def test_reflected_radiance_unbiased_and_mis_sky_with_sun():
    env = _sky()
    V, n_sun, _ = _configs(env)
    _check(*_estimates(env, 0.05, n_sun, V))


@pytest.mark.slow
@pytest.mark.parametrize("name,mu", [("sky", 0.05), ("sky", 0.2), ("sunrise.exr", 0.05),
                                     ("pedestrian_overpass_1k.hdr", 0.05), ("forest.exr", 0.2)])
@pytest.mark.parametrize("where", ["sun", "sky"])
def test_reflected_radiance_unbiased_and_mis_all_maps(name, mu, where):
    env = _sky() if name == "sky" else _photo(name)
    V, n_sun, n_sky = _configs(env)
    Y_ref, out = _estimates(env, mu, n_sun if where == "sun" else n_sky, V, M=256)
    # pedestrian_overpass_1k.hdr is not sun-dominated (clipped HDR): no strict MIS claim there
    _check(Y_ref, out, strict=where == "sun" and name != "pedestrian_overpass_1k.hdr")


def test_env_sampler_bilinear_weights_keep_sun_spill_bounded():
    """f/p (bilinear radiance over sampling density) is bounded near a one-texel sun."""
    L = np.full((16, 32, G7.size), 1e-3)
    L[5, 9] = 1e4
    env = EnvMap(jnp.asarray(L), G7)
    d = env.directions()
    from jkatana.light.envmap import direction_to_uv, uv_to_direction
    u, v = direction_to_uv(d)
    probe = uv_to_direction(u + 0.45 / 32, v)
    for bilinear, bound in ((True, 10.0), (False, 1e3)):
        s = EnvSampler.build(env, bilinear=bilinear)
        ratio = env.lookup(probe)[..., 0] / s.pdf(probe)
        r = float(jnp.max(ratio) / jnp.sum(env.radiance[..., 0] * env.solid_angles()))
        assert (r < bound) if bilinear else (r > bound), (bilinear, r)
