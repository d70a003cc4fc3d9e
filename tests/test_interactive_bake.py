"""The interactive bake for a new environment: level resolutions, banded convolution, small cache."""

from __future__ import annotations

import numpy as np
import pytest

from jkatana.interactive import bake as B
from jkatana.interactive import caps as CP
from jkatana.interactive import levels as LV
from jkatana.interactive import lobe_tables as LT
from jkatana.interactive import tables as T
from jkatana.light.prefilter import kernel_table, lobe_of_width
from jkatana.models.lobes import Gaussian


def test_level_convolution_matches_the_full_resolution_one():
    """At the source's resolution the banded, chunked FFT equals the dense convolution (the kernel
    is zero beyond its support); at the level's resolution the result stays within the level's resampling error."""
    rng = np.random.default_rng(0)
    H, W = 32, 64
    img = rng.random((H, W, 3)) + 0.1
    img[10, 20] = 200.0  # a sun
    for mu in (0.1, 0.3):
        th = (np.arange(H) + 0.5) / H * np.pi
        e = np.linspace(0, np.pi, H + 1)
        dom = (2 * np.pi / W) * (np.cos(e[:-1]) - np.cos(e[1:]))
        dl = 2 * np.pi * np.arange(W) / W
        ca = np.cos(th)[:, None, None] * np.cos(th)[None, :, None] + \
            np.sin(th)[:, None, None] * np.sin(th)[None, :, None] * np.cos(dl)
        x_tab, k_tab = kernel_table(lobe_of_width(Gaussian, mu))
        K = np.interp((1 - ca) / 2, x_tab, k_tab, right=0.0) * dom[None, :, None]   # sin²(α/2)
        K /= K.sum((1, 2), keepdims=True)
        # dense reference: out[o, φ] = Σ_i Σ_j K[o, i, j] img[i, φ − j]  (circular in longitude)
        rolled = np.stack([np.roll(img, j, axis=1) for j in range(W)])             # (j, i, φ, c)
        ref = np.einsum("oij,jiwc->owc", K, rolled)
        got = LV.prefilter_level(img, mu, texels_per_mu=1e9)
        np.testing.assert_allclose(got, ref, rtol=2e-4, atol=2e-4 * np.abs(ref).max())
        # on a coarser level (2 texels per μ) and resampled back: the lobe-scale structure survives
        coarse = LV.prefilter(img, mu)
        assert np.abs(coarse - ref).max() < 0.05 * np.abs(ref).max()


def test_level_stack_resamples_each_level_into_one_contiguous_block_per_basis_function():
    """Baked.env is every level upsampled to the finest size, (n_mu, rank, H, W, 3), and each basis function's
    stack env[:, r] is one C-contiguous float32 block: the GL upload passes it as it is, with no copy."""
    from jkatana.light.prefilter import level_shape

    rng = np.random.default_rng(2)
    H, W, rank = 64, 128, 3
    levels = [rng.random(level_shape(mu, (H, W), LV.TEXELS_PER_MU) + (3 * rank,)) for mu in LV.MU_LEVELS]
    assert len({lv.shape for lv in levels}) > 2                     # full-size and coarser levels
    env = B._level_stack(levels, H, W, rank)
    assert env.shape == (len(levels), rank, H, W, 3) and env.dtype == np.float32
    for k, lv in enumerate(levels):
        want = LV.upsample(lv.astype(np.float32), H, W).reshape(H, W, rank, 3)
        for r in range(rank):
            np.testing.assert_array_equal(env[k, r], want[:, :, r])
    for r in range(rank):
        assert env[:, r].flags.c_contiguous and np.shares_memory(np.ascontiguousarray(env[:, r]), env)
    two = B._level_stack(levels, H, W, rank, stack_rank=2)        # a rank-2 shading's stacks only
    assert two.shape == (len(levels), 2, H, W, 3)
    np.testing.assert_array_equal(two, env[:, :2])


def test_cached_bake_is_small_and_reads_back(tmp_path):
    from jkatana.spectral import DEFAULT_GRID as grid  # the shipped tap and material tables apply

    rng = np.random.default_rng(1)
    rad = rng.random((128, 256, grid.size)) + 0.05
    rad[5, 10] *= 500.0
    a = B.cached_bake(rad, grid, cache_dir=tmp_path)
    files = list((tmp_path / "interactive").glob("baked-*.npz"))
    assert len(files) == 1
    full = a.env.size * 8  # what the float64 full-resolution stack would take
    assert files[0].stat().st_size < 0.2 * full
    b = B.cached_bake(rad, grid, cache_dir=tmp_path)
    assert b.env.shape == a.env.shape and b.env.dtype == np.float32
    np.testing.assert_allclose(b.env, a.env, atol=1e-3 * np.abs(a.env).max())
    np.testing.assert_array_equal(b.lut, a.lut)


def test_shipped_material_table_is_current(tmp_path):
    """The Fresnel basis and lobe table shipped for iron carry the current key (else a first bake pays
    the JAX compilation again): regenerate with ``write_shipped_material_table``."""
    import jax.numpy as jnp

    from jkatana.models import Conductor
    from jkatana.spectral import DEFAULT_GRID

    conductor = Conductor.from_table("Fe-Johnson", DEFAULT_GRID, dtype=jnp.float32)
    b, err, lut, spread = T.cached_material_tables(conductor, 3, LV.MU_LEVELS, tmp_path)
    assert not (tmp_path / "interactive").exists(), f"stale shipped material table in {T.SHIPPED_TAPS}"
    assert lut.shape == (2, len(LV.MU_LEVELS), 64, 3) and b.shape == (3, DEFAULT_GRID.size)


def _sun_map(grid, height=64, sun=(20, 37), boost=5000.0):
    """A smooth sky with one bright texel (a sun of known direction) and a different spectrum."""
    from jkatana.light.envmap import texel_directions_np

    d = texel_directions_np(height, 2 * height)
    wl = np.asarray(grid.wavelengths, np.float64)
    rad = (0.5 + 0.3 * np.clip(d[..., 1:2], 0, 1)) * (1.0 + 0.2 * (wl - 550.0) / 150.0)
    rad[sun] = boost * (1.0 - 0.3 * (wl - 550.0) / 150.0)
    return rad, d[sun]


def test_sun_caps_conserve_power_and_find_the_sun():
    """The split keeps the projected power: remainder + caps = the whole map (per basis function and CIE
    channel), the cap sits on the sun's texel, and a map without a compact source is left alone."""
    from jkatana.light.envmap import texel_solid_angles_np
    from jkatana.render.film import film_weights
    from jkatana.spectral import DEFAULT_GRID as grid

    rng = np.random.default_rng(2)
    b = np.linalg.qr(rng.random((grid.size, 3)))[0].T                 # any orthonormal basis (3, wl)
    W = film_weights(grid)
    rad, sun_dir = _sun_map(grid)
    rest, cdir, crad, q = CP.sun_caps(rad, grid, b, W)
    assert cdir.shape == (1, 3) and crad.shape == (1,) and q.shape == (1, 3, 3)
    assert np.degrees(np.arccos(np.clip(cdir[0] @ sun_dir, -1, 1))) < 0.5 * 180 / 64   # within half a texel
    omega = texel_solid_angles_np(*rad.shape[:2])
    power = lambda m: np.einsum("hw,hwl,rl,lc->rc", omega, m, b, W)       # noqa: E731
    np.testing.assert_allclose(power(rest) + q[0], power(rad), rtol=1e-5, atol=1e-6 * np.abs(power(rad)).max())
    assert rest.max() < 0.01 * rad.max()                                   # the sun left the map
    # no compact source: nothing split, the map itself
    smooth = rad.copy()
    smooth[20, 37] = smooth[20, 36]
    rest, cdir, crad, q = CP.sun_caps(smooth, grid, b, W)
    assert cdir.shape == (0, 3) and q.shape == (0, 3, 3) and rest is smooth


def test_bake_without_a_compact_source_is_unchanged():
    """The built-in sky (its 3° sun is not compact) bakes to the same tables with and without the split."""
    from jkatana.interactive import scene as S
    from jkatana.spectral import DEFAULT_GRID as grid

    rad = S.environment("sky", grid, height=32)
    a = B.bake(rad, grid, split_sun=True)
    b = B.bake(rad, grid, split_sun=False)
    assert a.n_caps == 0
    np.testing.assert_array_equal(a.env, b.env)
    rad, _ = _sun_map(grid)                     # (a 32-row texel, 8e-3 sr, is too large to be compact)
    c = B.bake(rad, grid)
    assert c.n_caps == 1 and c.cap_q.shape == (1, 3, 3) and np.all(c.cap_q[:, 0, 1] > 0)


@pytest.mark.slow
def test_lobe_tables_of_a_parameter_files_lobe():
    """The bake's tables for another lobe (:func:`lobe_tables.region_lobes` of a GGX parameter file): its
    energy is the lobe's own ∫ f_r cos θi dω (against a 4× finer quadrature and the lobe's albedo from
    :meth:`~jkatana.models.lobes.Lobe.brdf_cos` by Monte Carlo over its own samples), the tables are keyed
    per lobe family, and a region without a file keeps the paper's lobe."""
    import jax
    import jax.numpy as jnp

    from jkatana.models import Conductor
    from jkatana.models.lobes import GGX, GaussianVCavity
    from jkatana.models.lobe_id import LobeId

    iron = Conductor.from_table("Fe-Johnson", dtype=jnp.float64)
    width, key = LobeId.shape_of(GGX(jnp.float64(0.08)).to_params())
    lobes = LT.region_lobes({"hiraji": key, "hamon": None})
    assert lobes[1] is GaussianVCavity and lobes[0] == LT.region_lobes({"hiraji": key})[0]   # hashable by value
    assert LT.region_lobes() == LT.PAPER_LOBES
    assert T.tap_fit_key(iron, lobes=lobes) != T.tap_fit_key(iron)
    b, _ = T.material_basis(iron, 3)
    mus = np.array([0.05, 0.1])
    cos, lut, shape = LT.lobe_lut(iron, b, mus, n_cos=5, lobes=lobes)
    F = np.asarray(iron.fresnel(jnp.asarray(1.0)))
    for j, mu in enumerate(mus):
        lobe = lobes[0](jnp.float64(mu))
        assert isinstance(lobe, GGX) and float(lobe.alpha) == pytest.approx(mu)
        V = np.array([[np.sqrt(1 - c * c), 0.0, c] for c in np.maximum(cos[[1, 2, 4]], 1e-3)])
        fine = np.asarray(LT.lobe_integral(lobe, iron, V, n_phi=128, n_psi=96, width=mu, tails=True))
        np.testing.assert_allclose(lut[0, j, [1, 2, 4]] @ b, fine, rtol=2e-3)
        # the albedo by the lobe's own importance sampling (an independent estimate), normal incidence
        u = jax.random.uniform(jax.random.PRNGKey(j), (200_000, 2), jnp.float64)
        Vn = jnp.asarray([0.0, 0.0, 1.0])
        L, p = lobe.sample(Vn, u)
        f = lobe.f_cos(L, Vn)
        mc = float(jnp.mean(jnp.where(p > 0, f / jnp.where(p > 0, p, 1.0), 0.0)))
        np.testing.assert_allclose((lut[0, j, -1] @ b) / F, mc, rtol=0.02)   # F varies < 1 % over the lobe
    # the paper's region is unchanged by the other one's lobe
    _, paper, _ = LT.lobe_lut(iron, b, mus, n_cos=5)
    np.testing.assert_array_equal(lut[1], paper[1])
