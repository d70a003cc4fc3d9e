"""Uncertainty that stays honest when the model is wrong: misfit flag, sandwich covariance, bootstrap, robust loss.

The Laplace interval (:func:`jkatana.fit.laplace.laplace`) is the curvature of
χ² under the assumption that the model is right and only noise remains. On
measured metal the model is not right (χ²/dof of 20–60), and then

- the **misfit flag** (:func:`misfit`) says so: χ²/dof above
  ``max(2, 1 + 5·sqrt(2/dof))`` (five standard deviations of χ²/dof under a
  correct model, and at least a factor 2);
- the **sandwich** covariance (:func:`sandwich`) is the covariance of the
  least-squares estimator under misspecification, H⁻¹ B H⁻¹ (Huber 1967,
  "The behavior of maximum likelihood estimates under nonstandard
  conditions", Proc. 5th Berkeley Symp.; White 1982, "Maximum likelihood
  estimation of misspecified models", Econometrica 50, 1–25). The bread H is
  the *full* Hessian of ½Σr² (Gauss–Newton JᵀJ plus Σ r ∇²r, which matters
  when residuals are systematic); the meat B = ŝ² JᵀJ, with the noise scale
  ŝ² estimated from local second differences of the residuals along θr
  within each incidence (Gasser, Sroka & Jennen-Steinmetz 1986, "Residual
  variance and residual pattern in nonlinear regression", Biometrika 73,
  625–633; :func:`difference_noise_scale`): the smooth systematic misfit
  cancels in the differences, the white noise does not. It
  describes how the fitted parameters would scatter over repeated campaigns
  on the same rig, around the parameters the model would give without noise
  (the pseudo-true values).
- the **bootstrap over incidences** (:func:`bootstrap_incidences`) resamples
  whole incidences with replacement and refits (the cluster bootstrap,
  Davison & Hinkley 1997, *Bootstrap Methods and their Application*, §3.8):
  percentile intervals that include how much the answer depends on which
  incidences were measured — wider than the sandwich when the misfit changes
  with incidence.
- a **robust loss** (:func:`irls_weights`: Huber 1964, ψ(r) = clip(r, ±c),
  c = 1.345; Cauchy, ψ(r) = r / (1 + (r/c)²), c = 2.385; the 95 %-efficiency
  constants of Holland & Welsch 1977) down-weights outlying captures by
  iteratively reweighted least squares.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.fit._model import ModelSpec, to_natural
from jkatana.fit.laplace import natural_intervals
from jkatana.fit.solve import fit_program, residuals, solve, verdict
from jkatana.fit.starts import start_vector

LOSSES = {"squared": None, "huber": 1.345, "cauchy": 2.385}


def misfit(chi2_dof: float, dof: int) -> dict:
    """The misfit flag (module docstring) as the parameter file stores it."""
    limit = max(2.0, 1.0 + 5.0 * math.sqrt(2.0 / max(1, dof)))
    flag = bool(chi2_dof > limit)
    note = (f"MISFIT: chi2/dof = {chi2_dof:.3g} > {limit:.3g}; the model does not describe the data within "
            "its noise. Laplace intervals describe noise only; use the robust (sandwich) or bootstrap intervals, "
            "and compare models (jkatana compare)." if flag else
            f"chi2/dof = {chi2_dof:.3g} (limit {limit:.3g}): consistent with the noise model")
    return dict(flag=flag, chi2_dof=float(chi2_dof), limit=float(limit), note=note)


def irls_weights(r, loss: str):
    """IRLS weights ψ(r)/r of a robust loss (module docstring); 1 for ``"squared"``."""
    c = LOSSES[loss]
    if c is None:
        return jnp.ones_like(r)
    a = jnp.abs(r)
    if loss == "huber":
        return jnp.where(a <= c, 1.0, c / jnp.maximum(a, c))
    return 1.0 / (1.0 + (r / c) ** 2)


@functools.partial(jax.jit, static_argnames=("spec",))
def _hessian_parts(p, terms, y, w, spec: ModelSpec):
    args = (terms, y, w, spec)
    J = jax.jacfwd(residuals)(p, args)
    H = jax.hessian(lambda q: 0.5 * jnp.sum(residuals(q, args) ** 2))(p)
    return J, H, residuals(p, args)


def difference_noise_scale(r, theta_i_deg, theta_r_deg, usable, azimuth_deg=None) -> tuple[float, int]:
    """Noise scale ŝ² of the residuals from local second differences along θr (Gasser et al. 1986).

    Within each incidence (and receiver azimuth), for consecutive points
    x₋, x, x₊ the pseudo-residual e = a r₋ + b r₊ − r with a = (x₊ − x)/(x₊ − x₋),
    b = (x − x₋)/(x₊ − x₋) removes any locally linear trend (the smooth
    systematic misfit) and keeps the white noise; ŝ² = mean(e² / (a² + b² + 1)).
    Returns ``(ŝ², number of pseudo-residuals)``.
    """
    r = np.asarray(r, np.float64)
    az = np.zeros_like(np.asarray(theta_i_deg, np.float64)) if azimuth_deg is None else np.asarray(azimuth_deg)
    total, count = 0.0, 0
    keys = np.unique(np.stack([np.round(theta_i_deg[usable], 6), np.round(az[usable], 6)], 1), axis=0)
    for inc, a_ in keys:
        m = usable & np.isclose(theta_i_deg, inc) & np.isclose(az, a_)
        o = np.argsort(theta_r_deg[m])
        x, y = theta_r_deg[m][o], r[m][o]
        if x.size < 3:
            continue
        span = x[2:] - x[:-2]
        ok = span > 0
        a = np.where(ok, (x[2:] - x[1:-1]) / np.where(ok, span, 1.0), 0.5)
        b = 1.0 - a
        e = a * y[:-2] + b * y[2:] - y[1:-1]
        total += float(np.sum(e * e / (a * a + b * b + 1.0)))
        count += e.size
    return (total / count if count else float("nan")), count


def sandwich(fit) -> dict:
    """Sandwich covariance and 95 % intervals of a :class:`~jkatana.fit.region.RegionFit` (module docstring)."""
    spec, terms = fit.spec, fit.terms
    w = np.asarray(fit.weight)
    y = np.where(fit.data.usable, fit.data.value, 0.0).astype(w.dtype)
    J, H, r = (np.asarray(a, np.float64) for a in _hessian_parts(fit.p.astype(w.dtype), terms, y, w, spec))
    s2, n_diff = difference_noise_scale(r, fit.data.theta_i_deg, fit.data.theta_r_deg, fit.data.usable,
                                        fit.data.azimuth_deg)
    jtj = J.T @ J
    reasons = []
    try:
        lam = np.linalg.eigvalsh(H)
        if not np.all(lam > 0):
            reasons.append("full Hessian not positive definite: Gauss-Newton bread used")
            H = jtj
        Hi = np.linalg.inv(H)
        cov = s2 * Hi @ jtj @ Hi
    except np.linalg.LinAlgError:
        cov = np.full_like(jtj, np.nan)
        reasons.append("singular Hessian")
    se, ci, ok = natural_intervals(fit.p, cov, spec)
    return dict(method="sandwich H^-1 (s2 J^T J) H^-1, s2 from second differences", ok=ok, noise_scale2=s2,
                n_differences=n_diff, cov_log=cov.tolist(), se=se, ci95=ci, reasons=reasons)


def refit_each(terms, y, W, p_hat, *, spec, solver="lm", max_steps=200) -> dict:
    """The fits of one table under each row of weights ``W`` ``(k, n)``, from the default start or, where it has
    no peak to measure, from ``p_hat`` (the whole table's optimum): :func:`_refits`' values, as k calls of the
    region fit's own compiled program (:func:`~jkatana.fit.solve.fit_program`) instead of a batched program
    compiled for them. Returns numpy arrays stacked over the rows."""
    outs = [fit_program(terms, y, wk, spec, fallback=p_hat, solver=solver, max_steps=max_steps)
            for wk in np.asarray(W)]
    return {k: np.stack([np.asarray(o[k]) for o in outs]) for k in outs[0]}


@functools.partial(jax.jit, static_argnames=("spec", "solver", "max_steps"))
def _refits(terms, y, W, p_hat, *, spec, solver="lm", max_steps=200):
    def one(wk):
        p0 = start_vector(terms, y, wk, spec, p_hat)
        p0 = jnp.where(jnp.all(jnp.isfinite(p0)), p0, p_hat)
        return solve(terms, y, wk, p0, spec=spec, solver=solver, max_steps=max_steps)

    return jax.vmap(one)(W)


def bootstrap_incidences(fit, n: int = 200, *, seed: int = 0, solver: str = "lm", max_steps: int = 200) -> dict:
    """Cluster bootstrap over incidences: percentile 95 % intervals of the natural parameters (module docstring).

    Each replicate draws as many incidences as the table has, with replacement,
    and refits with each point's weight multiplied by √(times its incidence
    was drawn) (the same compiled solver for every replicate: one ``vmap``).
    """
    data, spec = fit.data, fit.spec
    w = jnp.asarray(fit.weight)
    y = jnp.asarray(np.where(data.usable, data.value, 0.0), w.dtype)
    incs = data.incidences
    masks = np.stack([np.isclose(data.theta_i_deg, inc) & data.usable for inc in incs])
    rng = np.random.default_rng(seed)
    counts = np.stack([np.bincount(rng.integers(0, incs.size, incs.size), minlength=incs.size) for _ in range(n)])
    mult = counts @ masks.astype(np.float64)  # (n, points)
    W = w[None, :] * jnp.sqrt(jnp.asarray(mult, w.dtype))
    outs = {k: np.asarray(v) for k, v in _refits(fit.terms, y, W, jnp.asarray(fit.p, w.dtype), spec=spec,
                                                  solver=solver, max_steps=max_steps).items()}
    vals, n_ok = [], 0
    for i in range(n):
        o = {k: v[i] for k, v in outs.items()}
        ok, _ = verdict(o, np.dtype(w.dtype))
        if ok:
            n_ok += 1
            nat = to_natural(o["p"], spec)
            vals.append([nat[k] for k in spec.names])
    V = np.asarray(vals, np.float64).reshape(-1, len(spec.names))
    ci = ({k: [float(np.percentile(V[:, j], 2.5)), float(np.percentile(V[:, j], 97.5))]
           for j, k in enumerate(spec.names)} if n_ok >= 20 else {})
    sd = {k: float(np.std(V[:, j], ddof=1)) for j, k in enumerate(spec.names)} if n_ok >= 2 else {}
    return dict(method="cluster bootstrap over incidences, percentile", replicates=int(n), converged=int(n_ok),
                seed=int(seed), ci95=ci, sd=sd, ok=bool(n_ok >= 20))


__all__ = ["misfit", "sandwich", "bootstrap_incidences", "irls_weights", "difference_noise_scale", "LOSSES"]


def sandwich_batch(terms, Y, W, P, spec: ModelSpec, theta_i_deg, theta_r_deg, usable) -> tuple[np.ndarray, np.ndarray]:
    """Sandwich and Birge-scaled Laplace covariances for C campaigns of one geometry.

    ``Y``, ``W`` ``(C, n)`` values and weights, ``P`` ``(C, p)`` fitted vectors.
    Returns ``(cov_sandwich, cov_laplace)``, each ``(C, p, p)`` (same formulas
    as :func:`sandwich` and :func:`jkatana.fit.laplace.laplace`).
    """
    J, H, R = (np.asarray(a, np.float64) for a in jax.vmap(
        lambda p, y, w: _hessian_parts(p, terms, y, w, spec))(jnp.asarray(P), jnp.asarray(Y), jnp.asarray(W)))
    n_used = int(np.sum(usable))
    dof = max(1, n_used - spec.size)
    cs, cl = [], []
    for c in range(J.shape[0]):
        jtj = J[c].T @ J[c]
        s2, _ = difference_noise_scale(R[c], theta_i_deg, theta_r_deg, usable)
        Hc = H[c] if np.all(np.linalg.eigvalsh(H[c]) > 0) else jtj
        Hi = np.linalg.inv(Hc)
        cs.append(s2 * Hi @ jtj @ Hi)
        chi2_dof = float(np.sum(R[c] ** 2)) / dof
        cl.append(np.linalg.inv(jtj) * max(1.0, chi2_dof))
    return np.asarray(cs), np.asarray(cl)


__all__ += ["sandwich_batch"]
