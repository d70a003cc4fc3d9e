"""Validation against an independent renderer: Mitsuba 3 (Jakob et al., mitsuba-renderer.org).

A smooth and a rough (Beckmann) conductor sphere with iron's n, k under an
RGB environment map, rendered by Mitsuba 3.9.1 and by jkatana, compared in
CIE ΔE2000 (display-referred, :func:`jkatana.spectral.delta_e_2000`: the
Mitsuba frame's 99th-percentile Y maps to display white).

Conventions matched (those of Mitsuba 3.9.1, pinned by ``tests/test_render_mitsuba.py``):

- film: Mitsuba's spectral film integrates CIE 1931 over 360–830 nm and
  divides by 106.75 (≈ ∫ȳ dλ), then converts to linear Rec. 709 without white
  adaptation; jkatana renders on a 360–830 nm / 5 nm grid, XYZ with
  k = 1/Σȳ Δλ, rescaled by Σȳ Δλ / 106.75, and the same matrix;
- envmap: RGB upsampled with Jakob & Hanika (2019) × normalised D65 (jkatana's
  own ``load_envmap(..., upsampling="Jakob 2019")`` does the same per texel,
  see :mod:`jkatana.light.upsampling`; the comparison uses Mitsuba's LUT itself,
  :func:`mitsuba_env_spectra`, so that it tests renderers, not two LUTs).
  Mitsuba's latitude–longitude mapping has u = atan2(x, −z)/2π, half a turn
  from :mod:`jkatana.light.envmap`'s (the image centre looks along +Z, not −Z):
  the comparison turns jkatana's copy by 180° about +Y. Two more differences
  of its *lookup* (``eval_spectrum`` in Mitsuba's ``src/emitters/envmap.cpp``,
  pinned by ``tests/test_render_mitsuba.py``):

  1. rows are corner-aligned (row j at v = j/(H − 1), ours at (j + ½)/H;
     columns agree, (i + ½)/W): a shift of up to half a row, towards the poles;
  2. the spectral variants interpolate each texel's sigmoid spectrum and its
     scale (2·max rgb) *separately* and multiply the two interpolants, where
     interpolating radiance gives bilinear(sigmoid·scale): they differ by
     −t(1 − t)·Δsigmoid·Δscale per axis.

  Left uncompensated, both make jkatana's sphere darker than Mitsuba's by a
  colour-dependent ~1 %. Compensated: jkatana gets an image with ``ENV_NODES``
  = 3 nodes per texel and axis whose values are Mitsuba's lookup at our texel
  centres (:func:`mitsuba_env_spectra` with ``nodes``; between nodes the
  residual is our bilinear's interpolation error on the finer grid; 3 = odd
  puts a node on each of Mitsuba's column kinks). It costs 9× the texels:
  time jkatana with ``env_nodes=None`` (the texels Mitsuba has) when comparing
  speed, and measure its error with the matched copy at the same samples;
- Beckmann α = √2 × per-axis RMS slope (Mitsuba's parameter) is the α of
  :func:`jkatana.models.beckmann`; masking is separable Smith with Walter's
  rational G1 on both sides (the hamon region's lobe is
  :class:`~jkatana.models.lobes.Beckmann` with α = μ1: ``Plan(hamon_lobe=...)``);
- η, k outside the given range read as 0 in Mitsuba: the spectra are given
  on the whole 360–830 nm range;
- pixels: Mitsuba integrates each pixel with a box filter; jkatana renders at
  ``supersample``× resolution and box-averages.

The measured agreement, its noise budget and the residual's analysis are in
``benchmarks/reports/mitsuba-agreement/NOTES.md``; ``experiments/mitsuba_rough_bias.py``
reproduces them.

The variant: ``llvm_ad_spectral`` when it runs (needs Debian's ``libllvm19``;
with LLVM 15 it aborts the process, so it is probed in a subprocess), else
``scalar_spectral``.
"""

from __future__ import annotations

import functools
import subprocess
import sys
from pathlib import Path

import numpy as np

MITSUBA_Y_NORM = 106.75
#: Mitsuba's latlong u origin differs from jkatana's by half a turn (measured, 3.9.1).
MITSUBA_ENV_ROTATION_DEG = 180.0
#: Our texel centres per Mitsuba texel (per axis) at which :func:`mitsuba_env_spectra` evaluates
#: Mitsuba's envmap for jkatana's copy (see there).
ENV_NODES = 3


@functools.lru_cache(maxsize=2)
def mitsuba_variant(kind: str = "spectral") -> str | None:
    """The best ``kind`` (``"spectral"`` or ``"rgb"``) variant that runs here — LLVM, else scalar — probed in a
    subprocess (an LLVM abort can't kill us); ``None`` without Mitsuba."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return None
    for variant in (f"llvm_ad_{kind}", f"scalar_{kind}"):
        code = ("import mitsuba as mi; mi.set_variant('%s'); "
                "mi.render(mi.load_dict({'type': 'scene', 'i': {'type': 'path'}, 'e': {'type': 'constant'}, "
                "'s': {'type': 'perspective', 'film': {'type': 'hdrfilm', 'width': 4, 'height': 4}}}), spp=1)"
                % variant)
        try:
            r = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=180)
        except subprocess.TimeoutExpired:
            continue
        if r.returncode == 0:
            return variant
    return None


def small_envmap(src: str | Path, dst: str | Path, width: int = 256) -> Path:
    """Box-downsample an RGB equirectangular EXR to ``width × width/2`` (written atomically)."""
    from jkatana.io.exr import write_exr
    from jkatana.light.envmap import read_rgb_image

    rgb = np.maximum(np.nan_to_num(read_rgb_image(src).astype(np.float64)), 0.0)
    H, W = rgb.shape[:2]
    f = W // width
    rgb = rgb[: (H // f) * f, : (W // f) * f].reshape(H // f, f, W // f, f, 3).mean((1, 3))
    return write_exr(dst, {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})


#: Mitsuba 3.9.1's sample generators (its ``src/samplers``): pseudo-random; jittered strata;
#: correlated multi-jittered (Kensler 2013); orthogonal-array Latin hypercube (Jarosz et al. 2019;
#: the count is rounded up to a prime's square); Sobol-based low discrepancy (Kollig & Keller 2002).
MITSUBA_SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
#: Integrators that fit the scene (one bounce off the sphere into the environment): ``path``
#: (``max_depth`` 2: one BSDF sample and one emitter sample per spp, combined by MIS) and ``direct``
#: (one emitter and one BSDF sample per spp, MIS; Veach 1997).
MITSUBA_INTEGRATORS = ("path", "direct")


def _check_config(sampler: str, integrator: str) -> None:
    from jkatana.errors import InputError

    if sampler not in MITSUBA_SAMPLERS:
        raise InputError(f"unknown Mitsuba sampler {sampler!r} (one of {', '.join(MITSUBA_SAMPLERS)})",
                         field="sampler")
    if integrator not in MITSUBA_INTEGRATORS:
        raise InputError(f"unknown Mitsuba integrator {integrator!r} (one of {', '.join(MITSUBA_INTEGRATORS)})",
                         field="integrator")


def mitsuba_sample_count(sampler: str, spp: int, variant: str | None = None) -> int:
    """The samples per pixel Mitsuba renders when ``sampler`` is asked for ``spp`` (its own rounding:
    ``orthogonal`` needs the square of a prime)."""
    import mitsuba as mi

    _check_config(sampler, "path")
    mi.set_variant(variant or mitsuba_variant())
    return int(mi.load_dict({"type": sampler, "sample_count": int(spp)}).sample_count())


def render_mitsuba(env_path, *, alpha: float | None, size: int = 96, spp: int = 256,
                   variant: str | None = None, fov: float = 38.0, eye=(0.0, 0.3, 3.2), seed: int = 0,
                   sampler: str = "independent", integrator: str = "path") -> np.ndarray:
    """Mitsuba 3: iron sphere (radius 1 at the origin), linear Rec. 709 ``(size, size, 3)``.

    ``seed`` seeds Mitsuba's sampler: two seeds give independent frames (their
    difference estimates Mitsuba's own noise). ``sampler`` (one of
    :data:`MITSUBA_SAMPLERS`) and ``integrator`` (one of :data:`MITSUBA_INTEGRATORS`)
    choose Mitsuba's configuration; a sampler may round ``spp``
    (:func:`mitsuba_sample_count` says to what).
    """
    import mitsuba as mi

    from jkatana.spectral.optical_constants import load
    from jkatana.spectral.grid import WavelengthGrid

    _check_config(sampler, integrator)
    mi.set_variant(variant or mitsuba_variant())
    grid = WavelengthGrid(360.0, 830.0, 5.0)
    n, k = load("Fe-Johnson").on_grid(grid)
    wl = grid.wavelengths
    spec = lambda v: {"type": "spectrum", "value": [(float(a), float(b)) for a, b in zip(wl, v)]}  # noqa: E731
    bsdf = {"type": "conductor", "eta": spec(n), "k": spec(k)} if alpha is None else \
        {"type": "roughconductor", "distribution": "beckmann", "alpha": float(alpha), "sample_visible": True,
         "eta": spec(n), "k": spec(k)}
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2} if integrator == "path" else {"type": "direct"},
        "env": {"type": "envmap", "filename": str(env_path)},
        "sphere": {"type": "sphere", "radius": 1.0, "bsdf": bsdf},
        "sensor": {"type": "perspective", "fov": fov, "fov_axis": "y",
                   "to_world": mi.ScalarTransform4f().look_at(origin=list(eye), target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": sampler, "sample_count": spp}},
    })
    return np.asarray(mi.render(scene, spp=spp, seed=seed), np.float64)[..., :3]


def render_jkatana(env_path, *, alpha: float | None, size: int = 96, samples: int = 256, supersample: int = 3,
                   fov: float = 38.0, eye=(0.0, 0.3, 3.2), same_upsampling: bool = True, seed: int = 0,
                   env_nodes: int | None = ENV_NODES, env_samples: int | None = None,
                   fresnel_rank: int | None = None, env_window: float | None = None, split_sun: bool = False):
    """jkatana, same scene: ``(linear Rec. 709 (size, size, 3), mask, shading seconds)``.

    ``same_upsampling``: the environment is Mitsuba's own spectral envmap
    (:func:`mitsuba_env_spectra` with ``nodes=env_nodes``: ``None`` = its texel
    spectra at our texel centres, uncompensated); else jkatana's Jakob 2019 upsampling.
    ``seed``: jkatana's sampling key. ``env_samples``: environment samples per subpixel of the rough
    sphere (``Plan.env_samples``; ``None``: one beside each of the ``samples`` lobe samples).
    ``fresnel_rank``: rank of the folded Fresnel table of the rough sphere (``Plan.fresnel_rank``;
    ``None``: the frame's choice, for this reference-mode sphere within
    :data:`~jkatana.render.fresnel_fold.FRESNEL_RANK_TOL_SAMPLED` of the table; 0: full spectra).
    ``env_window``: ``Plan.env_window`` (``None``: environment samples from the whole map).
    ``split_sun``: split the map's compact bright sources off as caps (``build_environment(split_sun=)``),
    which the MIS shader samples on their own.
    """
    import jax.numpy as jnp

    from jkatana.light.envmap import load_envmap
    from jkatana.models import Conductor
    from jkatana.render.camera import Camera
    from jkatana.render.film import film_weights
    from jkatana.render.frame import pixel_blocks, render_frame
    from jkatana.render.environment import build_environment
    from jkatana.render.fresnel_fold import Material, fresnel_table
    from jkatana.render.plan import Plan
    from jkatana.spectral.colorimetry import xyz_to_linear_rgb, xyz_weights
    from jkatana.spectral.grid import WavelengthGrid

    grid = WavelengthGrid(360.0, 830.0, 5.0)
    radiance = mitsuba_env_spectra(env_path, grid, nodes=env_nodes) if same_upsampling else \
        np.asarray(load_envmap(env_path, grid, upsampling="Jakob 2019").radiance)
    from jkatana.render.renderer import rotation_y

    # Mitsuba 3.9.1's envmap maps u = atan2(x, −z)/2π (no +½): jkatana's map turned by 180° about +Y
    E, _, _ = build_environment(radiance, grid=grid, rotation=rotation_y(MITSUBA_ENV_ROTATION_DEG),
                                split_sun=split_sun)
    c = Conductor.from_table("Fe-Johnson", grid, dtype=jnp.float32)
    mat = Material(fresnel_table(c.n, c.k), jnp.float32(1.0), jnp.float32(1.0))
    s = size * supersample
    cam = Camera(position=tuple(eye), look_at=(0.0, 0.0, 0.0), fov_deg=fov, width=s, height=s)
    if alpha is None:
        plan, maps = Plan(samples=1, hiraji=True, hamon=False, mirror=True), [1.0, 0.0, 0.05]
    else:
        from jkatana.models.lobe_id import LobeId

        plan = Plan(samples=samples, hiraji=False, hamon=True, hamon_lobe=LobeId.of({"lobe": "beckmann", "alpha": 1.0}),
                    env_samples=env_samples, fresnel_rank=fresnel_rank, env_window=env_window)
        maps = [0.0, 0.05, alpha]
    cmf = film_weights(grid)
    f = render_frame(plan, mat, E, None, ("sphere", (0.0, 0.0, 0.0), 1.0), cam,
                     np.array([[maps]], np.float32).repeat(2, 0).repeat(2, 1), cmf, seed=seed,
                     supersample=supersample)  # one sample set per pixel across its subpixels
    scale = float(xyz_weights(grid)[:, 1].sum()) / MITSUBA_Y_NORM
    rgb = xyz_to_linear_rgb(f.xyz.astype(np.float64) * scale, "ITU-R BT.709")
    rgb = pixel_blocks(rgb, supersample).mean((1, 3))
    mask = pixel_blocks(f.mask, supersample).all((1, 3))
    return rgb, mask, f.timing["shade_s"]


def compare(rgb_mi: np.ndarray, rgb_jk: np.ndarray, mask: np.ndarray, erode: int = 1) -> dict:
    """ΔE2000 (mean, p95, p99, max) over the sphere's interior pixels (mask eroded by ``erode``), the first
    frame the reference: :func:`jkatana.spectral.delta_e_display` (sRGB display, the reference's
    99th-percentile Y to display white on both sides; also ``exposure`` and ``pixels``).
    """
    from scipy.ndimage import binary_erosion

    from jkatana.spectral import delta_e_display
    from jkatana.spectral.colorimetry import xyz_to_rgb_matrix

    m = binary_erosion(mask, iterations=erode) if erode else mask
    to_xyz = np.linalg.inv(xyz_to_rgb_matrix("ITU-R BT.709"))
    return delta_e_display(rgb_mi[m] @ to_xyz.T, rgb_jk[m] @ to_xyz.T, percentiles=(95.0, 99.0))


def _mitsuba_texels(env_path, grid):
    """Mitsuba 3's per-texel spectral envmap data on ``grid``: ``(sigmoid (H, W, wl), scale (H, W), D65 (wl,))``.

    Per texel (Mitsuba's ``envmap.cpp``): scale = 2·max(rgb), coefficients =
    ``srgb_model_fetch(rgb / scale)`` (Jakob & Hanika 2019, Mitsuba's 64³ LUT),
    sigmoid(λ) = ``srgb_model_eval(coeff, λ)``; D65 is Mitsuba's ``d65`` plugin
    (normalised). The texel's radiance is sigmoid · scale · D65.
    """
    import mitsuba as mi

    from jkatana.light.envmap import read_rgb_image

    mi.set_variant("scalar_spectral")
    rgb = np.maximum(np.nan_to_num(read_rgb_image(env_path).astype(np.float64)), 0.0)
    H, W = rgb.shape[:2]
    flat = rgb.reshape(-1, 3)
    wl = np.asarray(grid.wavelengths, np.float64)
    d65 = mi.load_dict({"type": "d65"})
    si = mi.SurfaceInteraction3f()
    d65_wl = []
    for i in range(0, len(wl), 4):
        chunk = np.resize(wl[i:i + 4], 4)
        si.wavelengths = mi.Spectrum(*chunk.tolist())
        d65_wl.extend(np.asarray(d65.eval(si))[: len(wl[i:i + 4])].tolist())
    d65_wl = np.asarray(d65_wl)
    scale = 2.0 * flat.max(-1)
    coeffs = np.array([list(mi.srgb_model_fetch(mi.ScalarColor3f(*(c / max(s, 1e-8)).tolist())))
                       for c, s in zip(flat, scale)])
    # sigmoid of a quadratic in λ (srgb_model_eval), vectorised here
    x = coeffs[:, 0:1] * wl * wl + coeffs[:, 1:2] * wl + coeffs[:, 2:3]
    sig = 0.5 + 0.5 * x / np.sqrt(1.0 + x * x)
    return sig.reshape(H, W, -1), scale.reshape(H, W), d65_wl


def _lerp_axis(a: np.ndarray, pos: np.ndarray, axis: int, wrap: bool) -> np.ndarray:
    """Linear interpolation of ``a`` along ``axis`` at fractional texel positions ``pos`` (wrapped or clamped)."""
    n = a.shape[axis]
    p0 = np.floor(pos) if wrap else np.clip(np.floor(pos), 0, n - 2)
    i0 = p0.astype(int) % n
    i1 = (i0 + 1) % n
    f = (pos - p0).astype(a.dtype).reshape((-1,) + (1,) * (a.ndim - axis - 1))
    return np.take(a, i0, axis=axis) * (1.0 - f) + np.take(a, i1, axis=axis) * f


def mitsuba_env_spectra(env_path, grid, nodes: int | None = None) -> np.ndarray:
    """The environment as Mitsuba 3's spectral ``envmap`` sees it, on ``grid``: ``(H', W', wl)``.

    ``nodes=None``: the texels' own spectra, ``sigmoid · scale · D65`` per texel
    (see :func:`_mitsuba_texels`), ``(H, W, wl)``.

    ``nodes=r``: an ``(r·H, r·W, wl)`` image whose value at each of *our*
    texel centres — jkatana's lookup puts row j′ at v = (j′ + ½)/H′ and column
    i′ at u = (i′ + ½)/W′ (:func:`jkatana.render.shading.bilinear_equirect`) —
    is exactly what Mitsuba 3.9.1's ``envmap.eval`` returns in that direction:
    rows corner-aligned (y = v·(H − 1)), columns centred (x = u·W − ½, wrapped),
    and, in its spectral variants, the bilinear interpolant of the texels'
    sigmoids *times* the bilinear interpolant of their scales (``eval_spectrum``
    in ``src/emitters/envmap.cpp``), not the interpolant of their product.
    Between our nodes our bilinear lookup differs from Mitsuba's by the
    interpolation error on the finer grid, which falls as 1/r² (measured by
    ``tests/test_render_mitsuba.py``). Directions are in the map's frame (the
    comparison's half-turn rotation is applied by the renderer).
    """
    sig, scale, d65 = _mitsuba_texels(env_path, grid)
    if nodes is None:
        return (sig * scale[..., None] * d65).astype(np.float32)
    H, W = scale.shape
    r = int(nodes)
    y = (np.arange(r * H) + 0.5) / (r * H) * (H - 1)  # Mitsuba's row coordinate at our row centres
    x = (np.arange(r * W) + 0.5) / r - 0.5  # its column coordinate at our column centres
    up = lambda a: _lerp_axis(_lerp_axis(a, y, 0, wrap=False), x, 1, wrap=True)  # noqa: E731
    out = up(sig.astype(np.float32))
    out *= up(scale.astype(np.float32))[..., None]
    out *= d65.astype(np.float32)
    return out
