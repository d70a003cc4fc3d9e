"""Compact bright sources split off as spherical caps."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.light import EnvMap, load_envmap
from jkatana.light import sky as S
from jkatana.light.envmap import texel_directions_np, texel_solid_angles_np
from jkatana.light.sun import split_compact_sources, split_sky_sun
from jkatana.shared import shared_data
from jkatana.spectral.grid import WavelengthGrid
from tests._scenes import paste_disc

GRID = WavelengthGrid(400.0, 700.0, 10.0)
SUN_R = S.SOLAR_RADIUS  # 0.00445 rad


def band_power(L):
    L = np.asarray(L, np.float64)
    return np.einsum("hw,hwl->l", texel_solid_angles_np(*L.shape[:2]), L)


def assert_conserved(env, split, rtol=1e-6):
    total = band_power(env.radiance)
    parts = band_power(split.remainder.radiance) + sum(np.asarray(c.power(), np.float64) for c in split.caps)
    np.testing.assert_allclose(parts, total, rtol=rtol, atol=0)


def angle(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return math.atan2(np.linalg.norm(np.cross(a, b)), a @ b)


# ---------------------------------------------------------------- synthetic sun


def smooth_sky(H, W):
    d = texel_directions_np(H, W)
    wl = GRID.wavelengths
    shape = 1.0 + 0.8 * (700.0 - wl) / 300.0  # bluish
    return (0.3 + 0.7 * np.maximum(d[..., 1], 0.0) + 0.05 * d[..., 0])[..., None] * shape


@pytest.mark.parametrize("H, radius_deg, elev, az, radius_rtol",
                         [(256, 1.5, 35.0, 120.0, 0.03), (128, 1.2, 12.0, 359.5, 0.1)])
def test_synthetic_sun_found_and_recovered(H, radius_deg, elev, az, radius_rtol):
    """A uniform disc pasted into a smooth sky: found, centred within a texel, its radius
    recovered (to 3 % at 2 texels of radius, 10 % at 0.9 texel, across the u seam), its
    spectrum and power carried by the cap, energy conserved to 1e-6 per band."""
    W = 2 * H
    s = S.sun_direction(elev, az)
    r = math.radians(radius_deg)
    sun = 3e4 * (1.0 + np.sin(GRID.wavelengths / 40.0) ** 2)  # structured spectrum
    sky = smooth_sky(H, W)
    L, disc_omega = paste_disc(sky, s, r, sun)
    env = EnvMap(jnp.asarray(L), GRID)
    split = split_compact_sources(env)
    assert len(split.caps) == 1
    cap = split.cap
    texel = math.pi / H
    assert angle(cap.direction, s) < texel
    assert abs(float(cap.radius) - r) < radius_rtol * r
    # the cap carries the disc's power (plus the sky under it, minus the fill), per band
    np.testing.assert_allclose(np.asarray(cap.power()), sun * disc_omega, rtol=2e-3)
    # and its spectrum is the sun's
    shape = np.asarray(cap.radiance) / np.asarray(cap.radiance).mean()
    np.testing.assert_allclose(shape, sun / sun.mean(), rtol=1e-3)
    assert_conserved(env, split)
    # the remainder is the sky: refilled texels within 5 % of it, the rest untouched
    rem = np.asarray(split.remainder.radiance)
    mask = split.regions[0]
    np.testing.assert_allclose(rem[mask], sky[mask], rtol=0.05)
    np.testing.assert_array_equal(rem[~mask], L[~mask])


def test_nothing_split_from_constant_or_black_map():
    for value in (0.0, 2.5):
        env = EnvMap(jnp.full((32, 64, GRID.size), value), GRID)
        split = split_compact_sources(env)
        assert split.caps == () and split.remainder is env


def test_large_bright_region_is_not_compact():
    """A window of 0.1 sr at 1e4× the sky: bright, powerful, but not compact → nothing split."""
    H, W = 128, 256
    L = smooth_sky(H, W)
    L, _ = paste_disc(L, S.sun_direction(30.0, 90.0), 0.18, np.full(GRID.size, 1e4))
    env = EnvMap(jnp.asarray(L), GRID)
    assert split_compact_sources(env).caps == ()
    # the same source passes when the bound on solid angle admits it
    assert len(split_compact_sources(env, max_solid_angle=0.2).caps) == 1


def test_weak_source_is_not_split():
    """Compact and bright but below the power fraction → nothing split."""
    H, W = 128, 256
    L, _ = paste_disc(smooth_sky(H, W), S.sun_direction(30.0, 90.0), 0.01, np.full(GRID.size, 5e3))
    env = EnvMap(jnp.asarray(L), GRID)
    assert split_compact_sources(env, min_power_fraction=0.5).caps == ()


# ---------------------------------------------------------------- the built-in sky


def test_sky_sun_split_is_the_solar_disc():
    env, split = split_sky_sun(25.0, 200.0, 3.0, 0.1, (64, 128), GRID)
    cap = split.cap
    np.testing.assert_allclose(np.asarray(cap.direction), S.sun_direction(25.0, 200.0), atol=1e-6)
    assert float(cap.radius) == pytest.approx(SUN_R, rel=1e-6)
    exact = S.solar_disc_integral(GRID.wavelengths, math.radians(25.0), 3.0)
    np.testing.assert_allclose(np.asarray(cap.power()), exact, rtol=1e-5)
    assert_conserved(env, split)
    # the detector finds the same sun in the rasterised map, within a texel
    found = split_compact_sources(env)
    assert len(found.caps) == 1
    assert angle(found.cap.direction, cap.direction) < math.pi / 64
    np.testing.assert_allclose(np.asarray(found.cap.power()), exact, rtol=0.02)
    assert_conserved(env, found)


# ---------------------------------------------------------------- real maps


@pytest.mark.slow
def test_real_hdr_sun_split():
    """sunrise.exr: the sun at ≈ 8° holds ≈ 56 % of the power in 13 texels (4.9e-4 sr)."""
    env = load_envmap(shared_data("envmaps", "sunrise.exr"), GRID)
    split = split_compact_sources(env)
    assert len(split.caps) == 1
    assert split.power_fractions[0] > 0.5
    assert split.region_solid_angles[0] <= 5e-3
    d = np.asarray(split.cap.direction)
    assert math.degrees(math.asin(d[1])) == pytest.approx(8.0, abs=0.5)
    assert math.radians(0.15) < float(split.cap.radius) < math.radians(0.5)
    assert_conserved(env, split)


@pytest.mark.slow
def test_real_maps_without_compact_source_unchanged():
    """studio.exr's softboxes are bright but large; pedestrian_overpass_1k.hdr's sun is clipped
    (42× the median, 0.3 % of the power): neither is a compact source by the stated criterion."""
    for name in ("studio.exr", "pedestrian_overpass_1k.hdr"):
        env = load_envmap(shared_data("envmaps", name), GRID)
        split = split_compact_sources(env)
        assert split.caps == () and split.remainder is env
