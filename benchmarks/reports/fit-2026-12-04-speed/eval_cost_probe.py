"""Value, forward-mode Jacobian and residual Jacobian costs of one lobe inside a compiled loop (µs per evaluation)."""
import os, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign
from jkatana.fit._model import _unit_value, evaluation_point
from jkatana.fit._solve import solve, start_vector, residuals
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
    y, w = jnp.asarray(data.value), jnp.asarray(ref.weight)
    terms, spec = ref.terms, ref.spec
    at = evaluation_point(terms, spec)
    p = jnp.asarray(ref.p)
    q = p[1:1+spec.n_shape]
    args = (terms, y, w, spec, at)
    def loop(g):
        @jax.jit
        def run(q):
            def body(i, acc):
                return acc + jnp.sum(g(q + 1e-9 * i))
            return jax.lax.fori_loop(0, N, body, 0.0)
        return lambda: run(q)
    f = lambda q: _unit_value(q, terms, at, spec)
    print(model, "f", cpu(loop(f)))
    print(model, "jvp1", cpu(loop(lambda q: jnp.stack(jax.jvp(f, (q,), (jnp.ones_like(q),))))))
    print(model, "jacfwd(f)", cpu(loop(lambda q: jax.jacfwd(f)(q))))
    print(model, "resid", cpu(loop(lambda q: residuals(jnp.concatenate([p[:1], q, p[1+spec.n_shape:]]), args))))
    print(model, "jac resid", cpu(loop(lambda q: jax.jacfwd(residuals)(jnp.concatenate([p[:1], q, p[1+spec.n_shape:]]), args))))
    from jkatana.fit._model import green
    @jax.custom_jvp
    def rfun(p):
        return (green(p, terms, spec, at) - y) * w
    @rfun.defjvp
    def rjvp(primals, tangents):
        (p,), (t,) = primals, tangents
        s = jnp.exp(p[0]); qq = p[1:1+spec.n_shape]
        fq = lambda qq: _unit_value(qq, terms, at, spec)
        val, jf = fq(qq), jax.jacfwd(fq)(qq)
        J = jnp.concatenate([(s * val)[:, None], s * jf], axis=1) * w[:, None]
        return (s * val - y) * w, J @ t
    print(model, "jac custom resid", cpu(loop(lambda q: jax.jacfwd(rfun)(jnp.concatenate([p[:1], q, p[1+spec.n_shape:]])))))
