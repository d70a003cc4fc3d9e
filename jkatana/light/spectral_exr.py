"""Spectral OpenEXR in the layout of Fichet, Pacanowski & Wilkie (2021).

Fichet A., Pacanowski R., Wilkie A. (2021), "An OpenEXR Layout for Spectral
Images", JCGT 10(3). Emissive images store one channel per wavelength named
``S0.<λ>nm`` with a comma as decimal separator (``S0.550,000000nm``), plus
``spectralLayoutVersion`` / ``emissiveUnits`` attributes. Reading and writing
go through colour-science's implementation
(``colour.io.read_spectral_image_Fichet2021``, colour-science 0.4.7, which
uses OpenImageIO); writing uses colour-science's channel names, sRGB preview
(``components_to_sRGB_Fichet2021``) and attributes, but hands OpenImageIO all
channels in one buffer: colour-science's writer appends them one at a time
(``ImageBufAlgo.channel_append``), copying the image once per channel, so its
time grows with pixels × bands² (one buffer: pixels × bands). Files interoperate
with colour-science by construction; the tests check it both ways.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from jkatana.errors import InputError
from jkatana.io.atomic import atomic_path
from jkatana.spectral.grid import WavelengthGrid, resample

_CHANNEL = re.compile(r"^S0\.(\d+(?:,\d+)?)(nm|um|pm|Hz)?$")
_T_CHANNEL = re.compile(r"^T\.(\d+(?:,\d+)?)(nm|um|pm|Hz)?$")


def _channel_names(path: Path) -> list[str]:
    import OpenEXR

    from jkatana.io.exr import os_path

    try:
        with OpenEXR.File(os_path(path), header_only=True) as f:
            return list(f.header()["channels"].keys()) if "channels" in f.header() else list(f.channels().keys())
    except Exception:
        try:
            with OpenEXR.File(os_path(path)) as f:
                return list(f.channels().keys())
        except Exception as err:
            raise InputError(f"not a readable OpenEXR file ({err})", path=path) from None


def is_spectral_exr(path: str | Path) -> bool:
    """True when the EXR has emissive (``S0.*``) or reflective (``T.*``) spectral channels."""
    names = _channel_names(Path(path))
    return any(_CHANNEL.match(n) or _T_CHANNEL.match(n) for n in names)


def read_spectral_exr_raw(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Wavelengths (nm) and values ``(H, W, n)`` of the ``S0`` (else ``T``) component, through colour-science."""
    from colour.io import read_spectral_image_Fichet2021

    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path=path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            components = read_spectral_image_Fichet2021(str(path))
    except Exception as err:
        raise InputError(f"not a readable spectral EXR ({err})", path=path) from None
    key = "S0" if "S0" in components else ("T" if "T" in components else None)
    if key is None:
        raise InputError(f"no S0 (emissive) or T (reflective) spectral component; found {sorted(components)}",
                         path=path)
    wl, values = components[key]
    wl = np.asarray(wl, np.float64)
    values = np.asarray(values, np.float32)
    order = np.argsort(wl)
    return wl[order], values[..., order]


def read_spectral_exr(path: str | Path, grid: WavelengthGrid) -> np.ndarray:
    """Spectral radiance ``(H, W, len(grid))`` resampled (linearly) onto ``grid``.

    Raises :class:`InputError` when the file's wavelengths do not cover the grid.
    """
    wl, values = read_spectral_exr_raw(path)
    if wl.size == grid.size and np.allclose(wl, grid.wavelengths, atol=1e-6):
        return values
    return resample(wl, values, grid, name=str(path)).astype(np.float32)


def _write_fichet(path: str, component: str, wl: np.ndarray, values: np.ndarray, bit_depth: str, spec) -> bool:
    """colour-science's ``write_spectral_image_Fichet2021`` for one component, with every channel in one buffer.

    Same channels in the same order (``R``, ``G``, ``B`` preview, then ``<component>.<λ>nm``), same names
    and attributes; linear in the number of channels instead of quadratic (module docstring).
    """
    from colour.io.fichet2021 import components_to_sRGB_Fichet2021
    from colour.io.image import MAPPING_BIT_DEPTH, add_attributes_to_image_specification_OpenImageIO
    from OpenImageIO import ImageBuf

    dtype = MAPPING_BIT_DEPTH[bit_depth].numpy
    components = {component: (wl, values)}
    rgb, attributes = components_to_sRGB_Fichet2021(components, spec)
    names = [f"{component}.{str(w).replace('.', ',')}nm" for w in wl]
    planes = [values.astype(dtype)]
    if rgb is not None:
        names = ["R", "G", "B"] + names
        planes.insert(0, np.asarray(rgb).astype(dtype))
    buf = ImageBuf(np.ascontiguousarray(np.concatenate(planes, axis=-1)))
    buf.specmod().channelnames = names
    add_attributes_to_image_specification_OpenImageIO(buf.specmod(), [*spec.attributes, *attributes])
    return bool(buf.write(path))


def write_spectral_exr(path: str | Path, radiance, grid: WavelengthGrid | np.ndarray, *,
                       bit_depth: str = "float32", emissive: bool = True,
                       header: dict[str, str | int | float] | None = None) -> Path:
    """Write ``radiance (H, W, wl)`` as a Fichet 2021 spectral EXR (through colour-science), atomically.

    colour-science also writes an sRGB preview (``R``, ``G``, ``B``) that any
    EXR viewer shows. ``emissive`` writes ``S0`` channels with
    ``emissiveUnits = W.m^-2.sr^-1`` (per nm); otherwise ``T`` (reflectance).
    The layout's ``spectralLayoutVersion`` attribute is always written;
    ``header`` adds further attributes (strings or numbers).
    """
    from colour.io import Image_Specification_Attribute, Specification_Fichet2021

    wl = grid.wavelengths if isinstance(grid, WavelengthGrid) else np.asarray(grid, np.float64)
    values = np.asarray(radiance, np.float32)
    if values.ndim != 3 or values.shape[-1] != wl.size:
        raise InputError(f"radiance must be (H, W, {wl.size}), got {values.shape}", path=path)
    path = Path(path)
    # colour-science adds the layout's own attributes only when given none: list them with the caller's
    attrs = {"spectralLayoutVersion": "1.0", **({"emissiveUnits": "W.m^-2.sr^-1"} if emissive else {}),
             **(header or {})}
    spec = Specification_Fichet2021(is_emissive=emissive, attributes=tuple(
        Image_Specification_Attribute(k, v) for k, v in attrs.items()))
    with atomic_path(path) as tmp:
        tmp_exr = Path(str(tmp) + ".exr") if Path(tmp).suffix.lower() != ".exr" else Path(tmp)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ok = _write_fichet(str(tmp_exr), "S0" if emissive else "T", wl, values, bit_depth, spec)
        if not ok:
            raise InputError("colour-science failed to write the spectral EXR", path=path)
        if tmp_exr != Path(tmp):
            tmp_exr.replace(tmp)
    return path


_UNIT_NM = {"nm": 1.0, None: 1.0, "um": 1000.0, "pm": 1e-3}


class SpectralRows:
    """A Fichet 2021 spectral EXR read in row blocks through OpenImageIO's ``read_scanlines``, so that a map
    larger than memory as float64 (61 bands × 6000 × 3000 is 4.4 GB as float32) is never held whole.

    The ``S0`` (else ``T``) channels are found from the header's channel names (the layout's
    ``<component>.<λ><unit>`` with a decimal comma), sorted by wavelength, and each block is resampled
    linearly onto ``grid`` as :func:`read_spectral_exr` resamples the whole image (the same
    :func:`jkatana.spectral.grid.resample`), so the blocks stacked equal the whole read.
    """

    def __init__(self, path: str | Path, grid: WavelengthGrid):
        import OpenImageIO as oiio

        self.path, self.grid = Path(path), grid
        inp = oiio.ImageInput.open(str(self.path))
        if inp is None:
            raise InputError(f"not a readable OpenEXR file ({oiio.geterror()})", path=path)
        spec = inp.spec()
        inp.close()
        self.height, self.width = int(spec.height), int(spec.width)
        names = list(spec.channelnames)
        found = {}
        for pattern in (_CHANNEL, _T_CHANNEL):
            found = {i: m for i, n in enumerate(names) if (m := pattern.match(n))}
            if found:
                break
        if not found:
            raise InputError(f"no S0 (emissive) or T (reflective) spectral channels; found {names[:8]}", path=path)
        wl = {i: float(m.group(1).replace(",", ".")) * _UNIT_NM.get(m.group(2), float("nan"))
              for i, m in found.items()}
        order = sorted(wl, key=wl.get)
        self.channels = np.asarray(order)
        self.wavelengths = np.asarray([wl[i] for i in order], np.float64)
        self.nchannels = len(names)
        self._identity = self.wavelengths.size == grid.size and np.allclose(self.wavelengths, grid.wavelengths,
                                                                              atol=1e-6)

    def rows(self, r0: int, r1: int) -> np.ndarray:
        """Radiance of rows ``[r0, r1)`` on the grid, ``(r1 − r0, W, len(grid))`` float32."""
        import OpenImageIO as oiio

        inp = oiio.ImageInput.open(str(self.path))
        if inp is None:
            raise InputError(f"not a readable OpenEXR file ({oiio.geterror()})", path=self.path)
        try:
            px = inp.read_scanlines(0, 0, int(r0), int(r1), 0, 0, self.nchannels, oiio.FLOAT)
        finally:
            inp.close()
        if px is None:
            raise InputError(f"rows {r0}–{r1} unreadable ({oiio.geterror()})", path=self.path)
        values = np.asarray(px, np.float32).reshape(r1 - r0, self.width, self.nchannels)[..., self.channels]
        if self._identity:
            return values
        return resample(self.wavelengths, values, self.grid, name=str(self.path)).astype(np.float32)


def write_spectral_exr_rows(path: str | Path, height: int, width: int, grid: WavelengthGrid, rows, *,
                            block: int = 64) -> Path:
    """Write a Fichet 2021 emissive spectral EXR (``S0.<λ>nm`` channels, no sRGB preview) of ``height × width``
    texels from ``rows(r0, r1) → (r1 − r0, width, len(grid))`` float32, ``block`` rows at a time through
    OpenImageIO's ``write_scanlines``: a map larger than memory is never held whole (:class:`SpectralRows`
    reads it back the same way)."""
    import OpenImageIO as oiio

    path = Path(path)
    spec = oiio.ImageSpec(int(width), int(height), grid.size, oiio.FLOAT)
    spec.channelnames = tuple(f"S0.{str(float(w)).replace('.', ',')}nm" for w in grid.wavelengths)
    spec.attribute("compression", "zip")
    spec.attribute("spectralLayoutVersion", "1.0")
    spec.attribute("emissiveUnits", "W.m^-2.sr^-1")
    with atomic_path(path) as tmp:
        tmp_exr = Path(str(tmp) + ".exr")
        out = oiio.ImageOutput.create(str(tmp_exr))
        if out is None or not out.open(str(tmp_exr), spec):
            raise InputError(f"cannot write the spectral EXR ({oiio.geterror()})", path=path)
        for r0 in range(0, int(height), block):
            r1 = min(int(height), r0 + block)
            if not out.write_scanlines(r0, r1, 0, np.ascontiguousarray(rows(r0, r1), np.float32)):
                raise InputError(f"cannot write rows {r0}–{r1} ({out.geterror()})", path=path)
        out.close()
        tmp_exr.replace(tmp)
    return path
