"""Measurements: protocol, camera weights, tables, RAW ingestion, synthetic goniometer round trips."""

from __future__ import annotations

import shutil
import struct

import numpy as np
import pytest
import rawpy  # a dependency (pyproject.toml): missing, the module fails; it is not skipped

from jkatana.errors import InputError
from jkatana.measure.camera import band_weights, green_sensitivity, light_spectrum
from jkatana.measure.goniometer import Sensor, simulate_campaign, write_dng
from jkatana.measure.ingest import measure, measure_to_file
from jkatana.measure.protocol import Protocol, paper_protocol, reduced_protocol
from jkatana.measure.synthetic import NoiseModel, green_values, simulate_table
from jkatana.measure.table import MeasurementTable, read_table, write_table
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid



def chi2_bound(dof: int, k: float = 4.0) -> float:
    """k-sigma half-width of χ²/dof around 1 (χ² has variance 2·dof)."""
    return k * np.sqrt(2.0 / dof)


# --------------------------------------------------------------------------- protocol

def test_paper_protocol_has_the_papers_shape():
    pairs = np.array(paper_protocol())
    assert len(pairs) == 1188
    assert sorted(set(pairs[:, 0])) == [15.0, 25.0, 35.0, 45.0, 55.0, 65.0]
    assert pairs[:, 1].min() == 10.0 and pairs[:, 1].max() == 80.0
    for ti in set(pairs[:, 0]):
        tr = np.sort(pairs[pairs[:, 0] == ti, 1])
        assert ti in tr  # the specular peak is captured
        steps = np.round(np.diff(tr), 6)
        near = np.abs(tr[1:] - ti) <= 20
        far = (np.abs(tr[:-1] - ti) > 20) & (np.abs(tr[1:] - ti) > 20)
        assert set(steps[near & (np.abs(tr[:-1] - ti) <= 20)]) == {0.2}
        assert set(steps[far]) <= {2.0}


def test_protocol_rejects_bad_settings():
    with pytest.raises(InputError, match="incidences_deg"):
        Protocol(incidences_deg=(95.0,))
    with pytest.raises(InputError, match="incidences_deg"):
        Protocol(incidences_deg=(float("nan"),))
    with pytest.raises(InputError, match="duplicate"):
        Protocol(incidences_deg=(45.0, 45.0))
    assert len(Protocol(incidences_deg=(45,), dense_step_deg=1, sparse_step_deg=5)) == 41 + 6  # 25..65 by 1; 10 15 20, 70 75 80


# --------------------------------------------------------------------------- camera

def test_green_sensitivity_is_colour_sciences_measured_curve():
    import colour

    s = green_sensitivity()
    table = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    expect = np.array([table[w][1] for w in DEFAULT_GRID.wavelengths])
    np.testing.assert_allclose(s, expect, rtol=1e-12)
    assert 500 <= DEFAULT_GRID.wavelengths[np.argmax(s)] <= 560
    with pytest.raises(InputError, match="camera"):  # 400–680 nm only: no silent extrapolation
        green_sensitivity(DEFAULT_GRID, "Sigma SDMerill (NPL)")
    assert green_sensitivity(WavelengthGrid(400, 680, 10), "Sigma SDMerill (NPL)").shape == (29,)


def test_band_weights_keep_chi_in_camera_units():
    E = light_spectrum("A")
    w = band_weights(E, green_sensitivity())
    assert w.sum() == pytest.approx(1.0) and np.all(w >= 0)
    # a constant spectral factor F gives back F exactly: rho = (C/E) @ w with C = F E
    assert ((0.37 * E) / E) @ w == pytest.approx(0.37)
    # hiraji at the specular peak (D = 1): rho = chi * (F(theta_i) @ w)
    from jkatana.models import Conductor

    F = np.asarray(Conductor.from_table("Fe-Johnson").fresnel(np.cos(np.deg2rad(35.0))))
    rho = green_values([35.0], [35.0], "hiraji", {"chi": 1000.0}, light="A")[0]
    assert rho == pytest.approx(1000.0 * F @ w, rel=1e-12)
    with pytest.raises(InputError):
        band_weights(np.zeros(61), green_sensitivity())


# --------------------------------------------------------------------------- table

def test_table_csv_round_trip_is_exact(tmp_path):
    table, _ = simulate_table(reduced_protocol(), "hamon", noise=NoiseModel(relative=0.02, absolute=3.0))
    path = write_table(table, tmp_path / "t.csv")
    back = read_table(path)
    for name, col in table.columns().items():
        assert np.array_equal(getattr(back, name), col), name
    assert back.regions() == ["hamon"] and back.incidences() == [15.0, 45.0]
    sel = back.select(region="hamon", incidence_deg=45)
    assert len(sel) and np.all(sel.theta_i_deg == 45.0)
    np.testing.assert_allclose(sel.phi_deg, (sel.theta_r_deg - 45.0) / 2)


@pytest.mark.parametrize("row,column,bad,field", [
    (2, "theta_i_deg", "nan", "theta_i_deg"),
    (3, "theta_r_deg", "-5", "theta_r_deg"),
    (1, "theta_i_deg", "95", "theta_i_deg"),
    (2, "region", "blade", "region"),
    (3, "capture", "dup", "capture"),
])
def test_read_table_names_row_and_column(tmp_path, row, column, bad, field):
    table = MeasurementTable.from_columns(capture=["a", "b", "c"], region=["hiraji"] * 3,
                                          theta_i_deg=[15, 15, 15], theta_r_deg=[14, 15, 16],
                                          value=[1.0, 2.0, 1.0], sigma=[0.1] * 3)
    cols = table.columns()
    lines = (tmp_path / "ok.csv")
    write_table(table, lines)
    text = lines.read_text().splitlines()
    header = text[0].split(",")
    if column == "capture":  # duplicate row: make row 3 repeat row 1's (capture, region)
        parts = text[row].split(",")
        parts[0] = text[1].split(",")[0]
    else:
        parts = text[row].split(",")
        parts[header.index(column)] = bad
        if column != "region":  # keep derived columns consistent so only the tested field is wrong
            parts[header.index("phi_deg")] = ""
            del cols
    text[row] = ",".join(parts)
    if column in ("theta_i_deg", "theta_r_deg"):  # drop the derived columns entirely
        drop = [header.index("phi_deg"), header.index("theta_h_deg")]
        text = [",".join(p for j, p in enumerate(t.split(",")) if j not in drop) for t in text]
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(InputError) as err:
        read_table(path)
    assert err.value.path == path and err.value.row == row and err.value.field == field


# --------------------------------------------------------------------------- in-memory simulator

def test_simulate_table_noise_is_what_it_says():
    noise = NoiseModel(relative=0.01, shot=2.0, absolute=5.0)
    table, truth = simulate_table(None, "hiraji", noise=noise, seed=3)
    z = (table.value - truth) / table.sigma
    assert abs(np.mean(z ** 2) - 1.0) < chi2_bound(len(z))
    np.testing.assert_allclose(table.sigma, noise.sigma(truth))
    quiet, truth0 = simulate_table(None, "hiraji")
    assert np.array_equal(quiet.value, truth0) and np.all(quiet.sigma == 0)
    np.testing.assert_allclose(truth0, truth)


def test_tilt_moves_the_specular_peak_by_twice_the_tilt():
    for tilt in (-1.0, 1.5):
        table, truth = simulate_table(None, "hiraji", tilt_deg=tilt)
        for ti in table.incidences():
            sel = table.theta_i_deg == ti
            peak = table.theta_r_deg[sel][np.argmax(truth[sel])]
            assert peak == pytest.approx(ti - 2 * tilt, abs=1e-9)


def test_stray_floor_and_jitter_only_when_asked():
    base, t0 = simulate_table(reduced_protocol(), "hamon")
    floor, t1 = simulate_table(reduced_protocol(), "hamon", stray_floor=12.5)
    np.testing.assert_allclose(t1 - t0, 12.5)
    jit, t2 = simulate_table(reduced_protocol(), "hamon", angle_jitter_deg=0.3, seed=1)
    assert np.array_equal(jit.theta_r_deg, base.theta_r_deg)  # the table keeps nominal angles
    assert not np.allclose(t2, t0)


# --------------------------------------------------------------------------- DNG writer, real RAW formats

def test_written_dng_opens_in_rawpy_exactly(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 16383, (32, 48)).astype(np.uint16)
    with pytest.raises(InputError, match="22"):  # LibRaw refuses frames under 22 photosites a side
        write_dng(tmp_path / "tiny.dng", img[:16, :16])
    path = write_dng(tmp_path / "x.dng", img, black=(1000, 1010, 990, 1005), white=16383, exposure_s=0.25)
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, img)
        assert raw.white_level == 16383
        # rawpy lists black per colour index (R, G, B, G2); ours was per CFA position (R, G, G, B)
        assert list(raw.black_level_per_channel) == [1000, 1010, 1005, 990]
        assert raw.color_desc == b"RGBG" and raw.raw_pattern.tolist() == [[0, 1], [3, 2]]
        assert raw.other.shutter_speed == pytest.approx(0.25)


def _nokia_raw(path, image: np.ndarray) -> None:
    """A headerless-style Nokia 8-bit RAW ('NOKIARAW' signature; LibRaw's identify(): data
    offset and byte count at 300, then width, height; GRBG Bayer pattern)."""
    H, W = image.shape
    header = bytearray(512)
    header[:8] = b"NOKIARAW"
    header[300:312] = struct.pack("<IIHH", 512, W * H, W, H)
    path.write_bytes(bytes(header) + image.astype(np.uint8).tobytes())


def test_non_dng_raw_nokia_opens_through_rawpy(tmp_path):
    rng = np.random.default_rng(5)
    img = rng.integers(10, 200, (48, 64)).astype(np.uint8)
    img[0, 0] = 255  # a saturated green photosite inside the ROI (G at even row, even column: GRBG)
    _nokia_raw(tmp_path / "cap.nok", img)
    (tmp_path / "m.csv").write_text("file,region,theta_i_deg,theta_r_deg,exposure_s,roi\n"
                                    "cap.nok,hamon,30,32,0.5,0 0 16 8\n")
    table = measure(tmp_path / "m.csv")
    roi = img[:8, :16].astype(float)
    green = np.zeros_like(roi, bool)
    green[0::2, 0::2] = green[1::2, 1::2] = True
    vals = roi[green & (roi < 255)] / 255.0
    assert table.n_saturated[0] == 1 and table.n_pixels[0] == vals.size == 63
    assert table.value[0] == pytest.approx(vals.mean() / 0.5, rel=1e-12)
    assert table.sigma[0] == pytest.approx(vals.std(ddof=1) / np.sqrt(vals.size) / 0.5, rel=1e-12)


def test_tiff_and_exr_captures(tmp_path):
    import tifffile

    from jkatana.io.exr import write_exr

    g = np.full((16, 16), 30000, np.uint16)
    g[::2] += 100
    rgb = np.stack([np.zeros_like(g), g, np.zeros_like(g)], -1)
    tifffile.imwrite(tmp_path / "c.tif", rgb)
    write_exr(tmp_path / "c.exr", {"G": np.full((8, 8), 0.25, np.float32), "R": np.zeros((8, 8), np.float32)})
    (tmp_path / "m.csv").write_text(
        "file,region,theta_i_deg,theta_r_deg,exposure_s,roi,black_level\n"
        "c.tif,hiraji,20,20,2,0 0 16 16,1000\n"
        "c.exr,hamon,20,22,0.5,2 2 4 4,\n")
    t = measure(tmp_path / "m.csv")
    assert t.value[0] == pytest.approx((30050 - 1000) / (65535 - 1000) / 2)
    assert t.value[1] == pytest.approx(0.5) and t.sigma[1] == 0 and t.n_pixels[1] == 16


# --------------------------------------------------------------------------- round trips

@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign")
    sensor = Sensor(bits=14, full_well_e=20000.0, read_noise_dn=2.0)
    simulate_campaign(out, reduced_protocol(), sensor=sensor, seed=7)
    return out


def test_round_trip_matches_truth_within_noise(campaign):
    table = measure(campaign / "manifest.csv")
    truth = read_table(campaign / "truth.csv")
    assert np.array_equal(table.capture, truth.capture) and np.array_equal(table.region, truth.region)
    z = (table.value - truth.value) / table.sigma
    assert abs(np.mean(z ** 2) - 1.0) < chi2_bound(len(z)), np.mean(z ** 2)
    # the standard errors measured from pixel scatter agree with the sensor model
    assert np.median(table.sigma / truth.sigma) == pytest.approx(1.0, abs=0.05)
    assert np.all(table.n_saturated == 0)


def test_noiseless_round_trip_is_exact_to_quantisation(tmp_path):
    sensor = Sensor()  # 16-bit, no noise
    simulate_campaign(tmp_path, Protocol(incidences_deg=(35.0,), dense_step_deg=2.0, sparse_step_deg=10.0),
                      sensor=sensor)
    table = measure(tmp_path / "manifest.csv")
    truth = read_table(tmp_path / "truth.csv")
    half_dn = 0.5 / (sensor.white - min(sensor.blacks)) * sensor.gain / table.exposure_s
    assert np.all(np.abs(table.value - truth.value) <= half_dn + 1e-12 * truth.value)
    assert np.abs(table.value - truth.value).max() > 0  # it really went through integers


def test_cli_simulate_and_measure_in_parallel(tmp_path, capsys):
    from jkatana.cli import main

    out = tmp_path / "sim"
    assert main(["simulate", "-o", str(out), "--incidences", "45", "--dense-step", "2", "--sparse-step", "10",
                 "--read-noise", "3", "--bits", "14", "--tilt", "1", "--quiet"]) == 0
    assert main(["measure", str(out / "manifest.csv"), "-o", str(tmp_path / "t2.csv"), "-j", "2",
                 "--quiet"]) == 0
    assert main(["measure", str(out / "manifest.csv"), "-o", str(tmp_path / "t1.csv"), "-j", "1",
                 "--plot", str(tmp_path / "t1.png"), "--overlay", str(out / "truth.csv"), "--quiet"]) == 0
    assert (tmp_path / "t1.png").is_file() and (tmp_path / "t1-residuals.png").is_file()
    t1, t2 = read_table(tmp_path / "t1.csv"), read_table(tmp_path / "t2.csv")
    assert np.array_equal(t1.value, t2.value) and len(t1) == 2 * 25  # 25..65 by 2; 10 20 70 80
    peak = t1.select("hiraji")
    assert peak.theta_r_deg[np.argmax(peak.value)] == 43.0  # tilt 1° moves the peak to 45 − 2


@pytest.mark.slow
def test_full_paper_campaign_round_trip(tmp_path):
    sensor = Sensor(bits=14, full_well_e=20000.0, read_noise_dn=2.0)
    info = simulate_campaign(tmp_path, None, sensor=sensor, seed=11)
    assert info["captures"] == 1188
    table = measure_to_file(tmp_path / "manifest.csv", tmp_path / "table.csv", workers=2)
    truth = read_table(tmp_path / "truth.csv")
    z = (table.value - truth.value) / table.sigma
    assert abs(np.mean(z ** 2) - 1.0) < chi2_bound(len(z)), np.mean(z ** 2)


# --------------------------------------------------------------------------- bad input

def _bad_manifest(folder, campaign, line: str, header="file,region,theta_i_deg,theta_r_deg,exposure_s,roi"):
    """A manifest whose row 2 is ``line`` (row 1 is a good capture)."""
    good = sorted((campaign / "raw").glob("*.dng"))[0]
    shutil.copy(good, folder / "good.dng")
    (folder / "m.csv").write_text(f"{header}\ngood.dng,hiraji,15,10,0.1,4 4 8 8\n{line}\n")
    return folder / "m.csv"


@pytest.mark.parametrize("case,line,field", [
    ("missing", "nothere.dng,hiraji,15,12,0.1,4 4 8 8", "file"),
    ("truncated", "trunc.dng,hiraji,15,12,0.1,4 4 8 8", "file"),
    ("corrupt", "junk.cr2,hiraji,15,12,0.1,4 4 8 8", "file"),
    ("roi", "good.dng,hamon,15,10,0.1,60 4 8 8", "roi"),
    ("saturated", "sat.dng,hiraji,15,12,0.1,4 4 8 8", "roi"),
    ("nan", "good.dng,hamon,15,nan,0.1,4 4 8 8", "theta_r_deg"),
    ("negative", "good.dng,hamon,-15,10,0.1,4 4 8 8", "theta_i_deg"),
    ("grazing", "good.dng,hamon,91,10,0.1,4 4 8 8", "theta_i_deg"),
    ("duplicate", "good.dng,hiraji,15,10,0.1,36 4 8 8", "capture"),
    ("escape", "../outside.dng,hiraji,15,12,0.1,4 4 8 8", "file"),
    ("absolute", "/etc/hostname,hiraji,15,12,0.1,4 4 8 8", "file"),
    ("symlink", "link.dng,hiraji,15,12,0.1,4 4 8 8", "file"),
])
def test_bad_input_names_row_and_field_and_writes_nothing(tmp_path, campaign, case, line, field):
    folder = tmp_path / "m"
    folder.mkdir()
    good = sorted((campaign / "raw").glob("*.dng"))[0]
    if case == "truncated":
        data = good.read_bytes()
        (folder / "trunc.dng").write_bytes(data[: len(data) // 2])
    elif case == "corrupt":
        (folder / "junk.cr2").write_bytes(b"II*\x00" + bytes(range(256)) * 8)
    elif case == "saturated":
        write_dng(folder / "sat.dng", np.full((64, 64), 16383, np.uint16), black=(1024,) * 4, white=16383)
    elif case in ("escape", "symlink"):
        shutil.copy(good, tmp_path / "outside.dng")
        if case == "symlink":  # a link inside the folder that points outside it
            (folder / "link.dng").symlink_to(tmp_path / "outside.dng")
    manifest = _bad_manifest(folder, campaign, line)
    out = folder / "table.csv"
    with pytest.raises(InputError) as err:
        measure_to_file(manifest, out)
    assert err.value.path == manifest and err.value.row == 2 and err.value.field == field, str(err.value)
    assert not out.exists() and not list(folder.glob(".table*"))


def test_cli_reports_bad_input_in_one_line_and_exits_2(tmp_path, campaign, capsys):
    from jkatana.cli import main

    manifest = _bad_manifest(tmp_path, campaign, "good.dng,hamon,15,10,0.1,4 4 100 8")
    assert main(["measure", str(manifest), "-o", str(tmp_path / "t.csv"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "row 2" in err[0] and "'roi'" in err[0] and "leaves the 64×64 frame" in err[0]
    assert not (tmp_path / "t.csv").exists()


def test_toml_manifest_and_multiple_rois(tmp_path, campaign):
    good = sorted((campaign / "raw").glob("*.dng"))[0]
    shutil.copy(good, tmp_path / "a.dng")
    (tmp_path / "m.toml").write_text(
        '[[capture]]\nfile = "a.dng"\nregion = "hiraji"\ntheta_i_deg = 15\ntheta_r_deg = 10\n'
        'exposure_s = 0.1\nroi = [[4, 4, 8, 8], [4, 20, 8, 8]]\n')
    t = measure(tmp_path / "m.toml")
    assert t.n_pixels[0] == 2 * 32 and t.capture[0] == "a"


# --------------------------------------------------------------------------- formats, dark frames, resume, plots

def test_parquet_round_trip_is_exact(tmp_path):
    table, _ = simulate_table(reduced_protocol(), "hiraji", noise=NoiseModel(absolute=1.0))
    back = read_table(write_table(table, tmp_path / "t.parquet"))
    for name, col in table.columns().items():
        assert np.array_equal(getattr(back, name), col), name


def test_dark_frame_replaces_the_black_level(tmp_path):
    img = np.full((32, 32), 1000 + 3000, np.uint16)
    dark = np.full((32, 32), 1000 + 200, np.uint16)
    write_dng(tmp_path / "c.dng", img, black=(1000,) * 4, white=16383)
    write_dng(tmp_path / "d.dng", dark, black=(1000,) * 4, white=16383)
    (tmp_path / "m.csv").write_text("file,region,theta_i_deg,theta_r_deg,exposure_s,roi,dark\n"
                                    "c.dng,hiraji,20,20,1,0 0 8 8,d.dng\nc.dng,hamon,20,20,1,8 8 8 8,\n")
    t = measure(tmp_path / "m.csv")
    assert t.value[0] == pytest.approx(2800 / (16383 - 1000))
    assert t.value[1] == pytest.approx(3000 / (16383 - 1000))


def test_simulate_resume_keeps_files_and_reproduces(tmp_path):
    proto = [(25.0, 20.0), (25.0, 25.0), (25.0, 30.0)]
    sensor = Sensor(read_noise_dn=3.0)
    simulate_campaign(tmp_path / "a", proto, sensor=sensor, seed=4)
    first = {p.name: p.read_bytes() for p in (tmp_path / "a" / "raw").glob("*.dng")}
    victim = tmp_path / "a" / "raw" / "i25.0_r25.0.dng"
    victim.unlink()
    (tmp_path / "a" / "manifest.csv").unlink()
    simulate_campaign(tmp_path / "a", proto, sensor=sensor, seed=4, resume=True)
    again = {p.name: p.read_bytes() for p in (tmp_path / "a" / "raw").glob("*.dng")}
    assert again == first  # the missing frame was rewritten identically, the others kept
    assert (tmp_path / "a" / "manifest.csv").is_file()


def test_plots_are_written(tmp_path):
    table, truth_values = simulate_table(reduced_protocol(), "hiraji", noise=NoiseModel(relative=0.02))
    truth = MeasurementTable(**{**table.columns(), "value": truth_values})
    from jkatana.measure.plot import plot_residuals, plot_table

    png = plot_table(table, tmp_path / "t.png", overlay=truth)
    res = plot_residuals(table, truth, tmp_path / "r.png")
    for p in (png, res):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000


def test_forced_exposure_clips_and_saturation_is_flagged(tmp_path):
    proto = [(35.0, r) for r in (25.0, 33.0, 34.0, 35.0, 36.0, 45.0)]
    sensor = Sensor(bits=14, read_noise_dn=30.0)
    peak = green_values([35.0], [35.0], "hiraji")[0]
    # exposure such that the peak sits right at full scale: part of its photosites clip
    exposure = (sensor.white - max(sensor.blacks)) / (sensor.white - min(sensor.blacks)) * sensor.gain / peak
    simulate_campaign(tmp_path, proto, regions=("hiraji",), sensor=sensor, exposure_s=exposure)
    table = measure(tmp_path / "manifest.csv")
    truth = read_table(tmp_path / "truth.csv")
    at_peak = table.theta_r_deg == 35.0
    assert table.n_saturated[at_peak][0] > 0
    assert table.n_pixels[at_peak][0] + table.n_saturated[at_peak][0] == truth.n_pixels[at_peak][0]
    assert table.value[at_peak][0] < truth.value[at_peak][0]  # the clipped tail is not averaged in
    assert np.all(table.n_saturated[np.abs(table.theta_r_deg - 35.0) >= 10] == 0)


# --------------------------------------------------------------------------- properties

from hypothesis import given, strategies as st  # noqa: E402


@given(st.lists(st.floats(0, 89.9), min_size=1, max_size=3, unique_by=lambda a: round(a * 10)),
       st.sampled_from([0.1, 0.2, 0.5, 1.0]), st.sampled_from([1.0, 2.0, 5.0]), st.floats(0, 30))
def test_protocol_properties(incidences, dense, sparse, half):
    proto = Protocol(incidences_deg=tuple(round(a, 1) for a in incidences), dense_step_deg=dense,
                     sparse_step_deg=sparse, dense_halfwidth_deg=round(half, 1))
    pairs = np.array(proto.pairs()).reshape(-1, 2)
    assert np.all((pairs[:, 1] >= 10) & (pairs[:, 1] <= 80))
    assert len({(a, b) for a, b in pairs}) == len(pairs)  # no duplicates
    for ti in set(pairs[:, 0]):
        tr = np.sort(pairs[pairs[:, 0] == ti, 1])
        assert np.all(np.diff(tr) > 0)
        near = tr[np.abs(tr - ti) <= proto.dense_halfwidth_deg + 1e-9]
        if near.size > 1:
            assert np.diff(near).max() <= dense + 1e-9


@given(st.integers(0, 40), st.integers(0, 40), st.integers(2, 24), st.integers(2, 24), st.integers(0, 2 ** 32 - 1))
def test_roi_stats_match_a_direct_computation(x, y, w, h, seed):
    from jkatana.measure.decode import Frame, roi_stats

    rng = np.random.default_rng(seed)
    dn = rng.integers(0, 4096, (64, 64)).astype(np.uint16)
    colors = np.tile(np.array([[0, 1], [3, 2]], np.uint8), (32, 32))
    frame = Frame(dn=dn, colors=colors, green_colors=(1, 3), black=np.array([10.0, 20.0, 30.0, 40.0]),
                  white=4000.0)
    sub, col = dn[y:y + h, x:x + w].astype(float), colors[y:y + h, x:x + w]
    g = ((col == 1) | (col == 3)) & (sub < 4000)
    black = np.array([10.0, 20.0, 30.0, 40.0])[col][g]
    v = (sub[g] - black) / (4000.0 - black)
    if v.size < 2:
        with pytest.raises(InputError):
            roi_stats(frame, [(x, y, w, h)])
        return
    s = roi_stats(frame, [(x, y, w, h), (x, y, w, h)])  # a repeated rectangle counts once
    assert s.n_pixels == v.size and s.n_saturated == int((((col == 1) | (col == 3)) & (sub >= 4000)).sum())
    assert s.mean == pytest.approx(v.mean(), rel=1e-12, abs=1e-15)
    assert s.stderr == pytest.approx(v.std(ddof=1) / np.sqrt(v.size), rel=1e-9, abs=1e-15)


def test_exposure_comes_from_the_raw_file_when_the_manifest_has_none(tmp_path):
    import tifffile

    write_dng(tmp_path / "c.dng", np.full((32, 32), 2000, np.uint16), black=(1000,) * 4, white=16383,
              exposure_s=0.125)
    tifffile.imwrite(tmp_path / "c.tif", np.full((8, 8), 500, np.uint16))
    (tmp_path / "m.csv").write_text("file,region,theta_i_deg,theta_r_deg,roi\nc.dng,hiraji,20,20,0 0 8 8\n")
    t = measure(tmp_path / "m.csv")
    assert t.exposure_s[0] == pytest.approx(0.125) and t.value[0] == pytest.approx(1000 / 15383 / 0.125)
    (tmp_path / "m2.csv").write_text("file,region,theta_i_deg,theta_r_deg,roi\nc.tif,hiraji,20,20,0 0 8 8\n")
    with pytest.raises(InputError) as err:
        measure(tmp_path / "m2.csv")
    assert err.value.row == 1 and err.value.field == "exposure_s"


def test_spreadsheet_csv_with_bom_and_quoted_roi(tmp_path, campaign):
    good = sorted((campaign / "raw").glob("*.dng"))[0]
    shutil.copy(good, tmp_path / "a.dng")
    (tmp_path / "m.csv").write_text('\ufefffile,region,theta_i_deg,theta_r_deg,exposure_s,roi\n'
                                    'a.dng,Hiraji, 15 ,10,0.1,"4,4,8,8"\n', encoding="utf-8")
    t = measure(tmp_path / "m.csv")
    assert t.region[0] == "hiraji" and t.n_pixels[0] == 32


def test_parallel_ingest_reports_the_bad_row_and_writes_nothing(tmp_path, campaign):
    shutil.copytree(campaign, tmp_path / "c")
    lines = (tmp_path / "c" / "manifest.csv").read_text().splitlines()
    victim_row = 41  # data row (1-based); its file is truncated below
    victim = tmp_path / "c" / lines[victim_row].split(",")[0]
    victim.write_bytes(victim.read_bytes()[:300])
    with pytest.raises(InputError) as err:
        measure_to_file(tmp_path / "c" / "manifest.csv", tmp_path / "t.csv", workers=2)
    rows_of_file = [i for i, line in enumerate(lines[1:], start=1) if line.startswith(lines[victim_row].split(",")[0])]
    assert err.value.row == rows_of_file[0] and err.value.field == "file" and victim.name in str(err.value)
    assert not (tmp_path / "t.csv").exists()
