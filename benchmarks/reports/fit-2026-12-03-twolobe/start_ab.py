"""Two-lobe start A/B: the default-weight start (grid of 3 sharp widths, haze ratio 10, weight 0.9; re-created here
as old_start) vs start_vector (fitted weight): LM steps, convergence, cost, max |dp|/SE on 4 truths x 12 seeds."""
import sys, os
import jax; jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np
from benchmarks.bench_fit import _lobe_campaign
from benchmarks._harness import timeit
from jkatana.fit import FitData, Setup
from jkatana.fit.region import fit_region
from jkatana.fit._model import ModelSpec, from_natural, green, prepare, to_natural
from jkatana.fit._solve import solve, start_vector, grid_start, _log_quadratic, MOMENT_FACTORS, verdict
from jkatana.models.lobes import Gaussian
from jkatana.measure.protocol import Protocol, as_pairs
spec = ModelSpec("two-lobe")

@jax.jit
def old_start(terms, y, w):
    p_cf, good = _log_quadratic(terms, y, w, False, False)
    mu = jnp.exp(p_cf[1])
    sigma = Gaussian(mu, jnp.ones_like(mu), normalised=False).reflected_width()
    lobe = spec.fit_model.build(jnp.concatenate([p_cf[1:2], jnp.asarray([np.log(9.0), np.log(9.0)])]))
    width = mu * sigma / lobe.first.reflected_width()
    lo, hi, n = MOMENT_FACTORS
    return grid_start(terms, y, w, spec, mus=width * jnp.geomspace(lo, hi, n))

setup = Setup(); nk = setup.nk(); W = setup.weights()
def camp(truth, seed, protocol):
    pairs = np.asarray(as_pairs(protocol), np.float64)
    terms = prepare("two-lobe", pairs[:, 0], pairs[:, 1], nk[0], nk[1], W)
    m = np.asarray(green(jnp.asarray(from_natural(truth, spec)), terms, spec))
    sig = np.sqrt((0.05 * m) ** 2 + (1e-3 * m.max()) ** 2)
    y = m + sig * np.random.default_rng(seed).standard_normal(m.size)
    return terms, jnp.asarray(y), jnp.asarray(1 / sig)
from jkatana.measure.protocol import paper_protocol
truths = [dict(scale=2000.0, alpha=0.03, alpha_haze=0.3, weight=0.8), dict(scale=2000.0, alpha=0.02, alpha_haze=0.5, weight=0.95),
          dict(scale=2000.0, alpha=0.05, alpha_haze=0.2, weight=0.5), dict(scale=2000.0, alpha=0.01, alpha_haze=0.05, weight=0.7)]
import collections
tot = collections.defaultdict(lambda: [0, 0, 0, 0.0])
for ti, truth in enumerate(truths):
    for seed in range(12):
        terms, y, w = camp(truth, 100 + seed, paper_protocol())
        o = solve(terms, y, w, old_start(terms, y, w), spec=spec); n = solve(terms, y, w, start_vector(terms, y, w, spec), spec=spec)
        se = np.sqrt(np.diag(np.linalg.inv(np.asarray(o["jtj"]))))
        d = float(np.max(np.abs(np.asarray(n["p"]) - np.asarray(o["p"])) / se))
        t = tot[ti]; t[0] += int(o["steps"]); t[1] += int(n["steps"]); t[2] += (verdict(o)[0], verdict(n)[0]) != (True, True); t[3] = max(t[3], d)
        print(ti, seed, int(o["steps"]), int(n["steps"]), verdict(o)[0], verdict(n)[0], f"{float(o['cost']):.5f} {float(n['cost']):.5f} {d:.1e}", flush=True)
for ti, t in tot.items(): print("truth", ti, truths[ti], "steps old/new", t[0], t[1], "not both converged", t[2], "max dp/SE", t[3])

