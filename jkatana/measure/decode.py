"""Decode one capture into green photosites and reduce a region of interest.

RAW files go through LibRaw (rawpy; Lukas Riechert's binding of LibRaw,
libraw.org), never through a demosaic: the measurement is taken on the raw
green photosites of the colour filter array — both G sites of a Bayer
pattern (``raw_colors`` indices whose ``color_desc`` letter is ``G``), or
every G site of another CFA. Per photosite:

    x = (DN − black[c]) / (white − black[c])

with the per-channel black level ``black_level_per_channel`` and the white
level read from the file (a dark frame, when given, replaces the black level
photosite by photosite). Photosites at or above the white level are
*saturated*: they are counted, excluded from the mean and reported
(``n_saturated``), never averaged in silently. The measurement is the mean of
x over the ROI, divided by the exposure time (and times the manifest's
gain), and its standard error s/√n with s the sample standard deviation.
That standard error measures the pixel-to-pixel scatter inside the ROI
(sensor noise, and on a real blade its texture); it does not include
systematic errors (shutter accuracy, angle setting, stray light), which the
fit can model (tilt, floor) or which must be added by the user.

Linear 16-bit TIFF and OpenEXR captures are accepted too (see
:mod:`jkatana.measure.manifest` for their black/white levels).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from jkatana.errors import InputError

TIFF_SUFFIXES = (".tif", ".tiff")
EXR_SUFFIXES = (".exr",)


@dataclasses.dataclass
class Frame:
    """Photosites of one capture, undecoded (values are converted only inside ROIs).

    ``dn``: the raw values (H×W, integer or float, as stored); ``colors``: the
    CFA colour index per photosite (H×W) or None when every photosite is
    green (TIFF/EXR); ``green_colors``: which colour indices are green;
    ``black``: black level per colour index (or a 1-vector); ``white``: white
    level (``inf`` when the format has none); ``shutter_s``: exposure time
    stored in the file (0 if unknown).
    """

    dn: np.ndarray
    colors: np.ndarray | None
    green_colors: tuple[int, ...]
    black: np.ndarray
    white: float
    shutter_s: float = 0.0
    kind: str = "raw"
    origin: tuple[int, int] = (0, 0)
    full_shape: tuple[int, int] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """The whole frame's (H, W), even when only a window of it was kept."""
        return self.full_shape or self.dn.shape

    def crop(self, y0: int, y1: int, x0: int, x1: int):
        """``(dn float64, green mask, black per photosite)`` of a window (frame coordinates)."""
        oy, ox = self.origin
        h, w = self.dn.shape
        if not (oy <= y0 and ox <= x0 and y1 - oy <= h and x1 - ox <= w):
            raise ValueError(f"window {y0}:{y1}, {x0}:{x1} was not decoded (kept {oy}:{oy + h}, {ox}:{ox + w})")
        sl = np.s_[y0 - oy:y1 - oy, x0 - ox:x1 - ox]
        dn = self.dn[sl].astype(np.float64)
        if self.colors is None:
            return dn, np.ones(dn.shape, bool), np.full(dn.shape, float(self.black[0]))
        c = self.colors[sl]
        return dn, np.isin(c, self.green_colors), self.black[c]


def _window(shape, window):
    """Clip a ``(y0, y1, x0, x1)`` window to ``shape``; None → the whole frame."""
    H, W = shape
    if window is None:
        return 0, H, 0, W
    y0, y1, x0, x1 = window
    return max(0, y0), min(H, y1), max(0, x0), min(W, x1)


def _read_raw(path: Path, window=None) -> Frame:
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            image = raw.raw_image_visible
            if image is None or image.ndim != 2:
                raise InputError("not a colour-filter-array RAW (no single-plane raw image); "
                                 "convert it to a linear TIFF", path=path)
            desc = raw.color_desc.decode("ascii", "replace")
            green_idx = tuple(i for i, ch in enumerate(desc) if ch == "G")
            if not green_idx:
                raise InputError(f"the colour filter array has no green photosites ({desc})", path=path)
            # raw_image_visible views LibRaw's buffer, valid only while the file is open:
            # copy the window that will be used, not the whole 10-Mpixel frame
            y0, y1, x0, x1 = _window(image.shape, window)
            frame = Frame(dn=np.array(image[y0:y1, x0:x1]),
                          colors=np.array(raw.raw_colors_visible[y0:y1, x0:x1], np.uint8),
                          green_colors=green_idx, black=np.asarray(raw.black_level_per_channel, np.float64),
                          white=float(raw.white_level), origin=(y0, x0), full_shape=tuple(image.shape))
            shutter = float(raw.other.shutter_speed) if hasattr(raw, "other") else 0.0
    except rawpy.LibRawError as err:
        detail = err.args[0].decode("utf-8", "replace") if err.args and isinstance(err.args[0], bytes) else str(err)
        hint = " — truncated or damaged file?" if isinstance(err, (rawpy.LibRawIOError, rawpy.LibRawDataError)) else ""
        raise InputError(f"cannot decode RAW with LibRaw ({type(err).__name__}: {detail}){hint}", path=path) from None
    frame.shutter_s = shutter if math.isfinite(shutter) and shutter > 0 else 0.0
    return frame


def _read_tiff(path: Path, black: float | None, white: float | None) -> Frame:
    import tifffile

    try:
        image = tifffile.imread(str(path))
    except Exception as err:  # noqa: BLE001  (tifffile raises several kinds for bad files)
        raise InputError(f"cannot read TIFF ({type(err).__name__}: {err})", path=path) from None
    if image.dtype != np.uint16:
        raise InputError(f"expects a linear 16-bit TIFF, got dtype {image.dtype}", path=path)
    if image.ndim == 3 and image.shape[-1] in (3, 4):
        image = image[..., 1]
    elif image.ndim != 2:
        raise InputError(f"expects one channel or RGB(A), got shape {image.shape}", path=path)
    b = 0.0 if black is None else float(black)
    return Frame(dn=image, colors=None, green_colors=(), black=np.array([b]),
                 white=65535.0 if white is None else float(white), kind="tiff")


def _read_exr(path: Path, black: float | None, white: float | None) -> Frame:
    from jkatana.io.exr import read_exr

    channels, _ = read_exr(path)
    for name in ("G", "Y"):
        if name in channels:
            plane = channels[name]
            break
    else:
        if len(channels) != 1:
            raise InputError(f"no 'G' or 'Y' channel among {sorted(channels)}", path=path)
        plane = next(iter(channels.values()))
    b = 0.0 if black is None else float(black)
    return Frame(dn=np.asarray(plane), colors=None, green_colors=(), black=np.array([b]),
                 white=math.inf if white is None else float(white), kind="exr")


def read_frame(path: str | Path, *, black_level: float | None = None,
               white_level: float | None = None, window=None) -> Frame:
    """Decode ``path`` by extension (module docstring). Raises :class:`InputError` naming the file.

    ``window = (y0, y1, x0, x1)`` keeps only that part of a RAW frame in memory
    (the union of the ROIs); :meth:`Frame.shape` is still the whole frame's.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path=path)
    suffix = path.suffix.lower()
    if suffix in TIFF_SUFFIXES:
        frame = _read_tiff(path, black_level, white_level)
    elif suffix in EXR_SUFFIXES:
        frame = _read_exr(path, black_level, white_level)
    else:
        frame = _read_raw(path, window)
    return _checked(frame, path)


def _checked(frame: Frame, path: Path) -> Frame:
    """Refuse levels that make x = (DN − black)/(white − black) meaningless: the white level must lie
    above every black level, and both must be finite (white may be ``inf`` for EXR: no saturation)."""
    black = np.asarray(frame.black, np.float64)
    if not np.all(np.isfinite(black)) or math.isnan(frame.white):
        raise InputError(f"black level {black.tolist()} / white level {frame.white} not finite", path=path)
    if not frame.white > float(black.max()):
        raise InputError(f"white level {frame.white:g} is not above the black level {float(black.max()):g}: "
                         "the file's levels are inconsistent (or the manifest's black_level/white_level)",
                         path=path)
    return frame


@dataclasses.dataclass(frozen=True)
class RoiStats:
    """Mean of the normalised green photosites over the ROI(s), before /exposure."""

    mean: float
    stderr: float
    n_pixels: int
    n_saturated: int


def roi_stats(frame: Frame, rois, *, dark: Frame | None = None) -> RoiStats:
    """Reduce the green photosites inside ``rois`` (``[(x, y, w, h), ...]``) of ``frame``.

    Raises :class:`InputError` (without a location: the caller adds the
    manifest row and field ``roi``) when a rectangle leaves the frame or fewer
    than two usable photosites remain (e.g. all saturated).
    """
    H, W = frame.shape
    for x, y, w, h in rois:
        if x + w > W or y + h > H:
            raise InputError(f"rectangle x={x} y={y} w={w} h={h} leaves the {W}×{H} frame")
    # convert only the bounding box of the ROIs (a 10-Mpixel frame stays uint16 elsewhere)
    y0, y1 = min(r[1] for r in rois), max(r[1] + r[3] for r in rois)
    x0, x1 = min(r[0] for r in rois), max(r[0] + r[2] for r in rois)
    values, green, black_px = frame.crop(y0, y1, x0, x1)
    mask = np.zeros(values.shape, bool)
    for x, y, w, h in rois:  # union: overlapping rectangles count each photosite once
        mask[y - y0:y - y0 + h, x - x0:x - x0 + w] = True
    mask &= green
    dn = values[mask]
    black_all = black_px[mask]
    if dark is not None:
        black = dark.crop(y0, y1, x0, x1)[0][mask]
    else:
        black = black_all
    saturated = dn >= frame.white
    n_sat = int(saturated.sum())
    keep = ~saturated
    n = int(keep.sum())
    scale = frame.white - black_all[keep] if math.isfinite(frame.white) else 1.0
    x = (dn[keep] - black[keep]) / scale
    if n < 2:
        what = (f"all {n_sat} green photosites in the ROI are saturated" if n_sat and n == 0
                else f"the ROI holds {n} usable green photosite(s) ({n_sat} saturated); need at least 2")
        raise InputError(what)
    if not np.all(np.isfinite(x)):
        raise InputError(f"{int(np.count_nonzero(~np.isfinite(x)))} photosite(s) in the ROI are not finite "
                         "(NaN or inf)")
    mean = float(x.mean())
    stderr = float(x.std(ddof=1) / math.sqrt(n))
    return RoiStats(mean=mean, stderr=stderr, n_pixels=n, n_saturated=n_sat)


__all__ = ["Frame", "RoiStats", "read_frame", "roi_stats"]
