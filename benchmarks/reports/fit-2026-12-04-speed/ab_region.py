"""Region fit per call after compilation, in ONE process, A and B alternated in rounds (2 shared cores):

A = the base's call pattern: ``solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec)`` (two compiled
    programs, two dispatches; their code is unchanged on the branch);
B = the branch's ``fit_program(terms, y, w, spec)`` (start and solve in one program, what fit_region calls).

bench_fit's campaigns (1188 points), seeds cycled; per round and variant: process CPU per call (ms) over
REPEATS calls and the wall median; the 1-minute load. Also checks that both return the same vector.
Run from the checkout: .venv/bin/python benchmarks/reports/fit-2026-12-04-speed/ab_region.py [models...]
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
from jkatana.fit._model import MODELS  # noqa: E402
from jkatana.fit._solve import fit_program, solve, start_vector  # noqa: E402
from jkatana.fit.region import fit_region  # noqa: E402

REPEATS = int(os.environ.get("REPEATS", 200))
ROUNDS = int(os.environ.get("ROUNDS", 3))
SEEDS = 4


def measure(fn, cases):
    for c in cases:
        jax.block_until_ready(fn(*c))
    walls = []
    c0 = time.process_time()
    for i in range(REPEATS):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*cases[i % len(cases)]))
        walls.append(time.perf_counter() - t0)
    return (time.process_time() - c0) / REPEATS * 1e3, float(np.median(walls)) * 1e3


A = lambda terms, y, w, spec: solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec)  # noqa: E731
B = lambda terms, y, w, spec: fit_program(terms, y, w, spec)  # noqa: E731
models = sys.argv[1:] or list(MODELS)
for model in models:
    cases = []
    for seed in range(SEEDS):
        data = _lobe_campaign(model, seed=seed)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        cases.append((ref.terms, jnp.asarray(data.value), jnp.asarray(ref.weight), ref.spec))
    a, b = A(*cases[0]), B(*cases[0])
    same = np.array_equal(np.asarray(a["p"]), np.asarray(b["p"]))
    steps = [int(B(*c)["steps"]) for c in cases]
    for r in range(ROUNDS):
        for name, fn in (("A", A), ("B", B)) if r % 2 == 0 else (("B", B), ("A", A)):
            cpu, wall = measure(fn, cases)
            print(f"{model:9s} round {r} {name}: cpu {cpu:.3f} ms/call  wall median {wall:.3f} ms  "
                  f"load {os.getloadavg()[0]:.2f}", flush=True)
    print(f"{model:9s} LM steps per seed {steps}; A and B the same vector: {same}", flush=True)
