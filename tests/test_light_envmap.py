"""Environment maps: orientation convention, lookups, I/O (real EXR/HDR files), spectral EXR interop."""

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, strategies as st

from jkatana.errors import InputError
from jkatana.io.exr import write_exr
from jkatana.light import EnvMap, direction_to_uv, load_envmap, uv_to_direction, write_spectral_exr
from jkatana.light.spectral_exr import is_spectral_exr, read_spectral_exr
from jkatana.spectral import WavelengthGrid
from jkatana.shared import shared_data

ENVMAPS = shared_data("envmaps")
G7 = WavelengthGrid(400, 700, 50)


def _map_with_texel(H=16, W=32, j=3, i=21, value=100.0, grid=G7):
    L = np.ones((H, W, grid.size)) * 0.5
    L[j, i] = value
    return EnvMap(jnp.asarray(L), grid)


def test_axes_convention():
    # image centre looks along -Z, u = 0.75 along +X, row 0 at the zenith
    u, v = direction_to_uv(jnp.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0],
                                      [-1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(np.asarray(u)[[0, 1, 4]], [0.5, 0.75, 0.25], atol=1e-12)
    np.testing.assert_allclose(np.asarray(v), [0.5, 0.5, 0.0, 1.0, 0.5], atol=1e-12)


@given(st.floats(0.0, 0.999), st.floats(0.001, 0.999))
def test_uv_round_trip(u, v):
    d = uv_to_direction(u, v)
    assert abs(float(jnp.linalg.norm(d)) - 1) < 1e-12
    u2, v2 = direction_to_uv(d)
    assert abs(float(u2) - u) < 1e-9 and abs(float(v2) - v) < 1e-9


def test_polynomial_atan2_matches_arctan2_in_float32():
    """The float32 polynomial atan2 is within 4e-7 rad of the exact angle on every octant, its boundaries,
    signed zeros and extreme ratios (a coefficient or octant error gives ≥ 1e-5), and its u, v match
    jnp.arctan2's; float64 is jnp.arctan2 itself."""
    from jkatana.light.envmap import atan2

    rng = np.random.default_rng(3)
    ang = np.concatenate([rng.uniform(-np.pi, np.pi, 20000), np.arange(-8, 9) * np.pi / 8,
                          np.arange(-8, 9) * np.pi / 8 + 1e-6,
                          np.arctan(0.41421356237309503) + np.array([-1e-7, 0, 1e-7])])
    r = np.concatenate([np.geomspace(1e-30, 1e30, 7), [1.0]])[:, None]
    y, x = (r * np.sin(ang)).ravel(), (r * np.cos(ang)).ravel()
    y = np.concatenate([y, [0.0, -0.0, 0.0, -0.0, 0.0, 1.0, -1.0, 1e-30, 1.0]])
    x = np.concatenate([x, [0.0, 0.0, -1.0, -1.0, 1.0, 0.0, 0.0, 1.0, 1e-30]])
    y32, x32 = y.astype(np.float32), x.astype(np.float32)
    exact = np.arctan2(y32.astype(np.float64), x32.astype(np.float64))
    got = np.asarray(jax.jit(atan2)(jnp.asarray(y32), jnp.asarray(x32)), np.float64)
    assert np.asarray(atan2(jnp.float32(1.0), jnp.float32(2.0))).dtype == np.float32
    # ±π are the same angle; the exact atan2 of the float32 inputs decides the sign at the branch cut
    err = np.abs(got - exact)
    err = np.minimum(err, np.abs(np.abs(err) - 2 * np.pi))
    assert err.max() < 4e-7, err.max()
    assert np.array_equal(np.signbit(got[-9:-4]), np.signbit(exact[-9:-4]))
    d = jnp.asarray(rng.normal(size=(5000, 3)), jnp.float32)
    u_ref = 0.5 + jnp.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    v_ref = jnp.arctan2(jnp.hypot(d[:, 0], d[:, 2]), d[:, 1]) / np.pi
    u, v = direction_to_uv(d)
    # within 2 float32 ulps of 1 (the map coordinates' own resolution)
    assert float(jnp.max(jnp.abs(u - u_ref))) <= 2.4e-7 and float(jnp.max(jnp.abs(v - v_ref))) <= 2.4e-7
    y64, x64 = jnp.asarray(y, jnp.float64), jnp.asarray(x, jnp.float64)  # the tests run with x64 enabled
    np.testing.assert_array_equal(np.asarray(atan2(y64, x64)), np.asarray(jnp.arctan2(y64, x64)))


def test_one_equirect_convention_for_numpy_and_jax():
    """Texel directions, uv → direction, the texel index and the sampler's warp share one convention."""
    from jkatana.light.envmap import equirect_direction, texel_directions_np, texel_index

    H, W = 8, 16
    d = texel_directions_np(H, W)
    assert isinstance(d, np.ndarray) and d.dtype == np.float64
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    uu, vv = np.meshgrid(u, v)
    np.testing.assert_allclose(np.asarray(uv_to_direction(jnp.asarray(uu), jnp.asarray(vv))), d, atol=1e-12)
    j, i = texel_index(jnp.asarray(uu), jnp.asarray(vv), H, W)
    np.testing.assert_array_equal(np.asarray(j), np.arange(H)[:, None].repeat(W, 1))
    np.testing.assert_array_equal(np.asarray(i), np.arange(W)[None].repeat(H, 0))
    jd = equirect_direction(jnp.asarray(0.75), jnp.asarray(0.0), jnp.asarray(1.0))
    assert isinstance(jd, jax.Array)
    np.testing.assert_allclose(np.asarray(jd), [1.0, 0.0, 0.0], atol=1e-12)  # u = 0.75 looks along +X


def test_bilinear_uv_is_the_lookup_away_from_the_poles():
    from jkatana.light.envmap import bilinear_uv

    env = _map_with_texel(value=7.0)
    rng = np.random.default_rng(5)
    u = jnp.asarray(rng.random(500))
    v = jnp.asarray(rng.uniform(0.5 / env.height, 1 - 0.5 / env.height, 500))  # between the rows of centres
    d = uv_to_direction(u, v)
    np.testing.assert_array_equal(np.asarray(bilinear_uv(env.radiance, *direction_to_uv(d))),
                                  np.asarray(env.lookup(d)))


def test_bright_texel_at_its_direction():
    env = _map_with_texel()
    d = env.directions()[3, 21]
    # texel centre convention ((i+0.5)/W, (j+0.5)/H)
    u, v = direction_to_uv(d)
    assert abs(float(u) - 21.5 / 32) < 1e-12 and abs(float(v) - 3.5 / 16) < 1e-12
    np.testing.assert_allclose(np.asarray(env.lookup(d)), 100.0)
    np.testing.assert_allclose(np.asarray(env.lookup_nearest(d)), 100.0)
    # neighbours are blends, far directions are background
    np.testing.assert_allclose(np.asarray(env.lookup(jnp.array([0.0, -1.0, 0.0]))), 0.5)


def test_lookup_wraps_and_is_continuous_across_seam_and_pole():
    rng = np.random.default_rng(1)
    env = EnvMap(jnp.asarray(rng.random((8, 16, G7.size))), G7)
    eps = 1e-9
    a = env.lookup(jnp.array([eps, 0.2, 1.0]))
    b = env.lookup(jnp.array([-eps, 0.2, 1.0]))  # the +Z seam (u = 0 / 1)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-7)
    p1 = env.lookup(jnp.array([1e-9, 1.0, 0.0]))
    p2 = env.lookup(jnp.array([0.0, 1.0, -1e-9]))
    np.testing.assert_allclose(np.asarray(p1), np.asarray(p2), atol=1e-7)
    np.testing.assert_allclose(np.asarray(p1), np.asarray(env.radiance[0].mean(0)), atol=1e-7)


def test_lookup_jit_and_grad_in_radiance():
    env = _map_with_texel()
    dirs = jax.random.normal(jax.random.PRNGKey(0), (50, 3))

    @jax.jit
    def total(rad):
        return jnp.sum(EnvMap(rad, G7).lookup(dirs))

    g = jax.grad(total)(env.radiance)
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.sum(g)) == pytest.approx(50 * G7.size)


def test_solid_angles_and_downsample_preserve_power():
    env = _map_with_texel(H=32, W=64, j=5, i=40, value=1e4)
    assert float(env.solid_angles().sum()) == pytest.approx(4 * math.pi, rel=1e-12)
    p = jnp.einsum("hw,hwl->l", env.solid_angles(), env.radiance)
    small = env.downsample(4)
    p2 = jnp.einsum("hw,hwl->l", small.solid_angles(), small.radiance)
    np.testing.assert_allclose(np.asarray(p2), np.asarray(p), rtol=1e-12)
    with pytest.raises(InputError):
        env.downsample(5)


def test_rotate_moves_features_by_compass_azimuth():
    env = _map_with_texel(H=16, W=32, j=4, i=8)
    r = env.rotate(2 * math.pi * 4 / 32)  # +45°: 4 columns towards east (+u)
    j, i = np.unravel_index(np.argmax(np.asarray(r.radiance[..., 0])), (16, 32))
    assert (j, i) == (4, 12)
    np.testing.assert_allclose(np.asarray(env.rotate(2 * math.pi).radiance), np.asarray(env.radiance), atol=1e-9)


def test_is_grey():
    assert EnvMap(jnp.ones((4, 8, G7.size)) * 3.0, G7).is_grey()
    L = np.ones((4, 8, G7.size))
    L[1, 2, 3] = 2.0
    assert not EnvMap(jnp.asarray(L), G7).is_grey()


def test_rgb_exr_with_known_bright_texel(tmp_path):
    H, W = 8, 16
    rgb = np.full((H, W, 3), 0.25, np.float32)
    rgb[2, 12] = (50.0, 40.0, 30.0)
    path = write_exr(tmp_path / "bright.exr", {c: rgb[..., k] for k, c in enumerate("RGB")})
    env = load_envmap(path, G7, upsampling="Mallett 2019")
    lum = np.asarray(env.luminance())
    assert np.unravel_index(np.argmax(lum), lum.shape) == (2, 12)
    d = env.directions()[2, 12]
    u, v = direction_to_uv(d)
    assert abs(float(u) - 12.5 / 16) < 1e-12 and abs(float(v) - 2.5 / 8) < 1e-12


@pytest.mark.parametrize("name", ["sunrise.exr", "pedestrian_overpass_1k.hdr"])
def test_real_maps_load(name):
    env = load_envmap(ENVMAPS / name, G7, upsampling="Mallett 2019")
    assert env.radiance.shape == (512, 1024, G7.size) and env.radiance.dtype == jnp.float32
    assert float(env.radiance.min()) >= 0 and np.isfinite(np.asarray(env.radiance)).all()
    lum = np.asarray(env.luminance())
    j, i = np.unravel_index(np.argmax(lum), lum.shape)
    assert j < 256  # the sun is above the horizon in both maps


def test_bad_inputs(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_envmap(tmp_path / "none.exr")
    p = tmp_path / "bad.exr"
    p.write_bytes(b"not an exr")
    with pytest.raises(InputError, match="bad.exr"):
        load_envmap(p)
    q = write_exr(tmp_path / "noRGB.exr", {"Z": np.zeros((4, 8))})
    with pytest.raises(InputError, match="channel"):
        load_envmap(q)
    with pytest.raises(InputError):
        EnvMap(jnp.zeros((4, 8, 5)), G7)


# ----------------------------------------------------------- spectral EXR (Fichet et al. 2021)


def test_colour_science_reads_what_jkatana_writes(tmp_path):
    from colour.io import read_spectral_image_Fichet2021

    rng = np.random.default_rng(3)
    L = (rng.random((6, 12, G7.size)) * 1e3).astype(np.float32)
    path = write_spectral_exr(tmp_path / "j.exr", L, G7)
    comps = read_spectral_image_Fichet2021(str(path))
    wl, values = comps["S0"]
    np.testing.assert_allclose(wl, G7.wavelengths)
    np.testing.assert_array_equal(values, L)  # float32 written, float32 read: bit-exact
    from jkatana.io.exr import read_exr

    path = write_spectral_exr(tmp_path / "h.exr", L, G7, header={"jkatana_samples": 16, "scene": "{}"})
    _, header = read_exr(path)
    assert header["spectralLayoutVersion"] == "1.0" and header["emissiveUnits"] == "W.m^-2.sr^-1"
    assert header["jkatana_samples"] == 16 and header["scene"] == "{}"


def test_jkatana_reads_what_colour_science_writes(tmp_path):
    from colour.io import Specification_Fichet2021, write_spectral_image_Fichet2021

    wl = np.arange(380.0, 781.0, 10.0)
    rng = np.random.default_rng(4)
    L = (rng.random((5, 10, wl.size)) * 10).astype(np.float32)
    path = tmp_path / "c.exr"
    assert write_spectral_image_Fichet2021({"S0": (wl, L)}, str(path), "float32",
                                           Specification_Fichet2021(is_emissive=True))
    assert is_spectral_exr(path)
    same = read_spectral_exr(path, WavelengthGrid(380, 780, 10))
    np.testing.assert_array_equal(same, L)
    env = load_envmap(path, G7)  # resampled onto 400..700/50: every 5th sample
    np.testing.assert_allclose(np.asarray(env.radiance), L[..., 2:33:5], rtol=1e-6)
    with pytest.raises(InputError, match="covers|range|outside|grid"):
        read_spectral_exr(path, WavelengthGrid(300, 700, 50))


def test_bilinear_taps_wrap_any_u_and_stay_in_the_image():
    """The taps wrap u as a modulo for any finite u (far outside [0, 1] too) and name texels of the image for any
    input, non-finite ones included: the loads (`gather_taps`) trust the indices."""
    from jkatana.light.envmap import bilinear_taps, bilinear_uv

    H, W = 6, 10
    img = jnp.asarray(np.random.default_rng(3).uniform(size=(H, W, 2)))
    u = jnp.asarray(np.random.default_rng(4).uniform(-40.0, 40.0, 500))
    v = jnp.asarray(np.random.default_rng(5).uniform(0.0, 1.0, 500))
    np.testing.assert_allclose(np.asarray(bilinear_uv(img, u, v)), np.asarray(bilinear_uv(img, u - jnp.floor(u), v)),
                               rtol=1e-9, atol=1e-12)
    bad = jnp.asarray(np.concatenate([[np.nan, np.inf, -np.inf, 1e30, -1e30, 0.5], np.geomspace(1e3, 1e12, 2000),
                                      -np.geomspace(1e3, 1e12, 2000)]), jnp.float32)  # float32: huge u round
    taps = bilinear_taps(bad, bad[::-1], H, W)
    for idx in taps[:4]:
        assert np.all((np.asarray(idx) >= 0) & (np.asarray(idx) < H * W))
    assert np.isfinite(np.asarray(bilinear_uv(img, bad[-1:], bad[-1:]))).all()
