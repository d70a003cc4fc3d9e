"""The sun split off real HDR environments: before / remainder / cap, with the numbers.

For each map (sunrise.exr: a low sun; pedestrian_overpass_1k.hdr: a sun clipped in the file;
the built-in Hosek–Wilkie sky at 10°) it runs :func:`jkatana.light.sun.split_compact_sources`
with the default criterion and writes ``experiments/output/sun_split.png``: per row the
whole map (tone-mapped, same exposure for both), the remainder, and a zoom of 48 × 48
texels about the sun — original, remainder, and the cap drawn as its circle over the
remainder — and prints power fraction, region solid angle, direction and cap radius.

Run: ``python experiments/sun_split.py`` (most of its time is the RGB → spectrum upsampling).
"""

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from jkatana.light import load_envmap  # noqa: E402
from jkatana.light.envmap import direction_to_uv  # noqa: E402
from jkatana.light.sun import split_compact_sources, split_sky_sun  # noqa: E402
from jkatana.shared import shared_data  # noqa: E402
from jkatana.spectral import WavelengthGrid  # noqa: E402
from jkatana.light.commands import preview_display8, preview_exposure  # noqa: E402

OUT = Path(__file__).parent / "output"
OUT.mkdir(parents=True, exist_ok=True)
GRID = WavelengthGrid(400, 700, 10)


def tone(env, exposure):
    """The light stage's preview of ``env`` (Reinhard's operator, sRGB), as floats in [0, 1]."""
    return preview_display8(env, exposure) / 255.0


def describe(name, split):
    if not split.caps:
        return f"{name}: nothing split"
    lines = [f"{name}:"]
    for cap, f, om in zip(split.caps, split.power_fractions, split.region_solid_angles):
        d = np.asarray(cap.direction, np.float64)
        elev = math.degrees(math.asin(d[1]))
        az = math.degrees(math.atan2(d[0], -d[2])) % 360
        lines.append(f"  power {100 * f:.1f} %, region {om:.2e} sr, elevation {elev:.2f}°, azimuth {az:.1f}°, "
                     f"cap radius {math.degrees(float(cap.radius)):.3f}° ({float(cap.solid_angle):.2e} sr)")
    return "\n".join(lines)


cases = []
for name in ("sunrise.exr", "pedestrian_overpass_1k.hdr"):
    env = load_envmap(shared_data("envmaps", name), GRID)
    cases.append((name, env, split_compact_sources(env)))
sky, sky_split = split_sky_sun(10.0, 135.0, 3.0, 0.1, (256, 512), GRID)
cases.append(("Hosek–Wilkie 10° (known sun)", sky, sky_split))

fig, axes = plt.subplots(len(cases), 5, figsize=(20, 3.3 * len(cases)),
                         gridspec_kw=dict(width_ratios=[2, 2, 1, 1, 1]))
for row, (name, env, split) in zip(axes, cases):
    print(describe(name, split))
    Y = np.asarray(env.luminance(), np.float64)
    exposure = preview_exposure(env)
    before, after = tone(env, exposure), tone(split.remainder, exposure)
    if split.caps:
        u, v = (float(t) for t in direction_to_uv(np.asarray(split.cap.direction)))
    else:
        j, i = np.unravel_index(np.argmax(Y), Y.shape)
        u, v = (i + 0.5) / env.width, (j + 0.5) / env.height
    cx, cy = u * env.width - 0.5, v * env.height - 0.5
    h = 24
    j0, i0 = int(round(cy)) - h, int(round(cx)) - h
    rows = np.clip(np.arange(j0, j0 + 2 * h), 0, env.height - 1)
    cols = np.mod(np.arange(i0, i0 + 2 * h), env.width)
    zoom = lambda img: img[rows][:, cols]  # noqa: E731
    row[0].imshow(before)
    row[0].set_title(f"{name}: before")
    row[1].imshow(after)
    row[1].set_title("remainder" + ("" if split.caps else " (= before: nothing split)"))
    row[2].imshow(zoom(before), interpolation="nearest")
    row[2].set_title("sun, before (48² texels)")
    row[3].imshow(zoom(after), interpolation="nearest")
    row[3].set_title("sun, remainder")
    row[4].imshow(zoom(after), interpolation="nearest")
    for cap in split.caps:
        cu, cv = (float(t) for t in direction_to_uv(np.asarray(cap.direction)))
        px = cu * env.width - 0.5 - i0
        py = cv * env.height - 0.5 - j0
        rad = float(cap.radius)
        sin_t = max(math.sin(cv * math.pi), 1e-3)
        ell = matplotlib.patches.Ellipse((px, py), 2 * rad / (2 * math.pi / env.width) / sin_t,
                                         2 * rad / (math.pi / env.height), fill=False, color="red", lw=1.5)
        row[4].add_patch(ell)
        row[4].plot([px], [py], "r+")
    row[4].set_title("cap (red) over remainder")
    for ax in row:
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in row[:2]:
        if split.caps:
            ax.plot([cx], [cy], "o", mfc="none", mec="red", ms=12)
fig.tight_layout()
path = OUT / "sun_split.png"
fig.savefig(path, dpi=80)
print("wrote", path)
