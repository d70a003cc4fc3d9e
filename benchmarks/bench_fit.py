"""Fitting benchmarks: region fit time, per-pixel throughput, emcee, float32 vs float64, solvers, intervals, lobes.

Lobes: the solve time of every fitted lobe after compilation (goal ≤ 1 ms per
region), the cost of a second fit of another table of the same shape (no
recompilation), the first and second call of ``jkatana fit`` (the second
reads JAX's persistent compilation cache), and ``compare`` on 6 incidences ×
all lobes (first and second call). ``--quick`` makes every kind of record
with fewer repetitions: 5 timed solves per lobe instead of 30, one timed
call instead of three of the whole region fit, the solver comparison and
emcee on the hiraji region only, 2000 pixels instead of 10000, one timed
float32 fit per solver and start; the float32 subprocess runs beside the
main process (started first, collected last) so that the module uses both
cores. Each section's CPU seconds (this process; the subprocesses' own)
are logged and recorded, a load-independent measure of its cost on a
shared machine.

This module's process runs XLA on the fit commands' one-thread pool
(:func:`jkatana.runtime.xla_threads`, ``$JKATANA_XLA_THREADS``); the region fit
is timed again in a subprocess with JAX's default pool, one thread per core (the
pool of a process that also renders), after the float32 subprocess has ended.

Every approximation is measured against a reference with error and time side
by side: solvers against the float64 LM optimum, the fixed-step per-pixel fit
against a per-pixel optimistix LM (max 200 steps), float32 against float64,
Laplace intervals against emcee's. float32 runs in a subprocess with
``jax_enable_x64`` off (lineax fails on mixed dtypes when x64 is on).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np

from benchmarks._harness import record, timeit
from jkatana.runtime import ENV_VAR as XLA_ENV

B = "bench_fit"


def _campaign(region="hiraji", seed=0):
    from jkatana.fit import FitData
    from jkatana.measure import synthetic
    from jkatana.measure.protocol import paper_protocol

    table, _ = synthetic.simulate_table(paper_protocol(), region, seed=seed,
                                        noise=synthetic.NoiseModel(relative=0.02, absolute=20.0))
    return FitData.from_table(table, region)


def _pixels(P, dtype, seed=0):
    import jax.numpy as jnp

    from jkatana.fit import Setup, prepare
    from jkatana.measure.noise import NoiseModel
    from jkatana.fit._model import ModelSpec, green

    pairs = np.array([(45.0, 35.0 + 0.1 * i) for i in range(200)])
    setup = Setup()
    n, k = setup.nk()
    terms = prepare("hiraji", pairs[:, 0], pairs[:, 1], n, k, setup.weights(), dtype)
    rng = np.random.default_rng(seed)
    chi = rng.uniform(3e4, 1.2e5, P)
    mu = rng.uniform(0.02, 0.08, P)
    t64 = prepare("hiraji", pairs[:, 0], pairs[:, 1], n, k, setup.weights())
    spec = ModelSpec("hiraji")
    import jax

    f = jax.jit(jax.vmap(lambda p: green(p, t64, spec)))
    clean = np.asarray(f(jnp.asarray(np.log(np.stack([chi, mu], 1)))))
    nm = NoiseModel(relative=0.02, absolute=20.0)
    Y = clean + rng.standard_normal(clean.shape) * np.asarray(nm.sigma(jnp.asarray(clean)))
    return terms, Y, chi, mu, nm


def _float32_worker(quick: bool = False):
    """Runs in a subprocess with x64 off: float32 region fits (LM, Dogleg; near and far start), pixels."""
    import jax.numpy as jnp

    from jkatana.fit import fit_pixels
    from jkatana.fit.region import fit_region

    out = {}
    data = _campaign("hamon", seed=1)
    for solver in ("lm", "dogleg"):
        for start_name, start in (("closed", None), ("far", {"beta": 1e4, "mu": 0.1})):
            f = fit_region(data, solver=solver, start=start, dtype=jnp.float32, per_incidence=False, irls=False)
            t = timeit(lambda: fit_region(data, solver=solver, start=start, dtype=jnp.float32,
                                          per_incidence=False, irls=False), repeats=1 if quick else 3, warmup=0)
            out[f"{solver}_{start_name}"] = dict(values=f.values, converged=f.converged, reasons=f.reasons,
                                                 time_s=t)
    for P in (2000,):
        terms, Y, chi, mu, nm = _pixels(P, jnp.float32)
        r = fit_pixels(Y, terms, noise=nm)
        t = timeit(lambda: fit_pixels(Y, terms, noise=nm), repeats=1 if quick else 3, warmup=0)
        out["pixels"] = dict(P=P, fits_per_s=P / t["median"], stragglers=r["n_stragglers"],
                             mu=r["mu"].tolist(), scale=r["scale"].tolist(), converged=r["converged"].tolist())
    out["cpu_s"] = time.process_time()
    print("JSON" + json.dumps(out))


def _region_fit_time(terms, spec, y, w, reps: int) -> tuple[dict, float]:
    """Wall time (timeit) and mean process CPU of one region fit (:data:`REGION_FIT`) of ``y`` with weights
    ``w``."""
    from jkatana.fit.solve import fit_program

    return (timeit(lambda: fit_program(terms, y, w, spec), repeats=reps),
            _mean_cpu(lambda: fit_program(terms, y, w, spec), reps))


def _default_pool_worker(quick: bool = False):
    """Runs in a subprocess with JAX's default thread pool (one thread per core): the region fit of each lobe
    (GTR and GGX in quick mode), beside the main process's one-thread pool of the fit commands."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from jkatana.fit._model import MODELS

    import jax.numpy as jnp

    from jkatana.fit.solve import fit_program
    from jkatana.fit.region import fit_region

    out = {}
    for model in ("gtr", "ggx") if quick else MODELS:
        data = _lobe_campaign(model)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        y, w = jnp.asarray(data.value), jnp.asarray(ref.weight)
        steps = int(fit_program(ref.terms, y, w, ref.spec)["steps"])
        t, cpu = _region_fit_time(ref.terms, ref.spec, y, w, 10 if quick else 50)
        out[model] = dict(time_s=t, cpu_mean_s=cpu, steps=steps)
    print("JSON" + json.dumps(out))


LOBE_TRUTH = {"hiraji": {"chi": 79000.0, "mu": 0.05}, "hamon": {"beta": 43000.0, "mu": 0.1},
              "beckmann": {"scale": 2000.0, "alpha": 0.2}, "ggx": {"scale": 2000.0, "alpha": 0.05},
              "gtr": {"scale": 2000.0, "alpha": 0.05, "gamma": 1.5},
              "two-lobe": {"scale": 2000.0, "alpha": 0.03, "alpha_haze": 0.3, "weight": 0.8}}


def _lobe_campaign(model, seed=0):
    import jax.numpy as jnp

    from jkatana.fit import FitData, Setup
    from jkatana.fit._model import ModelSpec, from_natural, prepare
    from jkatana.fit.solve import model_values  # one compiled program, not green's eager operations
    from jkatana.measure.protocol import as_pairs, paper_protocol

    setup = Setup()
    n, k = setup.nk()
    pairs = np.asarray(as_pairs(paper_protocol()), np.float64)
    spec = ModelSpec(model)
    m = np.asarray(model_values(jnp.asarray(from_natural(LOBE_TRUTH[model], spec)),
                                prepare(model, pairs[:, 0], pairs[:, 1], n, k, setup.weights()), spec))
    sig = np.sqrt((0.05 * m) ** 2 + (1e-3 * m.max()) ** 2)
    y = m + sig * np.random.default_rng(seed).standard_normal(m.size)
    return FitData(pairs[:, 0], pairs[:, 1], y, sig)


#: What one timed "region fit" is (the ≤ 1 ms goal): one compiled call on a region's 1188 points.
REGION_FIT = ("fit_program, as fit_region calls it: one compiled program that computes the start (closed form for "
              "hiraji/hamon, moment start for other lobes), the model's evaluation point (geometry and Fresnel "
              "factors, once per call), optimistix LM to convergence and the convergence check (residuals at the "
              "start; residuals and Jacobian at the optimum from the solver's last linearisation, J^T J, "
              "Gauss-Newton decrement); not the noise estimate, prepare (directions, Fresnel table), the Laplace "
              "covariance, per-incidence refits or the sandwich")


def _mean_cpu(fn, repeats: int) -> float:
    """Process CPU time per call of ``fn()``, over ``repeats`` calls in a row (seconds; less sensitive to load
    than wall time; per call it would be below the CPU clock's granularity)."""
    from benchmarks._harness import block

    block(fn())
    c0 = time.process_time()
    for _ in range(repeats):
        block(fn())
    return (time.process_time() - c0) / repeats


def _lobes(quick: bool, rows: list, log) -> None:
    import tempfile
    from pathlib import Path

    import jax.numpy as jnp

    from jkatana.fit._model import MODELS
    from jkatana.fit.solve import solve
    from jkatana.fit.starts import start_vector
    from jkatana.fit.compare import compare_models
    from jkatana.fit.region import fit_region

    for model in MODELS:
        data = _lobe_campaign(model)
        t0 = time.perf_counter()
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        first = time.perf_counter() - t0
        other = _lobe_campaign(model, seed=1)
        t0 = time.perf_counter()
        fit_region(other, model=model, per_incidence=False, robust=False)
        second = time.perf_counter() - t0
        y = jnp.asarray(data.value)
        w = jnp.asarray(ref.weight)
        terms, spec = ref.terms, ref.spec
        p0 = start_vector(terms, y, w, spec)
        out = solve(terms, y, w, p0, spec=spec)
        reps = 10 if quick else 50
        t = timeit(lambda: solve(terms, y, w, p0, spec=spec), repeats=reps)
        t_start = timeit(lambda: start_vector(terms, y, w, spec), repeats=reps)
        t_fit, cpu_fit = _region_fit_time(terms, spec, y, w, reps)
        rows.append(record(B, dict(method=f"lobe {model}: region fit after compilation", model=model,
                                   n_points=int(data.value.size)), time_s=t, steps=int(out["steps"]),
                           start_time_s=t_start["median"], start_and_solve_time_s=t_fit,
                           start_and_solve_cpu_mean_s=cpu_fit, load_avg_1min=os.getloadavg()[0],
                           xla_threads=XLA_THREADS, region_fit=REGION_FIT, goal="<= 1 ms per region fit",
                           first_fit_region_s=first, second_fit_region_other_table_s=second,
                           converged=bool(ref.converged)))
        log("lobe", model, "solve", t["median"], "start", t_start["median"], "start+solve", t_fit["median"],
            "min", t_fit["min"], "cpu mean", cpu_fit, "first", first, "second", second)
    # jkatana fit, first and second call (fresh persistent compilation cache)
    with tempfile.TemporaryDirectory() as tmp:
        from jkatana.measure.table import MeasurementTable, write_table

        d = _lobe_campaign("ggx")
        table = MeasurementTable.from_columns(capture=[f"c{i}" for i in range(d.value.size)],
                                              region=["hiraji"] * d.value.size, theta_i_deg=d.theta_i_deg,
                                              theta_r_deg=d.theta_r_deg, value=d.value, sigma=d.sigma)
        write_table(table, Path(tmp) / "t.csv")
        env = {**os.environ, "JKATANA_CACHE": tmp}
        times = []
        for _ in range(2):
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "jkatana.cli", "fit", str(Path(tmp) / "t.csv"), "-o",
                                   str(Path(tmp) / "p.json"), "--model", "ggx"], capture_output=True, text=True,
                                  env=env)
            times.append(time.perf_counter() - t0)
            if proc.returncode not in (0, 1):
                rows.append(record(B, dict(method="jkatana fit CLI"), failed=proc.stderr[-1500:]))
                break
        rows.append(record(B, dict(method="jkatana fit CLI (ggx, 1188 rows, per-incidence refits, sandwich)"),
                           first_call_s=times[0], second_call_s=times[-1],
                           note="second call: same table shape, JAX persistent compilation cache warm"))
        log("CLI fit", times)
    # compare: 6 incidences x all lobes
    data = _lobe_campaign("gtr")
    times = []
    for _ in range(2):
        t0 = time.perf_counter()
        res = compare_models(data, list(MODELS))
        times.append(time.perf_counter() - t0)
    rows.append(record(B, dict(method="compare: 6 incidences x all lobes (fits, per-incidence, LOIO)",
                               models=len(MODELS)), first_call_s=times[0], second_call_s=times[1],
                       selected_aic=res["best_aic"], selected_loio=res["best_loio"]))
    log("compare", times, res["best_aic"], res["best_loio"])


#: XLA's thread pool in this module's process: the fit commands' (:func:`jkatana.fit.commands._x64`).
XLA_THREADS = os.environ.get(XLA_ENV, "1")


def run(quick: bool) -> list[dict]:
    from jkatana.runtime import xla_threads

    pool_set = xla_threads(XLA_THREADS)  # before anything starts JAX's backend
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from jkatana.fit import fit_pixels, fit_region, sample
    from jkatana.fit.solve import solve
    from jkatana.fit.starts import closed_form_start

    rows = []
    log = lambda *a: print(*a, file=sys.stderr, flush=True)  # noqa: E731
    log("XLA pool", XLA_THREADS, "set here" if pool_set else "not set here (JAX's default or already started)")
    # float32 runs with x64 off in its own process, beside this one
    f32_proc = subprocess.Popen([sys.executable, "-c", "from benchmarks.bench_fit import _float32_worker as w; "
                                 f"w(quick={quick})"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "JAX_ENABLE_X64": "0"})
    t_f32 = time.perf_counter()
    cpu = {}

    def section(name, c0):
        cpu[name] = round(time.process_time() - c0, 2)
        log("cpu", name, cpu[name])
        return time.process_time()

    c0 = time.process_time()
    _lobes(quick, rows, log)
    c0 = section("lobes, CLI (this process's share), compare", c0)

    # ---- region fits: solvers after JIT, error vs the LM optimum
    for region in ("hiraji", "hamon"):
        data = _campaign(region)
        ref = fit_region(data, per_incidence=False)
        y = jnp.asarray(np.where(data.usable, data.value, 0.0))
        w = jnp.asarray(ref.weight)
        terms, spec = ref.terms, ref.spec
        reps = 5 if quick else 20
        t_cf = timeit(lambda: closed_form_start(terms, y, w, spec), repeats=reps)  # jitted
        p_cf = np.asarray(closed_form_start(terms, y, w, spec))
        rows.append(record(B, dict(region=region, method="closed form only", n_points=int(data.usable.sum())),
                           time_s=t_cf, error=dict(max_abs_log_param=float(np.max(np.abs(p_cf - ref.p)))),
                           reference="float64 optimistix LM optimum"))
        log(region, "closed form", t_cf["median"])
        p0 = closed_form_start(terms, y, w, spec)
        for solver in ("lm", "dogleg", "gn", "jaxopt"):
            out = solve(terms, y, w, p0, spec=spec, solver=solver)
            t = timeit(lambda: solve(terms, y, w, p0, spec=spec, solver=solver), repeats=reps)
            rows.append(record(B, dict(region=region, method=f"solve {solver} from closed form",
                                       n_points=int(data.usable.sum())), time_s=t,
                               error=dict(max_abs_log_param=float(np.max(np.abs(np.asarray(out["p"]) - ref.p)))),
                               reference="float64 optimistix LM optimum", steps=int(out["steps"]),
                               goal="<= 1 ms per region fit"))
            log(region, solver, t["median"], int(out["steps"]))
        t_full = timeit(lambda: fit_region(data, per_incidence=False), repeats=1 if quick else 3)
        rows.append(record(B, dict(region=region, method="fit_region (noise estimate, prepare, 2 solves, Laplace)"),
                           time_s=t_full))
        t_pi = timeit(lambda: fit_region(data, per_incidence=True), repeats=1 if quick else 3)
        rows.append(record(B, dict(region=region, method="fit_region + per-incidence refits"), time_s=t_pi))
        # emcee (a short first run compiles the log-prob; the timed run is the second)
        sample(ref, seed=1, min_steps=100, chunk=100, max_steps=100)
        em = sample(ref, seed=0)
        d = em["diagnostics"]
        widths = {n: dict(laplace=ref.laplace["ci95"][n][1] - ref.laplace["ci95"][n][0],
                          emcee=em["ci95"][n][1] - em["ci95"][n][0]) for n in spec.names}
        rows.append(record(B, dict(region=region, method="emcee (32 walkers, vectorised JAX log-prob)"),
                           time_s=dict(median=d["time_s"]), steps=d["steps"], tau=d["tau"], n_eff=d["n_eff"],
                           acceptance=d["acceptance_fraction"], long_enough=d["long_enough"],
                           interval_width_95=widths, goal="<= 3 s per region"))
        log(region, "emcee", d["time_s"], widths)
        if quick:  # one region: the hamon region's fits are timed by the float32 comparison's reference
            break
    c0 = section("region fits, solvers, emcee", c0)

    # ---- per-pixel throughput (200-point pixels), float64, vs per-pixel optimistix LM
    P = 2000 if quick else 10000
    terms, Y, chi, mu, nm = _pixels(P, jnp.float64)
    r = fit_pixels(Y, terms, noise=nm)
    c0 = time.process_time()
    t = timeit(lambda: fit_pixels(Y, terms, noise=nm), repeats=3 if quick else 5, warmup=0)
    cpu_per_call = (time.process_time() - c0) / t["repeats"]  # CPU seconds: robust on a shared machine
    # reference: optimistix LM per pixel (vmapped, capped at 200 steps) on a subset
    Pref = 500
    Yr = jnp.asarray(Y[:Pref])
    Wr = 1.0 / nm.sigma(Yr)
    from jkatana.fit._model import ModelSpec

    spec = ModelSpec("hiraji")
    vsolve = jax.jit(jax.vmap(lambda y, w: solve(terms, y, w, closed_form_start(terms, y, w, spec), spec=spec,
                                                 solver="lm")))
    ref = vsolve(Yr, Wr)
    t_ref = timeit(lambda: vsolve(Yr, Wr), repeats=1 if quick else 3)
    pref = np.asarray(ref["p"])
    err_mu = np.abs(np.log(r["mu"][:Pref]) - pref[:, 1])
    err_s = np.abs(np.log(r["scale"][:Pref]) - pref[:, 0])
    rows.append(record(B, dict(method="fit_pixels float64 (closed form + 4 damped GN steps)", pixels=P,
                               points_per_pixel=200), time_s=t, fits_per_s=P / t["median"],
                       stragglers=r["n_stragglers"],
                       error=dict(max_abs_log_mu=float(np.max(err_mu)), max_abs_log_scale=float(np.max(err_s)),
                                  median_rel_mu_vs_truth=float(np.median(np.abs(r["mu"] / mu - 1)))),
                       reference="optimistix LM per pixel (vmapped, max 200 steps)", goal=">= 50000 fits/s"))
    rows.append(record(B, dict(method="optimistix LM per pixel, vmapped, from closed form", pixels=Pref),
                       time_s=t_ref, fits_per_s=Pref / t_ref["median"]))
    log("pixels", P / t["median"], "fits/s wall,", P / cpu_per_call, "per CPU-s; LM ref", Pref / t_ref["median"])

    c0 = section("pixels", c0)

    # ---- float32 (subprocess started first, x64 off)
    stdout, stderr = f32_proc.communicate()
    log("float32 subprocess wall (beside the main process)", time.perf_counter() - t_f32)
    line = [ln for ln in stdout.splitlines() if ln.startswith("JSON")]
    if f32_proc.returncode != 0 or not line:
        rows.append(record(B, dict(method="float32 (subprocess)"), failed=stderr[-1500:]))
        return rows
    f32 = json.loads(line[0][4:])
    cpu["float32 subprocess"] = round(f32.pop("cpu_s"), 2)
    ref = fit_region(_campaign("hamon", seed=1), per_incidence=False, irls=False)
    for key, v in f32.items():
        if key == "pixels":
            continue
        vals = v["values"]
        err = {n: (abs(vals[n] / ref.values[n] - 1) if vals[n] is not None and math.isfinite(vals[n]) else None)
               for n in ref.values}
        rows.append(record(B, dict(method=f"float32 region fit {key}", region="hamon"), time_s=v["time_s"],
                           error=dict(rel=err), converged_verdict=v["converged"], reasons=v["reasons"],
                           reference="float64 LM"))
        log("float32", key, err, v["converged"])
    px = f32["pixels"]
    terms, Y, chi, mu, nm = _pixels(px["P"], jnp.float64)  # the same pixels the float32 worker fitted
    r64 = fit_pixels(Y, terms, noise=nm)
    m32 = np.asarray(px["mu"])
    rel = np.abs(m32 / r64["mu"] - 1)
    conv = np.asarray(px["converged"])
    rows.append(record(B, dict(method="fit_pixels float32", pixels=px["P"]), fits_per_s=px["fits_per_s"],
                       stragglers=px["stragglers"],
                       error=dict(max_rel_mu_converged=float(np.max(rel[conv])) if conv.any() else None,
                                  n_off_10pct=int(np.sum(rel > 0.1)),
                                  n_off_10pct_flagged=int(np.sum((rel > 0.1) & ~conv))),
                       reference="fit_pixels float64"))
    log("float32 pixels", px["fits_per_s"], float(np.max(rel)))
    section("float32 comparison (this process)", c0)

    # ---- the region fit with JAX's default pool (one thread per core), after the float32 process has ended
    proc = subprocess.run([sys.executable, "-c", "from benchmarks.bench_fit import _default_pool_worker as w; "
                           f"w(quick={quick})"], capture_output=True, text=True, timeout=600,
                          env={**os.environ, XLA_ENV: "all"})
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("JSON")]
    if proc.returncode != 0 or not line:
        rows.append(record(B, dict(method="region fit, JAX's default thread pool (subprocess)"),
                           failed=proc.stderr[-1500:]))
    else:
        one = {r["case"]["model"]: r for r in rows
               if r["case"].get("model") and r["case"].get("method", "").endswith("region fit after compilation")}
        for model, v in json.loads(line[0][4:]).items():
            ref = one.get(model, {}).get("start_and_solve_time_s", {}).get("median")
            rows.append(record(B, dict(method=f"lobe {model}: region fit after compilation, JAX's default pool",
                                       model=model), start_and_solve_time_s=v["time_s"],
                               start_and_solve_cpu_mean_s=v["cpu_mean_s"], steps=v["steps"], xla_threads="all",
                               one_thread_over_default=(ref / v["time_s"]["median"]) if ref else None,
                               load_avg_1min=os.getloadavg()[0],
                               note="one pool thread per core, as in a process that also renders; the records "
                                    "above use the fit commands' one-thread pool"))
            log("default pool", model, v["time_s"]["median"], v["cpu_mean_s"])
    rows.append(record(B, dict(method="CPU seconds per section", quick=quick), cpu_s=cpu,
                       load_avg_1min=os.getloadavg()[0],
                       note="process CPU time: the wall time of each section on an idle machine is about this "
                            "(compilation is single-threaded); the CLI subprocesses are not included"))
    return rows
