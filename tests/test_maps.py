"""Tests of reflectance maps: procedural default, EXR round trip, photo → map, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.io.exr import write_exr
from jkatana.maps import REFLECTANCE_CHANNELS, ReflectanceMap, default_map, read_map
from jkatana.maps.photo import map_from_photo, otsu_threshold, read_photo


def test_default_map_looks_like_a_hamon():
    m = default_map((128, 512))
    assert m.shape == (128, 512) and tuple(m.channels()) == REFLECTANCE_CHANNELS
    assert np.all(m.w[:20] == 1.0)  # mune side: mirror (hiraji, shinogi-ji)
    assert np.all(m.w[-5:] < 1e-6)  # edge side: hamon
    # a wavy line: its row of crossing varies along the blade (notare/gunome)
    crossing = np.argmax(m.w < 0.5, axis=0)
    assert crossing.std() > 1.0 and 0.5 * 128 < crossing.mean() < 0.85 * 128
    assert np.allclose(m.chi, 79000) and np.allclose(m.beta, 43000)
    assert abs(np.mean(m.mu0) - 0.05) < 0.002 and 0.02 < m.mu0.std() / 0.05 < 0.2  # hada grain
    assert np.all(m.mu0 > 0) and np.all(m.mu1 > 0)


def test_map_exr_round_trip(tmp_path):
    m = default_map((64, 256), seed=3)
    path = m.write(tmp_path / "map.exr")
    back = read_map(path)
    for name in REFLECTANCE_CHANNELS:
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name))
    assert back.meta["seed"] == 3


def test_read_map_names_missing_channel(tmp_path):
    path = tmp_path / "bad.exr"
    write_exr(path, {"w": np.ones((4, 4)), "mu0": np.ones((4, 4))})
    with pytest.raises(InputError) as err:
        read_map(path)
    assert "bad.exr" in str(err.value) and "'chi'" in str(err.value)


def test_map_validation():
    with pytest.raises(InputError, match="'w'"):
        ReflectanceMap.uniform((4, 4), w=1.5)
    m = ReflectanceMap.uniform((4, 4))
    with pytest.raises(InputError, match="mu1"):
        ReflectanceMap(w=m.w, mu0=m.mu0, chi=m.chi, mu1=np.full((4, 4), np.nan), beta=m.beta)


def test_sample_is_bilinear_and_clamped():
    m = ReflectanceMap.uniform((2, 2))
    m.w[:] = [[0, 1], [0, 1]]
    s = m.sample(np.array([0.0, 0.5, 1.0, 2.0]), np.array([0.5, 0.5, 0.5, 0.5]))
    np.testing.assert_allclose(s["w"], [0.0, 0.5, 1.0, 1.0])


@pytest.fixture
def photo():
    """A diffuse-lit 'photo': hiraji dark, hamon bright, with noise; blade 1200×300 inside 1400×400."""
    truth = default_map((300, 1200), seed=5).w
    rng = np.random.default_rng(0)
    img = np.full((400, 1400), 0.02)
    img[50:350, 100:1300] = 0.08 + 0.6 * (1 - truth) + rng.normal(0, 0.01, truth.shape)
    return np.clip(img, 0, 1), truth


@pytest.mark.parametrize("fmt", ["exr", "png", "tif"])
def test_photo_to_map_recovers_w(tmp_path, photo, fmt):
    img, truth = photo
    path = tmp_path / f"photo.{fmt}"
    if fmt == "exr":
        write_exr(path, {"R": img, "G": img, "B": img})
    elif fmt == "png":
        from PIL import Image

        Image.fromarray(np.round(img * 65535).astype(np.uint16)).save(path)
    else:
        import tifffile

        tifffile.imwrite(path, np.round(img * 65535).astype(np.uint16))
    y = read_photo(path)
    m = map_from_photo(y, resolution=(300, 1200), crop=(100, 50, 1300, 350), expected_aspect=4.0)
    t = otsu_threshold(y[50:350, 100:1300])
    assert 0.2 < t < 0.55
    assert np.mean(np.abs(m.w - truth)) < 0.05
    assert np.allclose(m.chi, 79000)


def test_photo_wrong_aspect_and_crop(photo):
    img, _ = photo
    with pytest.raises(InputError, match="wrong aspect"):
        map_from_photo(img, expected_aspect=6.0)  # the uncropped 1400×400 photo is 3.5
    with pytest.raises(InputError, match="taller than wide"):
        map_from_photo(img.T)  # a portrait photo: the blade runs down the columns
    with pytest.raises(InputError, match="outside"):
        map_from_photo(img, crop=(0, 0, 2000, 100))


def test_cli_map_from_photo_with_region_fits(tmp_path, photo, capsys):
    from jkatana.cli import main

    img, _ = photo
    path = tmp_path / "photo.exr"
    write_exr(path, {"R": img, "G": img, "B": img})
    hiraji = tmp_path / "hiraji.json"
    hiraji.write_text(json.dumps({"parameters": {"chi": {"value": 81000.0}, "mu0": {"value": 0.04}}}))
    hamon = tmp_path / "hamon.json"
    hamon.write_text(json.dumps({"beta": 40000.0, "mu1": 0.07}))
    out = tmp_path / "map.exr"
    assert main(["map", str(path), "-o", str(out), "--crop", "100", "50", "1300", "350",
                 "--hiraji", str(hiraji), "--hamon", str(hamon), "--resolution", "64", "256"]) == 0
    m = read_map(out)
    assert m.shape == (64, 256) and np.allclose(m.chi, 81000) and np.allclose(m.mu1, 0.07)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"beta": -1}))
    assert main(["map", str(path), "-o", str(out), "--hamon", str(bad)]) == 2
    assert "bad.json" in capsys.readouterr().err


def _bayer_dng(path, green, *, black=(512, 510, 514, 508), white=16383):
    """An RGGB mosaic whose green photosites carry ``green`` (0..1) per 2×2 block; R, B carry other values."""
    from jkatana.measure.goniometer import write_dng

    h, w = green.shape
    mosaic = np.zeros((2 * h, 2 * w))
    b = np.asarray(black, float)  # per CFA position: R, G1, G2, B
    span = white - b
    mosaic[0::2, 0::2] = b[0] + span[0] * 0.9 * (1 - green)  # red: deliberately anti-correlated
    mosaic[0::2, 1::2] = b[1] + span[1] * green
    mosaic[1::2, 0::2] = b[2] + span[2] * green
    mosaic[1::2, 1::2] = b[3] + span[3] * 0.05
    write_dng(path, np.round(mosaic).astype(np.uint16), black=black, white=white)


def test_raw_photo_through_the_measurement_decoder(tmp_path, photo):
    img, truth = photo
    half = img[::2, ::2]
    path = tmp_path / "photo.dng"
    _bayer_dng(path, half)
    y = read_photo(path)
    # green only, black per channel subtracted, /(white − black): back to the image within 14-bit rounding
    assert y.shape == half.shape
    assert np.max(np.abs(y - half)) < 1.0 / (16383 - 514)
    m = map_from_photo(y, resolution=(150, 600), crop=(50, 25, 650, 175), expected_aspect=4.0)
    assert np.mean(np.abs(m.w - truth[::2, ::2])) < 0.05


def test_raw_photo_with_saturated_green_is_refused(tmp_path, photo):
    img, _ = photo
    half = img[::2, ::2].copy()
    half[10, 10] = 1.2  # clips at the white level
    path = tmp_path / "over.dng"
    _bayer_dng(path, np.minimum(half, 1.0))
    with pytest.raises(InputError, match="saturated") as err:
        read_photo(path)
    assert "over.dng" in str(err.value)
