"""Compact bright sources (suns) split from an environment map as spherical-cap area lights.

A sun holds most of an outdoor map's power in a handful of texels. Sampled
or prefiltered as part of the map it is the source of the noise and of the
too-dark glints of the fast modes; as a separate light of known direction,
size and spectrum it can be integrated against the lobe deterministically
(:func:`cap_integral`), and what is left of the map (the *remainder*) is
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

## Integrating a cap against a lobe (:func:`cap_integral`)

``∫_cap f_r(L, V) cos θ_L dω`` by a product Gauss–Legendre rule in polar
coordinates ``(ψ, φ)`` about the lobe's centre R (the mirror direction of
V), with the cap's boundary treated exactly:

- azimuth φ: if R is inside the cap, the whole circle with the midpoint rule
  (exponentially convergent for the smooth periodic integrand) in the
  elliptic angle η, ``tan(φ − φ_p) = c tan η`` about the plane of incidence
  φ_p, which gives every node an equal share of a lobe narrowed by ``c``
  (below), with ``c`` relaxed towards 1 as the lobe widens past the cap;
  otherwise the arc ``|φ| ≤ β`` that meets the cap, ``sin β = sin r / sin δ``
  (δ = ∠(R, C)), with GL nodes in τ for ``φ = β sin τ``, which removes the
  square-root end behaviour of the chord length;
- along each azimuth the cap occupies ``ψ ∈ [ψ₀ − w, ψ₀ + w]`` (clipped at
  0), from the right spherical triangle through the cap centre C
  (Napier's rules; e.g. Todhunter 1886, *Spherical Trigonometry*):
  ``sin d = sin δ sin φ``, ``tan ψ₀ = tan δ cos φ``, ``cos w = cos r / cos d``
  (evaluated in half-angle form, accurate for sub-degree caps in float32);
- radially the substitution ``u = ψ²/(2σ²)`` and GL nodes in
  ``t = (1 − e^{−(u − u₀)})/(1 − e^{−Δu})``, the inverse-CDF variable of a
  Gaussian of width σ in ψ. For the paper's Gaussian facet lobe
  ``D = exp(−ln2 φ_h²/μ²)`` (Mochizuki et al.) the reflected lobe is such a
  Gaussian with ``σ = μ √(2/ln2)`` (ψ ≈ 2 φ_h), narrowed by ``cos θ`` across
  the plane of incidence (a facet tilt out of that plane turns the reflected
  ray by ``2 φ_h cos θ``), which σ follows per azimuth. The transformed
  integrand is then nearly constant whether the lobe is far narrower than
  the cap (a mirror: the result tends to ``F(θ) · [R inside the cap]``,
  antialiased over the lobe's own width) or far wider (the cap a point).

Gauss–Legendre nodes: Golub & Welsch (1969), "Calculation of Gauss
quadrature rules", Math. Comp. 23, via :func:`numpy.polynomial.legendre.leggauss`.

Error bound of the default rule (4 radial × 16 azimuthal nodes, 64 BRDF
evaluations), relative to the value with the cap centred on R, for the
paper's lobe at μ = 0.001…0.3, incidence 0–69°, the sun's 0.255° cap, pinned
against a dense quadrature in ``tests/test_light_sun.py``: ≤ 2e-2 where the
cap's edge crosses a lobe narrower than the cap (the antialiasing of the
glint's outline: there the integrand has a near-step in φ that the rule
resolves only to its node spacing), ≤ 1e-3 everywhere else. More azimuths
shrink the edge error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.errors import InputError
from jkatana.light.envmap import EnvMap, texel_directions_np, texel_solid_angles_np
from jkatana.models._safe import norm, normalize, safe_atan2, safe_div, safe_sqrt
from jkatana.models.geometry import tangent_frame
from jkatana.models.microfacet import LN2
from jkatana.spectral.colorimetry import xyz_weights
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid



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
        """``Ω = 2π (1 − cos r) = 4π sin²(r/2)`` (the half-angle form keeps small caps accurate)."""
        return 4.0 * jnp.pi * jnp.sin(0.5 * self.radius) ** 2

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
    L = np.asarray(env.radiance, np.float64)
    H, W, _ = L.shape
    y = L @ xyz_weights(env.grid)[:, 1]
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
    omega_cap = 4.0 * math.pi * math.sin(0.5 * radius) ** 2
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
    y = L @ xyz_weights(env.grid)[:, 1]
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
    y = L @ xyz_weights(grid)[:, 1]
    omega = texel_solid_angles_np(H, W)
    fraction = float((disc @ xyz_weights(grid)[:, 1] * omega).sum() / (y * omega).sum())
    return env, SunSplit((cap,), remainder, (mask,), (fraction,), (float(omega[mask].sum()),))


# ---------------------------------------------------------------- cap × lobe quadrature


def gaussian_lobe_sigma(mu):
    """Width σ (rad, in the reflected direction) of the paper's facet lobe: ``μ √(2/ln2)``.

    ``D = exp(−ln2 φ²/μ²)`` with the reflected ray at ``ψ = 2φ`` from the
    mirror direction is ``exp(−ψ²/(2σ²))``.
    """
    return jnp.asarray(mu) * math.sqrt(2.0 / LN2)


def lobe_width(lobe) -> Float[Array, "*p"]:
    """Width σ (rad, about the mirror direction) of a lobe of :mod:`jkatana.models.lobes`: the scale of
    :func:`cap_nodes`' radial nodes.

    The paper's Gaussian lobes (``mu``): :func:`gaussian_lobe_sigma`. Microfacet
    lobes (``alpha``): ``D ∝ exp(−tan²φ/α²) ≈ exp(−φ²/α²)`` near the peak
    (Beckmann; the core of GGX/GTR), with ψ = 2φ a Gaussian of ``σ = √2 α``.
    The width only places the nodes: a wrong one costs accuracy, not
    correctness. A :class:`~jkatana.models.lobes.Mixture` has no single width:
    integrate its parts.
    """
    if hasattr(lobe, "mu"):
        return gaussian_lobe_sigma(lobe.mu)
    if hasattr(lobe, "alpha"):
        return jnp.asarray(lobe.alpha) * math.sqrt(2.0)
    raise TypeError(f"no cap-rule width for a {type(lobe).__name__} lobe (integrate a mixture's parts)")


def cap_nodes(R: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius, sigma, *, normal=None,
              n_radial: int = 4, n_azimuth: int = 16) -> tuple[Float[Array, "*b A Q 3"], Float[Array, "*b A Q"]]:
    """Directions and weights of the cap rule about a lobe centre (module docstring).

    ``Σ w g(L) ≈ ∫_cap g dω`` for ``g`` a lobe of width ``sigma`` about ``R``.

    **Arguments:**

    - `R`: lobe centre (unit); `C`: cap centre (unit); `radius`: cap radius
      (rad); `sigma`: lobe width (rad, > 0) about R.
    - `normal`: the surface normal (same frame) when the lobe is a reflection
      lobe, narrowed by ``cos θ = R·N`` across the plane of incidence; None:
      isotropic.
    - `n_radial`, `n_azimuth`: nodes per azimuth and azimuths.

    **Returns:** ``(L, w)`` with ``A = n_azimuth``, ``Q = n_radial``. Pure JAX,
    jittable, finite values and gradients (R = C, R on the cap's edge, a lobe
    far narrower or wider than the cap).
    """
    R = jnp.asarray(R)
    C = jnp.asarray(C)
    R, C = jnp.broadcast_arrays(R, C)
    dt = jnp.result_type(R, C)  # the directions set the precision (Python-float radius/σ do not promote)
    R, C = normalize(R.astype(dt)), normalize(C.astype(dt))
    r = jnp.asarray(radius, dt)[..., None]
    sigma = jnp.asarray(sigma, dt)[..., None]
    # frame at R: e1 towards C (any ⟂ when C = R)
    cos_d = jnp.sum(R * C, axis=-1)
    perp = C - cos_d[..., None] * R
    sin_d = norm(perp)
    delta = safe_atan2(sin_d, cos_d)
    perp = perp - jnp.sum(perp * R, -1, keepdims=True) * R  # C ≈ R: perp is rounding noise, not ⟂ R
    e1 = jnp.where((norm(perp) > 16 * float(jnp.finfo(dt).eps))[..., None], normalize(perp), tangent_frame(R)[0])
    e2 = jnp.cross(R, e1)
    inside = (delta < r[..., 0])[..., None]
    # anisotropy of a reflection lobe: in-plane axis p (azimuth φ_p about R) and c = cos θ
    if normal is None:
        c_an = jnp.ones_like(delta)[..., None]
        phi_p = jnp.zeros_like(delta)[..., None]
    else:
        N = jnp.asarray(normal, dt)
        c_an = jnp.clip(jnp.sum(R * N, axis=-1), 0.05, 1.0)[..., None]
        p = normalize(N - jnp.sum(R * N, -1, keepdims=True) * R)
        phi_p = safe_atan2(jnp.sum(p * e2, -1), jnp.sum(p * e1, -1))[..., None]
    # azimuths. Inside: the whole circle, midpoint rule in the elliptic angle η
    # (tan(φ − φ_p) = c tan η), which spreads an anisotropic lobe's mass evenly over the
    # nodes. Outside: the arc |φ| ≤ β, GL in τ for φ = β sin τ.
    eta = jnp.asarray(2 * np.pi * (np.arange(n_azimuth) + 0.5) / n_azimuth - np.pi, dt)
    ce, se = jnp.cos(eta), jnp.sin(eta)
    c_map = c_an ** (r * r / (r * r + sigma * sigma))  # c for a lobe narrower than the cap, 1 wider
    phi_in = phi_p + jnp.arctan2(c_map * se, ce)
    w_in = (2 * np.pi / n_azimuth) * c_map / (ce * ce + (c_map * se) ** 2)
    x_a, w_a = np.polynomial.legendre.leggauss(n_azimuth)
    ratio = safe_div(jnp.sin(r), sin_d[..., None], fallback=1.0)
    # outside only (ratio ≤ 1 there), kept off 1 where arcsin' is infinite
    beta = jnp.arcsin(jnp.clip(jnp.where(inside, 0.5, ratio), 0.0, 1.0 - float(jnp.finfo(dt).eps)))
    tau = jnp.asarray(0.5 * np.pi * x_a, dt)
    w_a = jnp.asarray(w_a, dt)
    phi = jnp.where(inside, phi_in, beta * jnp.sin(tau))
    w_phi = jnp.where(inside, w_in, 0.5 * np.pi * w_a * beta * jnp.cos(tau))
    # chord of the cap along each azimuth: ψ ∈ [ψ0 − w, ψ0 + w] (half-angle forms)
    sd = sin_d[..., None]
    sin_dp = sd * jnp.sin(phi)
    cos_dp = safe_sqrt(1.0 - sin_dp * sin_dp)
    hav_dp = safe_div(sin_dp * sin_dp, 2.0 * (1.0 + cos_dp))
    hav_w = safe_div(jnp.sin(0.5 * r) ** 2 - hav_dp, cos_dp)
    half = 2.0 * jnp.arcsin(jnp.clip(safe_sqrt(hav_w), 0.0, 1.0))
    psi0 = jnp.arctan2(sd * jnp.cos(phi), jnp.cos(delta)[..., None])
    lo = jnp.maximum(psi0 - half, 0.0)
    hi = jnp.clip(psi0 + half, lo, np.pi)
    # lobe width along each azimuth: σ / √(cos²(φ − φ_p) + sin²(φ − φ_p)/c²)
    tdir = jnp.cos(phi)[..., None] * e1[..., None, :] + jnp.sin(phi)[..., None] * e2[..., None, :]
    cp, sp = jnp.cos(phi - phi_p), jnp.sin(phi - phi_p)
    sig = sigma * jax.lax.rsqrt(cp * cp + sp * sp / (c_an * c_an))
    # radial: u = ψ²/(2σ²), GL in the inverse-CDF variable t of e^{−u}
    x_r, w_r = np.polynomial.legendre.leggauss(n_radial)
    t = jnp.asarray(0.5 * (x_r + 1.0), dt)
    wt = jnp.asarray(0.5 * w_r, dt)
    inv2s2 = 0.5 / (sig * sig)
    u_lo = (lo * lo * inv2s2)[..., None]
    du = ((hi - lo) * (hi + lo) * inv2s2)[..., None]
    c = -jnp.expm1(-du)
    u = u_lo - jnp.log1p(-t * c)
    psi = sig[..., None] * safe_sqrt(2.0 * u)
    w = (w_phi[..., None] * wt * (sig * sig)[..., None] * jnp.sinc(psi / np.pi) * c / (1.0 - t * c))
    L = jnp.cos(psi)[..., None] * R[..., None, None, :] + jnp.sin(psi)[..., None] * tdir[..., None, :]
    return L, w


def cap_integral(brdf_cos: Callable, V: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius, sigma, *,
                 n_radial: int = 4, n_azimuth: int = 16) -> Float[Array, "*b wl"]:
    """``∫_cap f_r(L, V) cos θ_L dω`` for a reflection lobe about the mirror direction of V.

    **Arguments:**

    - `brdf_cos(L, V) -> (..., wl)`: f_r cos θ_L in the local shading frame
      (N = +z), broadcasting over leading axes (e.g. ``partial(Hiraji.brdf_cos,
      conductor=...)``).
    - `V`: view direction, local frame; `C`: cap centre, local frame.
    - `radius`: cap radius (rad); `sigma`: the lobe's width in the reflected
      direction (:func:`gaussian_lobe_sigma` for the paper's lobe).
    - `n_radial`, `n_azimuth`: the rule's size (``n_radial × n_azimuth`` BRDF
      evaluations per point).

    Multiply by :attr:`SunCap.radiance` for the reflected radiance
    (:func:`reflected_cap_radiance`). Pure JAX, jittable over pixels.

    Cost: ``n_radial × n_azimuth`` BRDF evaluations per point. The Fresnel
    factor varies by at most ``|dF/dθ| · r`` over the cap, so a renderer may
    pass the lobe alone (a trailing axis of 1) and multiply by ``F`` at the
    cap's centre; where the lobe is much wider than the cap,
    :func:`cap_point_integral` needs one evaluation.
    """
    V = jnp.asarray(V)
    R = V * jnp.asarray([-1.0, -1.0, 1.0], V.dtype)
    L, w = cap_nodes(R, C, radius, sigma, normal=jnp.asarray([0.0, 0.0, 1.0], V.dtype),
                     n_radial=n_radial, n_azimuth=n_azimuth)
    f = brdf_cos(L, jnp.broadcast_to(V[..., None, None, :], L.shape))
    return jnp.einsum("...aq,...aql->...l", w.astype(f.dtype), f)


def cap_point_integral(brdf_cos: Callable, V: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius
                       ) -> Float[Array, "*b wl"]:
    """The cap as a point light: ``f_r(C, V) cos θ_C · Ω_cap``, one BRDF evaluation.

    The midpoint rule of :func:`cap_integral`'s integral: for a lobe of width
    σ much wider than the cap its relative error is of order ``(r/σ)²`` (the
    lobe's curvature across the cap), so a renderer can use it wherever
    ``σ ≫ r`` and keep :func:`cap_integral` for the glints.
    """
    V = jnp.asarray(V)
    C = normalize(jnp.asarray(C, V.dtype))
    omega = 4.0 * jnp.pi * jnp.sin(0.5 * jnp.asarray(radius, V.dtype)) ** 2
    return brdf_cos(C, jnp.broadcast_to(V, C.shape)) * omega[..., None]


def cap_disc_nodes(C: Float[Array, "*b 3"], radius) -> tuple[Float[Array, "*b 4 3"], Float[Array, "*b 4"]]:
    """Stroud's degree-3 rule on a small cap: 4 directions, independent of the lobe.

    The disc rule S2:3-1 of Stroud (1971), *Approximate Calculation of Multiple
    Integrals* (Prentice-Hall): points at distance ``ρ/√2`` from a disc's centre
    on two orthogonal axes, equal weights, integrate every polynomial of degree
    ≤ 3 exactly. On the sphere: the directions at angle ``r/√2`` from the cap
    centre C along two orthogonal tangents, each weighted ``Ω_cap/4``. For a lobe
    of width σ ≫ r the error is of order ``(r/σ)⁴`` (the lobe's quartic term
    across the cap; for a Gaussian centred on the cap ``t²/24`` with
    ``t = r²/(2σ²)``), against ``(r/σ)²`` for the point light of
    :func:`cap_point_integral`: pinned in ``tests/test_light_sun.py`` (≤ 1e-3 of
    the peak value for σ ≥ 8 r, :data:`STROUD_MIN_WIDTH`, at incidence up to 70°,
    where a reflection lobe is narrowed to σ cos θ across the plane of incidence). The directions are the
    same for every shading point, so a renderer evaluates its lobe 4 times per
    cap and point instead of the 64 of :func:`cap_nodes`.

    **Returns:** ``(L, w)``: ``L (..., 4, 3)`` unit directions, ``w (..., 4)`` weights (sr).
    """
    C = normalize(jnp.asarray(C))
    r = jnp.asarray(radius, C.dtype)
    e1 = normalize(tangent_frame(C)[0])
    e2 = jnp.cross(C, e1)
    a = r / math.sqrt(2.0)
    ca, sa = jnp.cos(a)[..., None], jnp.sin(a)[..., None]
    L = jnp.stack([ca * C + sa * e1, ca * C - sa * e1, ca * C + sa * e2, ca * C - sa * e2], axis=-2)
    w = jnp.broadcast_to((jnp.pi * jnp.sin(0.5 * r) ** 2)[..., None], L.shape[:-1])  # Ω/4 each
    return L, w


#: Nodes (radial, azimuthal) of :func:`cap_nodes` a renderer uses: the defaults, whose error is stated above.
CAP_RULE = (4, 16)

#: Smallest lobe width, in cap radii (σ ≥ STROUD_MIN_WIDTH · r), for which :func:`cap_disc_nodes` is used.
STROUD_MIN_WIDTH = 8.0


def reflected_cap_radiance(cap: SunCap, brdf_cos: Callable, V_local: Float[Array, "*b 3"],
                           frame: Float[Array, "*b 3 3"], sigma, **rule) -> Float[Array, "*b wl"]:
    """Radiance reflected towards V from ``cap``: ``L_cap(λ) ∫_cap f_r cos θ dω``.

    `frame`: world → local rotation of :func:`jkatana.light.sampling.frame_from_normal`.
    `rule`: ``n_radial``, ``n_azimuth`` of :func:`cap_integral`.
    """
    C = jnp.einsum("...ij,j->...i", frame, cap.direction.astype(frame.dtype))
    integral = cap_integral(brdf_cos, V_local, C, cap.radius, sigma, **rule)
    return jnp.asarray(cap.radiance, integral.dtype) * integral


def cap_coverage(R: Float[Array, "*b 3"], C: Float[Array, "*b 3"], radius, width, *, n_radial: int = 4,
                 n_azimuth: int = 16) -> Float[Array, "*b"]:
    """Fraction of a normalised Gaussian footprint of ``width`` (rad) about ``R`` inside the cap.

    The antialiased indicator ``[R inside the cap]`` of a perfect mirror:
    its reflected radiance from the cap is ``F(θ) · L_cap · cap_coverage(R, …)``,
    with ``width`` the angular footprint of the pixel (or of the lobe).
    Tends to 1 inside, 0 outside, ½ on the edge as ``width → 0``.
    """
    L, w = cap_nodes(R, C, radius, width, n_radial=n_radial, n_azimuth=n_azimuth)
    Rb = jnp.asarray(R, L.dtype)[..., None, None, :]
    cos_psi = jnp.sum(L * Rb, axis=-1)
    psi = safe_atan2(jnp.linalg.norm(jnp.cross(L, Rb), axis=-1), cos_psi)
    s = jnp.asarray(width, L.dtype)[..., None, None]
    g = jnp.exp(-0.5 * (psi / s) ** 2) / (2 * jnp.pi * s * s)
    return jnp.sum(w * g, axis=(-2, -1))
