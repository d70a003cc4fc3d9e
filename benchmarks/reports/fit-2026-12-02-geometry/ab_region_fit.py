"""Region fit per lobe (start_vector, solve, both; 30 repeats after compilation) on bench_fit's seed-0 campaigns.

Run from a checkout with PYTHONPATH set to it; alternated between main and the branch for the A/B."""
import sys, time, os
import jax; jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np
from benchmarks.bench_fit import _lobe_campaign
from benchmarks._harness import timeit
from jkatana.fit.region import fit_region
from jkatana.fit._solve import solve, start_vector
models = sys.argv[1:] or ["hiraji","hamon","beckmann","ggx","gtr","two-lobe"]
for model in models:
    data = _lobe_campaign(model)
    ref = fit_region(data, model=model, per_incidence=False, robust=False)
    y = jnp.asarray(data.value); w = jnp.asarray(ref.weight); terms, spec = ref.terms, ref.spec
    p0 = start_vector(terms, y, w, spec); out = solve(terms, y, w, p0, spec=spec)
    ts = timeit(lambda: start_vector(terms, y, w, spec), repeats=int(os.environ.get("REPEATS", 30)))
    t = timeit(lambda: solve(terms, y, w, p0, spec=spec), repeats=int(os.environ.get("REPEATS", 30)))
    tf = timeit(lambda: solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec), repeats=int(os.environ.get("REPEATS", 30)))
    print(f"{model:9s} start {ts['median']*1e3:.3f} solve {t['median']*1e3:.3f} both {tf['median']*1e3:.3f}/{tf['min']*1e3:.3f} steps {int(out['steps'])} p {np.asarray(out['p'])} load {os.getloadavg()[0]:.2f}", flush=True)
