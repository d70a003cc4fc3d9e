"""Plots of the built-in Hosek–Wilkie spectral sky at several sun elevations.

Writes to experiments/output/:
- ``sky_elevations.png``: sRGB previews (fixed exposure per row: auto) of the sky at
  sun elevations 2°, 10°, 30°, 60°, 85° (azimuth 135°, turbidity 3, albedo 0.1), sun circled;
- ``sky_spectra.png``: zenith spectral radiance and the solar disc's mean radiance vs λ for
  each elevation, and the sky's horizontal illuminance-like integral (Y) vs elevation;
- ``sky_xyz_agreement.png``: Y of the CIE XYZ table vs ∫ L ȳ dλ of the spectral table along
  the solar vertical (the two are independent fits).

Run: ``python experiments/light_sky_elevations.py``.
"""

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from jkatana.light import hosek_wilkie_sky, sun_direction  # noqa: E402
from jkatana.light import sky as S  # noqa: E402
from jkatana.light.commands import preview_png  # noqa: E402
from jkatana.spectral import WavelengthGrid, xyz_weights  # noqa: E402

OUT = Path(__file__).parent / "output"
OUT.mkdir(parents=True, exist_ok=True)
ELEVATIONS = [2.0, 10.0, 30.0, 60.0, 85.0]
grid = WavelengthGrid(400, 700, 10)

fig, axes = plt.subplots(len(ELEVATIONS), 1, figsize=(8, 2.2 * len(ELEVATIONS)))
spectra, suns, E_y = [], [], []
for ax, e in zip(axes, ELEVATIONS):
    env = hosek_wilkie_sky(e, 135.0, 3.0, 0.1, (128, 256), grid)
    tmp = OUT / f"_sky_{e:g}.png"
    preview_png(env, tmp, sun_dir=sun_direction(e, 135.0))
    ax.imshow(plt.imread(tmp))
    tmp.unlink()
    ax.set_title(f"sun elevation {e:g}° (azimuth 135°, T = 3, albedo 0.1)", fontsize=9)
    ax.set_xticks([0, 64, 128, 192, 256], ["+Z (S)", "−X (W)", "−Z (N)", "+X (E)", "+Z"], fontsize=7)
    ax.set_yticks([0, 64, 128], ["zenith", "horizon", "nadir"], fontsize=7)
    spectra.append(np.asarray(env.lookup(np.array([0.0, 1.0, 0.0]))))
    x, w = np.polynomial.legendre.leggauss(32)
    suns.append(S.solar_disc_integral(grid.wavelengths, math.radians(e), 3.0)
                / (2 * math.pi * (1 - math.cos(S.SOLAR_RADIUS))))
    no_sun = hosek_wilkie_sky(e, 180.0, 3.0, 0.1, (64, 128), grid, sun=False, ground=False)
    E_y.append(float(np.asarray(no_sun.irradiance()) @ xyz_weights(grid)[:, 1]))
fig.tight_layout()
fig.savefig(OUT / "sky_elevations.png", dpi=110)
plt.close(fig)

fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(13, 3.8))
for e, sp, su in zip(ELEVATIONS, spectra, suns):
    a1.plot(grid.wavelengths, sp, label=f"{e:g}°")
    a2.semilogy(grid.wavelengths, su, label=f"{e:g}°")
a1.set(xlabel="λ (nm)", ylabel="W m⁻² sr⁻¹ nm⁻¹", title="zenith sky radiance")
a2.set(xlabel="λ (nm)", ylabel="W m⁻² sr⁻¹ nm⁻¹", title="solar disc, mean radiance (limb-darkened)")
a1.legend(title="sun elevation", fontsize=8)
a2.legend(fontsize=8)
es = np.linspace(1, 89, 45)
Ey = []
for e in es:
    env = hosek_wilkie_sky(float(e), 180.0, 3.0, 0.1, (32, 64), grid, sun=False, ground=False)
    Ey.append(float(np.asarray(env.irradiance()) @ xyz_weights(grid)[:, 1]))
a3.plot(es, Ey)
a3.set(xlabel="sun elevation (deg)", ylabel="∫ E(λ) ȳ dλ  (W m⁻² , k = 1)", title="diffuse sky, horizontal")
fig.tight_layout()
fig.savefig(OUT / "sky_spectra.png", dpi=110)
plt.close(fig)

# XYZ table vs spectral integral along the solar vertical
gxyz = WavelengthGrid(360, 720, 5)
fig, ax = plt.subplots(figsize=(6.5, 4))
for e in (10.0, 30.0, 60.0):
    th = np.linspace(-85, 85, 171)  # view zenith angle, signed: + towards the sun
    ct = np.cos(np.radians(th))
    gamma = np.abs(np.radians(th) - np.radians(90 - e))
    y_tab = S.hosek_wilkie_tristimulus(ct, gamma, math.radians(e), 3.0, 0.1, "CIEXYZ")[:, 1]
    y_sp = (S.sky_bands(ct, gamma, math.radians(e), 3.0, 0.1) @ S.band_weights(gxyz.wavelengths)) @ xyz_weights(gxyz)[:, 1]
    (line,) = ax.plot(th, y_sp, label=f"spectral ∫Lȳ, sun {e:g}°")
    ax.plot(th, y_tab, "--", color=line.get_color(), label=f"XYZ table, sun {e:g}°")
ax.set(xlabel="view zenith angle in the solar vertical (deg, + towards the sun)", ylabel="Y (k = 1)",
       yscale="log", title="Hosek–Wilkie: XYZ table vs spectral table")
ax.legend(fontsize=7)
fig.tight_layout()
fig.savefig(OUT / "sky_xyz_agreement.png", dpi=110)
plt.close(fig)
print("wrote", *(OUT / n for n in ("sky_elevations.png", "sky_spectra.png", "sky_xyz_agreement.png")))
