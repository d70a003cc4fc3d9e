"""The library's one colour difference: display-referred CIEDE2000 (and its 8-bit variant) and display8."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from jkatana.spectral import (delta_e_2000, delta_e_2000_8bit, delta_e_2000_display, delta_e_display, delta_e_stats,
                              display8, reference_exposure, to_display)
from jkatana.spectral.colorimetry import to_png8, xyz_to_rgb_matrix

D65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]


def test_in_gamut_it_is_colour_sciences_ciede2000_of_the_colours():
    """Inside the display gamut the display round trip is the identity: ΔE is CIEDE2000 of the XYZ."""
    rng = np.random.default_rng(1)
    to_xyz = np.linalg.inv(xyz_to_rgb_matrix("sRGB"))
    rgb = rng.uniform(0.05, 0.85, (200, 3))
    a, b = rgb @ to_xyz.T, (rgb * rng.uniform(0.9, 1.1, (200, 3))) @ to_xyz.T
    want = colour.delta_E(colour.XYZ_to_Lab(a, D65), colour.XYZ_to_Lab(b, D65), method="CIE 2000")
    # colour-science's sRGB matrices are IEC 61966-2-1's 4-digit values, inverse to each other only to
    # 4e-5: the display round trip moves a colour by that much
    np.testing.assert_allclose(delta_e_2000(a, b), want, rtol=5e-4)
    assert np.all(want > 0) and delta_e_2000(a, a).max() == 0.0
    # the published test pair of Sharma, Wu & Dalal (2005), table 1, row 1: ΔE00 = 2.0425
    lab1, lab2 = np.array([50.0, 2.6772, -79.7751]), np.array([50.0, 0.0, -82.7485])
    assert colour.delta_E(lab1, lab2, method="CIE 2000") == pytest.approx(2.0425, abs=1e-4)


def test_it_compares_what_the_display_shows():
    """Clipping and exposure apply to both sides: two colours brighter than white look the same."""
    a, b = np.array([[5.0, 5.0, 5.0]]), np.array([[9.0, 9.0, 9.0]])
    assert delta_e_2000(a, b)[0] == 0.0
    assert delta_e_2000(a, b, exposure=0.1)[0] > 5.0  # both on screen once exposed down
    # a green inside Display P3's gamut but outside sRGB's: sRGB clips both sides towards each other
    p3_to_xyz = np.linalg.inv(xyz_to_rgb_matrix("Display P3"))
    x, y = np.array([[0.0, 0.8, 0.0]]) @ p3_to_xyz.T, np.array([[0.1, 0.8, 0.1]]) @ p3_to_xyz.T
    assert delta_e_2000(x, y)[0] < 0.5 * delta_e_2000(x, y, colourspace_name="Display P3")[0]


def test_eight_bit_variant_and_display8():
    rng = np.random.default_rng(2)
    xyz = rng.uniform(0.0, 1.2, (16, 12, 3))
    d8 = display8(xyz, exposure=0.8)
    assert d8.dtype == np.uint8 and np.array_equal(d8, to_png8(to_display(xyz, exposure=0.8)))
    ref = 255.0 * to_display(xyz, exposure=0.8)
    de = delta_e_2000_8bit(d8, ref)
    np.testing.assert_allclose(de, delta_e_2000_display(d8 / 255.0, ref / 255.0))
    assert de.shape == (16, 12) and 0 < de.max() < 1.0  # 8-bit rounding alone: a fraction of a unit


def test_non_finite_colours_give_nan_not_a_number_that_hides_them():
    a = np.full((4, 3), 0.2)
    b = a.copy()
    b[1, 2] = np.nan
    b[3, 0] = np.inf
    de = delta_e_2000(a, b)
    assert np.isnan(de[[1, 3]]).all() and np.all(de[[0, 2]] == 0.0)


def test_delta_e_display_same_transform_and_nonfinite():
    rng = np.random.default_rng(0)
    xyz = rng.uniform(0.05, 0.6, (500, 3))
    assert delta_e_display(xyz, xyz)["dE2000_mean"] == 0.0
    # inside the display gamut, the display round trip is the identity: equals colour-science's ΔE2000
    a, b = np.array([[0.2, 0.21, 0.22]]), np.array([[0.21, 0.21, 0.2]])
    got = delta_e_display(a, b, exposure=1.0)["dE2000_mean"]
    want = colour.delta_E(colour.XYZ_to_Lab(a, D65), colour.XYZ_to_Lab(b, D65), method="CIE 2000")[0]
    assert got == pytest.approx(want, rel=1e-4) and got > 0.5
    bad = xyz.copy()
    bad[7] = np.inf
    d = delta_e_display(xyz, bad)
    assert np.isnan(d["dE2000_mean"]) and d["nonfinite_frac"] == pytest.approx(1 / 500)
    assert d["dE2000_mean_finite"] == 0.0


def test_delta_e_display_exposure_from_the_reference_p99_and_percentiles():
    """The exposure comes from the reference alone: its 99th-percentile Y maps to display white (1 where
    that is not positive); each requested percentile gets its key."""
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.05, 2.0, (400, 3))
    got, de = delta_e_display(ref, ref * 1.1, percentiles=(95.0, 99.0), return_de=True)
    assert reference_exposure(ref) == 1.0 / np.percentile(ref[:, 1], 99.0) == got["exposure"]
    assert reference_exposure(np.zeros((4, 3))) == 1.0
    want = delta_e_2000(ref, ref * 1.1, exposure=got["exposure"])
    np.testing.assert_array_equal(de, want)
    assert got["dE2000_p95"] == np.percentile(want, 95.0) and got["dE2000_p99"] == np.percentile(want, 99.0)
    assert got["dE2000_mean"] == np.mean(want) and got["dE2000_max"] == np.max(want) and got["pixels"] == 400
    assert delta_e_stats(want, prefix="") == {"mean": np.mean(want), "p95": np.percentile(want, 95.0),
                                              "max": np.max(want)}
