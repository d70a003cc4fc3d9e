"""Film: spectra → CIE XYZ → display RGB → transfer (SPEC eqs. 6–8), and image files.

- XYZ normalisation: ``k = 1/∫ȳ dλ`` on the render grid, so a flat spectrum of
  radiance 1 has Y = 1 (the same normalisation as Mitsuba 3's film).
- Display: :func:`jkatana.spectral.colorimetry.to_display` (the colourspace's
  XYZ→RGB matrix, no chromatic adaptation, then its transfer or a gamma).
- Files: a linear XYZ OpenEXR (channels X, Y, Z, plus ``mask``; spectral
  channels in the Fichet et al. 2021 layout on request, through
  :mod:`jkatana.light.spectral_exr`) and an 8-bit PNG; both carry
  the scene, the grid, samples and timing (EXR header attributes / PNG text
  chunks). Writes are atomic.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from jkatana.io.atomic import atomic_path
from jkatana.io.exr import write_exr
from jkatana.spectral.colorimetry import colourspace as _colourspace
from jkatana.spectral.colorimetry import decode, equal_energy_xyz_weights, to_display, to_png8
from jkatana.spectral.grid import WavelengthGrid


def film_weights(grid: WavelengthGrid) -> np.ndarray:
    """``(wl, 3)`` weights of the film: XYZ = S @ W with W = x̄ȳz̄ Δλ / Σ ȳ Δλ
    (:func:`jkatana.spectral.colorimetry.equal_energy_xyz_weights`)."""
    return equal_energy_xyz_weights(grid)


def auto_exposure(xyz: np.ndarray, mask: np.ndarray | None = None, key: float = 0.18,
                  percentile: float = 50.0) -> float:
    """Exposure that maps the ``percentile`` of Y (over ``mask`` or the whole frame) to ``key``.

    The default key 0.18 is photography's middle grey, the "key value" of Reinhard, Stark, Shirley &
    Ferwerda (2002), "Photographic tone reproduction for digital images", SIGGRAPH.
    """
    Y = xyz[..., 1] if mask is None or not mask.any() else xyz[..., 1][mask]
    ref = float(np.percentile(Y[np.isfinite(Y)], percentile)) if Y.size else 0.0
    return key / ref if ref > 0 else 1.0


#: The one automatic-exposure rule of ``render`` and ``view``: the exposure at which the object's mean
#: displayed luminance — each pixel's exposed Y clipped at white, as the display shows it — is
#: OBJECT_KEY (linear, before the transfer). Clipping at white keeps a glint on a few pixels from
#: setting the exposure; a frame without object pixels: the median of the whole frame to middle grey.
OBJECT_KEY = 0.35
FRAME_PERCENTILE, FRAME_KEY = 50.0, 0.18


def displayed_mean(Y: np.ndarray, exposure: float) -> float:
    """Mean of ``min(exposure · Y, 1)``: the object's mean luminance as the display shows it."""
    return float(np.mean(np.minimum(exposure * np.asarray(Y, np.float64), 1.0)))


def scene_exposure(xyz: np.ndarray, mask: np.ndarray | None) -> float:
    """The automatic exposure of a frame ``(H, W, 3)`` XYZ whose object pixels are ``mask``:
    :func:`displayed_mean` = :data:`OBJECT_KEY` (bisection in log exposure; the mean is increasing in it).

    ``render`` applies it to its XYZ frame; ``view`` measures the displayed mean on its GL frames
    (:func:`xyz_from_display`) and steps to the same target, so both show the same scene alike.
    """
    if mask is None or not np.any(mask):
        return auto_exposure(xyz, None, key=FRAME_KEY, percentile=FRAME_PERCENTILE)
    Y = np.asarray(xyz[..., 1])[mask]
    Y = Y[np.isfinite(Y) & (Y > 0)]
    if Y.size == 0:
        return 1.0
    # at lo every pixel shows ≤ key (mean ≤ key); at hi every pixel is white (mean 1 ≥ key)
    lo, hi = np.log(OBJECT_KEY / np.max(Y)), np.log(1.0 / np.min(Y)) + 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if displayed_mean(Y, float(np.exp(mid))) < OBJECT_KEY else (lo, mid)
    return float(np.exp(0.5 * (lo + hi)))


def xyz_from_display(rgb8: np.ndarray, colourspace: str = "sRGB", transfer: str | float | None = None,
                     exposure: float = 1.0) -> np.ndarray:
    """Inverse of :func:`display` for an 8-bit frame: display RGB → XYZ (divided by ``exposure``).

    Clipped channels stay clipped (1.0): decode frames exposed so that the
    object's bright end is below white.
    """
    lin = decode(np.asarray(rgb8, np.float64) / 255.0, colourspace if transfer is None else transfer)
    m = np.asarray(_colourspace(colourspace).matrix_RGB_to_XYZ, np.float64)
    return (lin @ m.T) / exposure


def display(xyz: np.ndarray, colourspace: str = "sRGB", transfer: str | float | None = None,
            exposure: float = 1.0) -> np.ndarray:
    """``(H, W, 3)`` XYZ → display-encoded RGB in [0, 1] (:func:`jkatana.spectral.colorimetry.to_display`)."""
    return to_display(xyz, colourspace, transfer, exposure=exposure)


def _text(meta: dict) -> dict[str, str]:
    return {k: v if isinstance(v, str) else json.dumps(v, default=str) for k, v in meta.items()}


def _attrs(meta: dict) -> dict:
    """EXR attributes: numbers stay numbers, anything else becomes a string (JSON for containers)."""
    return {k: v if isinstance(v, (str, int, float)) and not isinstance(v, bool) else json.dumps(v, default=str)
            for k, v in meta.items()}


def write_png(path: str | Path, display_rgb: np.ndarray, meta: dict | None = None) -> Path:
    """8-bit PNG with ``meta`` as tEXt chunks (atomic)."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    for k, v in _text(meta or {}).items():
        info.add_text(k, v)
    with atomic_path(path) as tmp:
        Image.fromarray(to_png8(display_rgb)).save(tmp, format="PNG", pnginfo=info)
    return Path(path)


def write_xyz_exr(path: str | Path, xyz: np.ndarray, mask: np.ndarray | None = None,
                  meta: dict | None = None) -> Path:
    """Linear XYZ float32 EXR (channels X, Y, Z[, mask]) with ``meta`` as string attributes."""
    ch = {"X": xyz[..., 0], "Y": xyz[..., 1], "Z": xyz[..., 2]}
    if mask is not None:
        ch["mask"] = mask.astype(np.float32)
    return write_exr(path, ch, header=_attrs(meta or {}))


def write_spectral_exr(path: str | Path, spectra: np.ndarray, grid: WavelengthGrid,
                       meta: dict | None = None) -> Path:
    """Spectral radiance EXR in the Fichet et al. (2021) layout (``S0.<λ>nm`` channels) with ``meta``
    as attributes (:func:`jkatana.light.spectral_exr.write_spectral_exr`)."""
    from jkatana.light.spectral_exr import write_spectral_exr as write  # the light stage, only when asked

    return write(path, spectra, grid, header=_attrs(meta or {}))
