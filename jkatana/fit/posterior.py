"""emcee posterior of a region fit (Foreman-Mackey, Hogg, Lang, Goodman 2013, "emcee: The MCMC Hammer").

The log-probability is the fit's Gaussian likelihood −½Σr²/s² (r the
noise-weighted residuals, s² the same Birge factor max(1, χ²/dof) that
widened the Laplace covariance, so the two are comparable) with flat priors
on the log of the scale and of μ (scale-free) and on tilt and floor, inside
broad bounds. It is one jitted ``vmap`` over walkers, handed to emcee with
``vectorize=True`` (one Python call per ensemble step instead of one per
walker).

Chain length is driven by the integrated autocorrelation time τ (Goodman &
Weare 2010; emcee's ``get_autocorr_time``): the sampler runs in chunks until
N > 50 τ (emcee's recommendation) or ``max_steps``; burn-in is 2 max τ and
thinning τ/2. Reported: acceptance fraction, τ per parameter, the number of
effective samples, and whether the chain is long enough.
"""

from __future__ import annotations

import functools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.fit._model import green

Q = (2.5, 50.0, 97.5)


def log_prob_fn(fit):
    """Vectorised log-probability ``(walkers, p) → (walkers,)`` (jitted) for a RegionFit."""
    spec, terms = fit.spec, fit.terms
    w = jnp.asarray(fit.weight)
    y = jnp.asarray(np.where(fit.data.usable, fit.data.value, 0.0), w.dtype)
    scale2 = float(fit.laplace.get("covariance_scale", 1.0))
    p_hat = jnp.asarray(fit.p, w.dtype)
    lo = p_hat.at[0].add(-20.0).at[1].set(math.log(1e-5))
    hi = p_hat.at[0].add(20.0).at[1].set(math.log(1.5))
    for j in range(2, 1 + spec.n_shape):  # transformed shape parameters (logit / log-ratio)
        lo = lo.at[j].set(-20.0)
        hi = hi.at[j].set(20.0)
    if spec.tilt:
        lo = lo.at[spec.tilt_index].set(-0.3)
        hi = hi.at[spec.tilt_index].set(0.3)
    if spec.floor:
        j = spec.floor_index
        span = 10.0 * float(np.max(np.abs(fit.data.value[fit.data.usable]))) + 1.0
        lo = lo.at[j].set(-span)
        hi = hi.at[j].set(span)

    s2 = jnp.asarray(scale2, w.dtype)
    return lambda P: np.asarray(_log_prob(jnp.asarray(P, w.dtype), terms, y, w, lo, hi, s2, spec), np.float64)


@functools.partial(jax.jit, static_argnames="spec")
def _log_prob(P, terms, y, w, lo, hi, scale2, spec):
    """Module-level and jitted on array arguments: compiled once per (shape, spec), not per fit."""

    def one(p):
        r = (green(p, terms, spec) - y) * w
        lp = -0.5 * jnp.sum(r * r) / scale2
        inside = jnp.all((p > lo) & (p < hi))
        return jnp.where(inside & jnp.isfinite(lp), lp, -jnp.inf)

    return jax.vmap(one)(P)


def sample(fit, *, walkers: int = 32, chunk: int = 500, max_steps: int = 10000, min_steps: int = 1000,
           seed: int = 0, keep_samples: int = 4000) -> dict:
    """Run emcee around the fit's optimum; returns the summary dict stored in the parameter file.

    **Arguments:**

    - `fit`: a :class:`~jkatana.fit.region.RegionFit`.
    - `walkers`: ensemble size (≥ 2 × number of parameters).
    - `chunk`, `min_steps`, `max_steps`: the chain grows by ``chunk`` steps
      until N > 50 τ (and N ≥ ``min_steps``) or ``max_steps``.
    - `seed`: random seed. `keep_samples`: include up to this many thinned samples
      (natural units, for the corner plot); 0 for none.

    **Returns:** dict with ``names``, ``median``, ``mean``, ``sd`` and ``ci95``
    (natural units, 2.5/97.5 % quantiles), and ``diagnostics``: steps,
    burn-in, thin, acceptance fraction, τ, n_eff, ``converged`` (N > 50 τ),
    time.
    """
    import emcee

    t0 = time.perf_counter()
    spec = fit.spec
    ndim = spec.size
    walkers = max(walkers, 2 * ndim + 2)
    rng = np.random.default_rng(seed)
    cov = np.asarray(fit.laplace["cov_log"], np.float64)
    if not np.all(np.isfinite(cov)):
        cov = np.eye(ndim) * 1e-4
    p_hat = np.asarray(fit.p, np.float64)
    try:
        chol = np.linalg.cholesky(cov + 1e-18 * np.eye(ndim))
    except np.linalg.LinAlgError:
        chol = np.diag(np.sqrt(np.abs(np.diag(cov))) + 1e-6)
    P0 = p_hat + 0.5 * rng.standard_normal((walkers, ndim)) @ chol.T
    logp = log_prob_fn(fit)
    sampler = emcee.EnsembleSampler(walkers, ndim, logp, vectorize=True)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    state = P0
    tau = np.full(ndim, np.nan)
    steps = 0
    while steps < max_steps:
        state = sampler.run_mcmc(state, chunk, progress=False)
        steps += chunk
        tau = sampler.get_autocorr_time(tol=0, discard=min(steps // 4, 200))
        if steps >= min_steps and np.all(np.isfinite(tau)) and steps > 50 * np.max(tau):
            break
    tau_max = float(np.max(tau)) if np.all(np.isfinite(tau)) else float("nan")
    long_enough = bool(np.isfinite(tau_max) and steps > 50 * tau_max)
    burn = int(min(steps // 2, math.ceil(2 * tau_max))) if np.isfinite(tau_max) else steps // 2
    thin = max(1, int(tau_max // 2)) if np.isfinite(tau_max) else 1
    chain = sampler.get_chain(discard=burn, thin=thin, flat=True)
    nat = to_natural_samples(chain, spec)
    names = list(spec.names)
    q = np.percentile(nat, Q, axis=0)
    n_eff = float(walkers * (steps - burn) / tau_max) if np.isfinite(tau_max) else float("nan")
    acc = float(np.mean(sampler.acceptance_fraction))
    out = dict(
        names=names,
        median={n: float(q[1, i]) for i, n in enumerate(names)},
        mean={n: float(np.mean(nat[:, i])) for i, n in enumerate(names)},
        sd={n: float(np.std(nat[:, i])) for i, n in enumerate(names)},
        ci95={n: [float(q[0, i]), float(q[2, i])] for i, n in enumerate(names)},
        cov_log=np.cov(chain.T).reshape(ndim, ndim).tolist(),
        diagnostics=dict(walkers=walkers, steps=steps, burn_in=burn, thin=thin, acceptance_fraction=acc,
                         tau=[float(t) for t in tau], n_eff=n_eff, long_enough=long_enough,
                         rule="N > 50 tau", samples=int(chain.shape[0]),
                         time_s=time.perf_counter() - t0),
    )
    out["converged"] = bool(long_enough and 0.15 < acc < 0.9)
    if keep_samples:
        idx = np.linspace(0, nat.shape[0] - 1, min(keep_samples, nat.shape[0])).astype(int)
        out["samples"] = nat[idx].tolist()
    return out


def to_natural_samples(chain, spec) -> np.ndarray:
    """(n, p) log-space samples → natural units in ``spec.names`` order."""
    from jkatana.fit._model import to_natural

    chain = np.asarray(chain, np.float64)
    return np.array([[to_natural(row, spec)[n] for n in spec.names] for row in chain], np.float64).reshape(
        chain.shape[0], len(spec.names))


__all__ = ["sample", "log_prob_fn", "to_natural_samples"]
