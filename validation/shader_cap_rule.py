"""The interactive shader's cap rule (``jkatana/interactive/shaders/shade.glsl``'s ``jk_caps_xyz``) transcribed
to NumPy: a test reference, not the product (the shader runs the GLSL).

A compact source split off the map (:func:`jkatana.interactive.caps.sun_caps`) is a spherical cap of angular
radius r about C. The shader's reflected radiance from it is ``A · Q · K(C)``: the lobe table A (the lobe's
energy on the Fresnel basis, :func:`jkatana.interactive.lobe_tables.lobe_lut`), the cap's projected radiance Q
(Ω_cap Σ_λ b_r W L_cap) and K, the lobe's normalised kernel averaged over the cap's disc.

K is one anisotropic Gaussian on the sphere with the lobe's own first and second moments
(:func:`jkatana.interactive.lobe_tables.lobe_integral`, ``moments=True``): centred on the lobe's mean direction M
(R turned by the mean offset towards N in the plane of incidence), variance ``var_par`` along that plane and
``var_perp`` across it, written in the prefilter kernel's form ``exp(−c h²)/cos h`` (Walter et al. 2007's
half-angle Gaussian, the form the map levels are filtered with: h is half the angle from M, ``c = 2/var``
per axis, blended by the azimuth of C about M). The normalisation on the sphere is the isotropic kernel's,
``(4π/c)(1 − 1/(6c) + 1/(60c²))``, with √(c_par c_perp) for the leading c and the axes' harmonic mean in the
curvature terms. The cap's disc is folded in per axis by keeping the kernel's exact average over the disc at
its centre: ``c' = 4 (1 − e^{−c r²/4})/r²``.

The moments match the lobe where it is close to a Gaussian: narrow lobes at any incidence, wide lobes near
normal incidence. A wide lobe at grazing incidence (μ ≳ 0.14 beyond ~55°) is skewed and cut by the horizon,
which two moments do not describe (``tests/test_interactive_caps.py`` states the error per incidence). A lobe
with algebraic tails (GGX, GTR) has moments set by its tails, which the Gaussian does not hold at all: a region
holding a lobe other than the paper's reads the caps through the bake's kernel table instead
(:mod:`jkatana.interactive.captable`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

#: ln 2: the paper's facet lobe D = exp(−ln2 φ²/μ²) has, in the reflected direction, c = ln2/μ² in h.
_LN2 = float(np.log(2.0))


def disc_constant(c: ArrayLike, radius: ArrayLike) -> np.ndarray:
    """``c'``: the kernel constant of an axis with the cap's disc of angular ``radius`` folded in (its exact
    average over the disc at the disc's centre)."""
    c = np.asarray(c, np.float64)
    r2 = np.asarray(radius, np.float64) ** 2
    x = 0.25 * c * r2
    return np.where(x < 1e-3, c * (1.0 - 0.5 * x), 4.0 * -np.expm1(-x) / np.maximum(r2, 1e-30))


def kernel(M: ArrayLike, t_par: ArrayLike, t_perp: ArrayLike, c_par: ArrayLike, c_perp: ArrayLike,
           cap_dir: ArrayLike, radius: ArrayLike) -> np.ndarray:
    """K: the normalised kernel (1/sr) about ``M`` (in-plane axis ``t_par``, across-plane ``t_perp``, unit and
    ⟂ M; zero vectors where ``c_par == c_perp``) with constants ``c_par ≤ c_perp`` before the disc, averaged over
    the cap of ``radius`` about ``cap_dir``. 0 where ``c_par' h² > 30``, as in the shader. Broadcasts over
    leading axes."""
    cp, cy = disc_constant(c_par, radius), disc_constant(c_perp, radius)
    e = np.asarray(cap_dir, np.float64) - np.asarray(M, np.float64)
    s2 = np.minimum(0.25 * np.sum(e * e, -1), 1.0)
    h = np.arcsin(np.sqrt(s2))
    ep, ey = np.sum(e * np.asarray(t_par, np.float64), -1), np.sum(e * np.asarray(t_perp, np.float64), -1)
    c = cp + (cy - cp) * ey * ey / np.maximum(ep * ep + ey * ey, 1e-30)
    cb = 2.0 * cp * cy / (cp + cy)
    n = np.sqrt(cp * cy) / (4.0 * np.pi * (1.0 - 1.0 / (6.0 * cb) + 1.0 / (60.0 * cb * cb)))
    k = np.exp(-c * h * h) / np.sqrt(np.maximum(1.0 - s2, 1e-6)) * n
    return np.where(cp * s2 > 30.0, 0.0, k)


def cap_response(R: ArrayLike, t: ArrayLike, spread: ArrayLike, mu_e: ArrayLike, cap_dir: ArrayLike,
                 radius: ArrayLike) -> np.ndarray:
    """K for a reflection lobe about the mirror direction ``R`` (unit), ``t`` the unit direction in the plane of
    incidence ⟂ R towards N, ``spread (..., 3)`` the lobe's moments as :func:`lobe_tables.lobe_lut` tabulates them
    (log across-width ratio, in-plane extra spread √(var_par − var_perp), mean offset towards N) and ``mu_e``
    the width of the moment pattern's prefilter level (μ·e^{spread[0]}): what ``shade.glsl`` computes per
    pixel and cap. Multiply by the lobe's energy and the cap's Ω_cap L_cap."""
    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    spread = np.asarray(spread, np.float64)
    mean = spread[..., 2:3]
    c_perp = _LN2 / np.asarray(mu_e, np.float64) ** 2
    c_par = c_perp / (1.0 + 0.5 * c_perp * spread[..., 1] ** 2)
    M = np.cos(mean) * R + np.sin(mean) * t
    t_par = np.cos(mean) * t - np.sin(mean) * R
    return kernel(M, t_par, np.cross(R, t), c_par, c_perp, cap_dir, radius)
