"""Spectral core: wavelength grids, optical constants, colorimetry."""

from jkatana.spectral.colorimetry import (
    cmfs as cmfs,
    decode as decode,
    delta_e_2000 as delta_e_2000,
    delta_e_2000_8bit as delta_e_2000_8bit,
    delta_e_2000_display as delta_e_2000_display,
    display8 as display8,
    encode as encode,
    equal_energy_xyz_weights as equal_energy_xyz_weights,
    illuminant as illuminant,
    luminance_weights as luminance_weights,
    reinhard as reinhard,
    spectrum_to_xyz as spectrum_to_xyz,
    to_display as to_display,
    xyz_to_linear_rgb as xyz_to_linear_rgb,
    xyz_to_rgb_matrix as xyz_to_rgb_matrix,
    xyz_weights as xyz_weights,
)
from jkatana.spectral.difference import (
    delta_e_display as delta_e_display,
    delta_e_stats as delta_e_stats,
    reference_exposure as reference_exposure,
)
from jkatana.spectral.grid import DEFAULT_GRID as DEFAULT_GRID, WavelengthGrid as WavelengthGrid, resample as resample
from jkatana.spectral.optical_constants import OpticalTable as OpticalTable, iron as iron, load as load_optical_constants
