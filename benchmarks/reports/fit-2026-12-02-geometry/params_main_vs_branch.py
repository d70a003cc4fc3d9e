"""Fitted parameters of every lobe on bench_fit's and the tests' campaigns (seeds 0-2): p, SE of p, steps, converged."""
import json, sys
import jax; jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np
from benchmarks.bench_fit import _lobe_campaign, LOBE_TRUTH
from jkatana.fit import FitData, Setup, fit_region
from jkatana.fit._model import ModelSpec, from_natural, green, prepare, MODELS
from jkatana.measure.protocol import Protocol, as_pairs
setup = Setup(); n, k = setup.nk()
pairs = np.asarray(as_pairs(Protocol()), np.float64)
out = {}
for model in MODELS:
    for seed in range(3):
        for src in ("bench", "tests"):
            if src == "bench":
                data = _lobe_campaign(model, seed)
            else:
                spec = ModelSpec(model)
                terms = prepare(model, pairs[:, 0], pairs[:, 1], n, k, setup.weights())
                m = np.asarray(green(jnp.asarray(from_natural(LOBE_TRUTH[model], spec)), terms, spec))
                sig = np.sqrt((0.05 * m) ** 2 + (1e-3 * m.max()) ** 2)
                y = m + sig * np.random.default_rng(100 + seed).standard_normal(m.size)
                data = FitData(pairs[:, 0], pairs[:, 1], y, sig)
            f = fit_region(data, model=model, per_incidence=False, robust=False)
            cov = np.asarray(f.laplace["cov_log"])
            out[f"{model}/{src}/{seed}"] = dict(p=f.p.tolist(), se=np.sqrt(np.diag(cov)).tolist(), steps=f.diagnostics["steps"], converged=f.converged)
json.dump(out, open(sys.argv[1], "w"), indent=1)
