"""Process CPU time per region fit (start_vector then solve, as fit_region calls them), mean over 300 calls after
compilation, bench_fit's seed-0 campaigns: less sensitive than wall time to the other processes on a loaded machine.

Run from a checkout with PYTHONPATH set to it; alternated between main and the branch for the A/B."""
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit._solve import solve, start_vector  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

for model in sys.argv[1:] or ["hiraji", "hamon", "beckmann", "ggx", "gtr", "two-lobe"]:
    data = _lobe_campaign(model)
    ref = fit_region(data, model=model, per_incidence=False, robust=False)
    y, w, terms, spec = jnp.asarray(data.value), jnp.asarray(ref.weight), ref.terms, ref.spec

    def fit():
        return solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec)["p"].block_until_ready()

    fit()
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(300):
        fit()
    print(f"{model:9s} cpu/call {(time.process_time() - c0) / 300 * 1e3:.3f} ms  wall/call "
          f"{(time.perf_counter() - t0) / 300 * 1e3:.3f} ms  load {os.getloadavg()[0]:.2f}", flush=True)
