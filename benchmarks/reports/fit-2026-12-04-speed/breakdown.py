"""Where one region fit's time goes, per lobe: start, solve, LM steps, one residual / Jacobian evaluation.

Process CPU per call (ms) over REPEATS calls after compilation; bench_fit's campaigns (seed 0, 1188 points).
Run: .venv/bin/python benchmarks/reports/fit-2026-12-04-speed/breakdown.py [models...]
"""
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit._model import MODELS, evaluation_point  # noqa: E402
from jkatana.fit._solve import _jac, residuals, solve, start_vector  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

REPEATS = int(os.environ.get("REPEATS", 200))


def cpu(fn, n=REPEATS):
    jax.block_until_ready(fn())
    c0 = time.process_time()
    for _ in range(n):
        jax.block_until_ready(fn())
    return (time.process_time() - c0) / n * 1e3


models = sys.argv[1:] or list(MODELS)
for model in models:
    data = _lobe_campaign(model)
    ref = fit_region(data, model=model, per_incidence=False, robust=False)
    y, w = jnp.asarray(data.value), jnp.asarray(ref.weight)
    terms, spec = ref.terms, ref.spec
    p0 = start_vector(terms, y, w, spec)
    out = solve(terms, y, w, p0, spec=spec)
    args = (terms, y, w, spec, evaluation_point(terms, spec))
    res = jax.jit(lambda p: residuals(p, args))
    jac = jax.jit(lambda p: _jac(p, args))
    both = lambda: solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec)  # noqa: E731
    t_both = cpu(both)
    t_start = cpu(lambda: start_vector(terms, y, w, spec))
    t_solve = cpu(lambda: solve(terms, y, w, p0, spec=spec))
    t_res = cpu(lambda: res(p0))
    t_jac = cpu(lambda: jac(p0))
    print(f"{model:9s} start+solve {t_both:.3f} ms  start {t_start:.3f}  solve {t_solve:.3f}  steps "
          f"{int(out['steps'])}  resid {t_res:.3f}  jac {t_jac:.3f}  cost0 {float(out['cost0']):.6g} cost "
          f"{float(out['cost']):.10g}  load {os.getloadavg()[0]:.2f}", flush=True)
