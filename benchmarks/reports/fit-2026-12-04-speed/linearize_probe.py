"""Value + shape Jacobian of one lobe inside a compiled loop of N evaluations (µs per evaluation): the rule before
(f(q) and jacfwd(f)(q)), one jax.linearize, and vmap of jvp. Run from the checkout with model names."""
import os, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign
from jkatana.fit._model import _unit_value, evaluation_point
from jkatana.fit.region import fit_region
N=200
def cpu(fn, n=30):
    jax.block_until_ready(fn())
    c0 = time.process_time()
    for _ in range(n): jax.block_until_ready(fn())
    return (time.process_time() - c0) / n / N * 1e3
for model in sys.argv[1:]:
    data = _lobe_campaign(model)
    ref = fit_region(data, model=model, per_incidence=False, robust=False)
    terms, spec = ref.terms, ref.spec
    at = evaluation_point(terms, spec)
    p = jnp.asarray(ref.p); q = p[1:1+spec.n_shape]
    def loop(g):
        @jax.jit
        def run(q):
            def body(i, acc):
                a, b = g(q + 1e-9 * i)
                return acc + jnp.sum(a) + jnp.sum(b)
            return jax.lax.fori_loop(0, N, body, 0.0)
        return lambda: run(q)
    f = lambda q: _unit_value(q, terms, at, spec)
    cur = lambda q: (f(q), jax.jacfwd(f)(q))
    def lin(q):
        y, l = jax.linearize(f, q)
        return y, jax.vmap(l, out_axes=1)(jnp.eye(q.shape[0], dtype=q.dtype))
    def vj(q):
        ys, J = jax.vmap(lambda t: jax.jvp(f, (q,), (t,)), out_axes=(0, 1))(jnp.eye(q.shape[0], dtype=q.dtype))
        return ys[0], J
    for r in range(2):
        print(model, "current", round(cpu(loop(cur)),4), "linearize", round(cpu(loop(lin)),4), "vmap-jvp", round(cpu(loop(vj)),4), os.getloadavg()[0], flush=True)
