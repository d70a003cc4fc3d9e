"""Region fit per lobe on bench_fit's seed-0 campaigns (start_vector, solve, both; after compilation).

Run from a checkout with PYTHONPATH set to it (alternated between the base and the branch for the A/B):
``REPEATS=30 python ab_region_fit.py [model ...]``. Prints the wall-clock median/min (ms) of the start, the
solve from it and both, the process CPU per call of both (ms, over the same number of calls in a row), the
LM steps, the fitted vector and the 1-minute load."""
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks._harness import block, timeit  # noqa: E402
from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit._solve import solve, start_vector  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

reps = int(os.environ.get("REPEATS", 30))
for model in sys.argv[1:] or ["hiraji", "hamon", "beckmann", "ggx", "gtr", "two-lobe"]:
    data = _lobe_campaign(model)
    ref = fit_region(data, model=model, per_incidence=False, robust=False)
    y, w = jnp.asarray(data.value), jnp.asarray(ref.weight)
    terms, spec = ref.terms, ref.spec
    p0 = start_vector(terms, y, w, spec)
    out = solve(terms, y, w, p0, spec=spec)
    both = lambda: solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec)  # noqa: E731
    ts = timeit(lambda: start_vector(terms, y, w, spec), repeats=reps)
    t = timeit(lambda: solve(terms, y, w, p0, spec=spec), repeats=reps)
    tf = timeit(both, repeats=reps)
    c0 = time.process_time()
    for _ in range(reps):
        block(both())
    cpu = (time.process_time() - c0) / reps
    print(f"{model:9s} start {ts['median']*1e3:.3f} solve {t['median']*1e3:.3f} both {tf['median']*1e3:.3f}/"
          f"{tf['min']*1e3:.3f} cpu {cpu*1e3:.3f} steps {int(out['steps'])} p {np.asarray(out['p'])} "
          f"load {os.getloadavg()[0]:.2f}", flush=True)
