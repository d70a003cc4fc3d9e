"""Reflectance map from a photo of the blade under uniform diffuse light (paper §3, eq. 5).

Under diffuse light the mirror-like hiraji reflects the (dark) surroundings and
looks dark, the rough hamon scatters the light and looks bright (Mochizuki et
al.). So luminance Y → w: ``Y ≤ dark`` → w = 1 (Fresnel/hiraji), ``Y ≥ bright``
→ w = 0 (Torrance–Sparrow/hamon), linear in between. Thresholds are given or
taken around Otsu's threshold of the luminance histogram (Otsu, "A threshold
selection method from gray-level histograms", IEEE SMC 9(1), 1979).

Luminance of linear RGB is the Y row of the sRGB / Rec. 709 primaries' RGB→XYZ matrix
(:func:`jkatana.spectral.colorimetry.luminance_weights`; 0.2126, 0.7152, 0.0722, ITU-R BT.709).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jkatana.errors import InputError
from jkatana.maps.reflectance_map import PAPER_PARAMETERS, ReflectanceMap
from jkatana.spectral.colorimetry import decode, luminance_weights



def read_photo(path: str | Path) -> np.ndarray:
    """Linear luminance (H, W) of an EXR, 16-bit PNG or TIFF photo (8-bit images are decoded sRGB),
    or the green signal of a camera RAW (see :func:`_raw_green`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("photo not found", path=path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        from jkatana.io.exr import read_exr

        ch, _ = read_exr(path)
        if all(k in ch for k in "RGB"):
            img = np.stack([ch["R"], ch["G"], ch["B"]], -1)
        elif "Y" in ch:
            img = ch["Y"]
        else:
            raise InputError(f"no R, G, B or Y channel (has {sorted(ch)})", path=path)
        img = np.asarray(img, np.float64)
    elif suffix in (".tif", ".tiff"):
        import tifffile

        try:
            img = np.asarray(tifffile.imread(path))
        except Exception as err:  # noqa: BLE001  (tifffile raises several kinds for bad files)
            raise InputError(f"not a readable TIFF ({type(err).__name__}: {err})", path=path) from None
        img = _normalise_int(img, path)
    elif suffix == ".png":
        from PIL import Image

        try:
            with Image.open(path) as im:
                img = np.asarray(im)
        except (OSError, ValueError, SyntaxError) as err:  # Pillow: truncated or not a PNG
            raise InputError(f"not a readable PNG ({str(err).splitlines()[0] if str(err) else type(err).__name__})",
                             path=path) from None
        img = _normalise_int(img, path)
    elif suffix in RAW_SUFFIXES:
        return _raw_green(path)
    else:
        raise InputError(f"photo must be .exr, .png, .tif, .tiff or a camera RAW ({', '.join(RAW_SUFFIXES)})",
                         path=path)
    if img.ndim == 3:
        img = img[..., :3] @ luminance_weights("sRGB")
    if img.ndim != 2 or img.size == 0:
        raise InputError(f"not a 2-D image (shape {img.shape})", path=path)
    if not np.all(np.isfinite(img)):
        raise InputError("photo has NaN or infinite pixels", path=path)
    return img


#: Camera RAW suffixes read through the measurement decoder (rawpy/LibRaw).
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".orf", ".rw2", ".raf", ".pef",
                ".srw", ".raw")


def _raw_green(path: Path) -> np.ndarray:
    """A RAW photo's green signal, one value per CFA block (half resolution for Bayer).

    Decoded by the measurement code (:func:`jkatana.measure.decode.read_frame`):
    per-channel black level from the file subtracted, divided by (white − black),
    then the mean of the green photosites in each repeat block of the colour
    filter array. The green channel stands in for luminance, as in the paper's
    fits (Mochizuki et al. fit the camera's green channel). Saturated green
    photosites make the photo unusable for w and are refused.
    """
    from jkatana.measure.decode import read_frame

    frame = read_frame(path)
    if frame.colors is None:  # pragma: no cover - read_frame returns a CFA for RAW files
        raise InputError("RAW file without a colour filter array", path=path)
    dn = frame.dn.astype(np.float64)
    green = np.isin(frame.colors, frame.green_colors)
    black = frame.black[frame.colors]
    if np.any(green & (frame.dn >= frame.white)):
        n = int(np.count_nonzero(green & (frame.dn >= frame.white)))
        raise InputError(f"{n} green photosites are saturated: expose the diffuse-lit photo lower", path=path)
    value = np.where(green, (dn - black) / (frame.white - black), 0.0)
    block = 2  # the Bayer repeat; other CFAs are caught below (blocks with no green)
    H, W = (dn.shape[0] // block) * block, (dn.shape[1] // block) * block
    v = value[:H, :W].reshape(H // block, block, W // block, block).sum(axis=(1, 3))
    n = green[:H, :W].reshape(H // block, block, W // block, block).sum(axis=(1, 3))
    if np.any(n == 0):
        raise InputError("colour filter array has 2×2 blocks without a green photosite "
                         "(not a Bayer pattern): convert the photo to a linear TIFF", path=path)
    return v / n


def _normalise_int(img: np.ndarray, path) -> np.ndarray:
    if img.dtype == np.uint16:
        return img.astype(np.float64) / 65535.0
    if img.dtype == np.uint8:
        return decode(img.astype(np.float64) / 255.0, "sRGB")  # 8-bit files are display-encoded
    if np.issubdtype(img.dtype, np.floating):
        return img.astype(np.float64)
    raise InputError(f"unsupported pixel type {img.dtype}", path=path)


def otsu_threshold(y: np.ndarray, bins: int = 256) -> float:
    """Otsu (1979): the threshold maximising the between-class variance of the histogram."""
    hist, edges = np.histogram(y, bins=bins)
    p = hist / max(hist.sum(), 1)
    centres = 0.5 * (edges[1:] + edges[:-1])
    w0 = np.cumsum(p)
    m0 = np.cumsum(p * centres)
    mt = m0[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (mt * w0 - m0) ** 2 / (w0 * (1 - w0))
    between[~np.isfinite(between)] = -1
    return float(centres[int(np.argmax(between))])


def crop_to_uv(y: np.ndarray, crop: Sequence[int] | None, resolution: tuple[int, int],
               *, path=None, flip_v: bool = False, aspect_tolerance: float = 0.25,
               expected_aspect: float | None = None) -> np.ndarray:
    """Cut the blade's rectangle (x0, y0, x1, y1) out of the photo and resample it to the UV grid.

    The crop's rows run mune → ha (v) unless ``flip_v``; columns machi → tip
    (u). When ``expected_aspect`` (UV width / height in the photo, i.e.
    length over width of the blade's straightened image) is given, a crop
    whose aspect differs by more than ``aspect_tolerance`` (relative) is
    rejected: it is not the blade.
    """
    from scipy.ndimage import zoom

    if crop is not None:
        x0, y0, x1, y1 = (int(c) for c in crop)
        if not (0 <= x0 < x1 <= y.shape[1] and 0 <= y0 < y1 <= y.shape[0]):
            raise InputError(f"crop {crop} is outside the {y.shape[1]}×{y.shape[0]} photo",
                             path=path, field="crop")
        y = y[y0:y1, x0:x1]
    if y.shape[0] >= y.shape[1]:
        raise InputError(f"wrong aspect: the blade region is {y.shape[1]}×{y.shape[0]}, taller than "
                         "wide; the blade must run along the image rows (rotate it or give --crop)",
                         path=path)
    if expected_aspect is not None:
        aspect = y.shape[1] / y.shape[0]
        if abs(aspect / expected_aspect - 1) > aspect_tolerance:
            raise InputError(f"wrong aspect: the blade region is {y.shape[1]}×{y.shape[0]} "
                             f"(aspect {aspect:.2f}), expected about {expected_aspect:.2f} "
                             "(length over width); give --crop", path=path)
    if flip_v:
        y = y[::-1]
    H, W = resolution
    return zoom(y, (H / y.shape[0], W / y.shape[1]), order=1, mode="nearest", grid_mode=True)


def load_region_parameters(path: str | Path, model: str) -> dict[str, float]:
    """Read a region fit JSON (fit stage) and return the model's parameters.

    Accepts a ``jkatana fit`` parameter file (its ``values``: ``chi``/``beta`` and ``mu``),
    ``{"parameters": {name: value | {"value": v}}}`` or a flat ``{name: value}``;
    hiraji needs chi and mu0 (or mu), hamon beta and mu1 (or mu). Read through
    :func:`jkatana.io.jsonfile.read_json`; the values are checked by
    :func:`jkatana.models.bounds.region_params` (scale finite and > 0, width in (0, π/2]).
    """
    from jkatana.io.jsonfile import expect, read_json
    from jkatana.models.bounds import WIDTH_MAX, scale, width

    path = Path(path)
    data = expect(read_json(path, "a region parameter file"), dict, "(top level)", path)
    where = ""
    if "values" in data and "model" in data:  # a `jkatana fit` parameter file
        if data["model"] != model:
            raise InputError(f"is a {data['model']!r} fit; --{model} needs a {model!r} one", path=path,
                             field="model")
        data, where = expect(data["values"], dict, "values", path), "values."
    elif "parameters" in data:
        data, where = expect(data["parameters"], dict, "parameters", path), "parameters."
    flat = {k: (v.get("value") if isinstance(v, dict) else v) for k, v in data.items()}
    keys = ("chi", "mu0") if model == "hiraji" else ("beta", "mu1")
    out = {}
    for k in keys:
        name = k if k in flat or not k.startswith("mu") else "mu"
        if flat.get(name) is None:
            raise InputError(f"missing {model} parameter", path=path, field=where + k)
        v, f = flat[name], where + name
        out[k] = width(v, f, path, hi=WIDTH_MAX) if k.startswith("mu") else scale(v, f, path)
    return out


def map_from_photo(luminance: np.ndarray, *, resolution: tuple[int, int] = (256, 1024),
                   crop=None, dark: float | None = None, bright: float | None = None,
                   hiraji: dict | None = None, hamon: dict | None = None, flip_v: bool = False,
                   expected_aspect: float | None = None, path=None) -> ReflectanceMap:
    """Luminance photo → :class:`ReflectanceMap` (w from thresholds, parameters per region).

    Without thresholds, ``dark``/``bright`` are Otsu's threshold ∓ 0.25 of
    the spread between the two classes' means (a soft transition band).
    """
    y = crop_to_uv(np.asarray(luminance, float), crop, resolution, path=path, flip_v=flip_v,
                   expected_aspect=expected_aspect)
    if dark is None or bright is None:
        # Otsu needs two classes; a photo without contrast has one, and its threshold is an artefact of the
        # histogram's binning (it put every pixel above it: w = 0 everywhere)
        lo_y, hi_y = float(y.min()), float(y.max())
        if not hi_y - lo_y > 1e-6 * max(abs(lo_y), abs(hi_y)):
            raise InputError(f"no contrast: the blade's luminance is {hi_y:.6g} everywhere, so hiraji and hamon "
                             "cannot be told apart; give --dark and --bright", path=path)
        t = otsu_threshold(y)
        lo, hi = y[y <= t].mean() if (y <= t).any() else t, y[y > t].mean() if (y > t).any() else t
        band = 0.25 * (hi - lo)
        dark = t - band if dark is None else dark
        bright = t + band if bright is None else bright
    if not bright > dark:
        raise InputError(f"need bright > dark, got dark={dark:g}, bright={bright:g}", field="thresholds")
    w = np.clip((bright - y) / (bright - dark), 0.0, 1.0)
    p = {**PAPER_PARAMETERS, **(hiraji or {}), **(hamon or {})}
    full = lambda x: np.full(y.shape, x, np.float32)  # noqa: E731
    return ReflectanceMap(w=w, mu0=full(p["mu0"]), chi=full(p["chi"]), mu1=full(p["mu1"]),
                          beta=full(p["beta"]),
                          meta={"source": str(path) if path else "photo", "dark": float(dark),
                                "bright": float(bright)})
