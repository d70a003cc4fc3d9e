"""Fitted vectors, LM steps and costs of fit_program on bench_fit's campaigns (every lobe, seeds 0-3) as JSON on
stdout, with the SE of each entry (Laplace, unit Birge), so two checkouts' optima can be compared in SE units.
Run from the checkout: .venv/bin/python benchmarks/reports/fit-2026-12-04-speed/params_dump.py > out.json"""
import json
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit._model import MODELS  # noqa: E402
from jkatana.fit._solve import fit_program, verdict  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

out = {}
for model in MODELS:
    for seed in range(4):
        data = _lobe_campaign(model, seed=seed)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        o = {k: np.asarray(v) for k, v in fit_program(ref.terms, jnp.asarray(data.value), jnp.asarray(ref.weight),
                                                      ref.spec).items()}
        out[f"{model}/{seed}"] = dict(p=o["p"].tolist(), se=np.sqrt(np.diag(np.linalg.inv(o["jtj"]))).tolist(),
                                      steps=int(o["steps"]), cost=float(o["cost"]), converged=verdict(o)[0],
                                      region_fit_p=ref.p.tolist())
print(json.dumps(out))
