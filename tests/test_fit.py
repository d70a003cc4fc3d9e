"""Tests of jkatana.fit: recovery, calibration, tilt, hard cases, parameter file, pixels, CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.fit import FitData, Setup, fit_pixels, fit_region, prepare, read_params, write_params
from jkatana.fit._model import ModelSpec, green
from jkatana.fit.laplace import laplace
from jkatana.fit.region import fit_arrays
from jkatana.measure import synthetic
from jkatana.measure.noise import NoiseModel, estimate_noise
from jkatana.measure.protocol import paper_protocol
from jkatana.measure.synthetic import simulate_table

TRUTH = {"hiraji": {"chi": 79000.0, "mu": 0.05}, "hamon": {"beta": 43000.0, "mu": 0.05}}
SIM_NOISE = synthetic.NoiseModel(relative=0.02, absolute=20.0)


def campaign(region="hiraji", seed=0, **kw):
    kw.setdefault("noise", SIM_NOISE)
    table, truth = simulate_table(kw.pop("protocol", paper_protocol()), region, kw.pop("params", None),
                                  seed=seed, **kw)
    return FitData.from_table(table, region), truth


def inside(ci, v):
    return ci[0] <= v <= ci[1]


# ----------------------------------------------------------------------------- model


def test_green_matches_spectral_models():
    """The precomputed green model equals jkatana.models' spectral model integrated with band weights."""
    data, truth = campaign("hamon", noise=synthetic.NoiseModel())
    setup = Setup()
    n, k = setup.nk()
    for region in ("hiraji", "hamon"):
        t = prepare(region, data.theta_i_deg, data.theta_r_deg, n, k, setup.weights())
        expect = synthetic.green_values(data.theta_i_deg, data.theta_r_deg, region)
        for tilt in (False, True):
            spec = ModelSpec(region, tilt=tilt)
            p = np.log([TRUTH[region][ModelSpec(region).names[0]], 0.05] + ([] if not tilt else [1.0]))
            if tilt:
                p[2] = 0.0
            got = np.asarray(green(jnp.asarray(p), t, spec))
            np.testing.assert_allclose(got, expect, rtol=2e-7 if tilt else 1e-12, atol=1e-9 * expect.max())
    # tilt path against the simulator's tilted truth
    t = prepare("hiraji", data.theta_i_deg, data.theta_r_deg, n, k, setup.weights())
    ti, tr = synthetic.true_angles(np.stack([data.theta_i_deg, data.theta_r_deg], 1), tilt_deg=0.7)
    expect = synthetic.green_values(ti, tr, "hiraji")
    got = np.asarray(green(jnp.asarray([math.log(79000.0), math.log(0.05), math.radians(0.7)]), t,
                           ModelSpec("hiraji", tilt=True)))
    np.testing.assert_allclose(got, expect, rtol=1e-6, atol=1e-9 * expect.max())


from hypothesis import given, strategies as st  # noqa: E402


@pytest.fixture(scope="module")
def small_terms():
    setup = Setup()
    n, k = setup.nk()
    ti = np.array([0.0, 15.0, 45.0, 65.0, 89.9, 30.0, 30.0])
    tr = np.array([0.0, 15.0, 45.1, 80.0, 89.9, 30.0001, -30.0])
    return {m: prepare(m, ti, tr, n, k, setup.weights()) for m in ("hiraji", "hamon")}


@given(log_mu=st.floats(-14.0, 0.5), tilt=st.floats(-0.3, 0.3), model=st.sampled_from(["hiraji", "hamon"]),
       floor=st.booleans())
def test_green_and_gradient_finite(small_terms, log_mu, tilt, model, floor):
    """μ down to 1e-6 rad, grazing, back-scatter, θi = θr: values and gradients finite (hypothesis)."""
    p = jnp.asarray([math.log(5e4), log_mu, tilt] + ([3.0] if floor else []))
    value, grad = _value_grad(p, small_terms[model], ModelSpec(model, tilt=True, floor=floor))
    assert np.all(np.isfinite(np.asarray(value)))
    assert np.all(np.isfinite(np.asarray(grad)))


@__import__("functools").partial(__import__("jax").jit, static_argnames="spec")
def _value_grad(p, terms, spec):
    import jax

    def f(q):
        return jnp.sum(((green(q, terms, spec) - 100.0) / 10.0) ** 2)

    return green(p, terms, spec), jax.grad(f)(p)


def test_noise_estimate_recovers_simulator():
    data, _ = campaign("hiraji", seed=3, noise=synthetic.NoiseModel(relative=0.03, shot=2.0, absolute=15.0))
    nm = estimate_noise(data.value, data.sigma)
    assert nm.relative == pytest.approx(0.03, rel=0.05)
    assert nm.absolute == pytest.approx(15.0, rel=0.1)
    # pure relative noise: the floor is still there (the 1e-55 tail trap)
    data, _ = campaign("hiraji", seed=3, noise=synthetic.NoiseModel(relative=0.02))
    nm = estimate_noise(data.value, data.sigma)
    assert nm.absolute >= 1e-4 * np.max(data.value) * 0.999


# ----------------------------------------------------------------------------- recovery


@pytest.fixture(scope="module")
def fits():
    out = {}
    for region in ("hiraji", "hamon"):
        data, _ = campaign(region, seed=11)
        out[region] = fit_region(data)
    return out


@pytest.mark.parametrize("region", ["hiraji", "hamon"])
def test_recovery_inside_95(fits, region):
    f = fits[region]
    assert f.converged, f.reasons
    for name, v in TRUTH[region].items():
        assert inside(f.laplace["ci95"][name], v), (name, f.values, f.laplace["ci95"])
        # intervals are informative, not absurdly wide or absurdly tight
        lo, hi = f.laplace["ci95"][name]
        assert 1e-4 < (hi - lo) / v < 0.05
    assert 0.85 < f.diagnostics["chi2_dof"] < 1.15
    assert len(f.per_incidence) == 6
    for row in f.per_incidence:
        assert row["refit"]["converged"], row
        assert 0.6 < row["chi2_dof"] < 1.5


def test_solvers_agree(fits):
    """LM, Dogleg, Gauss–Newton and jaxopt LM reach the same optimum from the closed form."""
    f = fits["hiraji"]
    y = jnp.asarray(np.where(f.data.usable, f.data.value, 0.0))
    w = jnp.asarray(f.weight)
    for solver in ("dogleg", "gn", "jaxopt"):
        out = fit_arrays(f.terms, y, w, f.spec, solver=solver, start=f.p * 1.0 + np.array([0.3, 0.2]))
        np.testing.assert_allclose(out["p"], f.p, rtol=1e-7, atol=1e-8)


def test_emcee_agrees_with_laplace(fits):
    from jkatana.fit import sample

    f = fits["hamon"]
    em = sample(f, seed=1, max_steps=6000)
    d = em["diagnostics"]
    assert d["long_enough"] and em["converged"], d
    assert 0.2 < d["acceptance_fraction"] < 0.9
    assert d["steps"] > 50 * max(d["tau"])
    for name in f.spec.names:
        lo, hi = f.laplace["ci95"][name]
        elo, ehi = em["ci95"][name]
        assert (ehi - elo) == pytest.approx(hi - lo, rel=0.15)
        assert inside(em["ci95"][name], TRUTH["hamon"][name])


def test_calibration_laplace_fast():
    """200 campaigns (one compiled solver, ~3 s): Laplace 95 % coverage within 91–99 % (binomial
    ±2.6 sd at N = 200: P(fail | calibrated) ≈ 1 %), and the interval width matches the scatter
    of the estimates (ratio of mean SE to empirical SD in 0.85–1.15)."""
    spec = ModelSpec("hiraji")
    setup = Setup()
    n, k = setup.nk()
    proto = paper_protocol()
    pairs = np.asarray(proto)
    terms = prepare("hiraji", pairs[:, 0], pairs[:, 1], n, k, setup.weights())
    truth = synthetic.green_values(pairs[:, 0], pairs[:, 1], "hiraji")
    rng = np.random.default_rng(2024)
    hits = np.zeros(2, int)
    est, se = [], []
    N = 200
    for _ in range(N):
        y = truth + rng.standard_normal(truth.shape) * SIM_NOISE.sigma(truth)
        sig = SIM_NOISE.sigma(truth)
        nm = estimate_noise(y, sig)
        w = 1.0 / np.asarray(nm.sigma(jnp.asarray(y)))
        out = fit_arrays(terms, jnp.asarray(y), jnp.asarray(w), spec)
        m = green(jnp.asarray(out["p"]), terms, spec)
        w = jnp.asarray(1.0 / nm.sigma(m))
        out = fit_arrays(terms, jnp.asarray(y), w, spec, start=out["p"])
        lap = laplace(out["jtj"], float(out["cost"]), y.size, out["p"], spec)
        hits += [inside(lap["ci95"]["chi"], 79000.0), inside(lap["ci95"]["mu"], 0.05)]
        est.append(out["p"])
        se.append(np.sqrt(np.diag(np.asarray(lap["cov_log"]))))
    coverage = hits / N
    print("Laplace coverage (chi, mu):", coverage)
    assert np.all((coverage >= 0.91) & (coverage <= 0.99)), coverage
    ratio = np.mean(se, axis=0) / np.std(est, axis=0, ddof=1)
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio


# ----------------------------------------------------------------------------- tilt: model or rig?


@pytest.fixture(scope="module")
def tilted():
    data, _ = campaign("hamon", seed=5, tilt_deg=0.4)
    return data, fit_region(data), fit_region(data, tilt=True)


def test_tilt_shows_as_misfit_and_tilt_parameter_removes_it(tilted):
    data, plain, free = tilted
    chi_plain = np.array([r["chi2_dof"] for r in plain.per_incidence])
    chi_free = np.array([r["chi2_dof"] for r in free.per_incidence])
    # the rig error shows as misfit at every incidence, growing from the smallest to the largest
    assert np.all(chi_plain > 10), chi_plain
    assert chi_plain[-1] > 1.5 * chi_plain[0], chi_plain
    # with the tilt free, it's gone and the tilt is recovered inside its interval
    assert free.converged, free.reasons
    assert np.all(chi_free < 1.5), chi_free
    assert inside(free.laplace["ci95"]["tilt_deg"], 0.4), free.laplace["ci95"]
    assert inside(free.laplace["ci95"]["beta"], 43000.0)
    assert inside(free.laplace["ci95"]["mu"], 0.05)
    # the plain fit's (Birge-widened) interval is honest about its misfit: much wider than the free one
    lo, hi = plain.laplace["ci95"]["mu"]
    flo, fhi = free.laplace["ci95"]["mu"]
    assert (hi - lo) > 3 * (fhi - flo)


def test_floor_parameter_recovers_stray_light():
    data, _ = campaign("hiraji", seed=8, stray_floor=150.0)
    f = fit_region(data, floor=True, per_incidence=False)
    assert f.converged, f.reasons
    assert inside(f.laplace["ci95"]["floor"], 150.0), f.laplace["ci95"]
    assert inside(f.laplace["ci95"]["chi"], 79000.0)


# ----------------------------------------------------------------------------- hard cases


def _finite_report(f):
    d = json.loads(json.dumps(__import__("jkatana.fit.params", fromlist=["to_dict"]).to_dict(f)))
    assert isinstance(d["converged"], bool)
    if not f.converged:
        assert f.reasons
    return d


def test_hard_case_zeros_and_one_incidence():
    data, _ = campaign("hiraji", seed=2)
    v = data.value.copy()
    v[::3] = 0.0
    f = fit_region(FitData(data.theta_i_deg, data.theta_r_deg, v, data.sigma), per_incidence=False)
    _finite_report(f)
    assert np.all(np.isfinite(f.p))
    # one incidence only (other rows marked unusable: same array shapes, so no recompilation)
    one = FitData(data.theta_i_deg, data.theta_r_deg, data.value, data.sigma,
                  usable=np.isclose(data.theta_i_deg, 45.0))
    f1 = fit_region(one, per_incidence=True)
    assert f1.converged, f1.reasons
    assert len(f1.per_incidence) == 1
    assert inside(f1.laplace["ci95"]["mu"], 0.05)


def test_hard_case_all_zero_data_is_reported_as_failure():
    data, _ = campaign("hiraji", seed=2)
    z = FitData(data.theta_i_deg, data.theta_r_deg, np.zeros_like(data.value), None)
    f = fit_region(z, per_incidence=False)
    d = _finite_report(f)
    assert not f.converged
    assert d["values"]["chi"] is None or np.isfinite(d["values"]["chi"])


def test_hard_case_mu_near_zero():
    data, _ = campaign("hiraji", seed=4, params={"chi": 79000.0, "mu": 0.003})
    f = fit_region(data, per_incidence=False)
    _finite_report(f)
    assert np.all(np.isfinite(f.p))
    if f.converged:
        assert inside(f.laplace["ci95"]["mu"], 0.003)


@pytest.mark.parametrize("solver", ["lm", "dogleg"])
def test_hard_case_start_off_by_100x(fits, solver):
    f0 = fits["hamon"]
    for start in ({"beta": 43000.0 * 100, "mu": 0.05}, {"beta": 430.0, "mu": 0.05 * 100}):
        f = fit_region(f0.data, solver=solver, start=start, per_incidence=False, irls=False)
        _finite_report(f)
        assert np.all(np.isfinite(f.p))
        if f.converged:
            np.testing.assert_allclose(f.p, f0.p, atol=0.01)
        else:
            assert f.reasons


def test_verdict_catches_no_progress(fits):
    """A solve given max_steps=1 from a far start must not be called converged."""
    f0 = fits["hiraji"]
    f = fit_region(f0.data, start={"chi": 7.9e6, "mu": 0.5}, max_steps=1, per_incidence=False, irls=False)
    assert not f.converged
    assert any("gradient not small" in r or "solver did not" in r for r in f.reasons)


def test_float32_in_x64_process_is_refused():
    data, _ = campaign("hiraji", seed=1, protocol=[(45.0, 45.0 + 0.2 * i) for i in range(-50, 50)])
    with pytest.raises(ValueError, match="float32"):
        fit_region(data, dtype=jnp.float32)


# ----------------------------------------------------------------------------- pixels


def test_fit_pixels_recovers_and_reports_stragglers():
    pairs = np.array([(45.0, 35.0 + 0.1 * i) for i in range(200)])
    setup = Setup()
    n, k = setup.nk()
    terms = prepare("hiraji", pairs[:, 0], pairs[:, 1], n, k, setup.weights())
    rng = np.random.default_rng(0)
    P = 300
    chi = rng.uniform(3e4, 1.2e5, P)
    mu = rng.uniform(0.02, 0.08, P)
    t = ModelSpec("hiraji")
    clean = np.stack([np.asarray(green(jnp.log(jnp.array([c, m])), terms, t)) for c, m in zip(chi, mu)])
    nm = NoiseModel(relative=0.02, absolute=20.0)
    Y = clean + rng.standard_normal(clean.shape) * np.asarray(nm.sigma(jnp.asarray(clean)))
    Y[0] = 0.0  # a dead pixel
    Y[1, :] = np.nan  # a pixel with no data
    out = fit_pixels(Y, terms, noise=nm)
    good = out["converged"]
    assert not good[0] and not good[1]
    assert out["n_stragglers"] >= 2
    assert good[2:].mean() > 0.98
    np.testing.assert_allclose(out["mu"][2:][good[2:]], mu[2:][good[2:]], rtol=0.05)
    np.testing.assert_allclose(out["scale"][2:][good[2:]], chi[2:][good[2:]], rtol=0.08)
    assert np.all(np.isfinite(out["scale"][2:]))


# ----------------------------------------------------------------------------- params file and CLI


def test_params_roundtrip_and_validation(fits, tmp_path):
    p = write_params(fits["hiraji"], tmp_path / "p.json")
    P = read_params(p)
    assert P.model == "hiraji" and P.converged
    assert P.scale == pytest.approx(fits["hiraji"].values["chi"])
    d = json.loads(p.read_text())
    assert d["format"] == "jkatana-params/1"
    assert set(d["laplace"]) >= {"names", "cov_log", "ci95"}
    for field, bad in (("values", {"chi": -1.0, "mu": 0.05}), ("model", "mirror"), ("format", "x")):
        d2 = dict(d)
        d2[field] = bad
        (tmp_path / "bad.json").write_text(json.dumps(d2))
        with pytest.raises(InputError, match=field):
            read_params(tmp_path / "bad.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(InputError, match="junk.json"):
        read_params(tmp_path / "junk.json")


@pytest.mark.slow
def test_cli_fit_and_report(tmp_path):
    from jkatana.measure.table import write_table

    proto = [(ti, ti + 0.2 * j) for ti in (25.0, 45.0) for j in range(-60, 61)]
    table, _ = simulate_table(proto, "hiraji", noise=SIM_NOISE, seed=9)
    write_table(table, tmp_path / "t.csv")
    env = {**__import__("os").environ, "JAX_PLATFORMS": "cpu"}
    r = subprocess.run([sys.executable, "-m", "jkatana.cli", "fit", str(tmp_path / "t.csv"), "-o",
                        str(tmp_path / "p.json"), "--emcee"], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    P = read_params(tmp_path / "p.json")
    assert P.raw["emcee"]["diagnostics"]["long_enough"]
    r = subprocess.run([sys.executable, "-m", "jkatana.cli", "report", str(tmp_path / "p.json"), "-o",
                        str(tmp_path / "rep")], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    for name in ("report.md", "fit_per_incidence.png", "residuals.png", "quality_vs_incidence.png", "corner.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 1000
    r = subprocess.run([sys.executable, "-m", "jkatana.cli", "fit", str(tmp_path / "t.csv"), "-o",
                        str(tmp_path / "q.json"), "--region", "hamon"], capture_output=True, text=True, env=env)
    assert r.returncode == 2 and "region" in r.stderr


@pytest.mark.slow
def test_float32_far_start_trap_is_detected(tmp_path):
    """float32 in a process with x64 off: LM from a far start must never be silently 'converged' when off."""
    code = r"""
import json, jax.numpy as jnp, numpy as np
from jkatana.fit import FitData, fit_region
from jkatana.measure import synthetic
from jkatana.measure.protocol import paper_protocol
t, _ = synthetic.simulate_table(paper_protocol(), "hamon", seed=1,
                                noise=synthetic.NoiseModel(relative=0.02, absolute=20.0))
d = FitData.from_table(t, "hamon")
out = {}
for solver in ("lm", "dogleg"):
    f = fit_region(d, solver=solver, start={"beta": 1e4, "mu": 0.1}, dtype=jnp.float32,
                   per_incidence=False, irls=False)
    out[solver] = dict(values=f.values, converged=f.converged, reasons=f.reasons)
print("JSON" + json.dumps(out))
"""
    env = {**__import__("os").environ, "JAX_ENABLE_X64": "0"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads([ln for ln in r.stdout.splitlines() if ln.startswith("JSON")][0][4:])
    for solver, o in out.items():
        off = abs(o["values"]["beta"] / 43000.0 - 1) > 0.1 or abs(o["values"]["mu"] / 0.05 - 1) > 0.1
        assert not (off and o["converged"]), (solver, o)
