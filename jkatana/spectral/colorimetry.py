"""Colorimetry: CMFs, illuminants, spectrum → XYZ → display RGB → transfer.

All tables come from colour-science (Mansencal et al., colour-science.org),
not typed in here:

- CIE 1931 2° standard observer colour-matching functions (CIE 015:2018);
- CIE illuminants D65 and A, and the CIE daylight series by correlated colour
  temperature (CIE 015:2018, §4.1);
- RGB colourspaces (sRGB / IEC 61966-2-1:1999, Display P3, Adobe RGB (1998),
  ITU-R BT.2020) and their XYZ→RGB matrices.

Paper equations (Mochizuki et al., §5):

- eq. (6): X = k Σλ S(λ) x̄(λ) Δλ (likewise Y, Z) — a Riemann sum on the
  grid, identical to colour-science's ``"Integration"`` method;
- eq. (7): [R G B]ᵀ = M [X Y Z]ᵀ with M the colourspace's XYZ→RGB matrix;
- eq. (8): display value = clip(RGB)^(1/γ) per channel (plain gamma), or the
  colourspace's own transfer function (e.g. the sRGB piecewise curve).

The matrices are plain arrays, so the JAX renderer can apply them inside a
jitted function; the transfer is applied once per frame on the host.
"""

from __future__ import annotations

import functools
import sys
import types

import numpy as np

from jkatana.errors import InputError
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid


class _DeferredModule(types.ModuleType):
    """A placeholder in ``sys.modules`` for a subpackage that imports its real self on first attribute use."""

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        import importlib

        if sys.modules.get(self.__name__) is self:
            del sys.modules[self.__name__]
        return getattr(importlib.import_module(self.__name__), name)


def _import_colour():
    """``import colour``, with ``colour.plotting`` imported on its first use rather than with the package.

    colour-science 0.4.7's ``colour/__init__.py`` imports ``colour.plotting``, and with it Matplotlib's pyplot,
    whenever Matplotlib is installed (upstream colour-science/colour#1416): about 0.4 s of the start of every
    command that reads a colour table, for a subpackage jkatana never calls. While colour imports, a placeholder
    (:class:`_DeferredModule`) stands for it in ``sys.modules``; reading an attribute of ``colour.plotting``
    imports the real subpackage, which then replaces it there and on ``colour``."""
    if "colour" not in sys.modules and "colour.plotting" not in sys.modules:
        sys.modules["colour.plotting"] = _DeferredModule("colour.plotting")
    import colour

    return colour


colour = _import_colour()

CMFS_NAME = "CIE 1931 2 Degree Standard Observer"

#: Colourspaces accepted by name (case-insensitive); values are colour-science names.
COLOURSPACES = {
    "srgb": "sRGB",
    "display p3": "Display P3",
    "p3": "Display P3",
    "adobe rgb": "Adobe RGB (1998)",
    "adobe rgb (1998)": "Adobe RGB (1998)",
    "rec.2020": "ITU-R BT.2020",
    "rec2020": "ITU-R BT.2020",
    "itu-r bt.2020": "ITU-R BT.2020",
    "rec.709": "ITU-R BT.709",
}


def _shape(grid: WavelengthGrid) -> colour.SpectralShape:
    return colour.SpectralShape(grid.start, grid.stop, grid.step)


@functools.lru_cache(maxsize=32)
def cmfs(grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """CIE 1931 2° colour-matching functions on ``grid``, shape ``(len(grid), 3)``.

    Interpolated by colour-science from the 1 nm (360–830 nm) CIE table; a
    grid outside 360–830 nm is refused.
    """
    if grid.start < 360 or grid.stop > 830:
        raise InputError(f"grid {grid.start}–{grid.stop} nm lies outside the CMFs' 360–830 nm",
                         field="grid")
    table = colour.MSDS_CMFS[CMFS_NAME].copy()
    values = table.copy().align(_shape(grid)).values
    # align() interpolates at grid points; when step is not a divisor of 1 nm use explicit interp
    if values.shape[0] != grid.size:
        values = np.stack([np.interp(grid.wavelengths, table.wavelengths, table.values[:, i])
                           for i in range(3)], axis=-1)
    out = np.asarray(values, dtype=np.float64)
    out.setflags(write=False)
    return out


def illuminant(name: str | float = "D65", grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """Relative spectral power of a CIE illuminant on ``grid`` (normalised to 100 at 560 nm).

    ``name`` is ``"D65"``, ``"A"`` (or another key of colour-science's
    ``SDS_ILLUMINANTS``), or a correlated colour temperature in kelvin
    (``6500`` or ``"5000K"``) for the CIE daylight series (4000–25000 K).
    """
    if isinstance(name, str) and name.upper().endswith("K") and name[:-1].replace(".", "").isdigit():
        name = float(name[:-1])
    if isinstance(name, (int, float)):
        cct = float(name)
        if not 4000 <= cct <= 25000:
            raise InputError(f"CIE daylight is defined for 4000–25000 K, got {cct:g} K", field="illuminant")
        xy = colour.temperature.CCT_to_xy_CIE_D(cct * 1.4388 / 1.4380)
        sd = colour.sd_CIE_illuminant_D_series(xy)
    else:
        try:
            sd = colour.SDS_ILLUMINANTS[name].copy()
        except KeyError:
            raise InputError(f"unknown illuminant {name!r}", field="illuminant") from None
    wl = grid.wavelengths
    values = sd.copy().align(_shape(grid)).values if grid.step >= 1 else sd[wl]
    values = np.asarray(values, dtype=np.float64)
    if values.shape[0] != wl.shape[0]:
        values = np.interp(wl, sd.wavelengths, sd.values)
    return values / np.interp(560.0, wl, values) * 100.0 if wl[0] <= 560 <= wl[-1] else values


def xyz_weights(grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """Eq. (6) as a matrix: ``XYZ = S @ W`` with ``W = x̄ȳz̄(λ) Δλ``, shape ``(len(grid), 3)``.

    With this weighting, XYZ is in the spectrum's own units times nm (no
    normalisation constant k). See :func:`spectrum_to_xyz` for normalised forms.
    """
    return cmfs(grid) * grid.step


def equal_energy_xyz_weights(grid: WavelengthGrid = DEFAULT_GRID) -> np.ndarray:
    """Eq. (6) normalised to the equal-energy white: ``XYZ = S @ W`` with ``W = x̄ȳz̄ Δλ / Σ ȳ Δλ``,
    so that a flat spectrum of 1 has Y = 1 (k = 1/∫ȳ dλ; Mitsuba 3's film uses the same constant).
    The renderer's film and the RGB ↔ spectrum conversions of environment maps share it."""
    w = xyz_weights(grid)
    return w / w[:, 1].sum()


def spectrum_to_xyz(spectrum, grid: WavelengthGrid = DEFAULT_GRID, *, normalise_to=None):
    """Eq. (6): spectra (last axis = wavelength) → CIE XYZ (last axis = 3).

    **Arguments:**

    - `spectrum`: array ``(..., len(grid))``; NumPy or JAX.
    - `normalise_to`: ``None`` for k = 1 (absolute, in the spectrum's units ×
      nm); or a white spectrum ``(len(grid),)``: k = 1 / Σ ȳ·white Δλ, so that
      the white has Y = 1 (colour-science's convention times 1/100). For a
      reflectance R under illuminant I, pass ``spectrum = R * I`` and
      ``normalise_to = I``.
    """
    w = xyz_weights(grid)
    xyz = spectrum @ w.astype(getattr(spectrum, "dtype", np.float64))
    if normalise_to is not None:
        xyz = xyz / float(np.asarray(normalise_to) @ w[:, 1])
    return xyz


def colourspace(name: str) -> colour.RGB_Colourspace:
    """A colour-science RGB colourspace by jkatana name (see :data:`COLOURSPACES`)."""
    key = COLOURSPACES.get(name.lower().strip(), name)
    if key not in colour.RGB_COLOURSPACES:
        raise InputError(f"unknown colourspace {name!r}; known: {sorted(set(COLOURSPACES.values()))}",
                         field="colourspace")
    return colour.RGB_COLOURSPACES[key]


def xyz_to_rgb_matrix(name: str = "sRGB") -> np.ndarray:
    """Eq. (7): the 3×3 matrix M with RGB = M · XYZ (linear, the colourspace's own white).

    No chromatic adaptation: all supported display spaces have a D65 white,
    and a scene lit by another illuminant is meant to look the colour it is.
    """
    return np.asarray(colourspace(name).matrix_XYZ_to_RGB, dtype=np.float64)


def xyz_to_linear_rgb(xyz, name: str = "sRGB"):
    """Eq. (7) applied to ``(..., 3)`` XYZ arrays (NumPy or JAX)."""
    m = xyz_to_rgb_matrix(name)
    return xyz @ m.T.astype(getattr(xyz, "dtype", np.float64))


def encode(rgb, transfer: str | float = "sRGB", *, clip: bool = True) -> np.ndarray:
    """Eq. (8): linear RGB → display values in [0, 1].

    ``transfer`` is a number γ (plain power law ``v^(1/γ)``, the paper's eq. 8),
    ``"linear"``, or a colourspace name whose encoding CCTF colour-science
    provides (``"sRGB"``: the IEC 61966-2-1 piecewise curve; ``"Display P3"``
    uses the same; ``"Adobe RGB"`` γ = 563/256; ``"Rec.2020"`` the BT.2020 OETF).
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if clip:
        rgb = np.clip(rgb, 0.0, 1.0)
    if isinstance(transfer, (int, float)):
        if transfer <= 0:
            raise InputError(f"gamma must be > 0, got {transfer}", field="transfer")
        return np.power(np.maximum(rgb, 0.0), 1.0 / float(transfer))
    if str(transfer).lower() == "linear":
        return rgb
    return np.asarray(colourspace(str(transfer)).cctf_encoding(rgb), dtype=np.float64)


def decode(values, transfer: str | float = "sRGB") -> np.ndarray:
    """Inverse of :func:`encode`: display values → linear RGB (what was clipped stays clipped).

    ``transfer`` as in :func:`encode`: a number γ (``v^γ``), ``"linear"``, or a colourspace name whose
    decoding CCTF colour-science provides (``"sRGB"``: the IEC 61966-2-1 piecewise curve).
    """
    v = np.asarray(values, dtype=np.float64)
    if isinstance(transfer, (int, float)):
        if transfer <= 0:
            raise InputError(f"gamma must be > 0, got {transfer}", field="transfer")
        return np.power(v, float(transfer))
    if str(transfer).lower() == "linear":
        return v
    return np.asarray(colourspace(str(transfer)).cctf_decoding(v), dtype=np.float64)


def reinhard(xyz) -> np.ndarray:
    """Reinhard, Stark, Shirley & Ferwerda (2002), "Photographic tone reproduction for digital images",
    SIGGRAPH, eq. 3 on luminance: ``XYZ / (1 + Y)``. Chromaticity is kept and highlights are compressed
    instead of clipped, so a preview of an HDR map keeps the sun's surroundings readable."""
    x = np.asarray(xyz, np.float64)
    return x / (1.0 + x[..., 1:2])


def luminance_weights(name: str = "sRGB") -> np.ndarray:
    """``(3,)`` weights with Y = w · RGB for linear RGB of colourspace ``name``: the Y row of its RGB→XYZ
    matrix (for sRGB / Rec. 709 primaries 0.2126, 0.7152, 0.0722, ITU-R BT.709-6 item 3.2)."""
    return np.asarray(colourspace(name).matrix_RGB_to_XYZ, dtype=np.float64)[1]


def to_display(xyz, colourspace_name: str = "sRGB", transfer: str | float | None = None,
               *, exposure: float = 1.0) -> np.ndarray:
    """XYZ → display-encoded RGB in [0, 1] (eqs. 7–8); ``transfer`` defaults to the space's own."""
    rgb = xyz_to_linear_rgb(np.asarray(xyz, np.float64) * exposure, colourspace_name)
    return encode(rgb, colourspace_name if transfer is None else transfer)


def to_png8(display_rgb) -> np.ndarray:
    """Display values in [0, 1] → uint8, rounded."""
    return np.clip(np.round(np.asarray(display_rgb) * 255.0), 0, 255).astype(np.uint8)


def display8(xyz, colourspace_name: str = "sRGB", transfer: str | float | None = None,
             *, exposure: float = 1.0) -> np.ndarray:
    """XYZ → 8-bit display RGB as a PNG stores it: :func:`to_display` then :func:`to_png8`."""
    return to_png8(to_display(xyz, colourspace_name, transfer, exposure=exposure))


def delta_e_2000_display(display_a, display_b, colourspace_name: str = "sRGB") -> np.ndarray:
    """CIEDE2000 between colours as a display shows them: ``(..., 3)`` values in [0, 1] encoded with
    the colourspace's own transfer function.

    Each side is decoded to linear RGB, taken to XYZ and to CIE L*a*b* with the
    colourspace's white (D65 for every space of :data:`COLOURSPACES`) and compared
    with CIEDE2000 (Sharma, Wu & Dalal 2005, *Color Res. Appl.* 30(1); colour-science's
    ``delta_E(..., method="CIE 2000")``). Comparing display values rather than scene
    XYZ is what makes the number a visible difference: clipping and the transfer
    curve apply to both sides as on screen.
    """
    cs = colourspace(colourspace_name)

    def lab(d):
        xyz = colour.RGB_to_XYZ(cs.cctf_decoding(np.asarray(d, np.float64)), cs, apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz, cs.whitepoint)

    return np.asarray(colour.delta_E(lab(display_a), lab(display_b), method="CIE 2000"), np.float64)


def delta_e_2000_8bit(a8, b8, colourspace_name: str = "sRGB") -> np.ndarray:
    """:func:`delta_e_2000_display` of images on the 0–255 scale (uint8 as written, or unrounded floats)."""
    return delta_e_2000_display(np.asarray(a8, np.float64) / 255.0, np.asarray(b8, np.float64) / 255.0,
                                colourspace_name)


def delta_e_2000(xyz_a, xyz_b, *, exposure: float = 1.0, colourspace_name: str = "sRGB") -> np.ndarray:
    """Display-referred CIEDE2000 between two ``(..., 3)`` XYZ arrays: both sides through the same
    :func:`to_display` (``exposure``, eq. 7, clipping, the colourspace's transfer, eq. 8), then
    :func:`delta_e_2000_display`. A colour with a non-finite component gives NaN (it is not dropped)."""
    a = np.asarray(xyz_a, np.float64)
    b = np.asarray(xyz_b, np.float64)
    bad = ~(np.all(np.isfinite(a), axis=-1) & np.all(np.isfinite(b), axis=-1))

    def shown(x):
        return to_display(np.where(bad[..., None], 0.0, x), colourspace_name, exposure=exposure)

    de = delta_e_2000_display(shown(a), shown(b), colourspace_name)
    return np.where(bad, np.nan, de)
