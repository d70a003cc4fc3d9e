"""OpenEXR images through the OpenEXR Python bindings (Academy Software Foundation).

Generic multi-channel read/write used by every stage (environment maps,
reflectance maps, rendered frames). The spectral layout of Fichet,
Pacanowski & Wilkie (2021), "An OpenEXR layout for spectral images", JCGT
10(3), lives in :mod:`jkatana.light.spectral_exr` on top of this module.

Channels are ``dict[str, ndarray (H, W)]``; RGB(A) files that the bindings
group into one ``"RGB"``/``"RGBA"`` array are split into ``R``, ``G``, ``B``
(``A``). Writes are atomic (temporary file + rename).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR

from jkatana.errors import InputError
from jkatana.io.atomic import atomic_path

_COMPRESSION = {
    "none": OpenEXR.NO_COMPRESSION,
    "zip": OpenEXR.ZIP_COMPRESSION,
    "piz": OpenEXR.PIZ_COMPRESSION,
    "dwab": OpenEXR.DWAB_COMPRESSION,
    "zips": OpenEXR.ZIPS_COMPRESSION,
}


def os_path(path: str | Path) -> str | bytes:
    """The name to hand the bindings: text, or the raw bytes of a name that is not valid UTF-8
    (Python keeps such bytes as surrogates, which the bindings cannot encode)."""
    text = os.fspath(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return os.fsencode(text)
    return text


def read_exr(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read every channel of a scanline/tiled EXR as ``(channels, header)``.

    Grouped channels (``"RGB"``, ``"RGBA"``, ``"XYZ"``) are split into single
    ones. Raises :class:`InputError` naming the file when it is missing or not
    a readable EXR.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    try:
        with OpenEXR.File(os_path(path), separate_channels=False) as f:
            header = dict(f.header())
            raw = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    except Exception as err:  # the bindings raise a bare Exception/RuntimeError
        raise InputError(f"not a readable OpenEXR file ({err})", path=path) from None
    channels: dict[str, np.ndarray] = {}
    for name, pixels in raw.items():
        if pixels.ndim == 3:
            if name in ("RGB", "RGBA", "XYZ", "XYZA") and pixels.shape[2] == len(name):
                for i, letter in enumerate(name):
                    channels[letter] = pixels[:, :, i]
            else:
                for i in range(pixels.shape[2]):
                    channels[f"{name}.{i}"] = pixels[:, :, i]
        else:
            channels[name] = pixels
    return channels, header


def write_exr(path: str | Path, channels: dict[str, np.ndarray], *,
              header: dict[str, Any] | None = None, compression: str = "zip",
              half: bool = False) -> Path:
    """Write single channels ``{name: (H, W) array}`` to an EXR, atomically.

    ``header`` entries become EXR attributes (str, int, float, or tuples
    thereof; other values are stored as their ``str``). ``half`` stores
    float16 (as renderers do for display-bound images); default float32.
    """
    if not channels:
        raise InputError("no channels to write", path=path)
    shapes = {np.shape(v) for v in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise InputError(f"channels must share one (H, W) shape, got {sorted(shapes)}", path=path)
    dtype = np.float16 if half else np.float32
    data = {name: np.ascontiguousarray(np.asarray(v), dtype=dtype) for name, v in channels.items()}
    hdr: dict[str, Any] = {"compression": _COMPRESSION[compression], "type": OpenEXR.scanlineimage}
    for key, value in (header or {}).items():
        if isinstance(value, (str, int, float)) and not isinstance(value, bool):
            hdr[key] = value
        else:
            hdr[key] = str(value)
    with atomic_path(path) as tmp:
        with OpenEXR.File(hdr, data) as f:
            f.write(os_path(tmp))
    return Path(path)


def read_rgb(path: str | Path) -> np.ndarray:
    """An RGB EXR as ``(H, W, 3)`` float32 (A dropped)."""
    channels, _ = read_exr(path)
    try:
        return np.stack([channels["R"], channels["G"], channels["B"]], axis=-1).astype(np.float32)
    except KeyError:
        raise InputError(f"no R, G, B channels (has {sorted(channels)[:8]})", path=path) from None
