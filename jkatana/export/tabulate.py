"""A lobe that other renderers cannot name, tabulated as an RGL ``.bsdf`` file they can read.

Mitsuba 3's ``measured`` plugin and pbrt-v4's ``measured`` material read the
RGL tensor format (Dupuy & Jakob 2018; :mod:`jkatana.brdf.rgl`), which holds
any isotropic BRDF, reciprocal or not, on an adaptive grid warped by a facet
distribution. The paper's lobes (Mochizuki et al., eqs. 1–2), GTR and the
two-lobe mixture go out this way, with the conductor's spectral Fresnel factor
baked in (a spectral file: one table per wavelength).

*Which direction is incident.* The paper's hiraji lobe is not reciprocal
(Fresnel and 1/cos at the light's angle). Mitsuba looks the table up with its
camera-side direction ``si.wi`` as the table's incident direction, so the table
is written as f(ωi = V, ωo = L): the camera direction indexes the incidences,
and a renderer that samples lights from the surface gets the lobe jkatana
renders.

*Resolution.* The table follows the lobe's facet density (its ``pdf_h``, with
a floor of 10⁻³ of its peak so the tails get cells too); the reflectance
table's cells set the accuracy (:func:`jkatana.brdf.rgl.rgl_from_function`).
"""

from __future__ import annotations

import numpy as np

from jkatana.brdf.rgl import RGLBRDF, rgl_from_function

#: Incidences of the exported tables (deg): every 5° to 85°, then 88° (Mitsuba clamps beyond the last).
TABLE_INCIDENCES_DEG = np.concatenate([np.arange(0.0, 86.0, 5.0), [88.0]])
#: Wavelengths of the exported tables (nm): 10 nm over the CIE observer's domain (iron's Fresnel factor is
#: smooth in λ; Mitsuba interpolates linearly between them).
TABLE_WAVELENGTHS = np.arange(360.0, 831.0, 10.0)


def lobe_table(region_lobe, n: np.ndarray, k: np.ndarray, wavelengths: np.ndarray, *,
               refl_res: int = 65, vndf_res: int = 65, ndf_res: int = 129,
               description: str = "jkatana lobe") -> RGLBRDF:
    """``region_lobe`` (:class:`jkatana.export.scene.RegionLobe`) × the conductor's Fresnel factor (n, k on
    ``wavelengths``) as a spectral RGL table at :data:`TABLE_WAVELENGTHS` (module docstring)."""
    import jax
    import jax.numpy as jnp

    from jkatana.models.reflectance import Conductor

    lam = TABLE_WAVELENGTHS
    nn = np.interp(lam, wavelengths, n)
    kk = np.interp(lam, wavelengths, k)
    lobe, gain = region_lobe.lobe, region_lobe.gain

    with jax.enable_x64(True):
        cond = Conductor(jnp.asarray(nn, jnp.float64), jnp.asarray(kk, jnp.float64))
        peak = float(lobe.pdf_h(jnp.zeros(()), jnp.ones(())))

    def brdf(wi, wo):
        """f(ωi = V, ωo = L) per wavelength: the table's incident direction is the camera's."""
        with jax.enable_x64(True):
            L, V = jnp.asarray(wo, jnp.float64), jnp.asarray(wi, jnp.float64)
            fc = np.asarray(lobe.brdf_cos(L, V, cond), np.float64)
        cos_l = np.asarray(wo, np.float64)[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = gain * fc / cos_l[..., None]
        return np.where((cos_l > 0)[..., None] & np.isfinite(f), f, 0.0)

    def ndf(cos_m):
        with jax.enable_x64(True):
            c = jnp.clip(jnp.asarray(cos_m, jnp.float64), 0.0, 1.0)
            d = np.asarray(lobe.pdf_h(jnp.arccos(c), c), np.float64) / np.maximum(np.asarray(c), 1e-6)
        return d + 1e-3 * peak

    return rgl_from_function(brdf, ndf, theta_i_deg=TABLE_INCIDENCES_DEG,
                             channels=tuple(f"{x:g}nm" for x in lam), ndf_res=ndf_res, vndf_res=vndf_res,
                             refl_res=refl_res, description=description)


__all__ = ["lobe_table", "TABLE_INCIDENCES_DEG", "TABLE_WAVELENGTHS"]
