"""Probe kept with its report (NOTES.md): run from the repository root with .venv/bin/python; models as arguments."""
import os, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np
import optimistix as optx, lineax as lx
sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign
import jkatana.fit._solve as S
from jkatana.fit.region import fit_region
R = int(os.environ.get("REPEATS", 200))
def cpu(fn, n=R):
    jax.block_until_ready(fn()); c0 = time.process_time()
    for _ in range(n): jax.block_until_ready(fn())
    return (time.process_time() - c0) / n * 1e3
orig = S._solver
def normal(name, rtol, atol):
    if name == "lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    return orig(name, rtol, atol)
VAR = {"qr": orig, "normal": normal}
models = sys.argv[1:]
for model in models:
    cases = []
    for seed in range(4):
        data = _lobe_campaign(model, seed)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        cases.append((ref.terms, jnp.asarray(data.value), jnp.asarray(ref.weight), ref.spec))
    res = {}
    for v in VAR:
        S._solver = VAR[v]; jax.clear_caches()
        outs = [S.fit_program(t, y, w, s) for t, y, w, s in cases]
        res[v] = outs
    S._solver = orig
    for i in range(4):
        a, b = res["qr"][i], res["normal"][i]
        print(model, i, "steps", int(a["steps"]), int(b["steps"]), "max|dp|", float(jnp.max(jnp.abs(a["p"] - b["p"]))),
              "dcost", float(b["cost"] - a["cost"]), "ok", bool(a["solver_ok"]), bool(b["solver_ok"]))
    times = {v: [] for v in VAR}
    for rnd in range(3):
        for v in (VAR if rnd % 2 == 0 else list(VAR)[::-1]):
            S._solver = VAR[v]; jax.clear_caches()
            for t, y, w, s in cases: jax.block_until_ready(S.fit_program(t, y, w, s)["p"])
            k = [0]
            def call():
                t, y, w, s = cases[k[0] % 4]; k[0] += 1
                return S.fit_program(t, y, w, s)["p"]
            times[v].append(cpu(call))
    S._solver = orig
    print(model, {v: [round(x, 3) for x in t] for v, t in times.items()}, "load %.1f" % os.getloadavg()[0], flush=True)
