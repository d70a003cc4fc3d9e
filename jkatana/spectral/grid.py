"""Wavelength grids and resampling of tabulated spectra.

jkatana's default grid is the paper's: 400–700 nm every 5 nm, 61 samples
(Mochizuki et al., §5). Every spectral array has the wavelength axis last.
The grid is a parameter everywhere, because the cost of spectral accuracy is
one of the things the project measures.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float

from jkatana.errors import InputError


#: The finest wavelength step any grid may have (nm). 1 nm is the spacing of the finest spectral table
#: jkatana reads: the CIE 1931 2° colour matching functions (CIE 015:2018, 360–830 nm every 1 nm), through
#: which every spectrum reaches XYZ. The other tables are coarser: CIE illuminants D65 and A and the camera
#: sensitivities (colour-science, 5 nm), the Hosek–Wilkie sky (11 bands, 40 nm apart), the optical constants
#: (Johnson & Christy: 49 photon energies, tens of nm apart in the visible). A finer grid only interpolates
#: linearly between tabulated samples: it costs time and memory in proportion and resolves nothing more.
MIN_STEP_NM = 1.0
#: Wavelengths a grid may span (nm): the CIE 1931 2° observer's domain, outside which no spectrum has a colour.
WAVELENGTH_RANGE = (360.0, 830.0)
#: Most samples a grid can have: 1 nm over :data:`WAVELENGTH_RANGE`.
MAX_BANDS = int(round((WAVELENGTH_RANGE[1] - WAVELENGTH_RANGE[0]) / MIN_STEP_NM)) + 1


@dataclasses.dataclass(frozen=True)
class WavelengthGrid:
    """A regular wavelength grid in nanometres, ``start`` and ``stop`` inclusive.

    **Arguments:**

    - `start`, `stop`: first and last wavelength (nm).
    - `step`: spacing (nm), at least :data:`MIN_STEP_NM` (one sample: any step); ``(stop - start)`` must be a
      whole number of steps.
    """

    start: float = 400.0
    stop: float = 700.0
    step: float = 5.0

    def __post_init__(self):
        if not (self.step > 0 and self.stop >= self.start):
            raise InputError(f"invalid wavelength grid {self.start}..{self.stop} step {self.step}",
                             field="grid")
        if self.stop > self.start and self.step < MIN_STEP_NM - 1e-12:
            raise InputError(f"step {self.step:g} nm is below {MIN_STEP_NM:g} nm, the finest step of any spectral "
                             "data jkatana reads (the CIE colour matching functions'): a finer grid resolves "
                             "nothing more", field="grid")
        n = (self.stop - self.start) / self.step
        if abs(n - round(n)) > 1e-9:
            raise InputError(f"({self.stop} - {self.start}) is not a multiple of step {self.step}",
                             field="grid")

    @classmethod
    def with_count(cls, start: float, stop: float, count: int) -> "WavelengthGrid":
        """A grid of ``count`` samples from ``start`` to ``stop`` (e.g. 16 bands)."""
        if count < 2:
            return cls(start, start, 1.0)
        return cls(start, stop, (stop - start) / (count - 1))

    @property
    def size(self) -> int:
        return int(round((self.stop - self.start) / self.step)) + 1

    def __len__(self) -> int:
        return self.size

    @property
    def wavelengths(self) -> Float[np.ndarray, "wl"]:
        """Sample wavelengths (nm), float64."""
        return self.start + self.step * np.arange(self.size, dtype=np.float64)

    def as_dict(self) -> dict[str, float]:
        return {"start": self.start, "stop": self.stop, "step": self.step, "size": self.size}


DEFAULT_GRID = WavelengthGrid(400.0, 700.0, 5.0)


def resample(wavelengths_src, values_src, grid: WavelengthGrid | np.ndarray, *,
             extrapolate: bool = False, name: str = "spectrum") -> np.ndarray:
    """Linearly interpolate a tabulated spectrum onto ``grid``.

    **Arguments:**

    - `wavelengths_src`: increasing sample wavelengths (nm), shape ``(m,)``.
    - `values_src`: values, shape ``(..., m)`` (wavelength axis last).
    - `grid`: a :class:`WavelengthGrid` or an array of target wavelengths.
    - `extrapolate`: if False (default), a target outside the table's range
      raises :class:`InputError` instead of silently holding the end value.
    - `name`: used in the error message (e.g. the file name).

    **Returns:** values on the grid, shape ``(..., len(grid))``.
    """
    wl_src = np.asarray(wavelengths_src, dtype=np.float64)
    vals = np.asarray(values_src, dtype=np.float64)
    target = grid.wavelengths if isinstance(grid, WavelengthGrid) else np.asarray(grid, np.float64)
    if wl_src.ndim != 1 or vals.shape[-1] != wl_src.shape[0]:
        raise InputError(f"wavelengths {wl_src.shape} and values {vals.shape} do not match", path=name)
    if np.any(np.diff(wl_src) <= 0):
        order = np.argsort(wl_src)
        wl_src, vals = wl_src[order], vals[..., order]
        if np.any(np.diff(wl_src) == 0):
            raise InputError("duplicate wavelengths in table", path=name)
    lo, hi = wl_src[0], wl_src[-1]
    tol = 1e-9 * max(abs(lo), abs(hi), 1.0)
    if not extrapolate and (target.min() < lo - tol or target.max() > hi + tol):
        raise InputError(
            f"table covers {lo:g}–{hi:g} nm but the grid needs {target.min():g}–{target.max():g} nm; "
            "refusing to extrapolate (pass extrapolate=True to hold the end values)", path=name)
    flat = vals.reshape(-1, wl_src.shape[0])
    out = np.stack([np.interp(target, wl_src, row) for row in flat])
    return out.reshape(vals.shape[:-1] + (target.shape[0],))
