"""The instrument (source size, detector aperture) comes from the manifest/protocol and travels with the table."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.measure.manifest import read_manifest
from jkatana.measure.protocol import Instrument, Protocol, instrument_path, read_instrument, write_instrument

HEADER = "file,region,theta_i_deg,theta_r_deg,roi,source_radius_deg,aperture_radius_deg\n"


def _manifest(tmp_path, rows):
    for name in ("a.dng", "b.dng"):
        (tmp_path / name).write_bytes(b"x")  # read_manifest checks existence, not content
    p = tmp_path / "manifest.csv"
    p.write_text(HEADER + "".join(rows))
    return p


def test_manifest_gives_the_instrument(tmp_path):
    m = read_manifest(_manifest(tmp_path, ["a.dng,hiraji,25,25,0 0 4 4,0.25,0.5\n",
                                           "b.dng,hiraji,45,45,0 0 4 4,0.25,0.5\n"]))
    assert m.instrument == Instrument(0.25, 0.5)
    assert m.instrument.radians() == (math.radians(0.25), math.radians(0.5), 12)


def test_manifest_without_instrument_has_none(tmp_path):
    m = read_manifest(_manifest(tmp_path, ["a.dng,hiraji,25,25,0 0 4 4,,\n", "b.dng,hiraji,45,45,0 0 4 4,,\n"]))
    assert m.instrument is None


@pytest.mark.parametrize("rows,field,row", [
    (["a.dng,hiraji,25,25,0 0 4 4,0.25,0.5\n", "b.dng,hiraji,45,45,0 0 4 4,0.25,0.6\n"], "aperture_radius_deg", 2),
    (["a.dng,hiraji,25,25,0 0 4 4,0.25,0.5\n", "b.dng,hiraji,45,45,0 0 4 4,,0.5\n"], "source_radius_deg", 2),
    (["a.dng,hiraji,25,25,0 0 4 4,-1,0.5\n", "b.dng,hiraji,45,45,0 0 4 4,-1,0.5\n"], "source_radius_deg", 1),
    (["a.dng,hiraji,25,25,0 0 4 4,0.25,wide\n", "b.dng,hiraji,45,45,0 0 4 4,0.25,0.5\n"], "aperture_radius_deg", 1)])
def test_inconsistent_or_bad_instrument_names_row_and_field(tmp_path, rows, field, row):
    with pytest.raises(InputError) as e:
        read_manifest(_manifest(tmp_path, rows))
    assert e.value.field == field and e.value.row == row and "\n" not in str(e.value)


def test_protocol_carries_the_instrument_and_sidecar_round_trips(tmp_path):
    assert Protocol().instrument is None
    inst = Protocol(source_radius_deg=0.25, aperture_radius_deg=0.5).instrument
    assert inst == Instrument(0.25, 0.5)
    with pytest.raises(InputError, match="aperture_radius_deg"):
        Protocol(aperture_radius_deg=12.0)
    table = tmp_path / "t.csv"
    assert write_instrument(table, inst) == instrument_path(table) == tmp_path / "t.instrument.json"
    assert read_instrument(table) == inst
    write_instrument(table, None)  # no instrument: a stale sidecar goes
    assert read_instrument(table) is None
    instrument_path(table).write_text(json.dumps({"format": "jkatana-instrument/1", "aperture_radius_deg": "x"}))
    with pytest.raises(InputError, match="t.instrument.json.*aperture_radius_deg"):
        read_instrument(table)


def test_measure_writes_the_manifest_instrument_beside_the_table(tmp_path, monkeypatch):
    from jkatana.measure import ingest
    from jkatana.measure.table import MeasurementTable

    path = _manifest(tmp_path, ["a.dng,hiraji,25,25,0 0 4 4,0.25,0.5\n", "b.dng,hiraji,45,45,0 0 4 4,0.25,0.5\n"])
    table = MeasurementTable.from_columns(capture=["a", "b"], region=["hiraji"] * 2, theta_i_deg=[25.0, 45.0],
                                          theta_r_deg=[25.0, 45.0], value=[1.0, 2.0], sigma=[0.1, 0.1])
    monkeypatch.setattr(ingest, "measure", lambda manifest, **kw: table)  # decoding is tested elsewhere
    ingest.measure_to_file(path, tmp_path / "m.csv")
    assert read_instrument(tmp_path / "m.csv") == Instrument(0.25, 0.5)


def _instrument_table(tmp_path, mu_deg=0.2):
    """A table of the paper's hiraji lobe seen through source 0.25° and aperture 0.5° (radii), with the
    instrument stored beside it as ``jkatana measure`` stores a manifest's."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from jkatana.fit import Setup
    from jkatana.fit._model import ModelSpec, from_natural, green, prepare
    from jkatana.measure.table import MeasurementTable, write_table

    inst = read_manifest(_manifest(tmp_path, ["a.dng,hiraji,25,25,0 0 4 4,0.25,0.5\n",
                                              "b.dng,hiraji,45,45,0 0 4 4,0.25,0.5\n"])).instrument
    setup = Setup()
    n, k = setup.nk()
    ti = np.repeat([25.0, 45.0], 121)
    tr = ti + np.tile(np.linspace(-3, 3, 121), 2)
    spec = ModelSpec("hiraji", instrument=inst.radians())
    truth = {"chi": 79000.0, "mu": math.radians(mu_deg)}
    m = np.asarray(green(jnp.asarray(from_natural(truth, spec)), prepare("hiraji", ti, tr, n, k, setup.weights()),
                         spec))
    sig = 0.02 * m + 1e-3 * m.max()
    y = m + sig * np.random.default_rng(3).standard_normal(m.size)
    table = MeasurementTable.from_columns(capture=[f"c{i}" for i in range(m.size)], region=["hiraji"] * m.size,
                                          theta_i_deg=ti, theta_r_deg=tr, value=y, sigma=sig)
    write_table(table, tmp_path / "t.csv")
    write_instrument(tmp_path / "t.csv", inst)
    return tmp_path / "t.csv", truth


@pytest.mark.slow
def test_fit_uses_the_tables_instrument_without_any_flag(tmp_path, capsys):
    """Manifest with aperture 0.5°, source 0.25°: ``jkatana fit`` recovers μ = 0.2° within its interval, no flag."""
    from jkatana.cli import main

    table, truth = _instrument_table(tmp_path)
    assert main([ "fit", str(table), "-o", str(tmp_path / "p.json"), "--noise", "given"]) == 0
    d = json.loads((tmp_path / "p.json").read_text())
    assert d["options"]["instrument"] == pytest.approx({"source_radius_deg": 0.25, "aperture_radius_deg": 0.5,
                                                        "points": 12})
    lo, hi = d["laplace"]["ci95"]["mu"]
    assert lo <= truth["mu"] <= hi, (lo, truth["mu"], hi)
    assert "overrides" not in capsys.readouterr().err


def test_cli_flag_overrides_the_table_with_a_note(tmp_path, capsys):
    import argparse

    from jkatana.fit.commands import instrument_from_args

    write_instrument(tmp_path / "t.csv", Instrument(0.25, 0.5))
    args = argparse.Namespace(source_radius_deg=None, aperture_radius_deg=0.3, instrument_points=None)
    assert instrument_from_args(args, tmp_path / "t.csv") == (math.radians(0.25), math.radians(0.3), 12)
    err = capsys.readouterr().err
    assert "--aperture-radius-deg 0.3 overrides the table's 0.5" in err and err.count("\n") == 1
    args = argparse.Namespace(source_radius_deg=None, aperture_radius_deg=None, instrument_points=None)
    assert instrument_from_args(args, tmp_path / "none.csv") is None  # no file, no flags: no response
    args.source_radius_deg = 11.0
    with pytest.raises(InputError, match="source-radius-deg"):
        instrument_from_args(args, tmp_path / "none.csv")
