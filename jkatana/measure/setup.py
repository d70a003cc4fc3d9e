"""The spectral setup of a measurement, which a fit of it needs: the sample's optical constants, the wavelength
grid, the camera's sensitivity and the light (names or arrays; :mod:`jkatana.measure.camera`), and the band
weights w(λ) = light × sensitivity they give (SPEC §4). Parameter files store it (:meth:`Setup.describe`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from jkatana.errors import InputError
from jkatana.measure.camera import DEFAULT_CAMERA
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid


@dataclasses.dataclass(frozen=True)
class Setup:
    """Spectral setup of a fit: optical constants, grid, camera and light (names or arrays)."""

    optical_constants: str = "Fe-Johnson"
    grid: WavelengthGrid = DEFAULT_GRID
    camera: Any = DEFAULT_CAMERA
    light: Any = "D65"

    def weights(self) -> np.ndarray:
        from jkatana.measure.camera import band_weights, camera_sensitivity, light_spectrum

        return band_weights(light_spectrum(self.light, self.grid), camera_sensitivity(self.camera, self.grid),
                            self.grid)

    def nk(self):
        from jkatana.spectral.optical_constants import load

        return load(self.optical_constants).on_grid(self.grid)

    def describe(self) -> dict:
        """The setup as the parameter file stores it.

        Names are kept as given; the camera sensitivity and light spectrum on
        the grid are stored too (``camera_sensitivity``, ``light_spectrum``), so
        a file fitted with an array or a sensitivity file that has since moved
        can still be re-read by :func:`Setup.from_dict`.
        """
        from jkatana.measure.camera import camera_sensitivity, light_spectrum

        g = self.grid
        return dict(optical_constants=str(self.optical_constants),
                    grid=dict(start=float(g.start), stop=float(g.stop), step=float(g.step), size=int(g.size)),
                    camera=str(self.camera) if isinstance(self.camera, (str, Path)) else "array",
                    light=self.light if isinstance(self.light, (str, int, float)) else "array",
                    camera_sensitivity=np.asarray(camera_sensitivity(self.camera, g), np.float64).tolist(),
                    light_spectrum=np.asarray(light_spectrum(self.light, g), np.float64).tolist())

    @classmethod
    def from_dict(cls, d: dict, path=None) -> "Setup":
        """The setup of a parameter file (inverse of :meth:`describe`; older files without arrays too)."""
        from jkatana.spectral.grid import WavelengthGrid

        g = d.get("grid") or {}
        try:
            grid = WavelengthGrid(g["start"], g["stop"], g["step"]) if g else DEFAULT_GRID
        except (KeyError, TypeError, ValueError):
            raise InputError(f"not a wavelength grid: {g!r}", path=path, field="grid") from None

        def arr(key, name_key, default):
            a = d.get(key)
            if isinstance(a, list) and len(a) == grid.size:
                return np.asarray(a, np.float64)
            name = d.get(name_key)
            if name is None:
                return default
            if name == "array":
                raise InputError(f"{name_key} was an array and the file lacks {key!r}", path=path, field=key)
            return name

        return cls(optical_constants=d.get("optical_constants") or "Fe-Johnson", grid=grid,
                   camera=arr("camera_sensitivity", "camera", DEFAULT_CAMERA),
                   light=arr("light_spectrum", "light", "D65"))


__all__ = ["Setup"]
