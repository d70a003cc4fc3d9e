"""Region fit per lobe after compilation: process CPU per call of start_vector + solve, LM steps, fitted vector.

Run from a checkout with PYTHONPATH set to it (alternated between the base and the branch for the A/B):
``REPEATS=200 SEEDS=10 python region_ab.py [model ...]`` (default gtr ggx). For each model, seeds 0..SEEDS-1 of
bench_fit's campaign (1188 points): after one compiling call, the process CPU (user+sys) per call of the start
plus the solve, averaged over REPEATS calls cycling through the seeds; the LM steps of the solve from the start
per seed and their sum; and the fitted vector of seed 0 (to show base and branch reach the same optimum).
"""
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks._harness import block  # noqa: E402
from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit._solve import solve, start_vector  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

reps, seeds = int(os.environ.get("REPEATS", 200)), int(os.environ.get("SEEDS", 10))
for model in sys.argv[1:] or ["gtr", "ggx"]:
    cases = []
    for s in range(seeds):
        data = _lobe_campaign(model, s)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        cases.append((ref.terms, jnp.asarray(data.value), jnp.asarray(ref.weight), ref.spec))
    steps, p_first = [], None
    for terms, y, w, spec in cases:
        out = solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec)
        steps.append(int(out["steps"]))
        p_first = np.asarray(out["p"]) if p_first is None else p_first
    c0 = time.process_time()
    for i in range(reps):
        terms, y, w, spec = cases[i % seeds]
        block(solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec))
    cpu = (time.process_time() - c0) / reps
    print(f"{model:9s} cpu/call {cpu * 1e3:.3f} ms  steps {sum(steps)} {steps}  p(seed 0) {p_first}  "
          f"load {os.getloadavg()[0]:.2f}", flush=True)
