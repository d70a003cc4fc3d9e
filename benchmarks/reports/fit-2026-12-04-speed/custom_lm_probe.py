"""A hand-written Levenberg-Marquardt (normal equations, Cholesky, Nielsen damping, optimistix's Cauchy criterion)
against optimistix LM from the same start: optimum, steps and CPU per call. Tried, not kept (NOTES.md)."""
import os, sys, time, functools
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
sys.path.insert(0, os.getcwd())
from benchmarks.bench_fit import _lobe_campaign
from jkatana.fit._model import evaluation_point
from jkatana.fit._solve import solve, start_vector, residuals, _decrement
from jkatana.fit.region import fit_region

def lm(p0, args, rtol=1e-6, atol=1e-6, max_steps=200):
    def rj(p):
        def both(q):
            r = residuals(q, args); return r, r
        return jax.jacfwd(both, has_aux=True)(p)[::-1]
    r0, J0 = rj(p0)
    n = p0.shape[0]
    eye = jnp.eye(n, dtype=p0.dtype)
    def cond(s):
        return (~s["done"]) & (s["steps"] < max_steps)
    def body(s):
        p, r, J, lam, nu = s["p"], s["r"], s["J"], s["lam"], s["nu"]
        g = J.T @ r; A = J.T @ J
        d = jnp.diag(A)
        M = A + lam * jnp.diag(d)
        L = jnp.linalg.cholesky(M)
        delta = -jax.scipy.linalg.cho_solve((L, True), g)
        pn = p + delta
        rn, Jn = rj(pn)
        cost, costn = 0.5 * r @ r, 0.5 * rn @ rn
        pred = -(g @ delta + 0.5 * delta @ (A @ delta))
        rho = (cost - costn) / jnp.where(pred > 0, pred, 1.0)
        acc = jnp.isfinite(costn) & (costn <= cost) & (pred > 0) & (rho > 1e-4)
        ysc = atol + rtol * jnp.abs(pn); fsc = atol + rtol * jnp.abs(rn)
        term = acc & (jnp.max(jnp.abs(delta) / ysc) < 1) & (jnp.max(jnp.abs(rn - r) / fsc) < 1)
        lam_acc = lam * jnp.maximum(1/3, 1 - (2 * rho - 1) ** 3)
        return dict(p=jnp.where(acc, pn, p), r=jnp.where(acc, rn, r), J=jnp.where(acc, Jn, J),
                    lam=jnp.where(acc, lam_acc, lam * nu), nu=jnp.where(acc, 2.0, 2 * nu),
                    steps=s["steps"] + 1, done=term)
    s = dict(p=p0, r=r0, J=J0, lam=jnp.asarray(1e-3, p0.dtype), nu=jnp.asarray(2.0, p0.dtype), steps=jnp.asarray(0), done=jnp.asarray(False))
    s = jax.lax.while_loop(cond, body, s)
    return s, r0

@functools.partial(jax.jit, static_argnames=("spec",))
def solve2(terms, y, w, p0, spec):
    args = (terms, y, w, spec, evaluation_point(terms, spec))
    s, r0 = lm(p0, args)
    r, J = s["r"], s["J"]
    g = J.T @ r; jtj = J.T @ J
    return dict(p=s["p"], cost0=0.5 * r0 @ r0, cost=0.5 * r @ r, decrement=_decrement(jtj, g), steps=s["steps"], solver_ok=s["done"], jtj=jtj)

def cpu(fn, n=200):
    jax.block_until_ready(fn())
    c0 = time.process_time()
    for _ in range(n): jax.block_until_ready(fn())
    return (time.process_time() - c0) / n * 1e3
for model in sys.argv[1:]:
    data = _lobe_campaign(model)
    ref = fit_region(data, model=model, per_incidence=False, robust=False)
    y, w = jnp.asarray(data.value), jnp.asarray(ref.weight)
    terms, spec = ref.terms, ref.spec
    p0 = start_vector(terms, y, w, spec)
    a = solve(terms, y, w, p0, spec=spec); b = solve2(terms, y, w, p0, spec)
    se = np.sqrt(np.diag(np.linalg.inv(np.asarray(a["jtj"]))))
    print(model, "steps", int(a["steps"]), int(b["steps"]), "dp/se", np.abs(np.asarray(a["p"]) - np.asarray(b["p"])) / se, "cost", float(a["cost"]), float(b["cost"]), "dec", float(a["decrement"]), float(b["decrement"]), bool(b["solver_ok"]))
    for rnd in range(2):
        print(model, "optx", cpu(lambda: solve(terms, y, w, p0, spec=spec)), "custom", cpu(lambda: solve2(terms, y, w, p0, spec)), os.getloadavg()[0])
