"""Measured-BRDF formats: MERL binary, RGL .bsdf, BRDF table; slicing; round trips through the fit."""

from __future__ import annotations

import json
import struct

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from jkatana.brdf import merl, rgl  # noqa: E402
from jkatana.brdf.analytic import analytic_brdf, lobe_ndf  # noqa: E402
from jkatana.brdf.geometry import from_half_diff, goniometer_vectors, half_diff  # noqa: E402
from jkatana.brdf.slicing import load_brdf, slice_brdf, to_measurement_table  # noqa: E402
from jkatana.brdf.table import BRDFTable, read_brdf_table, write_brdf_table  # noqa: E402
from jkatana.errors import InputError  # noqa: E402
from jkatana.measure.protocol import Protocol  # noqa: E402

TRUTH = {"hiraji": {"chi": 79000.0, "mu": 0.05}, "hamon": {"beta": 43000.0, "mu": 0.05},
         "beckmann": {"scale": 2000.0, "alpha": 0.07}, "ggx": {"scale": 2000.0, "alpha": 0.05},
         "gtr": {"scale": 2000.0, "alpha": 0.05, "gamma": 1.5},
         "two-lobe": {"scale": 2000.0, "alpha": 0.03, "alpha_haze": 0.3, "weight": 0.8}}
PROTO = Protocol(incidences_deg=(15.0, 35.0, 55.0))


def _dirs(n, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(2):
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        out.append(v / np.linalg.norm(v, axis=1, keepdims=True))
    return out


def test_half_diff_inverts_and_matches_goniometer_convention():
    wi, wo = _dirs(500)
    a, b = from_half_diff(*half_diff(wi, wo))
    np.testing.assert_allclose(a, wi, atol=1e-12)
    np.testing.assert_allclose(b, wo, atol=1e-12)
    wi, wo = goniometer_vectors(30.0, 30.0, 0.0)  # mirror direction: θh = 0, θd = θi
    th, _, td, _ = half_diff(wi, wo)
    assert th == pytest.approx(0.0, abs=1e-12) and td == pytest.approx(np.radians(30.0))


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory):
    f = analytic_brdf("ggx", TRUTH["ggx"])
    path = tmp_path_factory.mktemp("merl") / "ggx.binary"
    merl.write_merl(merl.merl_from_function(f), path)
    return path, f


def test_merl_file_layout_and_reference_lookup(merl_file):
    path, f = merl_file
    raw = path.read_bytes()
    assert struct.unpack("<3i", raw[:12]) == (90, 90, 180) and len(raw) == 12 + 3 * 90 * 90 * 180 * 8
    B = merl.read_merl(path)
    wi, wo = merl.node_directions()
    truth = f(wi, wo)
    vis = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    for c, ch in enumerate(merl.CHANNELS):  # stored / scale round trip is exact to float64 rounding
        np.testing.assert_allclose(B.data[c][vis], truth[..., c][vis], rtol=1e-14)
        assert np.all(np.isnan(B.data[c][~vis]))
    # nearest: the reference reader's index formulas, by hand
    a, b = _dirs(200, seed=2)
    th, _, td, pd = half_diff(a, b)
    ih = np.clip((np.sqrt(th / (np.pi / 2) * 90 * 90)).astype(int), 0, 89)
    idd = np.clip((td / (np.pi / 2) * 90).astype(int), 0, 89)
    ip = np.clip(((np.where(pd < 0, pd + np.pi, pd)) / np.pi * 180).astype(int), 0, 179)
    np.testing.assert_array_equal(B.eval(a, b, "blue", method="nearest"), B.data[2][ih, idd, ip])
    # linear interpolation follows the analytic lobe closely where it is smooth (away from grazing)
    wi, wo = goniometer_vectors([20, 20, 40, 40], [20.0, 22.0, 40.5, 44.0], [0, 0, 0, 2.0])
    np.testing.assert_allclose(B.eval(wi, wo, "green"), f(wi, wo)[:, 1], rtol=5e-3)


def test_merl_bad_files_name_the_file(tmp_path):
    p = tmp_path / "short.binary"
    p.write_bytes(struct.pack("<3i", 90, 90, 180) + b"\0" * 100)
    with pytest.raises(InputError, match="short.binary"):
        merl.read_merl(p)
    p2 = tmp_path / "dims.binary"
    p2.write_bytes(struct.pack("<3i", 90, 90, 90) + b"\0" * 8)
    with pytest.raises(InputError) as err:
        merl.read_merl(p2)
    assert err.value.field == "header"


def test_tensor_file_round_trip_and_rgl_eval(tmp_path):
    fields = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "b": np.array([1, 2], np.uint8),
              "c": np.linspace(0, 1, 5)}
    rgl.write_tensor_file(fields, tmp_path / "t.bsdf")
    back = rgl.read_tensor_file(tmp_path / "t.bsdf")
    for k, v in fields.items():
        assert back[k].dtype == v.dtype and np.array_equal(back[k], v)
    f = analytic_brdf("ggx", TRUTH["ggx"])
    R = rgl.rgl_from_function(f, lobe_ndf("ggx", TRUTH["ggx"]), theta_i_deg=[15, 35, 55])
    rgl.write_rgl(R, tmp_path / "g.bsdf")
    B = load_brdf(tmp_path / "g.bsdf")
    # at the tabulated incidences the evaluation reproduces the BRDF (float32 tables, bilinear warps)
    wi, wo = goniometer_vectors([15, 15, 35, 35, 55, 55], [15, 17, 35, 36, 55, 58], [0, 0, 0, 3, 0, 0])
    np.testing.assert_allclose(B.eval(wi, wo, "green"), f(wi, wo)[:, 1], rtol=5e-3)
    with pytest.raises(InputError):
        B.eval(wi, wo, "550nm")  # an RGB file has no wavelengths
    (tmp_path / "bad.bsdf").write_bytes(b"not a tensor file at all")
    with pytest.raises(InputError, match="bad.bsdf"):
        rgl.read_rgl(tmp_path / "bad.bsdf")


def test_brdf_table_round_trip_and_errors(tmp_path):
    t = BRDFTable([10.0, 20.0], [11.0, 25.5], [0.0, 4.0], ["green", "550nm"], [1.5, 2.0e-3], [0.1, np.nan])
    write_brdf_table(t, tmp_path / "t.csv")
    b = read_brdf_table(tmp_path / "t.csv")
    for k in ("theta_i_deg", "theta_o_deg", "azimuth_deg", "value"):
        np.testing.assert_array_equal(getattr(b, k), getattr(t, k))
    assert list(b.channel) == ["green", "550nm"] and b.sigma[0] == 0.1 and np.isnan(b.sigma[1])
    (tmp_path / "bad.csv").write_text("theta_i_deg,theta_o_deg,azimuth_deg,channel,value\n10,95,0,green,1\n")
    with pytest.raises(InputError) as err:
        read_brdf_table(tmp_path / "bad.csv")
    assert err.value.row == 1 and err.value.field == "theta_o_deg"


def test_slice_equals_the_fit_model_in_and_out_of_plane(merl_file):
    """A slice of the analytic BRDF is the fit's forward model at the protocol's geometry (value = f_r cos θi)."""
    import jax.numpy as jnp

    from jkatana.fit._model import ModelSpec, from_natural, green, prepare
    from jkatana.fit.region import Setup

    path, f = merl_file
    tab = slice_brdf(_Exact(f), PROTO, azimuths_deg=(0.0, 2.0))
    setup = Setup()
    n, k = setup.nk()
    terms = prepare("ggx", tab.theta_i_deg, tab.theta_o_deg, n, k, setup.weights(), azimuth_deg=tab.azimuth_deg)
    spec = ModelSpec("ggx")
    model = np.asarray(green(jnp.asarray(from_natural(TRUTH["ggx"], spec)), terms, spec))
    seen = tab.value * np.cos(np.radians(tab.theta_i_deg))
    np.testing.assert_allclose(seen, model, rtol=1e-6, atol=1e-9 * model.max())
    mt = to_measurement_table(tab)  # in-plane rows only
    assert len(mt) == int(np.sum(tab.azimuth_deg == 0)) and np.all(mt.sigma == 0)


class _Exact:
    """An analytic BRDF as a measured source (``eval`` by channel)."""

    def __init__(self, f):
        self.f = f

    def eval(self, wi, wo, channel="green"):
        return self.f(wi, wo)[..., ("red", "green", "blue").index(channel)]


def _round_trip(kind, model, tmp_path, seed=3):
    from jkatana.fit import FitData, fit_region

    f = analytic_brdf(model, TRUTH[model])
    if kind == "merl":
        merl.write_merl(merl.merl_from_function(f), tmp_path / "x.binary")
        src = load_brdf(tmp_path / "x.binary")
    elif kind == "bsdf":
        rgl.write_rgl(rgl.rgl_from_function(f, lobe_ndf(model, TRUTH[model]), theta_i_deg=PROTO.incidences_deg),
                      tmp_path / "x.bsdf")
        src = load_brdf(tmp_path / "x.bsdf")
    else:
        write_brdf_table(slice_brdf(_Exact(f), PROTO), tmp_path / "x.csv")
        src = _TableSource(read_brdf_table(tmp_path / "x.csv"))
    tab = slice_brdf(src, PROTO, noise=(0.05, 1e-3), seed=seed)
    fit = fit_region(FitData.from_brdf_table(tab), model=model, per_incidence=False, robust=False)
    assert fit.converged, fit.reasons
    return fit


class _TableSource:
    """A BRDF table read back, looked up at the protocol's rows (exact match of the angles)."""

    def __init__(self, t):
        self.t = t

    def eval(self, wi, wo, channel="green"):
        t = self.t.select(channel)
        ti = np.degrees(np.arccos(wi[..., 2]))
        to = np.degrees(np.arccos(wo[..., 2]))
        key = {(round(a, 6), round(b, 6)): v for a, b, v in zip(t.theta_i_deg, t.theta_o_deg, t.value)}
        return np.array([key[(round(a, 6), round(b, 6))] for a, b in zip(ti, to)])


def test_round_trip_merl_ggx_parameters_within_intervals(tmp_path):
    fit = _round_trip("merl", "ggx", tmp_path)
    for name, v in TRUTH["ggx"].items():
        lo, hi = fit.laplace["ci95"][name]
        assert lo <= v <= hi, (name, v, lo, hi)


@pytest.mark.slow
@pytest.mark.parametrize("kind,model", [(k, m) for k in ("merl", "bsdf", "table") for m in TRUTH
                                        if (k, m) != ("merl", "hiraji")])
def test_round_trip_every_lobe_every_format(kind, model, tmp_path):
    """Every lobe through every format and back, sliced and fitted: the truth inside the 95 % intervals.

    MERL cannot hold the paper's hiraji lobe (it is not reciprocal; the limit is asserted by
    :func:`test_merl_holds_the_reciprocal_image_of_the_non_reciprocal_hiraji_lobe`)."""
    fit = _round_trip(kind, model, tmp_path, seed=5)
    for name, v in TRUTH[model].items():
        lo, hi = fit.laplace["ci95"][name]
        assert lo <= v <= hi, (kind, model, name, v, lo, hi)


def _protocol_rows():
    from jkatana.measure.protocol import as_pairs

    pairs = np.asarray(as_pairs(PROTO), np.float64)
    wi, wo = goniometer_vectors(pairs[:, 0], pairs[:, 1], np.zeros(len(pairs)))
    return pairs, wi, wo


def _error_in_sigma(read, exact, pairs):
    """Read-back error of f_r in units of the round trips' σ = 5 % ⊕ 1e-3 of the peak of f_r cos θi."""
    cos_i = np.cos(np.radians(pairs[:, 0]))
    m = exact * cos_i
    z = (read - exact) * cos_i / np.sqrt((0.05 * m) ** 2 + (1e-3 * m.max()) ** 2)
    return float(np.sqrt(np.mean(z * z))), float(np.max(np.abs(z)))


@pytest.mark.slow
def test_merl_holds_the_reciprocal_image_of_the_non_reciprocal_hiraji_lobe():
    """MERL stores φd over [0, π) only (reciprocity: (ωi, ωo) at φd + π is (ωo, ωi) at φd), so a BRDF with
    f(ωi, ωo) ≠ f(ωo, ωi) cannot be held. The paper's hiraji lobe is one: f_r = χ D F̄(θi) / cos θi puts
    Fresnel and 1/cos at θi. In plane, the rows at φd = π read back f(ωo, ωi) — off by
    cos θi F̄(θo) / (cos θo F̄(θi)), ×1.93 at θi 55°, θo 73° — and every row agrees with f at the pair the
    format stores to 0.1σ RMS and 2 % relative (the MERL grid's own interpolation)."""

    f = analytic_brdf("hiraji", TRUTH["hiraji"])
    pairs, wi, wo = _protocol_rows()
    read = merl.merl_from_function(f).eval(wi, wo, "green")
    exact, swapped = f(wi, wo)[:, 1], f(wo, wi)[:, 1]
    folded = np.abs(half_diff(wi, wo)[3]) > np.pi / 2  # in plane: φd = π, stored as the reciprocal pair at 0
    stored = np.where(folded, swapped, exact)
    assert folded.any() and (~folded).any()
    rms, _ = _error_in_sigma(read, exact, pairs)
    assert rms > 1.0  # the lobe itself does not survive: the limit is real, not interpolation
    rms, worst = _error_in_sigma(read, stored, pairs)
    assert rms < 0.1 and worst < 0.3, (rms, worst)
    big = stored > 1e-3 * stored.max()
    assert np.max(np.abs(read[big] / stored[big] - 1)) < 0.02
    g = analytic_brdf("hamon", TRUTH["hamon"])  # the paper's hamon lobe is reciprocal: MERL holds it
    np.testing.assert_allclose(g(wi, wo), g(wo, wi), rtol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["beckmann", "hiraji"])
def test_bsdf_reads_back_gaussian_tailed_lobes_within_a_tenth_sigma(model):
    """The .bsdf reflectance table at the writer's default resolution holds Gaussian-tailed lobes (the
    hardest: few warped samples in their tails) within 0.1σ RMS and 0.5σ at worst on the protocol's rows."""
    f = analytic_brdf(model, TRUTH[model])
    pairs, wi, wo = _protocol_rows()
    read = rgl.rgl_from_function(f, lobe_ndf(model, TRUTH[model]), theta_i_deg=PROTO.incidences_deg).eval(
        wi, wo, "green")
    rms, worst = _error_in_sigma(read, f(wi, wo)[:, 1], pairs)
    assert rms < 0.1 and worst < 0.5, (rms, worst)


def _cli(module, prefix, argv):
    import argparse

    p = argparse.ArgumentParser()
    getattr(module, f"{prefix}_add_arguments")(p)
    return getattr(module, f"{prefix}_run")(p.parse_args(argv))


def test_brdf_slice_command_writes_tables_fit_reads(merl_file, tmp_path, capsys):
    from jkatana.brdf import commands as bc
    from jkatana.fit.region import load_fit_data
    from jkatana.measure.table import read_table

    path, _ = merl_file
    assert _cli(bc, "brdf", ["slice", str(path), "-o", str(tmp_path / "t.csv"), "--incidences", "15,45",
                             "--seed", "1"]) == 0
    t = read_table(tmp_path / "t.csv")
    assert t.incidences() == [15.0, 45.0] and np.all(t.sigma > 0)
    assert _cli(bc, "brdf", ["slice", str(path), "-o", str(tmp_path / "o.csv"), "--incidences", "30",
                             "--azimuth", "0,2"]) == 0
    d = load_fit_data(tmp_path / "o.csv")  # a BRDF table: azimuth kept for the fit
    assert set(np.unique(d.azimuth_deg)) == {0.0, 2.0}
    from jkatana.measure.protocol import Instrument, read_instrument

    assert read_instrument(tmp_path / "t.csv") is None  # no instrument given: none stored
    assert _cli(bc, "brdf", ["slice", str(path), "-o", str(tmp_path / "t.csv"), "--incidences", "15,45",
                             "--source-radius-deg", "0.25", "--aperture-radius-deg", "0.5"]) == 0
    assert read_instrument(tmp_path / "t.csv") == Instrument(0.25, 0.5)  # beside the table, for `jkatana fit`
    with pytest.raises(InputError) as err:
        _cli(bc, "brdf", ["slice", str(path), "-o", str(tmp_path / "x.csv"), "--aperture-radius-deg", "-1"])
    assert err.value.field == "aperture-radius-deg" and not (tmp_path / "x.csv").exists()
    with pytest.raises(InputError) as err:
        _cli(bc, "brdf", ["slice", str(path), "-o", str(tmp_path / "x.csv"), "--incidences", "15,abc"])
    assert err.value.field == "incidences"
    with pytest.raises(InputError):
        _cli(bc, "brdf", ["slice", str(tmp_path / "nope.xyz"), "-o", str(tmp_path / "x.csv")])


@pytest.mark.slow
def test_compare_command_on_a_gtr_merl_slice(tmp_path):
    from jkatana.brdf import commands as bc
    from jkatana.fit import commands as fc

    merl.write_merl(merl.merl_from_function(analytic_brdf("gtr", TRUTH["gtr"])), tmp_path / "g.binary")
    _cli(bc, "brdf", ["slice", str(tmp_path / "g.binary"), "-o", str(tmp_path / "t.csv"), "--seed", "1"])
    assert _cli(fc, "compare", [str(tmp_path / "t.csv"), "-o", str(tmp_path / "cmp")]) == 0
    res = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert res["best_aic"] == "gtr" and res["best_loio"] == "gtr"
    assert (tmp_path / "cmp" / "compare.png").is_file()
