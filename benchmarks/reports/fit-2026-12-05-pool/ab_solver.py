"""The solver's stopping tolerance and the moment start's widths, before and after, alternated in one process.

``before``: optimistix LM at rtol = atol = 1e-6 and the moment start over five widths (÷3 … ×3); ``after``: the
defaults now (1e-4, three widths ÷√3, 1, ×√3). Per lobe and seed (bench_fit's campaigns, seeds 0–9): wall µs of
``fit_program`` (the minimum over ROUNDS alternations of 100 calls), LM steps, the cost's change from ``before``
and the verdict with its largest Gauss–Newton decrement. On the fit commands' one-thread pool. Run from the
repository root: ``.venv/bin/python benchmarks/reports/fit-2026-12-05-pool/ab_solver.py [models,...]``.
"""
import functools
import gc
import os
import sys
import time

sys.path.insert(0, os.getcwd())
from jkatana.runtime import xla_threads  # noqa: E402

xla_threads(os.environ.get("JKATANA_XLA_THREADS", "1"))
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit import _solve  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

SOLVE, FACTORS = _solve.solve, _solve.MOMENT_FACTORS


def configure(name):
    if name == "before":
        _solve.solve = functools.partial(SOLVE, rtol=1e-6, atol=1e-6)
        _solve.MOMENT_FACTORS = (1.0 / 3.0, 3.0, 5)
    else:
        _solve.solve, _solve.MOMENT_FACTORS = SOLVE, FACTORS
    jax.clear_caches()


models = sys.argv[1].split(",") if len(sys.argv) > 1 else ["hiraji", "hamon", "beckmann", "ggx", "gtr", "two-lobe"]
seeds = range(10)
cases = {}
for model in models:
    for seed in seeds:
        data = _lobe_campaign(model, seed)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        cases[(model, seed)] = (ref.terms, ref.spec, jnp.asarray(data.value), jnp.asarray(ref.weight))
res = {}
for _ in range(int(os.environ.get("ROUNDS", 2))):
    for name in ("before", "after"):
        configure(name)
        for (model, seed), (terms, spec, y, w) in cases.items():
            out = _solve.fit_program(terms, y, w, spec)
            jax.block_until_ready(out["p"])
            gc.collect()
            t0 = time.perf_counter()
            for _ in range(100):
                jax.block_until_ready(_solve.fit_program(terms, y, w, spec)["p"])
            ok, _why = _solve.verdict(out)
            res.setdefault((name, model, seed), []).append(
                ((time.perf_counter() - t0) / 100 * 1e6, int(out["steps"]), float(out["cost"]), ok,
                 float(out["decrement"])))
for model in models:
    for name in ("before", "after"):
        rows = [res[(name, model, s)] for s in seeds]
        us = np.array([min(r[0] for r in rr) for rr in rows])
        steps = [rr[0][1] for rr in rows]
        dcost = max(abs(rr[0][2] - res[("before", model, s)][0][2]) for s, rr in zip(seeds, rows))
        print(f"{model:9s} {name:6s} wall us median {np.median(us):6.1f} max {us.max():6.1f} | LM steps {sum(steps):3d} "
              f"{steps} | |cost - before| max {dcost:.1e} | converged {sum(rr[0][3] for rr in rows)}/10 "
              f"decrement max {max(rr[0][4] for rr in rows):.1e}", flush=True)
