"""Fitted parameters of the two-lobe model (or the lobes named after the output file) on bench_fit's and the
tests' campaigns, seeds 0-9: p, SE of p, χ², steps, converged. Run on the base and on the branch, then
``python params_base_vs_branch.py --compare base.json branch.json``."""
import json
import sys

import numpy as np

if sys.argv[1] == "--compare":
    a, b = (json.load(open(f)) for f in sys.argv[2:4])
    worst = 0.0
    for key in a:
        d = np.abs(np.asarray(a[key]["p"]) - np.asarray(b[key]["p"])) / np.asarray(a[key]["se"])
        worst = max(worst, float(d.max()))
        print(f"{key:22s} steps {a[key]['steps']:3d} -> {b[key]['steps']:3d}  converged {a[key]['converged']}/"
              f"{b[key]['converged']}  chi2 {a[key]['chi2']:.6f} / {b[key]['chi2']:.6f}  max|dp|/SE {d.max():.2e}")
    print("worst max|dp|/SE", worst, "total steps", sum(v["steps"] for v in a.values()), "->",
          sum(v["steps"] for v in b.values()))
    sys.exit()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

from benchmarks.bench_fit import LOBE_TRUTH, _lobe_campaign  # noqa: E402
from jkatana.fit import FitData, Setup, fit_region  # noqa: E402
from jkatana.fit._model import ModelSpec, from_natural, green, prepare  # noqa: E402
from jkatana.measure.protocol import Protocol, as_pairs  # noqa: E402

setup = Setup()
n, k = setup.nk()
pairs = np.asarray(as_pairs(Protocol()), np.float64)
out = {}
for model in sys.argv[2:] or ["two-lobe"]:
    for seed in range(10):
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
            out[f"{model}/{src}/{seed}"] = dict(p=f.p.tolist(), se=np.sqrt(np.diag(cov)).tolist(),
                                                steps=int(f.diagnostics["steps"]), converged=bool(f.converged),
                                                chi2=2.0 * float(f.diagnostics["cost"]))
json.dump(out, open(sys.argv[1], "w"), indent=1)
