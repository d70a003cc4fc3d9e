"""The shape derivative's rule, A = jacfwd beside a separate primal call (the base), B = one jax.linearize (the
branch), in ONE process: the rule of jkatana.fit._model._shape_value is swapped, JAX's caches cleared and the
region fit program recompiled before each measurement; alternated in rounds. Process CPU ms per fit_program
call over REPEATS calls cycling over bench_fit's campaigns seeds 0-3, and the 1-minute load.
Run from the checkout: .venv/bin/python benchmarks/reports/fit-2026-12-04-speed/ab_jvp.py [models...]"""
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.fit import _model as M  # noqa: E402
from jkatana.fit._solve import fit_program  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

REPEATS = int(os.environ.get("REPEATS", 300))
ROUNDS = int(os.environ.get("ROUNDS", 4))
NEW = M._shape_jvp


def old_rule(spec, primals, tangents):
    q, terms, at = primals
    f = lambda q: M._unit_value(q, terms, at, spec)  # noqa: E731
    return f(q), jax.jacfwd(f)(q) @ tangents[0]


def use(rule):
    M._shape_value.defjvp(rule)
    jax.clear_caches()


for model in sys.argv[1:] or ["hiraji", "beckmann", "ggx", "gtr"]:
    cases = []
    for seed in range(4):
        data = _lobe_campaign(model, seed=seed)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        cases.append((ref.terms, jnp.asarray(data.value), jnp.asarray(ref.weight), ref.spec))
    ps = {}
    for r in range(ROUNDS):
        for name, rule in (("A", old_rule), ("B", NEW)) if r % 2 == 0 else (("B", NEW), ("A", old_rule)):
            use(rule)
            ps[name] = [np.asarray(fit_program(*c)["p"]) for c in cases]
            c0 = time.process_time()
            for i in range(REPEATS):
                jax.block_until_ready(fit_program(*cases[i % 4]))
            cpu = (time.process_time() - c0) / REPEATS * 1e3
            print(f"{model:9s} round {r} {name}: cpu {cpu:.3f} ms/call load {os.getloadavg()[0]:.2f}", flush=True)
    same = all(np.array_equal(a, b) for a, b in zip(ps["A"], ps["B"]))
    print(f"{model:9s} A and B the same vectors: {same}", flush=True)
use(NEW)
