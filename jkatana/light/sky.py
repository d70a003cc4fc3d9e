"""The built-in spectral daylight: the Hosek–Wilkie sky with its solar disc.

Sky dome: Hosek L., Wilkie A. (2012), "An Analytic Model for Full Spectral
Sky-Dome Radiance", ACM TOG 31(4), 95. Sun: Hosek L., Wilkie A. (2013),
"Adding a Solar-Radiance Function to the Hosek–Wilkie Skylight Model", IEEE
CG&A 33(3), 44–52. This module re-implements the evaluation functions of the
authors' reference C code (``ArHosekSkyModel.c`` v1.4a) in NumPy and uses
their coefficient tables, shipped in ``jkatana/data/sky/`` as NumPy arrays:

    Copyright (c) 2012 - 2013, Lukas Hosek and Alexander Wilkie. All rights
    reserved. Redistribution and use in source and binary forms, with or
    without modification, are permitted under the BSD 3-Clause licence; the
    full notice is ``jkatana/data/sky/LICENSE_Hosek-Wilkie_BSD3.txt``.

Model (per band λ ∈ {320, 360, …, 720} nm; the 11 bands are linearly
interpolated to any wavelength in 320–720 nm, as the reference code does):

    L(θ, γ) = (1 + A e^{B/(cos θ + 0.01)}) (C + D e^{Eγ} + F cos²γ
              + G (1 + cos²γ)/(1 + H² − 2H cos γ)^{3/2} + I √cos θ) · L_M

with θ the view zenith angle, γ the angle to the sun, the nine coefficients
A…I and L_M interpolated from the tables by a quintic Bézier in
``(elevation/(π/2))^{1/3}``, linearly in turbidity (1–10) and ground albedo
(0–1). Spectral radiance is in W m⁻² sr⁻¹ nm⁻¹.

Solar disc (2013 paper): radius 0.255° (0.51° diameter), direct radiance
from the ``solarDataset`` piecewise cubic (45 pieces in
``(2 elevation/π)^{1/3}`` of the *viewing* elevation, per turbidity) times the
fifth-order limb-darkening polynomial in ``cos`` of the angle from the disc
centre at the solar surface. The tables start at 320 nm but the solar table is
zero below 400 nm (no solar radiance is defined there).

Rasterisation: every texel holds its *average* radiance. Texels that overlap
the disc are supersampled and the disc's contribution rescaled so that
``Σ ΔL Ω`` equals the disc's exact integral ``2π ∫ L_sun(γ) sin γ dγ``
(Gauss–Legendre), so the sun's power is exact at any resolution even when the
disc is smaller than a texel.

Ground (below the horizon; the model is undefined there): a Lambertian
plane of reflectance ``albedo`` (the same value the sky model was fitted
with) lit by the map's own upper hemisphere, ``L_g(λ) = albedo/π · E(λ)``
with ``E`` the horizontal irradiance of sky and sun. Interreflection between
ground and sky is already inside the model's fit; nothing else is added.

The tristimulus variants (``hosek_wilkie_tristimulus``, RGB and CIE XYZ
tables) are independent fits of the same model.

Sun position for a place and time: :func:`sun_position`, NOAA Global
Monitoring Laboratory, "General Solar Position Calculations" (after Spencer
1971, "Fourier series representation of the position of the sun", Search
2(5)): accurate to about 0.1°–0.5° (no refraction), enough for lighting.
"""

from __future__ import annotations

import datetime as _dt
import functools
import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from jkatana.errors import InputError
from jkatana.light.envmap import (EnvMap, direction_to_uv, equirect_direction, irradiance_weights_np,
                                  texel_directions_np, texel_solid_angles_np)
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid, resample

DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "sky"
BANDS = np.arange(320.0, 721.0, 40.0)  # the 11 model bands (nm)
SOLAR_RADIUS = math.radians(0.51) / 2.0  # rad (Hosek & Wilkie 2013)
_PIECES, _ORDER = 45, 4


@functools.lru_cache(maxsize=None)
def _tables(variant: str = "Spectral") -> dict[str, np.ndarray]:
    path = DATA_DIR / f"ArHosekSkyModelData_{variant}_arrays.npz"
    if not path.is_file():
        raise InputError("Hosek–Wilkie table missing from the installation", path=path)
    with np.load(path) as d:
        return {k: np.asarray(d[k], np.float64) for k in d.files}


def _check(elevation: float, turbidity: float, albedo: float) -> None:
    if not (0.0 <= elevation <= math.pi / 2 + 1e-12):
        raise InputError(f"sun elevation must be within 0..90 degrees for the Hosek–Wilkie model, "
                         f"got {math.degrees(elevation):.3f}", field="elevation")
    if not (1.0 <= turbidity <= 10.0):
        raise InputError(f"turbidity must be within 1..10, got {turbidity}", field="turbidity")
    if not (0.0 <= albedo <= 1.0):
        raise InputError(f"ground albedo must be within 0..1, got {albedo}", field="albedo")


def _bezier(m: np.ndarray, x: float, stride: int) -> np.ndarray:
    """Quintic Bézier over the 6 elevation control points of ``m`` (entries ``i + k·stride``)."""
    w = np.array([(1 - x) ** 5, 5 * (1 - x) ** 4 * x, 10 * (1 - x) ** 3 * x**2,
                  10 * (1 - x) ** 2 * x**3, 5 * (1 - x) * x**4, x**5])
    return np.einsum("k,ki->i", w, m[: 6 * stride].reshape(6, stride))


def cook_configuration(dataset: np.ndarray, turbidity: float, albedo: float, elevation: float,
                       stride: int = 9) -> np.ndarray:
    """``ArHosekSkyModel_CookConfiguration`` (stride 9) / ``CookRadianceConfiguration`` (stride 1).

    Interpolates the table in albedo (2 nodes), turbidity (10 nodes, 1…10) and
    solar elevation (quintic Bézier in ``(elevation/(π/2))^{1/3}``).
    """
    t_int = int(turbidity)
    t_rem = turbidity - t_int
    x = (elevation / (math.pi / 2)) ** (1.0 / 3.0)
    block = 6 * stride

    def at(alb: int, t: int) -> np.ndarray:
        start = block * 10 * alb + block * (t - 1)
        return _bezier(dataset[start:start + block], x, stride)

    out = (1 - albedo) * (1 - t_rem) * at(0, t_int) + albedo * (1 - t_rem) * at(1, t_int)
    if t_int < 10:
        out = out + (1 - albedo) * t_rem * at(0, t_int + 1) + albedo * t_rem * at(1, t_int + 1)
    return out


def _internal(config: np.ndarray, cos_theta, gamma):
    """``ArHosekSkyModel_GetRadianceInternal``; ``config (..., 9)`` broadcasts against the angles."""
    c = [config[..., i] for i in range(9)]
    cg = np.cos(gamma)
    exp_m = np.exp(c[4] * gamma)
    ray_m = cg * cg
    mie_m = (1.0 + cg * cg) / np.power(1.0 + c[8] * c[8] - 2.0 * c[8] * cg, 1.5)
    zenith = np.sqrt(np.maximum(cos_theta, 0.0))
    return (1.0 + c[0] * np.exp(c[1] / (np.maximum(cos_theta, 0.0) + 0.01))) * (
        c[2] + c[3] * exp_m + c[5] * ray_m + c[6] * mie_m + c[7] * zenith)


def sky_bands(cos_theta, gamma, elevation: float, turbidity: float, albedo: float) -> np.ndarray:
    """Spectral sky radiance at the 11 model bands, ``(..., 11)`` in W m⁻² sr⁻¹ nm⁻¹.

    ``cos_theta``: cosine of the view zenith angle (clamped to ≥ 0); ``gamma``:
    angle to the sun (rad); ``elevation``: solar elevation (rad).
    """
    _check(elevation, turbidity, albedo)
    t = _tables("Spectral")
    configs = np.stack([cook_configuration(t[f"dataset{int(b)}"], turbidity, albedo, elevation)
                        for b in BANDS])  # (11, 9)
    rads = np.array([cook_configuration(t[f"datasetRad{int(b)}"], turbidity, albedo, elevation, 1)[0]
                     for b in BANDS])
    ct = np.asarray(cos_theta, np.float64)[..., None]
    g = np.asarray(gamma, np.float64)[..., None]
    return _internal(configs, ct, g) * rads


def hosek_wilkie_tristimulus(cos_theta, gamma, elevation: float, turbidity: float, albedo: float,
                             variant: str = "CIEXYZ") -> np.ndarray:
    """The tristimulus variants of the model (``"CIEXYZ"`` or ``"RGB"``), ``(..., 3)``.

    The reference code's ``arhosek_tristim_skymodel_radiance``: the same
    functional form with independently fitted tables. Units as the tables
    (see ``tests/test_light_sky.py`` for the measured relation to the spectral
    variant).
    """
    _check(elevation, turbidity, albedo)
    if variant not in ("CIEXYZ", "RGB"):
        raise InputError(f"variant must be 'CIEXYZ' or 'RGB', got {variant!r}", field="variant")
    t = _tables(variant)
    key = "XYZ" if variant == "CIEXYZ" else "RGB"
    configs = np.stack([cook_configuration(t[f"dataset{key}{i}"], turbidity, albedo, elevation) for i in (1, 2, 3)])
    rads = np.array([cook_configuration(t[f"dataset{key}Rad{i}"], turbidity, albedo, elevation, 1)[0]
                     for i in (1, 2, 3)])
    ct = np.asarray(cos_theta, np.float64)[..., None]
    g = np.asarray(gamma, np.float64)[..., None]
    return _internal(configs, ct, g) * rads


def band_weights(wavelengths: np.ndarray) -> np.ndarray:
    """``(11, n)`` matrix taking radiance at the model bands to ``wavelengths`` (320–720 nm) by linear
    interpolation, as the reference code interpolates between its bands (:func:`jkatana.spectral.resample`)."""
    wl = np.asarray(wavelengths, np.float64)
    if wl.min() < BANDS[0] - 1e-9 or wl.max() > BANDS[-1] + 1e-9:
        raise InputError(f"the Hosek–Wilkie model covers 320–720 nm; grid spans {wl.min()}–{wl.max()} nm",
                         field="grid")
    return resample(BANDS, np.eye(BANDS.size), wl, name="Hosek–Wilkie bands")


def solar_direct(wavelengths, view_elevation, turbidity: float) -> np.ndarray:
    """Direct solar radiance at the disc centre (no limb darkening), ``(..., n)``.

    ``arhosekskymodel_sr_internal`` interpolated in turbidity and wavelength as
    ``arhosekskymodel_solar_radiance_internal2`` does. ``view_elevation`` (rad) ≥ 0.
    """
    t = _tables("Spectral")
    wl = np.asarray(wavelengths, np.float64)
    elev = np.clip(np.asarray(view_elevation, np.float64), 0.0, math.pi / 2)[..., None]
    t_low = int(turbidity) - 1
    t_frac = turbidity - (t_low + 1)
    if t_low == 9:
        t_low, t_frac = 8, 1.0
    pos = np.minimum((np.power(2.0 * elev / math.pi, 1.0 / 3.0) * _PIECES).astype(int), _PIECES - 1)
    break_x = np.power(pos / _PIECES, 3.0) * (math.pi / 2)
    x = elev - break_x

    def sr(turb: int, band: np.ndarray) -> np.ndarray:
        table = np.stack([t[f"solarDataset{int(b)}"] for b in BANDS])  # (11, 1800)
        end = _ORDER * _PIECES * turb + _ORDER * (pos + 1) - 1  # index of the constant term
        res = np.zeros(np.broadcast(x, band).shape)
        xe = np.ones_like(res)
        for i in range(_ORDER):
            res = res + xe * table[band, end - i]
            xe = xe * x
        return res

    wl_low = np.minimum(((wl - 320.0) / 40.0).astype(int), 9)
    wl_frac = (wl - BANDS[wl_low]) / 40.0
    return ((1 - t_frac) * ((1 - wl_frac) * sr(t_low, wl_low) + wl_frac * sr(t_low, wl_low + 1))
            + t_frac * ((1 - wl_frac) * sr(t_low + 1, wl_low) + wl_frac * sr(t_low + 1, wl_low + 1)))


def limb_darkening(wavelengths, gamma) -> np.ndarray:
    """Limb-darkening factor ``(..., n)`` at angle ``gamma`` (rad) from the disc centre (0 outside)."""
    t = _tables("Spectral")
    ld = np.stack([t[f"limbDarkeningDataset{int(b)}"] for b in BANDS])  # (11, 6)
    coef = band_weights(wavelengths).T @ ld  # (n, 6)
    s = np.sin(np.asarray(gamma, np.float64))[..., None] / math.sin(SOLAR_RADIUS)
    mu = np.sqrt(np.maximum(1.0 - s * s, 0.0))
    poly = sum(coef[:, i] * mu**i for i in range(6))
    return np.where(s < 1.0, poly, 0.0)


def solar_disc_radiance(wavelengths, view_elevation, gamma, turbidity: float) -> np.ndarray:
    """Direct radiance of the disc at angle ``gamma`` from its centre (0 outside the disc)."""
    return solar_direct(wavelengths, view_elevation, turbidity) * limb_darkening(wavelengths, gamma)


def solar_disc_integral(wavelengths, elevation: float, turbidity: float, n: int = 64) -> np.ndarray:
    """``∫_disc L_sun dω = 2π ∫₀^r L(γ) sin γ dγ`` (Gauss–Legendre, ``n`` nodes), W m⁻² nm⁻¹."""
    x, w = np.polynomial.legendre.leggauss(n)
    g = 0.5 * SOLAR_RADIUS * (x + 1)
    L = solar_disc_radiance(wavelengths, np.full_like(g, elevation), g, turbidity)  # (n, wl)
    return 2 * math.pi * 0.5 * SOLAR_RADIUS * np.einsum("k,kl->l", w * np.sin(g), L)


def sun_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit world direction towards the sun: azimuth clockwise from north (−Z) towards east (+X), Y up."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.sin(a) * math.cos(e), math.sin(e), -math.cos(a) * math.cos(e)])


def sun_position(latitude_deg: float, longitude_deg: float, when: _dt.datetime) -> tuple[float, float]:
    """Solar ``(elevation_deg, azimuth_deg)`` (azimuth clockwise from north) for a place and time.

    NOAA Global Monitoring Laboratory, "General Solar Position Calculations"
    (Spencer 1971 Fourier series for the equation of time and declination).
    ``when`` is timezone-aware or taken as UTC; longitude positive east.
    Atmospheric refraction is ignored (≲ 0.6° at the horizon).
    """
    if when.tzinfo is not None:
        when = when.astimezone(_dt.timezone.utc).replace(tzinfo=None)
    if not (-90 <= latitude_deg <= 90):
        raise InputError(f"latitude must be within ±90°, got {latitude_deg}", field="latitude")
    doy = when.timetuple().tm_yday
    days = 366 if (when.year % 4 == 0 and (when.year % 100 != 0 or when.year % 400 == 0)) else 365
    hour = when.hour + when.minute / 60 + when.second / 3600
    g = 2 * math.pi / days * (doy - 1 + (hour - 12) / 24)
    eqtime = 229.18 * (0.000075 + 0.001868 * math.cos(g) - 0.032077 * math.sin(g)
                       - 0.014615 * math.cos(2 * g) - 0.040849 * math.sin(2 * g))
    decl = (0.006918 - 0.399912 * math.cos(g) + 0.070257 * math.sin(g) - 0.006758 * math.cos(2 * g)
            + 0.000907 * math.sin(2 * g) - 0.002697 * math.cos(3 * g) + 0.00148 * math.sin(3 * g))
    tst = hour * 60 + eqtime + 4 * longitude_deg  # true solar time (min), UTC input
    ha = math.radians(tst / 4 - 180)
    lat = math.radians(latitude_deg)
    cos_zen = math.sin(lat) * math.sin(decl) + math.cos(lat) * math.cos(decl) * math.cos(ha)
    elev = 90 - math.degrees(math.acos(max(-1.0, min(1.0, cos_zen))))
    az = math.degrees(math.atan2(math.sin(ha), math.cos(ha) * math.sin(lat) - math.tan(decl) * math.cos(lat))) + 180
    return elev, az % 360


def hosek_wilkie_sky(elevation_deg: float = 30.0, azimuth_deg: float = 180.0, turbidity: float = 3.0,
                     albedo: float = 0.1, resolution: tuple[int, int] = (256, 512),
                     grid: WavelengthGrid = DEFAULT_GRID, sun: bool = True, *, ground: bool = True,
                     sun_supersampling: int = 24, dtype=jnp.float32) -> EnvMap:
    """The Hosek–Wilkie spectral sky (+ solar disc, + ground) as an :class:`EnvMap`.

    **Arguments:**

    - `elevation_deg`, `azimuth_deg`: sun position; azimuth clockwise from north
      (−Z, the image centre) towards east (+X). Elevation 0–90°.
    - `turbidity`: 1–10 (Linke-like; 2 = very clear, 3 = clear, 6+ = hazy).
    - `albedo`: ground albedo 0–1 (used by the sky fit and for the ground).
    - `resolution`: ``(H, W)`` of the equirectangular map.
    - `grid`: wavelength grid, within 320–720 nm.
    - `sun`: add the solar disc (power-exact rasterisation, see module docstring).
    - `ground`: fill the lower hemisphere with the albedo-weighted Lambertian
      ground; otherwise zero.
    - `sun_supersampling`: subsamples per texel side for texels under the disc.

    **Returns:** :class:`EnvMap` in W m⁻² sr⁻¹ nm⁻¹.
    """
    H, W = int(resolution[0]), int(resolution[1])
    if H < 2 or W < 2:
        raise InputError(f"resolution must be at least 2×2, got {resolution}", field="resolution")
    elev = math.radians(elevation_deg)
    _check(elev, turbidity, albedo)
    wl = grid.wavelengths
    Wb = band_weights(wl)
    s = sun_direction(elevation_deg, azimuth_deg)
    dirs = texel_directions_np(H, W)
    omega = texel_solid_angles_np(H, W)
    L = np.zeros((H, W, wl.size), np.float64)
    upper = dirs[..., 1] >= 0.0
    rows = np.nonzero(upper.any(axis=1))[0]
    for r0 in range(0, rows.size, 64):
        rr = rows[r0:r0 + 64]
        d = dirs[rr]
        gamma = np.arctan2(np.linalg.norm(np.cross(d, s), axis=-1), d @ s)
        bands = sky_bands(d[..., 1], gamma, elev, turbidity, albedo)
        L[rr] = np.where(upper[rr][..., None], bands @ Wb, 0.0)
    if sun:
        L += _sun_texels(H, W, s, elev, turbidity, wl, omega, sun_supersampling)
    if ground:
        E = np.einsum("hw,hwl->l", irradiance_weights_np(H, W), L)
        L[~upper] = albedo / math.pi * E
    return EnvMap(jnp.asarray(L, dtype), grid)


def _sun_texels(H, W, s, elev, turbidity, wl, omega, n_sub) -> np.ndarray:
    """Texel-average solar radiance, rescaled so the disc's power is exact."""
    out = np.zeros((H, W, wl.size))
    u, v = (float(x) for x in direction_to_uv(s))
    # texels whose centre is within the disc radius + one texel diagonal of the sun
    ci, cj = int(u * W) % W, min(int(v * H), H - 1)
    dv = math.pi / H
    sin_t = max(math.sin(v * math.pi), math.sin(dv))
    ri = int(math.ceil((SOLAR_RADIUS / (2 * math.pi / W)) / sin_t)) + 2
    rj = int(math.ceil(SOLAR_RADIUS / dv)) + 2
    js = [j for j in range(cj - rj, cj + rj + 1) if 0 <= j < H]
    iis = [i % W for i in range(ci - ri, ci + ri + 1)]
    iis = list(dict.fromkeys(iis))
    t = (np.arange(n_sub) + 0.5) / n_sub
    total = np.zeros(wl.size)
    for j in js:
        theta = (j + t) * dv  # (n,)
        for i in iis:
            th, uu = np.meshgrid(theta, (i + t) / W, indexing="ij")
            d = equirect_direction(uu, np.cos(th), np.sin(th))
            gamma = np.arctan2(np.linalg.norm(np.cross(d, s), axis=-1), d @ s)
            inside = (gamma < SOLAR_RADIUS) & (d[..., 1] >= 0)
            if not inside.any():
                continue
            wgt = np.sin(th) * inside
            Ls = solar_disc_radiance(wl, np.arcsin(np.clip(d[..., 1], 0, 1))[inside], gamma[inside], turbidity)
            avg = np.einsum("k,kl->l", wgt[inside], Ls) / np.sin(th).sum()
            out[j, i] = avg
            total += avg * omega[j, i]
    exact = solar_disc_integral(wl, elev, turbidity)
    if elev < SOLAR_RADIUS:  # part of the disc is below the horizon: keep the rasterised power
        return out
    scale = np.where(total > 0, exact / np.where(total > 0, total, 1.0), 0.0)
    return out * scale
