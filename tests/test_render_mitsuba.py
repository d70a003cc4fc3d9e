"""jkatana vs Mitsuba 3 (an independent spectral renderer): iron spheres under an environment map.

Skipped when Mitsuba is not installed (``pip install mitsuba==3.9.1``) or no
spectral variant runs (probed in a subprocess). See
:mod:`validation.mitsuba` for the conventions matched.
"""

from __future__ import annotations

import pytest

from validation import mitsuba as mc
from jkatana.shared import shared_data

ENV = str(shared_data("envmaps", "courtyard.exr"))

pytestmark = pytest.mark.mitsuba


@pytest.fixture(scope="module")
def env_small(tmp_path_factory):
    from pathlib import Path

    if mc.mitsuba_variant() is None:
        pytest.skip("Mitsuba 3 not installed or no spectral variant runs here")
    src = Path(ENV)
    if not src.is_file():
        pytest.skip(f"{ENV} not available")
    return mc.small_envmap(src, tmp_path_factory.mktemp("env") / "env.exr", width=256)


def _channel_ratios(a, b, mask):
    """Per-channel ratio of the image sums over the eroded sphere (a systematic offset shows here first)."""
    import numpy as np
    from scipy.ndimage import binary_erosion

    m = binary_erosion(mask)
    return a[m].sum(0) / b[m].sum(0)


def test_smooth_iron_sphere_matches_mitsuba(env_small):
    mi_img = mc.render_mitsuba(env_small, alpha=None, size=64, spp=4096)
    jk, mask, _ = mc.render_jkatana(env_small, alpha=None, size=64, supersample=6)
    err = mc.compare(mi_img, jk, mask)
    ratio = _channel_ratios(mi_img, jk, mask)
    # measured (Mitsuba 4096 spp, jkatana 6×6 subpixels, envmap nodes 3): mean 0.087, p95 0.30, p99 0.54;
    # R, G, B sums 1.0002, 1.0001, 1.0003. With 3×3 subpixels p99 is 1.3 (edges of sharp reflections: the
    # pixel's box integral, not the renderers). The uncompensated envmap (texel spectra under our centred
    # rows): 0.33 / 1.43 / 4.0 and sums 1.012, 1.010, 1.007 — the p99 and ratio bars catch that.
    assert err["dE2000_mean"] <= 0.5, err
    assert err["dE2000_p99"] <= 0.8, err
    assert abs(ratio - 1).max() <= 0.003, ratio


@pytest.mark.slow
def test_rough_beckmann_iron_sphere_matches_mitsuba(env_small):
    """The issue's bar: ΔE2000 mean ≤ 0.5, with p99 and the per-channel sums stated from the measurement.

    Mitsuba at 16384 spp (its own noise: two seeds differ by ΔE mean 0.26, so
    each is ≈ 0.18 from converged), jkatana 256 samples × 9 subpixels (vs
    1024: ΔE 0.09). Residual bias: the mean of two 16384-spp seeds vs jkatana
    1024 differs per pixel by an RMS that Mitsuba's noise fully accounts for
    (≤ 0.2 % after subtracting it); sums agree to < 0.06 %.
    """
    mi_img = mc.render_mitsuba(env_small, alpha=0.2, size=64, spp=16384, seed=0)
    jk, mask, _ = mc.render_jkatana(env_small, alpha=0.2, size=64, samples=256, supersample=3, seed=0)
    err = mc.compare(mi_img, jk, mask)
    ratio = _channel_ratios(mi_img, jk, mask)
    # measured (this test): mean 0.209, p95 0.55, p99 0.78; R, G, B sums 0.9994, 0.9996, 0.9995 (seeds 0/1 of
    # each renderer, 4 pairs: mean 0.205–0.211, p99 0.78–0.81, sums within 0.06 %). The uncompensated
    # envmap (the previous comparison) at the same settings: 0.33 / 0.88 / 1.14, sums 1.0114, 1.0093, 1.0056
    # — it passes the mean bar, so the p99 and ratio bars are the ones that guard the conventions.
    assert err["dE2000_mean"] <= 0.5, err
    assert err["dE2000_p99"] <= 1.0, err
    assert abs(ratio - 1).max() <= 0.003, ratio


def test_jkatana_copy_of_mitsuba_envmap_is_exact_at_its_nodes(tmp_path):
    """:func:`mc.mitsuba_env_spectra` with ``nodes=r`` equals Mitsuba's spectral ``envmap.eval`` at our texel centres.

    Mitsuba 3.9.1's spectral envmap = bilinear(sigmoid) × bilinear(scale) × D65
    with corner-aligned rows; our lookup interpolates one image with centred
    rows. At our nodes the copy is exact (float32); between them it is our
    bilinear of Mitsuba's function, whose error falls with r. A random,
    high-contrast map (worst case): measured mean |relative error| at 550 nm
    0.31 with the texels' own spectra (``nodes=None``), 0.029 at r = 3, 0.012 at r = 5.
    """
    import jax.numpy as jnp
    import numpy as np

    mi = pytest.importorskip("mitsuba")
    from jkatana.io.exr import write_exr
    from jkatana.light.envmap import uv_to_direction
    from jkatana.render.renderer import rotation_y
    from jkatana.render.environment import bilinear_equirect
    from jkatana.spectral.grid import WavelengthGrid

    rng = np.random.default_rng(0)
    H, W, r = 16, 32, 3
    img = (rng.uniform(0, 1, (H, W, 3)) ** 3 * rng.uniform(0.1, 10, (H, W, 1))).astype(np.float32)
    path = write_exr(tmp_path / "env.exr", {"R": img[..., 0], "G": img[..., 1], "B": img[..., 2]})
    grid = WavelengthGrid(360.0, 830.0, 5.0)
    idx = [8, 38, 48, 58]  # 400, 550, 600, 650 nm
    mi.set_variant("scalar_spectral")
    em = mi.load_dict({"type": "envmap", "filename": str(path)})
    si = mi.SurfaceInteraction3f()
    si.wavelengths = mi.Spectrum(*np.asarray(grid.wavelengths)[idx].tolist())
    turn = rotation_y(mc.MITSUBA_ENV_ROTATION_DEG)

    def theirs(d_map):
        out = []
        for x in d_map @ turn:  # map → world
            si.wi = mi.Vector3f(*(-x))
            out.append(np.asarray(em.eval(si)))
        return np.array(out)

    def ours(nodes, d_map):
        copy = mc.mitsuba_env_spectra(path, grid, nodes=nodes)[..., idx]
        return np.asarray(bilinear_equirect(jnp.asarray(copy, jnp.float64), jnp.asarray(d_map)))

    j, i = rng.integers(0, r * H, 200), rng.integers(0, r * W, 200)
    at_nodes = np.asarray(uv_to_direction(jnp.asarray((i + 0.5) / (r * W)), jnp.asarray((j + 0.5) / (r * H))))
    np.testing.assert_allclose(ours(r, at_nodes), theirs(at_nodes), rtol=1e-4, atol=1e-6)
    d = rng.normal(size=(1500, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    t = theirs(d)
    err = {n: np.abs(ours(n, d) - t).sum(0) / t.sum(0) for n in (None, r)}
    assert np.all(err[r] < 0.15 * err[None]) and np.all(err[r] < 0.06), err


def test_mitsuba_latlong_is_ours_turned_half_a_turn_with_corner_aligned_rows():
    """Mitsuba 3.9.1's ``envmap`` = our image at R·d (R = 180° about +Y), rows corner-aligned.

    Measured with ``scalar_rgb`` (no render): Mitsuba's column coordinate is
    ours turned by half a turn, columns centred as ours ((i + ½)/W); its row j
    lies at v = j/(H − 1) (zenith and nadir on the first and last rows) where
    ours lies at (j + ½)/H. See :mod:`jkatana.light.envmap`.
    """
    import numpy as np

    mi = pytest.importorskip("mitsuba")
    import jax.numpy as jnp

    from jkatana.light.envmap import direction_to_uv
    from jkatana.render.renderer import rotation_y
    from jkatana.render.environment import bilinear_equirect

    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(0)
    H, W = 8, 16
    img = rng.uniform(0.1, 1.0, (H, W, 3)).astype(np.float32)
    em = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(img)})
    d = rng.normal(size=(128, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    si = mi.SurfaceInteraction3f()
    theirs = []
    for x in d:
        si.wi = mi.Vector3f(*(-x))  # wi points back along the looked-up direction
        theirs.append(np.asarray(em.eval(si)))
    theirs = np.array(theirs)
    turned = d @ rotation_y(mc.MITSUBA_ENV_ROTATION_DEG).T
    u, v = (np.asarray(a, np.float64) for a in direction_to_uv(jnp.asarray(turned)))
    # bilinear with our columns and corner-aligned rows
    x, y = u * W - 0.5, v * (H - 1)
    x0, y0 = np.floor(x), np.clip(np.floor(y), 0, H - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    i0 = x0.astype(int) % W
    i1, j0 = (i0 + 1) % W, y0.astype(int)
    expect = ((img[j0, i0] * (1 - fx) + img[j0, i1] * fx) * (1 - fy)
              + (img[j0 + 1, i0] * (1 - fx) + img[j0 + 1, i1] * fx) * fy)
    np.testing.assert_allclose(theirs, expect, rtol=1e-5)
    # neither our own lookup of the turned direction (centred rows) nor the unturned one matches
    ours_turned = np.asarray(bilinear_equirect(jnp.asarray(img, jnp.float64), jnp.asarray(turned)))
    ours = np.asarray(bilinear_equirect(jnp.asarray(img, jnp.float64), jnp.asarray(d)))
    assert np.max(np.abs(theirs - ours_turned)) > 0.05 and np.max(np.abs(theirs - ours)) > 0.1


@pytest.fixture(scope="module")
def jk_rough_converged(env_small):
    """jkatana's converged rough sphere (the agreement test's settings): ``(rgb, mask)``."""
    jk, mask, _ = mc.render_jkatana(env_small, alpha=0.2, size=64, samples=256, supersample=3, seed=0)
    return jk, mask


_LD_DIRECT = pytest.mark.xfail(strict=True, reason=(
    "measured (seeds 0, deterministic): Mitsuba ldsampler + direct at 16384 spp vs jkatana's converged frame "
    "mean 0.203, p99 1.034 > 1.0 (ldsampler + path 16384: passes; ldsampler at 4096: p99 1.41-1.54 where "
    "stratified/multijitter give 1.05): the low-discrepancy pattern's residual is not analysed yet"))


@pytest.mark.slow
@pytest.mark.parametrize("sampler, integrator", [
    pytest.param(s, i, marks=[_LD_DIRECT] if (s, i) == ("ldsampler", "direct") else [])
    for s in mc.MITSUBA_SAMPLERS for i in mc.MITSUBA_INTEGRATORS])
def test_each_mitsuba_configuration_matches_jkatana(env_small, jk_rough_converged, sampler, integrator):
    """Every sampler × integrator the benchmark times renders the same image: the rough sphere within
    the agreement test's bars against jkatana's converged frame (mean ≤ 0.5, p99 ≤ 1.0, sums ≤ 0.3 %),
    at the agreement test's 16384 spp (at 4096 the stratified and low-discrepancy samplers' p99 is
    1.05–1.5: their advantage at a given spp does not reach 4× here).
    """
    spp = 16384
    mi_img = mc.render_mitsuba(env_small, alpha=0.2, size=64, spp=spp, seed=0, sampler=sampler,
                               integrator=integrator)
    jk, mask = jk_rough_converged
    err = mc.compare(mi_img, jk, mask)
    ratio = _channel_ratios(mi_img, jk, mask)
    assert err["dE2000_mean"] <= 0.5, err
    assert err["dE2000_p99"] <= 1.0, err
    assert abs(ratio - 1).max() <= 0.003, ratio


def test_mitsuba_configuration_is_checked_and_sample_count_is_mitsubas(env_small):
    """An unknown sampler or integrator is an :class:`InputError` naming the field; ``orthogonal``
    rounds the spp up to a prime's square (Mitsuba's own rule), the others keep it."""
    from jkatana.errors import InputError

    with pytest.raises(InputError, match="sampler"):
        mc.render_mitsuba(env_small, alpha=0.2, size=4, spp=1, sampler="sobol")
    with pytest.raises(InputError, match="integrator"):
        mc.render_mitsuba(env_small, alpha=0.2, size=4, spp=1, integrator="volpath")
    assert mc.mitsuba_sample_count("orthogonal", 16) == 25
    assert mc.mitsuba_sample_count("orthogonal", 49) == 49
    assert [mc.mitsuba_sample_count(s, 64) for s in ("independent", "stratified", "multijitter", "ldsampler")] \
        == [64, 64, 64, 64]
