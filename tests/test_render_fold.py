"""Shading speed paths: Fresnel folded into the environment, the 2-uniform environment warp, Sobol points."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.models import Conductor
from jkatana.models.lobe_id import LobeId
from jkatana.render.camera import Camera
from jkatana.render.film import film_weights
from jkatana.render.fresnel_fold import FRESNEL_RANK_TOL_SAMPLED
from jkatana.render.dispatch import resolve_plan
from jkatana.render.frame import render_frame
from jkatana.render.plan import MODES, SAMPLED_MODES
from jkatana.render.points import sobol_table
from jkatana.render.environment import build_environment
from jkatana.render.fresnel_fold import FRESNEL_RANK_TOL, Material, fold_fresnel, fresnel_rank_for, fresnel_table
from jkatana.render.plan import Pixels, Plan
from jkatana.render.shading import shade
from jkatana.spectral import DEFAULT_GRID

GRID = DEFAULT_GRID
CMF = film_weights(GRID)
SPHERE = ("sphere", (0.0, 0.0, 0.0), 1.0)


def _mat(source="Fe-Johnson", dtype=jnp.float32):
    c = Conductor.from_table(source, GRID, dtype=dtype)
    return Material(fresnel_table(c.n, c.k), jnp.asarray(79000.0, dtype), jnp.asarray(43000.0, dtype))


def _sky(res=(32, 64)):
    from jkatana.light.sky import hosek_wilkie_sky

    return np.asarray(hosek_wilkie_sky(35.0, 160.0, 3.0, 0.1, res, GRID, sun_supersampling=4).radiance)


def _maps(w, mu0, mu1):
    return np.array([[[w, mu0, mu1]]], np.float32).repeat(2, 0).repeat(2, 1)


def _cam(n=20):
    return Camera(position=(0.0, 0.0, 4.0), fov_deg=32.0, width=n, height=n)


@pytest.mark.parametrize("source", ["Fe-Johnson", "Fe-Querry"])
def test_fresnel_rank_meets_its_tolerance(source):
    """The chosen rank reproduces the whole F(cos θ, λ) table within the tolerance; one less does not."""
    F = np.asarray(_mat(source, jnp.float64).ftable)
    r = fresnel_rank_for(F)
    assert 1 <= r <= 6
    u, s, vt = np.linalg.svd(F, full_matrices=False)
    approx = lambda k: (u[:, :k] * s[:k]) @ vt[:k]  # noqa: E731
    assert np.max(np.abs(F - approx(r))) <= FRESNEL_RANK_TOL
    assert np.max(np.abs(F - approx(r - 1))) > FRESNEL_RANK_TOL if r > 1 else True


@pytest.mark.parametrize("mode,kw", [pytest.param("reference", dict(hiraji=True, hamon=True), marks=pytest.mark.slow),
                                     pytest.param("reference", dict(hiraji=False, hamon=True, hamon_lobe=LobeId.of({"lobe": "beckmann", "alpha": 1.0})), marks=pytest.mark.slow),
                                     ("paper", dict(hiraji=True, hamon=True)),
                                     ("reference", dict(hiraji=True, hamon=False, mirror=True)),
                                     ("prefiltered", dict(hiraji=True, hamon=True))])
def test_folded_frame_equals_full_spectral_frame(mode, kw):
    """Same seed → same directions: the folded frame at the rank exact to ``FRESNEL_RANK_TOL`` differs from the
    61-band one only by rounding."""
    mat = _mat()
    env, _, _ = build_environment(_sky(), prefilter_mus=(0.04, 0.06, 0.09) if mode == "prefiltered" else (),
                                  prefilter_resolution=64)
    plan = Plan(mode=mode, samples=8, fresnel_rank=fresnel_rank_for(mat.ftable), **kw)
    full = render_frame(dataclasses.replace(plan, fresnel_rank=0), mat, env, None, SPHERE, _cam(), _maps(0.5, 0.05, 0.1), CMF)
    auto = render_frame(plan, mat, env, None, SPHERE, _cam(), _maps(0.5, 0.05, 0.1), CMF)
    assert full.stats["fresnel_rank"] == 0 and auto.stats["fresnel_rank"] >= 1
    m = full.mask
    scale = full.xyz[m].max()
    np.testing.assert_allclose(auto.xyz[m], full.xyz[m], rtol=2e-4, atol=2e-5 * scale)
    assert not np.allclose(auto.xyz[m], 0.0)


def test_folding_is_off_where_it_cannot_apply():
    mat = _mat()
    assert resolve_plan(Plan(spectral=True), mat).fresnel_rank == 0
    assert resolve_plan(Plan(lights=1), mat).fresnel_rank == 0
    assert resolve_plan(Plan(factored=True), mat).fresnel_rank == 0
    assert resolve_plan(Plan(fresnel_rank=0), mat).fresnel_rank == 0
    assert resolve_plan(Plan(mode="paper"), mat).fresnel_rank == fresnel_rank_for(mat.ftable) > 0


@pytest.mark.parametrize("source", ["Fe-Johnson", "Fe-Querry"])
def test_sampled_modes_default_to_the_sampled_tolerance_rank(source):
    """The sampled modes fold at the rank of ``FRESNEL_RANK_TOL_SAMPLED`` (iron: 3), the others at the exact one;
    an explicit rank, full spectra (0) included, is kept in every mode."""
    mat = _mat(source)
    exact, sampled = fresnel_rank_for(mat.ftable), fresnel_rank_for(mat.ftable, FRESNEL_RANK_TOL_SAMPLED)
    assert sampled == 3 and exact > sampled
    for mode in MODES:
        want = sampled if mode in SAMPLED_MODES else exact
        assert resolve_plan(Plan(mode=mode), mat).fresnel_rank == want, mode
        for r in (0, 1, exact):
            assert resolve_plan(Plan(mode=mode, fresnel_rank=r), mat).fresnel_rank == r
    assert set(SAMPLED_MODES) == {"reference", "lowrank"}


@pytest.mark.parametrize("kw", [dict(hiraji=True, hamon=True),
                                pytest.param(dict(hiraji=False, hamon=True,
                                                  hamon_lobe=LobeId.of({"lobe": "beckmann", "alpha": 1.0})),
                                             marks=pytest.mark.slow)])
def test_sampled_default_rank_bias_is_bounded_by_the_table_residual(kw):
    """Same samples at the default (rank-3) fold and at full spectra: every sample's weight and radiance are
    non-negative, so per pixel and channel |XYZ_R − XYZ| ≤ max|F − F_R| / min F · XYZ. The difference is
    not zero (the fold is really of lower rank) and full spectra stay selectable."""
    mat = _mat()
    env, _, _ = build_environment(_sky())
    plan = Plan(mode="reference", samples=8, **kw)
    maps = _maps(0.5, 0.05, 0.1)
    full = render_frame(dataclasses.replace(plan, fresnel_rank=0), mat, env, None, SPHERE, _cam(), maps, CMF)
    auto = render_frame(plan, mat, env, None, SPHERE, _cam(), maps, CMF)
    assert full.stats["fresnel_rank"] == 0 and auto.stats["fresnel_rank"] == 3
    F = np.asarray(mat.ftable, np.float64)
    u, s, vt = np.linalg.svd(F, full_matrices=False)
    bound = np.max(np.abs(F - (u[:, :3] * s[:3]) @ vt[:3])) / F.min()
    assert bound <= FRESNEL_RANK_TOL_SAMPLED / F.min()
    m = full.mask
    a, b = auto.xyz[m].astype(np.float64), full.xyz[m].astype(np.float64)
    assert not np.allclose(b, 0.0)
    # float32 rounding of the two paths (the exact-rank fold meets rtol 2e-4 above) on top of the bound
    assert np.all(np.abs(a - b) <= (bound + 2e-4) * np.abs(b) + 2e-5 * b.max())
    assert np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-3 * b.max())) > 1e-4


def _pixels(P=64, dtype=jnp.float32):
    rng = np.random.default_rng(0)
    n = rng.normal(size=(P, 3))
    n[:, 2] = np.abs(n[:, 2]) + 0.5
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    v = n + 0.3 * rng.normal(size=(P, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    a = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    return Pixels(a(np.zeros((P, 3))), a(n), a(v), a(np.full(P, 0.5)), a(np.full(P, 0.05)), a(np.full(P, 0.1)))


def test_unfolded_inputs_with_a_folded_plan_are_refused():
    mat = _mat()
    env, _, _ = build_environment(_sky((8, 16)))
    with pytest.raises(ValueError, match="fold_fresnel"):
        shade(Plan(samples=2, fresnel_rank=3), mat, env, None, _pixels(), jnp.asarray(CMF, jnp.float32),
              jax.random.PRNGKey(0))


@pytest.mark.slow
def test_folded_shading_gradients_match_the_full_path():
    """d(Σ XYZ)/d(environment) through fold + shade equals the full path's (float64, same samples)."""
    mat = _mat(dtype=jnp.float64)
    env, _, _ = build_environment(_sky((8, 16)), dtype=jnp.float64)
    px, cmf, key = _pixels(32, jnp.float64), jnp.asarray(CMF, jnp.float64), jax.random.PRNGKey(1)
    R = fresnel_rank_for(mat.ftable)

    def loss(ch, rank):
        import equinox as eqx

        e = eqx.tree_at(lambda x: x.channels, env, ch)
        m, e = fold_fresnel(rank, mat, e, cmf) if rank else (mat, e)
        return jnp.sum(shade(Plan(samples=4, fresnel_rank=rank), m, e, None, px, cmf, key)[0])

    g_full = jax.grad(loss)(env.channels, 0)
    g_fold = jax.grad(loss)(env.channels, R)
    assert np.all(np.isfinite(np.asarray(g_fold)))
    assert np.abs(np.asarray(g_full)).max() > 0
    np.testing.assert_allclose(np.asarray(g_fold), np.asarray(g_full), rtol=1e-3,
                               atol=1e-4 * np.abs(np.asarray(g_full)).max())


def test_two_uniform_environment_warp_is_unbiased_and_consistent():
    """E(d)/pdf(d) over Sobol-warped directions integrates the map; pdf, uv and direction agree."""
    sky = _sky((16, 32)).astype(np.float64)
    env, _, _ = build_environment(sky, dtype=jnp.float64)
    s = env.sampler
    pts = sobol_table(4096).astype(np.float64) / 2.0**32
    d, pdf, u, v = s.sample_uniform2(jnp.asarray(pts[:, :2]))
    d, pdf, u, v = map(np.asarray, (d, pdf, u, v))
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(s.pdf(jnp.asarray(d))), pdf, rtol=1e-12)
    from jkatana.light.envmap import direction_to_uv

    uu, vv = map(np.asarray, direction_to_uv(jnp.asarray(d)))
    np.testing.assert_allclose(np.mod(uu - u + 0.5, 1.0) - 0.5, 0.0, atol=1e-9)
    np.testing.assert_allclose(vv, v, atol=1e-9)
    # the integral of the luminance channel of the *piecewise-constant* map, exactly and by the estimator
    from jkatana.light.envmap import texel_solid_angles_np

    Y = sky @ CMF[:, 1]
    exact = float(np.sum(Y * texel_solid_angles_np(*Y.shape)))
    H, W = Y.shape
    est = np.mean(Y[np.clip((v * H).astype(int), 0, H - 1), np.mod((u * W).astype(int), W)] / pdf)
    assert abs(est / exact - 1.0) < 2e-3, (est, exact)


def test_sobol_points_are_a_02_net():
    """Each power-of-two prefix of dims 0, 1 puts one point in every elementary interval (here 4 × 4 and 2 × 8)."""
    p = sobol_table(16).astype(np.float64) / 2.0**32
    for a, b in ((4, 4), (2, 8), (8, 2), (16, 1)):
        cells = set(zip(np.floor(p[:, 0] * a).astype(int), np.floor(p[:, 1] * b).astype(int)))
        assert len(cells) == 16
