"""The interactive bake for a new environment: level resolutions, banded convolution, small cache."""

from __future__ import annotations

import numpy as np

from jkatana.interactive import bake as B
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
        got = B.prefilter_level(img, mu, texels_per_mu=1e9)
        np.testing.assert_allclose(got, ref, rtol=2e-4, atol=2e-4 * np.abs(ref).max())
        # on a coarser level (2 texels per μ) and resampled back: the lobe-scale structure survives
        coarse = B.prefilter(img, mu)
        assert np.abs(coarse - ref).max() < 0.05 * np.abs(ref).max()


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
    b, err, lut, spread = B._cached_material_tables(conductor, 3, B.MU_LEVELS, tmp_path)
    assert not (tmp_path / "interactive").exists(), f"stale shipped material table in {B.SHIPPED_TAPS}"
    assert lut.shape == (2, len(B.MU_LEVELS), 64, 3) and b.shape == (3, DEFAULT_GRID.size)
