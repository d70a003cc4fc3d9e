"""Compact bright sources (suns) split from an environment map as spherical-cap area lights.

A sun holds most of an outdoor map's power in a handful of texels. Sampled
or prefiltered as part of the map it is the source of the noise and of the
too-dark glints of the fast modes; as a separate light of known direction,
size and spectrum it can be integrated against the lobe deterministically
(:func:`jkatana.light.capquad.cap_integral`), and what is left of the map (the *remainder*) is
smooth enough to prefilter and sample.

## Which texels are a compact source (:func:`find_compact_sources`)

On the CIE-Y luminance ``Y`` of every texel and the exact texel solid angles
``Ω`` of the equirectangular grid (:func:`~jkatana.light.envmap.texel_solid_angles_np`):

1. a texel is *bright* when ``Y > contrast · median_Ω(Y)``, the median taken
   over the sphere (solid-angle weighted), default ``contrast = 1000``;
2. bright texels are grouped into 8-connected regions, connected across the
   ``u = 0/1`` seam of the map;
3. a region is a compact source when its solid angle is at most
   ``max_solid_angle`` (default 5e-3 sr, a cap of 2.3° radius, some 70 times
   the sun's disc: room for the partly covered texels and the glare around
   a sun in a 1k map, ≈ 130 of its texels) **and** it holds at
   least ``min_power_fraction`` (default 1 %) of the map's luminous power
   ``Σ Y Ω``. At most ``max_sources`` regions, most powerful first.

A constant map, a black one, or one whose bright parts are large (windows,
softboxes, an overcast sky) has no such region: nothing is split.

## The cap (:func:`split_compact_sources`)

Each region becomes a :class:`SunCap`:

- **direction**: the power-weighted (``Y Ω``) mean of the texel-centre
  directions, normalised;
- **angular radius** ``r`` from the region's power-weighted second moment
  about that direction: a uniform disc of radius ``r`` has
  ``E[ψ²] = r²/2``; the texels' own box variance ``(Δθ² + sin²θ Δφ²)/12``
  (the rasterisation's, which adds to the disc's) is subtracted first, so
  ``r² = 2 (E[ψ²] − E[box])``. It is *not* the cap enclosing the region (the
  threshold region includes partly covered edge texels and glare). A source
  smaller than the map resolves (``E[ψ²] ≤ E[box]``) gets half a texel's
  height, the size the map can still show;
- **spectral radiance**, uniform over the cap (no limb darkening), per band
  ``L_cap(λ) = [P_env(λ) − P_remainder(λ)] / Ω_cap`` with ``P = Σ L Ω`` and
  ``Ω_cap = 2π (1 − cos r)``: the cap carries exactly the power removed from
  the map, so ``P_env = P_cap + P_remainder`` per band (to rounding);
- **remainder**: the region's texels refilled with the per-band median of
  the ring of texels around it (``ring`` texels wide), never above the
  original value (so no band gets power added back and the cap's radiance
  stays ≥ 0).

The built-in sky knows its sun: :func:`split_sky_sun` takes the solar disc of
Hosek & Wilkie (2013) (direction, 0.255° radius, the power its
rasterisation put into the map) instead of detecting it.

How a cap is integrated against a lobe is :mod:`jkatana.light.capquad`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.errors import InputError
from jkatana.light.envmap import EnvMap, texel_directions_np, texel_solid_angles_np
from jkatana.spectral.colorimetry import xyz_weights
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid


def cap_solid_angle(radius):
    """Solid angle of a spherical cap of angular radius ``r``: ``Ω = 2π (1 − cos r) = 4π sin²(r/2)``.

    The half-angle form keeps sub-degree caps accurate in float32 (``1 − cos r``
    would cancel). A JAX array (traced or not) gives a JAX array of its dtype;
    a Python or NumPy number is evaluated on the host in float64.
    """
    if isinstance(radius, jax.Array):
        return 4.0 * jnp.pi * jnp.sin(0.5 * radius) ** 2
    return 4.0 * np.pi * np.sin(0.5 * np.float64(radius)) ** 2


class SunCap(eqx.Module):
    """A spherical-cap area light of uniform spectral radiance.

    **Fields:**

    - `direction`: ``(3,)`` unit world direction of the cap centre (Y up).
    - `radius`: angular radius ``r`` (rad).
    - `radiance`: ``(wl,)`` spectral radiance over the cap, the map's units.
    - `grid`: wavelength grid of `radiance` (static).
    """

    direction: Float[Array, "3"]
    radius: Float[Array, ""]
    radiance: Float[Array, "wl"]
    grid: WavelengthGrid = eqx.field(static=True, default=DEFAULT_GRID)

    @property
    def solid_angle(self) -> Float[Array, ""]:
        """``Ω`` of the cap (:func:`cap_solid_angle`)."""
        return cap_solid_angle(self.radius)

    def power(self) -> Float[Array, "wl"]:
        """``L_cap Ω_cap`` per band (units of the map × sr), comparable to ``Σ L Ω`` of a map."""
        return self.radiance * self.solid_angle


@dataclass(frozen=True)
class SunSplit:
    """Result of splitting compact sources off a map.

    **Fields:**

    - `caps`: the :class:`SunCap` lights, most powerful first (empty: nothing split).
    - `remainder`: the map without them (the input map itself when nothing is split).
    - `regions`: ``(H, W)`` boolean masks of the texels each cap replaced.
    - `power_fractions`: each region's share of the map's luminous power ``Σ Y Ω``.
    - `region_solid_angles`: each region's solid angle (sr).
    """

    caps: tuple[SunCap, ...]
    remainder: EnvMap
    regions: tuple[np.ndarray, ...] = ()
    power_fractions: tuple[float, ...] = ()
    region_solid_angles: tuple[float, ...] = ()

    @property
    def cap(self) -> SunCap | None:
        """The most powerful cap, or None."""
        return self.caps[0] if self.caps else None


# ---------------------------------------------------------------- detection


def _luminance(L: np.ndarray, grid: WavelengthGrid) -> np.ndarray:
    """CIE Y of spectral radiances ``L (..., wl)`` (the grid's ȳ quadrature weights), in L's NumPy precision."""
    return L @ xyz_weights(grid)[:, 1]


def _weighted_median(y: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(y, axis=None)
    ys, cw = y.ravel()[order], np.cumsum(w.ravel()[order])
    return float(ys[min(np.searchsorted(cw, 0.5 * cw[-1]), ys.size - 1)])


def _label_wrapped(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """8-connected labels of ``mask`` with columns 0 and W−1 adjacent (the ``u`` seam)."""
    from scipy.ndimage import label

    lab, n = label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return lab, 0
    parent = np.arange(n + 1)

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    H = mask.shape[0]
    for j in np.nonzero(lab[:, 0])[0]:
        for jj in range(max(j - 1, 0), min(j + 2, H)):
            b = lab[jj, -1]
            if b:
                ra, rb = find(lab[j, 0]), find(b)
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(a) for a in range(n + 1)])
    uniq, relabel = np.unique(roots, return_inverse=True)  # root 0 (background) stays 0
    return relabel[lab], uniq.size - 1


def _dilate(mask: np.ndarray, k: int) -> np.ndarray:
    """Binary dilation by a (2k+1)² square, wrapping in ``u``, clamped at the poles."""
    from scipy.ndimage import maximum_filter

    return maximum_filter(mask, size=2 * k + 1, mode=("nearest", "wrap"))


@dataclass(frozen=True)
class CompactRegion:
    """A region of texels that meets the compact-source criterion (see the module docstring)."""

    mask: np.ndarray
    power_fraction: float
    solid_angle: float


def find_compact_sources(env: EnvMap, *, contrast: float = 1000.0, max_solid_angle: float = 5e-3,
                         min_power_fraction: float = 0.01, max_sources: int = 4) -> list[CompactRegion]:
    """The regions of ``env`` that are compact bright sources, most powerful first.

    Criterion (module docstring): texels with ``Y > contrast · median_Ω(Y)``,
    8-connected (across the ``u`` seam), each region of solid angle
    ``≤ max_solid_angle`` sr holding ``≥ min_power_fraction`` of ``Σ Y Ω``;
    at most ``max_sources``. NumPy, not jittable (a one-off per map).
    """
    if contrast <= 1.0 or max_solid_angle <= 0 or not (0.0 <= min_power_fraction <= 1.0):
        raise InputError(f"compact-source criterion needs contrast > 1, max_solid_angle > 0 and "
                         f"0 ≤ min_power_fraction ≤ 1; got {contrast}, {max_solid_angle}, {min_power_fraction}",
                         field="sun")
    return compact_regions(_luminance(np.asarray(env.radiance, np.float64), env.grid), contrast=contrast,
                           max_solid_angle=max_solid_angle, min_power_fraction=min_power_fraction,
                           max_sources=max_sources)


def compact_regions(y: np.ndarray, *, contrast: float = 1000.0, max_solid_angle: float = 5e-3,
                    min_power_fraction: float = 0.01, max_sources: int = 4) -> list[CompactRegion]:
    """:func:`find_compact_sources` on a map's CIE-Y luminance ``y (H, W)`` alone (what a map read in row
    blocks keeps, :mod:`jkatana.light.streaming`)."""
    H, W = y.shape
    omega = texel_solid_angles_np(H, W)
    power = y * omega
    total = power.sum()
    if not total > 0:
        return []
    bright = y > contrast * _weighted_median(y, omega)
    lab, n = _label_wrapped(bright)
    if n == 0:
        return []
    idx = lab.ravel()
    region_power = np.bincount(idx, power.ravel(), n + 1)[1:]
    region_omega = np.bincount(idx, omega.ravel(), n + 1)[1:]
    keep = [k for k in np.argsort(region_power)[::-1]
            if region_omega[k] <= max_solid_angle and region_power[k] >= min_power_fraction * total]
    return [CompactRegion(lab == k + 1, float(region_power[k] / total), float(region_omega[k]))
            for k in keep[:max_sources]]


def _cap_geometry(y: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float]:
    """Power-weighted centroid direction and the second-moment radius of a region (module docstring)."""
    H, W = mask.shape
    j, i = np.nonzero(mask)
    d = texel_directions_np(H, W)[j, i]
    p = (y * texel_solid_angles_np(H, W))[j, i]
    p = np.maximum(p, 0.0)
    c = (p[:, None] * d).sum(axis=0)
    c = c / np.linalg.norm(c)
    psi = np.arctan2(np.linalg.norm(np.cross(d, c), axis=-1), d @ c)
    theta = (j + 0.5) * math.pi / H
    box = ((math.pi / H) ** 2 + (np.sin(theta) * 2 * math.pi / W) ** 2) / 12.0
    m2 = float((p * (psi**2 - box)).sum() / p.sum())
    floor = 0.5 * math.pi / H
    return c, max(math.sqrt(max(2.0 * m2, 0.0)), floor)


def _cap_from_powers(direction, radius: float, removed_power: np.ndarray, grid: WavelengthGrid, dtype) -> SunCap:
    omega_cap = cap_solid_angle(radius)
    return SunCap(jnp.asarray(direction, dtype), jnp.asarray(radius, dtype),
                  jnp.asarray(np.maximum(removed_power, 0.0) / omega_cap, dtype), grid)


def _band_power(L: np.ndarray) -> np.ndarray:
    H, W = L.shape[:2]
    return np.einsum("hw,hwl->l", texel_solid_angles_np(H, W), np.asarray(L, np.float64))


def split_compact_sources(env: EnvMap, *, contrast: float = 1000.0, max_solid_angle: float = 5e-3,
                          min_power_fraction: float = 0.01, max_sources: int = 4, ring: int = 2) -> SunSplit:
    """Split every compact bright source of ``env`` off as a :class:`SunCap`.

    **Arguments:** the criterion of :func:`find_compact_sources`; `ring`: width
    (texels) of the ring around a region whose per-band median refills it.

    **Returns:** a :class:`SunSplit`; when no region qualifies, ``caps`` is
    empty and ``remainder`` is ``env`` itself. Per band,
    ``Σ L_env Ω = Σ_caps L_cap Ω_cap + Σ L_remainder Ω`` up to the rounding of
    the stored dtype. NumPy, not jittable.
    """
    regions = find_compact_sources(env, contrast=contrast, max_solid_angle=max_solid_angle,
                                   min_power_fraction=min_power_fraction, max_sources=max_sources)
    if not regions:
        return SunSplit((), env)
    dtype = env.radiance.dtype
    L = np.asarray(env.radiance, np.float64)
    y = _luminance(L, env.grid)
    rest = L.copy()
    fills = []
    for reg in regions:
        ring_mask = _dilate(reg.mask, int(ring)) & ~reg.mask
        fill = np.median(L[ring_mask], axis=0) if ring_mask.any() else np.zeros(L.shape[-1])
        fills.append(fill)
        rest[reg.mask] = np.minimum(fill, L[reg.mask])
    remainder = EnvMap(jnp.asarray(rest, dtype), env.grid)
    stored = np.asarray(remainder.radiance, np.float64)
    caps = []
    for reg in regions:
        removed = _band_power(np.where(reg.mask[..., None], L - stored, 0.0))
        direction, radius = _cap_geometry(y, reg.mask)
        caps.append(_cap_from_powers(direction, radius, removed, env.grid, dtype))
    return SunSplit(tuple(caps), remainder, tuple(r.mask for r in regions),
                    tuple(r.power_fraction for r in regions), tuple(r.solid_angle for r in regions))


def split_texels(y: np.ndarray, spectra_of, grid: WavelengthGrid, *, ring: int = 2, dtype=jnp.float32,
                 **criterion) -> tuple[tuple[SunCap, ...], list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """:func:`split_compact_sources` for a map held as its luminance ``y (H, W)`` and a function
    ``spectra_of(rows, cols) → (N, wl)`` giving the exact spectra of chosen texels (a map read in row blocks,
    :mod:`jkatana.light.streaming`): the same regions, ring fill and caps, reading the spectra of each
    region and its ring only.

    **Returns:** ``(caps, changes)``; each change ``(texels, before, after)`` is a region's texels as flat
    indices ``row · W + column``, their spectra and the remainder's (rounded to ``dtype``), float64 ``(N, wl)``.
    """
    regions = compact_regions(y, **criterion)
    W = y.shape[1]
    caps, changes = [], []
    for reg in regions:
        ring_mask = _dilate(reg.mask, int(ring)) & ~reg.mask
        rr, rc = np.nonzero(ring_mask)
        mr, mc = np.nonzero(reg.mask)
        before = np.asarray(spectra_of(mr, mc), np.float64)
        fill = np.median(spectra_of(rr, rc), axis=0) if rr.size else np.zeros(grid.size)
        after = np.minimum(fill, before).astype(np.dtype(dtype)).astype(np.float64)
        omega = texel_solid_angles_np(*y.shape)[mr, mc]
        removed = (omega[:, None] * (before - after)).sum(axis=0)
        direction, radius = _cap_geometry(y, reg.mask)
        caps.append(_cap_from_powers(direction, radius, removed, grid, dtype))
        changes.append((mr * W + mc, before, after))
    return tuple(caps), changes


def split_sky_sun(elevation_deg: float = 30.0, azimuth_deg: float = 180.0, turbidity: float = 3.0,
                  albedo: float = 0.1, resolution: tuple[int, int] = (256, 512),
                  grid: WavelengthGrid = DEFAULT_GRID, *, sun_supersampling: int = 24,
                  dtype=jnp.float32) -> tuple[EnvMap, SunSplit]:
    """The built-in Hosek–Wilkie sky and its sun split off by what the model knows.

    The cap is the solar disc of Hosek & Wilkie (2013): the sun's direction,
    the 0.255° radius (:data:`~jkatana.light.sky.SOLAR_RADIUS`) and, per band,
    the power the disc's rasterisation put into the map (its exact integral
    when the disc is above the horizon), spread uniformly over the cap (the
    limb darkening is averaged out). The remainder is the same sky with the
    disc's texels taken out: sky dome and ground (the ground keeps the sun's
    light) unchanged.

    **Returns:** ``(env, split)``: the full map, as
    :func:`~jkatana.light.sky.hosek_wilkie_sky` with the same arguments returns
    it, and its :class:`SunSplit` (one cap).
    """
    from jkatana.light import sky

    env = sky.hosek_wilkie_sky(elevation_deg, azimuth_deg, turbidity, albedo, resolution, grid,
                               sun=True, sun_supersampling=sun_supersampling, dtype=dtype)
    H, W = env.height, env.width
    s = sky.sun_direction(elevation_deg, azimuth_deg)
    disc = sky._sun_texels(H, W, s, math.radians(elevation_deg), turbidity, grid.wavelengths,
                           texel_solid_angles_np(H, W), sun_supersampling)
    L = np.asarray(env.radiance, np.float64)
    mask = disc.max(axis=-1) > 0
    remainder = EnvMap(jnp.asarray(np.where(mask[..., None], np.maximum(L - disc, 0.0), L), dtype), grid)
    removed = _band_power(L) - _band_power(np.asarray(remainder.radiance, np.float64))
    cap = _cap_from_powers(s, sky.SOLAR_RADIUS, removed, grid, dtype)
    y = _luminance(L, grid)
    omega = texel_solid_angles_np(H, W)
    fraction = float((_luminance(disc, grid) * omega).sum() / (y * omega).sum())
    return env, SunSplit((cap,), remainder, (mask,), (fraction,), (float(omega[mask].sum()),))
