"""Region fit after compilation on ten campaigns per lobe (bench_fit's, seeds 0–9), on a chosen XLA thread pool.

``JKATANA_XLA_THREADS`` (default 1, the fit commands' pool; ``all`` for JAX's default, one per core) sizes the
pool before JAX's backend starts (:func:`jkatana.runtime.xla_threads`).

bench_fit times seed 0 only; a lobe whose other campaigns need more LM steps can be slower. Per lobe and seed:
``fit_program`` (what ``fit_region`` calls), REPEATS calls after one compiled warm-up call, process CPU ms per
call. Run on an idle machine from the repository root:
``.venv/bin/python benchmarks/reports/fit-2026-12-05-pool/seeds.py [models...]``.
"""
import gc
import os
import sys
import time

sys.path.insert(0, os.getcwd())
from jkatana.runtime import xla_threads  # noqa: E402

POOL = os.environ.get("JKATANA_XLA_THREADS", "1")
xla_threads(POOL)
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit._model import MODELS  # noqa: E402
from jkatana.fit._solve import fit_program  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

REPEATS = int(os.environ.get("REPEATS", 100))
SEEDS = [int(s) for s in os.environ["SEED_LIST"].split(",")] if os.environ.get("SEED_LIST") else range(int(os.environ.get("SEEDS", 10)))

for model in sys.argv[1:] or list(MODELS):
    rows = []
    for seed in SEEDS:
        data = _lobe_campaign(model, seed)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        terms, spec = ref.terms, ref.spec
        y, w = jnp.asarray(data.value), jnp.asarray(ref.weight)
        out = fit_program(terms, y, w, spec)
        jax.block_until_ready(out["p"])
        if os.environ.get("GC_FIRST", "1") == "1":
            gc.collect()  # the earlier campaigns' garbage would be collected inside the timed loop
        c0, w0 = time.process_time(), time.perf_counter()
        for _ in range(REPEATS):
            jax.block_until_ready(fit_program(terms, y, w, spec)["p"])
        rows.append(((time.process_time() - c0) / REPEATS * 1e3, int(out["steps"]),
                     (time.perf_counter() - w0) / REPEATS * 1e3))
    ms = np.array([r[0] for r in rows])
    print(f"pool {POOL:3s} {model:9s} ms " + " ".join(f"{m:.3f}" for m in ms) + f" | steps " + " ".join(str(r[1]) for r in rows)
          + f" | median {np.median(ms):.3f} max {ms.max():.3f} | wall ms "
          + " ".join(f"{r[2]:.3f}" for r in rows) + f" | load {os.getloadavg()[0]:.2f}", flush=True)
