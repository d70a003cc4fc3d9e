"""CLI of the light stage: ``jkatana light build | convert | inspect | prefilter | cache``.

- ``build``: the Hosek–Wilkie spectral sky (sun by elevation/azimuth or place + time) →
  spectral EXR (Fichet 2021) + PNG preview with the sun marked.
- ``convert``: RGB EXR / Radiance HDR → spectral EXR by a named upsampling method; prints
  the RGB → spectrum → RGB round-trip error.
- ``inspect``: any environment map → PNG preview (sun = brightest texel marked) and a
  summary (size, grid, power, sun direction and its share of the power).
- ``prefilter`` (added and run by :mod:`jkatana.render.commands`): a scene's environment (spectra, sampler, the prefiltered levels its
  materials call for) built into the render cache (:mod:`jkatana.light.cache`), so that
  every later render or batch of that scene loads it at once.
- ``cache``: list the environment and bake cache (size, last use) or clear it; its size budget
  is ``$JKATANA_CACHE_MAX_MB`` (:mod:`jkatana.light.cache`).
"""

from __future__ import annotations

import argparse
import datetime as dt
from pathlib import Path

import numpy as np

from jkatana.errors import InputError

LIGHT_HELP = ("Build (Hosek–Wilkie sky), convert (RGB → spectral EXR), inspect and prefilter environment maps; "
              "list or clear their cache.")


def _grid_args(p):
    p.add_argument("--grid", nargs=3, type=float, metavar=("START", "STOP", "STEP"), default=(400.0, 700.0, 5.0),
                   help="wavelength grid in nm (default 400 700 5)")


def light_add_arguments(p: argparse.ArgumentParser):
    """The light stage's subcommands; returns their subparsers, to which the render stage adds ``prefilter``
    (it prepares a render, :func:`jkatana.render.commands.light_add_arguments`)."""
    sub = p.add_subparsers(dest="light_command", metavar="ACTION", required=True)

    b = sub.add_parser("build", help="spectral Hosek–Wilkie sky (+ sun, + ground) → spectral EXR + PNG")
    b.add_argument("-o", "--output", required=True, help="output spectral EXR (a .png preview is written beside it)")
    b.add_argument("--elevation", type=float, default=30.0, help="sun elevation (deg, 0–90)")
    b.add_argument("--azimuth", type=float, default=180.0, help="sun azimuth, clockwise from north = −Z (deg)")
    b.add_argument("--place", nargs=2, type=float, metavar=("LAT", "LON"),
                   help="latitude, longitude (deg, east positive): sun from --time instead")
    b.add_argument("--time", help="ISO date-time, e.g. 2024-06-21T12:00+09:00 (UTC if no offset)")
    b.add_argument("--turbidity", type=float, default=3.0)
    b.add_argument("--albedo", type=float, default=0.1, help="ground albedo 0–1")
    b.add_argument("--resolution", nargs=2, type=int, default=(512, 1024), metavar=("H", "W"))
    b.add_argument("--no-sun", action="store_true", help="sky only")
    _grid_args(b)

    c = sub.add_parser("convert", help="RGB EXR/HDR → spectral EXR (Fichet 2021)")
    c.add_argument("input")
    c.add_argument("-o", "--output", required=True)
    c.add_argument("--upsampling", default="Jakob 2019", help="Jakob 2019 | Mallett 2019 | Smits 1999 | Flat")
    c.add_argument("--scale", type=float, default=1.0)
    _grid_args(c)

    i = sub.add_parser("inspect", help="PNG preview with the sun marked, and a summary")
    i.add_argument("input")
    i.add_argument("-o", "--output", help="PNG path (default: input with .png)")
    i.add_argument("--upsampling", default="Mallett 2019", help="for RGB inputs")
    i.add_argument("--exposure", type=float, help="multiplier on luminance (default: median sky → 0.18)")
    _grid_args(i)

    k = sub.add_parser("cache", help="list the environment/bake cache (default) or clear it; size budget "
                                     "$JKATANA_CACHE_MAX_MB (default 2048), least recently used entries evicted")
    k.add_argument("--clear", action="store_true", help="remove every entry no running process uses")
    return sub


def _grid(args):
    from jkatana.spectral import WavelengthGrid

    start, stop, step = _check_grid(args)
    return WavelengthGrid(start, stop, step)


def _check_grid(args) -> tuple[float, float, float]:
    """``--grid`` within the CIE observer's 360–830 nm, its step at least 1 nm (:mod:`jkatana.spectral.grid`)."""
    from jkatana.io.limits import numbers
    from jkatana.spectral.grid import WAVELENGTH_RANGE, WavelengthGrid

    start, stop, step = numbers(args.grid, "--grid", lo=0, lo_open=True, hi=1e5)
    if not stop > start:
        raise InputError(f"STOP must be above START, got {start:g} {stop:g}", field="--grid")
    lo, hi = WAVELENGTH_RANGE
    if start < lo or stop > hi:
        raise InputError(f"must lie within {lo:g}–{hi:g} nm (the CIE 1931 observer's domain, outside which no "
                         f"spectrum has a colour), got {start:g}–{stop:g}", field="--grid")
    try:
        WavelengthGrid(start, stop, step)
    except InputError as err:
        raise InputError(str(err).split(": ", 1)[-1], field="--grid") from None
    return start, stop, step


def _bands(args) -> int:
    start, stop, step = _check_grid(args)
    return int((stop - start) / step) + 1


def _need(args, nbytes: float, field: str, what: str, values: float = 0) -> None:
    """Refuse a request of ``nbytes`` of memory (and ``values`` spectral values of work) beyond the budget."""
    from jkatana.io.limits import require_memory, require_work

    require_memory(nbytes, field, what, getattr(args, "max_memory", None))
    require_work(values, field, what)


def preview_exposure(env) -> float:
    """Exposure of an environment preview: the median luminance of the upper half (the sky) to middle
    grey 0.18 (:func:`jkatana.render.film.auto_exposure`'s key)."""
    Y = np.asarray(env.xyz(), np.float64)[..., 1]
    return 0.18 / (float(np.median(Y[: env.height // 2])) or float(Y.mean()) or 1.0)


def preview_display8(env, exposure: float) -> np.ndarray:
    """8-bit sRGB preview ``(H, W, 3)`` of ``env``: XYZ × ``exposure``, Reinhard's operator on luminance
    (:func:`jkatana.spectral.colorimetry.reinhard`), encoded for display."""
    from jkatana.spectral.colorimetry import display8, reinhard

    return display8(reinhard(np.asarray(env.xyz(), np.float64) * exposure))


def preview_png(env, path, *, exposure: float | None = None, mark_sun: bool = True, sun_dir=None) -> dict:
    """Write a tone-mapped sRGB PNG of ``env`` with the sun circled; return summary facts."""
    from PIL import Image, ImageDraw

    from jkatana.io.atomic import atomic_path
    from jkatana.light.envmap import direction_to_uv

    xyz = np.asarray(env.xyz(), np.float64)
    Y = xyz[..., 1]
    omega = np.asarray(env.solid_angles(), np.float64)
    if exposure is None:
        exposure = preview_exposure(env)
    im = Image.fromarray(preview_display8(env, exposure))
    j, i = np.unravel_index(np.argmax(Y), Y.shape)
    d = np.asarray(env.directions())[j, i] if sun_dir is None else np.asarray(sun_dir)
    power = Y * omega
    share = float(np.sort(power.ravel())[::-1][: max(1, Y.size // 1000)].sum() / power.sum()) if power.sum() > 0 else 0
    u, v = (float(t) for t in direction_to_uv(d))
    elev = 90.0 - 180.0 * v  # the map's convention (jkatana.light.envmap): v = 0 at the zenith
    az = (360.0 * (u - 0.5)) % 360  # compass azimuth, clockwise from north (−Z)
    if mark_sun:
        cx, cy = u * env.width, v * env.height
        r = max(6, env.width // 64)
        draw = ImageDraw.Draw(im)
        draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=(255, 0, 0), width=max(1, env.width // 512))
    with atomic_path(path) as tmp:
        im.save(tmp, format="PNG")
    return {"exposure": exposure, "sun_elevation_deg": elev, "sun_azimuth_deg": az,
            "brightest_0.1%_power_share": share}


def _finite(values, what: str, field: str) -> None:
    """No NaN/inf written to a spectral EXR: refuse, naming the option that led to it."""
    arr = np.asarray(values)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what} holds {int(np.count_nonzero(~np.isfinite(arr)))} non-finite values; "
                         "nothing written", field=field)


def light_run(args: argparse.Namespace) -> int:
    """``jkatana light`` but ``prefilter``, which prepares a scene for the renderer: the command line runs that
    one from :func:`jkatana.render.commands.light_run`."""
    return {"build": _build, "convert": _convert, "inspect": _inspect, "cache": _cache}[args.light_command](args)


def _build(args) -> int:
    from jkatana.io.limits import number, numbers
    from jkatana.io.outputs import Output, check_outputs
    from jkatana.light.sky import hosek_wilkie_sky, sun_direction, sun_position
    from jkatana.light.spectral_exr import write_spectral_exr

    number(args.elevation, "--elevation", lo=-90, hi=90)
    number(args.azimuth, "--azimuth", lo=-360, hi=720)
    if args.place:
        lat, lon = numbers(args.place, "--place", lo=-180, hi=180)
        number(lat, "--place", lo=-90, hi=90)
    number(args.turbidity, "--turbidity", lo=1, hi=10)
    number(args.albedo, "--albedo", lo=0, hi=1)
    h, w = numbers(args.resolution, "--resolution", lo=2, hi=2 ** 20, integer=True)
    nb = _bands(args)
    # radiance (float32) and its float64 copies for the XYZ preview and the EXR channels
    _need(args, h * w * (nb * (4 + 8 + 4) + 64), "--resolution", f"a {h}×{w} sky with {nb} bands", h * w * nb)
    out = Path(args.output)
    png = out.with_suffix(".png")
    check_outputs([Output(out, "--output", (".exr",)), Output(png, "--output (its .png preview)", (".png",))])
    elev, az = args.elevation, args.azimuth
    if args.place:
        if not args.time:
            raise InputError("--place needs --time", field="time")
        try:
            when = dt.datetime.fromisoformat(args.time)
        except ValueError:
            raise InputError(f"not an ISO date-time: {args.time!r}", field="time") from None
        elev, az = sun_position(args.place[0], args.place[1], when)
        print(f"sun at elevation {elev:.2f}°, azimuth {az:.2f}° (NOAA)")
        if elev < 0:
            raise InputError(f"the sun is below the horizon ({elev:.1f}°) at that place and time", field="time")
    env = hosek_wilkie_sky(elev, az, args.turbidity, args.albedo, tuple(args.resolution), _grid(args),
                           sun=not args.no_sun)
    _finite(env.radiance, "the sky model", "--elevation")
    write_spectral_exr(out, np.asarray(env.radiance), env.grid)
    facts = preview_png(env, png, sun_dir=sun_direction(elev, az))
    print(f"wrote {out} ({env.height}×{env.width}×{env.grid.size}) and {png}; "
          f"sun share of luminous power (brightest 0.1 % texels): {facts['brightest_0.1%_power_share']:.3f}")
    return 0


def _convert(args) -> int:
    from jkatana.light.envmap import read_rgb_image
    from jkatana.light.spectral_exr import write_spectral_exr
    from jkatana.light.upsampling import rgb_to_spectrum, round_trip_error

    from jkatana.io.limits import number
    from jkatana.io.outputs import Output, check_outputs

    number(args.scale, "--scale", lo=0, lo_open=True)
    grid = _grid(args)
    check_outputs([Output(args.output, "--output", (".exr",))], inputs=[args.input])
    _need(args, 1e6 * grid.size * 4 * 3, "--grid", f"{grid.size} bands")  # per megapixel, before reading
    rgb = read_rgb_image(args.input)
    _need(args, rgb.shape[0] * rgb.shape[1] * grid.size * 4 * 3, "--grid",
          f"a {rgb.shape[0]}×{rgb.shape[1]} map with {grid.size} bands", rgb.shape[0] * rgb.shape[1] * grid.size)
    rgb = rgb * args.scale
    L = rgb_to_spectrum(rgb, args.upsampling, grid)
    _finite(L, "the upsampled spectra", "--scale")
    write_spectral_exr(args.output, L, grid)
    sub = rgb.reshape(-1, 3)[:: max(1, rgb.size // 3 // 20000)]
    err = round_trip_error(sub, args.upsampling, grid)
    print(f"wrote {args.output} ({L.shape[0]}×{L.shape[1]}×{grid.size}, {args.upsampling}); "
          f"RGB→spectrum→RGB error (relative to max channel): mean {err['mean']:.2e}, "
          f"p99 {err['p99']:.2e}, max {err['max']:.2e}")
    return 0


def _inspect(args) -> int:
    from jkatana.light.envmap import load_envmap

    from jkatana.io.limits import number
    from jkatana.io.outputs import Output, check_outputs

    number(args.exposure, "--exposure", lo=0, lo_open=True)
    grid = _grid(args)
    out = Path(args.output) if args.output else Path(args.input).with_suffix(".png")
    check_outputs([Output(out, "--output", (".png",))], inputs=[args.input])
    env = load_envmap(args.input, grid, upsampling=args.upsampling)
    facts = preview_png(env, out, exposure=args.exposure)
    p = np.asarray(env.irradiance((0.0, 1.0, 0.0)))
    print(f"{args.input}: {env.height}×{env.width}, grid {env.grid.start:g}–{env.grid.stop:g}/{env.grid.step:g} nm, "
          f"grey={env.is_grey()}")
    print(f"  brightest texel at elevation {facts['sun_elevation_deg']:.2f}°, azimuth {facts['sun_azimuth_deg']:.2f}°; "
          f"brightest 0.1 % of texels carry {100 * facts['brightest_0.1%_power_share']:.1f} % of the luminous power")
    print(f"  horizontal irradiance at 550 nm: {np.interp(550, env.grid.wavelengths, p):.4g} (map units × sr)")
    print(f"  preview: {out}")
    return 0


def _cache(args) -> int:
    import time

    from jkatana.light import cache

    base = cache.cache_base()
    if args.clear:
        removed, kept = cache.clear()
        print(f"{base}: removed {len(removed)} entries" + (f", kept {len(kept)} in use" if kept else ""))
        return 0
    listed = cache.entries()
    total = sum(e.size for e in listed)
    for e in listed[::-1]:
        when = time.strftime("%Y-%m-%d %H:%M", time.localtime(e.last_used))
        print(f"{e.size / 1e6:10.1f} MB  {when}  {e.path.parent.name}/{e.path.name}")
    print(f"{base}: {len(listed)} entries, {total / 1e6:.1f} MB of {cache.cache_budget() / 1e6:.0f} MB "
          f"(${cache.BUDGET_VARIABLE})")
    return 0
