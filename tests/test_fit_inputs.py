"""Inputs of a fit: shipped optical constants, any camera channel or band, the one noise model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.measure.noise import NoiseModel
from jkatana.measure.camera import camera_sensitivity, green_sensitivity
from jkatana.spectral.grid import DEFAULT_GRID
from jkatana.spectral.optical_constants import SHIPPED, load


def test_every_shipped_table_covers_the_visible_and_names_its_source():
    assert {"Fe-Johnson", "Fe-Querry", "Cr-Johnson", "Ni-Johnson", "Mo-Kirillova", "W-Rakic-LD",
            "SS-Karlsson-austenitic"} <= set(SHIPPED)
    for name in SHIPPED:
        t = load(name)
        n, k = t.on_grid(DEFAULT_GRID)
        assert np.all(n > 0) and np.all(k >= 0) and t.reference, name
    # aliases and case
    assert load("chromium").source == "Cr-Johnson" and load("cr-johnson").source == "Cr-Johnson"
    with pytest.raises(InputError) as err:
        load("unobtainium")
    assert err.value.field == "optical_constants"


def test_camera_channels_bands_and_files(tmp_path):
    g = DEFAULT_GRID
    cam = "Nikon 5100 (NPL)"
    np.testing.assert_array_equal(camera_sensitivity(cam, g), green_sensitivity(g, cam))
    red, blue = camera_sensitivity(f"{cam}:red", g), camera_sensitivity(f"{cam}:blue", g)
    wl = g.wavelengths
    assert wl[np.argmax(red)] > 570 and wl[np.argmax(blue)] < 480
    band = camera_sensitivity("band:540-560", g)
    assert set(np.unique(band)) == {0.0, 1.0} and band[wl == 550][0] == 1 and band[wl == 600][0] == 0
    (tmp_path / "s.csv").write_text("wavelength,value\n380,0\n550,1\n780,0\n")
    s = camera_sensitivity(str(tmp_path / "s.csv"), g)
    assert s[wl == 550][0] == pytest.approx(1.0) and s[wl == 465][0] == pytest.approx(0.5)
    (tmp_path / "s.json").write_text(json.dumps({"wavelength": [380, 550, 780], "sensitivity": [0, 1, 0]}))
    np.testing.assert_allclose(camera_sensitivity(str(tmp_path / "s.json"), g), s)
    (tmp_path / "bad.csv").write_text("wavelength,value\n380,0\n550,x\n")
    with pytest.raises(InputError) as err:
        camera_sensitivity(str(tmp_path / "bad.csv"), g)
    assert err.value.row == 3
    with pytest.raises(InputError):
        camera_sensitivity("band:900-950", g)


def test_noise_model_is_one_class_for_simulation_and_fit():
    from jkatana.measure import synthetic

    assert synthetic.NoiseModel is NoiseModel
    nm = NoiseModel(relative=0.1, absolute=3.0, shot=2.0)
    np.testing.assert_allclose(nm.sigma([0.0, 10.0]), [3.0, np.sqrt(1.0 + 20.0 + 9.0)])
    assert NoiseModel().is_zero
    with pytest.raises(InputError):
        NoiseModel(relative=-1.0)
