"""Spectral core: grids, resampling, optical constants, colorimetry.

References are computed independently in the tests (the YAML files are parsed
here by hand; colour-science is called directly), never copied from jkatana.
"""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path

import colour
import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.models import Conductor, normal_incidence
from jkatana.spectral import (
    DEFAULT_GRID,
    WavelengthGrid,
    cmfs,
    encode,
    illuminant,
    resample,
    spectrum_to_xyz,
    xyz_to_linear_rgb,
    xyz_to_rgb_matrix,
)
from jkatana.spectral.colorimetry import to_display, to_png8, xyz_weights
from jkatana.spectral.optical_constants import iron, load, read_yaml

DATA = Path(str(resources.files("jkatana") / "data" / "optical_constants"))


# ---------------------------------------------------------------- grids ---


def test_default_grid_is_the_papers():
    wl = DEFAULT_GRID.wavelengths
    assert DEFAULT_GRID.size == 61 and len(wl) == 61
    assert wl[0] == 400.0 and wl[-1] == 700.0
    np.testing.assert_array_equal(np.diff(wl), 5.0)


def test_grid_that_is_not_whole_steps_is_refused():
    with pytest.raises(InputError, match="multiple"):
        WavelengthGrid(400.0, 700.0, 7.0)
    with pytest.raises(InputError):
        WavelengthGrid(400.0, 700.0, 0.0)
    with pytest.raises(InputError):
        WavelengthGrid(700.0, 400.0, 5.0)


def test_sixteen_bands():
    g = WavelengthGrid.with_count(400.0, 700.0, 16)
    assert g.size == 16
    assert g.wavelengths[0] == 400.0
    assert g.wavelengths[-1] == pytest.approx(700.0, abs=1e-9)


@pytest.mark.parametrize("grid", [WavelengthGrid(380.0, 780.0, 10.0), WavelengthGrid.with_count(400, 700, 16),
                                  WavelengthGrid(400.0, 700.0, 1.0)])
def test_other_grids_work_end_to_end(grid):
    """Optical constants, Fresnel, XYZ and display RGB on a non-default grid."""
    cond = Conductor.from_table("Fe-Johnson", grid)
    assert cond.n.shape == (grid.size,)
    F = np.asarray(cond.fresnel(np.array([1.0, 0.5])))
    assert F.shape == (2, grid.size)
    assert np.all((F > 0.4) & (F < 0.8))  # iron in the visible reflects ~50–65 %
    d65 = illuminant("D65", grid)
    xyz = spectrum_to_xyz(F * d65, grid, normalise_to=d65)
    rgb = to_display(xyz)
    assert rgb.shape == (2, 3) and np.all(np.isfinite(rgb))
    # grey-ish metal: channels within a few per cent of each other
    assert np.ptp(rgb[0]) < 0.1


def test_querry_on_wide_grid_is_refused():
    """Querry's table starts at 0.21 µm, Johnson's at 0.188 µm; a 150 nm grid needs extrapolation."""
    with pytest.raises(InputError, match="extrapolate"):
        iron("querry", WavelengthGrid(150.0, 700.0, 10.0))


# ----------------------------------------------------------- resampling ---


def test_resample_linear_and_exact_at_nodes():
    wl = np.array([400.0, 500.0, 700.0])
    v = np.array([[1.0, 3.0, 7.0], [0.0, 1.0, 0.0]])
    out = resample(wl, v, np.array([400.0, 450.0, 600.0, 700.0]))
    np.testing.assert_allclose(out, [[1.0, 2.0, 5.0, 7.0], [0.0, 0.5, 0.5, 0.0]], rtol=0, atol=1e-15)


def test_resample_refuses_to_extrapolate_and_names_the_table():
    wl = np.array([450.0, 500.0, 650.0])
    with pytest.raises(InputError) as err:
        resample(wl, np.ones(3), DEFAULT_GRID, name="my_table.csv")
    assert "my_table.csv" in str(err.value) and "extrapolate" in str(err.value)
    # opt-in holds end values
    out = resample(wl, np.array([1.0, 2.0, 3.0]), DEFAULT_GRID, extrapolate=True)
    assert out[0] == 1.0 and out[-1] == 3.0


def test_resample_rejects_duplicate_wavelengths():
    with pytest.raises(InputError, match="duplicate"):
        resample(np.array([400.0, 500.0, 500.0]), np.ones(3), np.array([450.0]))


# ---------------------------------------------------- optical constants ---


def _parse_nk_rows(path: Path) -> np.ndarray:
    """Independent reader: the numeric rows (λ µm, n, k) under ``data: |``."""
    rows = []
    in_data = False
    for line in path.read_text().splitlines():
        if re.match(r"\s*data:\s*\|", line):
            in_data = True
            continue
        if in_data:
            parts = line.split()
            if len(parts) == 3 and all(re.fullmatch(r"[-+0-9.eE]+", p) for p in parts):
                rows.append([float(p) for p in parts])
            elif rows:
                break
    return np.array(rows)


@pytest.mark.parametrize("source,fname", [("Fe-Johnson", "Johnson.yml"), ("Fe-Querry", "Querry.yml")])
def test_iron_normal_incidence_at_550nm_by_hand(source, fname):
    rows = _parse_nk_rows(DATA / "Fe" / fname)
    assert rows.shape[0] > 10
    wl_nm = rows[:, 0] * 1000.0
    j = np.searchsorted(wl_nm, 550.0)  # rows j-1, j bracket 550 nm (or j hits it exactly)
    lo, hi = rows[j - 1], rows[j]
    t = (550.0 - lo[0] * 1000.0) / ((hi[0] - lo[0]) * 1000.0)
    n = lo[1] + t * (hi[1] - lo[1])
    k = lo[2] + t * (hi[2] - lo[2])
    F_hand = ((n - 1.0) ** 2 + k**2) / ((n + 1.0) ** 2 + k**2)
    grid = WavelengthGrid(550.0, 550.0, 1.0)
    cond = Conductor.from_table(source, grid)
    F = float(np.asarray(cond.fresnel(np.array(1.0)))[0])
    assert abs(F - F_hand) < 1e-6
    assert abs(float(normal_incidence(cond.n, cond.k)[0]) - F_hand) < 1e-6
    # and at 550 on the default grid (index 30)
    F_default = float(np.asarray(Conductor.from_table(source).fresnel(np.array(1.0)))[30])
    assert abs(F_default - F_hand) < 1e-6


def test_tables_differ_as_spec_says():
    nj, _ = iron("johnson")
    nq, _ = iron("querry")
    assert np.max(np.abs(nj - nq)) > 0.3  # the two sources disagree visibly in n


def test_licence_and_citations_shipped():
    assert "CC0" in (DATA / "LICENSE_refractiveindex.info-database_CC0.txt").read_text() or \
        "Creative Commons" in (DATA / "LICENSE_refractiveindex.info-database_CC0.txt").read_text()
    assert "Johnson" in load("Fe-Johnson").reference
    assert "Querry" in load("Fe-Querry").reference


def test_yaml_errors_name_the_file(tmp_path):
    bad = tmp_path / "broken.yml"
    bad.write_text("DATA: [\n  - type: tabulated nk\n")
    with pytest.raises(InputError) as err:
        read_yaml(bad)
    assert "broken.yml" in str(err.value)

    nodata = tmp_path / "nodata.yml"
    nodata.write_text("REFERENCES: nothing\n")
    with pytest.raises(InputError) as err:
        load(nodata)
    assert "nodata.yml" in str(err.value)

    badrow = tmp_path / "badrow.yml"
    badrow.write_text("DATA:\n  - type: tabulated nk\n    data: |\n        0.5 2.0 3.0\n        0.6 abc 3.1\n")
    with pytest.raises(InputError) as err:
        load(badrow)
    assert "badrow.yml" in str(err.value) and "DATA[0]" in str(err.value)

    negative = tmp_path / "negk.yml"
    negative.write_text("DATA:\n  - type: tabulated nk\n    data: |\n        0.5 2.0 -3.0\n        0.6 2.1 3.1\n")
    with pytest.raises(InputError) as err:
        load(negative)
    assert "negk.yml" in str(err.value)

    with pytest.raises(InputError) as err:
        load(tmp_path / "missing.yml")
    assert "missing.yml" in str(err.value)

    with pytest.raises(InputError, match="unknown optical-constant"):
        load("unobtainium")


def test_user_yaml_roundtrip(tmp_path):
    p = tmp_path / "mine.yml"
    p.write_text("REFERENCES: test\nDATA:\n  - type: tabulated nk\n    data: |\n"
                 "        0.35 1.0 2.0\n        0.75 3.0 4.0\n")
    n, k = load(p).on_grid(DEFAULT_GRID)
    np.testing.assert_allclose(n, 1.0 + 2.0 * (DEFAULT_GRID.wavelengths - 350.0) / 400.0, atol=1e-12)
    np.testing.assert_allclose(k, 2.0 + 2.0 * (DEFAULT_GRID.wavelengths - 350.0) / 400.0, atol=1e-12)


# ----------------------------------------------------------- colorimetry ---


def _shape(grid):
    return colour.SpectralShape(grid.start, grid.stop, grid.step)


@pytest.mark.parametrize("grid", [DEFAULT_GRID, WavelengthGrid(380.0, 780.0, 10.0)])
def test_d65_xyz_equals_colour_science(grid):
    """XYZ of the D65 SPD with k = 1 on both sides (jkatana's ``normalise_to=None``).

    colour-science's ``sd_to_XYZ(..., method="Integration", k=1)`` with no
    illuminant uses the equal-energy illuminant E = 1, so it computes
    Σ S x̄ Δλ, the same sum as eq. (6) with k = 1. The SPD is colour-science's
    own D65 aligned to the grid, not jkatana's.
    """
    shape = _shape(grid)
    sd = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    cm = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    ref = colour.sd_to_XYZ(sd, cm, method="Integration", k=1)
    ours = spectrum_to_xyz(illuminant("D65", grid), grid)
    np.testing.assert_allclose(ours, ref, rtol=1e-6)
    # colour-science's default normalisation k = 100 / Σ ȳ Δλ (illuminant E) — same ratio
    ref100 = colour.sd_to_XYZ(sd, cm, method="Integration")
    np.testing.assert_allclose(ours * 100.0 / xyz_weights(grid)[:, 1].sum(), ref100, rtol=1e-6)
    # reflectance-under-illuminant normalisation: white reflector has Y = 1 (colour: 100)
    refl = colour.sd_to_XYZ(colour.sd_ones(shape), cm, illuminant=sd, method="Integration")
    ours_refl = spectrum_to_xyz(illuminant("D65", grid), grid, normalise_to=illuminant("D65", grid))
    np.testing.assert_allclose(ours_refl * 100.0, refl, rtol=1e-6)


def test_cmfs_on_grid_equal_colour_table():
    table = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    np.testing.assert_allclose(cmfs(DEFAULT_GRID), table[DEFAULT_GRID.wavelengths], rtol=1e-12)


def test_srgb_of_d65_is_white():
    """Linear sRGB of a D65 white (Y = 1) is (1, 1, 1).

    Tolerance 5e-3 on the paper's 400–700 nm / 5 nm grid: the truncation of the
    CMFs outside 400–700 nm moves x by ~1e-4 and z by ~1.6e-3 (measured
    0.26 % in R). On the full 360–830 nm / 1 nm grid the remaining error is the
    4-decimal rounding of the IEC 61966-2-1 matrix: 3e-4.
    """
    for grid, tol in ((DEFAULT_GRID, 5e-3), (WavelengthGrid(360.0, 830.0, 1.0), 3e-4)):
        d65 = illuminant("D65", grid)
        rgb = xyz_to_linear_rgb(spectrum_to_xyz(d65, grid, normalise_to=d65), "sRGB")
        np.testing.assert_allclose(rgb, 1.0, atol=tol)
    assert tuple(to_png8(to_display(spectrum_to_xyz(d65, grid, normalise_to=d65)))) == (255, 255, 255)


def test_illuminants_a_and_cct():
    a = illuminant("A")
    ref = colour.SDS_ILLUMINANTS["A"][DEFAULT_GRID.wavelengths]
    np.testing.assert_allclose(a, ref / np.interp(560, DEFAULT_GRID.wavelengths, ref) * 100, rtol=1e-9)
    d65_by_cct = illuminant(6504)
    assert np.max(np.abs(d65_by_cct / illuminant("D65") - 1.0)) < 0.02
    assert illuminant("5000K").shape == (61,)
    with pytest.raises(InputError):
        illuminant(1000)
    with pytest.raises(InputError):
        illuminant("Z99")


@pytest.mark.parametrize("name,key", [("sRGB", "sRGB"), ("Display P3", "Display P3"),
                                      ("Adobe RGB", "Adobe RGB (1998)"), ("Rec.2020", "ITU-R BT.2020")])
def test_matrices_equal_colour_science(name, key):
    m = xyz_to_rgb_matrix(name)
    np.testing.assert_array_equal(m, colour.RGB_COLOURSPACES[key].matrix_XYZ_to_RGB)
    xyz = np.array([[0.2, 0.3, 0.4], [0.9505, 1.0, 1.089]])
    np.testing.assert_allclose(xyz_to_linear_rgb(xyz, name), xyz @ m.T, rtol=1e-14)


def test_decode_inverts_encode_and_luminance_weights_are_bt709():
    from jkatana.spectral import decode, luminance_weights

    v = np.linspace(0.0, 1.0, 101)
    for transfer in ("sRGB", "Display P3", "Rec.2020", 2.2, "linear"):
        np.testing.assert_allclose(decode(encode(v, transfer), transfer), v, atol=1e-12)
    # IEC 61966-2-1's decoding written out here, independent of colour-science
    lin = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(decode(v, "sRGB"), lin, atol=1e-12)
    with pytest.raises(InputError):
        decode(v, -1.0)
    w = luminance_weights("sRGB")  # ITU-R BT.709-6: Y = 0.2126 R + 0.7152 G + 0.0722 B
    np.testing.assert_allclose(w, [0.2126, 0.7152, 0.0722], atol=5e-5)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)  # white (1, 1, 1) has Y = 1


def test_equal_energy_weights_give_a_flat_spectrum_y_one():
    from jkatana.spectral import equal_energy_xyz_weights

    for grid in (WavelengthGrid(400, 700, 5), WavelengthGrid(380, 780, 10)):
        W = equal_energy_xyz_weights(grid)
        assert (np.ones(grid.size) @ W)[1] == pytest.approx(1.0, abs=1e-14)
        np.testing.assert_allclose(W, xyz_weights(grid) / (xyz_weights(grid)[:, 1].sum()), rtol=1e-15)


def test_unknown_colourspace_is_input_error():
    with pytest.raises(InputError, match="colourspace"):
        xyz_to_rgb_matrix("CMYK-ish")
    with pytest.raises(InputError):
        encode(np.ones(3), "nonsense")


def test_gamma_eq8_and_srgb_curve():
    v = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(encode(v, 2.2), v ** (1 / 2.2), rtol=1e-14)
    # IEC 61966-2-1 piecewise curve written out here, independent of colour-science
    srgb = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(encode(v, "sRGB"), srgb, atol=1e-12)
    np.testing.assert_array_equal(encode(np.array([-0.5, 2.0]), 2.2), [0.0, 1.0])  # clipped
    np.testing.assert_array_equal(encode(v, "linear"), v)
    with pytest.raises(InputError):
        encode(v, 0.0)


def test_colour_plotting_is_imported_on_its_first_use_only():
    """jkatana's colorimetry imports colour-science without its plotting subpackage (and Matplotlib) in a fresh
    interpreter; the first attribute read from ``colour.plotting`` imports the real one, in sys.modules and on
    ``colour``, and colour's tables are those of a plain ``import colour``."""
    import subprocess
    import sys

    code = (
        "import sys, types\n"
        "import jkatana.spectral.colorimetry as C\n"
        "import colour\n"
        "print('matplotlib' in sys.modules, C.cmfs().shape == (61, 3))\n"
        "from colour.plotting import plot_single_sd\n"
        "print(callable(plot_single_sd), type(sys.modules['colour.plotting']) is types.ModuleType,\n"
        "      colour.plotting is sys.modules['colour.plotting'], 'matplotlib' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "True", "True", "True", "True", "True"], out
