"""Probe kept with its report (NOTES.md): run from the repository root with .venv/bin/python; models as arguments."""
import os, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np
sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign
import jkatana.fit._solve as S
from jkatana.fit._model import green, default_shape
from jkatana.fit.region import fit_region

def grid_start_parab(terms, y, w, spec, mus=None):
    mus = jnp.asarray(mus, y.dtype)
    tail = jnp.zeros(int(spec.tilt) + int(spec.floor), y.dtype)
    def vec(log_s, log_mu):
        return jnp.concatenate([jnp.reshape(log_s, (1,)), default_shape(spec, log_mu, y.dtype), tail])
    def cost_at(mu):
        m1 = green(vec(jnp.zeros((), y.dtype), jnp.log(mu)), terms, spec)
        a = jnp.sum(m1 * y * w * w) / jnp.maximum(jnp.sum((m1 * w) ** 2), jnp.finfo(y.dtype).tiny)
        a = jnp.maximum(a, jnp.finfo(y.dtype).tiny)
        r = (a * m1 - y) * w
        return jnp.sum(r * r), jnp.log(a)
    costs, logs = jax.vmap(cost_at)(mus)
    costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
    i = jnp.argmin(costs)
    n = mus.shape[0]
    k = jnp.clip(i, 1, n - 2)
    x = jnp.log(mus)
    c0, c1, c2 = costs[k - 1], costs[k], costs[k + 1]
    h = x[k + 1] - x[k]
    den = c0 - 2 * c1 + c2
    t = jnp.where((den > 0) & (i == k) & jnp.isfinite(den), 0.5 * (c0 - c2) / den, 0.0)
    t = jnp.clip(t, -0.5, 0.5)
    lx = x[k] + t * h
    l0, l1, l2 = logs[k - 1], logs[k], logs[k + 1]
    ls = l1 + 0.5 * t * (l2 - l0) + 0.5 * t * t * (l2 - 2 * l1 + l0)
    use = (i == k)
    return vec(jnp.where(use, ls, logs[i]), jnp.where(use, lx, x[i]))

orig = S.grid_start
for model in sys.argv[1:]:
    tot = {"orig": 0, "parab": 0}
    for seed in range(10):
        data = _lobe_campaign(model, seed)
        ref = fit_region(data, model=model, per_incidence=False, robust=False)
        y, w = jnp.asarray(data.value), jnp.asarray(ref.weight)
        row = []
        for v, g in (("orig", orig), ("parab", grid_start_parab)):
            S.grid_start = g; jax.clear_caches()
            o = S.fit_program(ref.terms, y, w, ref.spec)
            tot[v] += int(o["steps"]); row.append((int(o["steps"]), float(o["cost0"]), float(o["cost"])))
        S.grid_start = orig
        print(model, seed, row, flush=True)
    print(model, tot)
