"""Laplace intervals of a region's fit at its optimum (:mod:`jkatana.fit.solve`).

**Laplace.** cov(log-params) = s² (JᵀJ)⁻¹ at the optimum with
s² = max(1, χ²/dof) (Birge ratio: a noise model that is too optimistic for
real data widens the interval instead of lying), natural-unit standard errors
by the delta method and 95 % intervals from the normal in log space (so the
intervals of χ, β, μ stay positive).
"""

from __future__ import annotations

import math

import numpy as np

from jkatana.fit._model import ModelSpec

Z95 = 1.959963984540054


def natural_intervals(p, cov, spec: ModelSpec, z: float = Z95) -> tuple[dict, dict, bool]:
    """Natural-unit standard errors and intervals from a covariance of the fit vector.

    Each natural parameter v is a monotone function of one scalar u(p) that is
    close to normal: log v for positive parameters (scale, widths, the haze
    width), the logit for γ and the mixture weight, v itself for tilt and
    floor. The interval is v(u ± z·sd(u)) (so it stays inside the parameter's
    domain), sd(u)² = ∇uᵀ Σ ∇u (delta method), and the standard error is
    |dv/du|·sd(u). Returns ``(se, ci, ok)``.
    """
    p = np.asarray(p, np.float64)
    cov = np.asarray(cov, np.float64)
    ok = bool(np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0))
    fm = spec.fit_model
    from scipy.special import expit as sig
    exp = lambda t: math.exp(min(t, 700.0))  # noqa: E731
    items = [(fm.scale_name, np.eye(spec.size)[0], p[0], exp)]
    items.append((fm.names[0], np.eye(spec.size)[1], p[1], exp))
    if spec.model == "gtr":
        items.append(("gamma", np.eye(spec.size)[2], p[2], lambda t: 1.0 + 3.0 * sig(t)))
    if spec.model == "two-lobe":
        g = np.eye(spec.size)[1] + np.eye(spec.size)[2] * sig(p[2])
        items.append(("alpha_haze", g, p[1] + float(np.logaddexp(0.0, p[2])), exp))
        items.append(("weight", np.eye(spec.size)[3], p[3], sig))
    if spec.tilt:
        items.append(("tilt_deg", np.eye(spec.size)[spec.tilt_index], p[spec.tilt_index], math.degrees))
    if spec.floor:
        items.append(("floor", np.eye(spec.size)[spec.floor_index], p[spec.floor_index], lambda t: t))
    se, ci = {}, {}
    for name, g, u, f in items:
        sd = math.sqrt(abs(float(g @ cov @ g))) if ok else float("nan")
        lo, hi = (f(u - z * sd), f(u + z * sd)) if math.isfinite(sd) else (float("nan"), float("nan"))
        h = 1e-6 * max(1.0, abs(u))
        se[name] = float(abs(f(u + h) - f(u - h)) / (2 * h) * sd)
        ci[name] = [float(lo), float(hi)]
    return se, ci, ok


def laplace(jtj, cost: float, n_eff: int, p, spec: ModelSpec, *, birge: bool = True) -> dict:
    """Gauss–Newton covariance at the optimum, natural-unit errors and 95 % intervals (:func:`natural_intervals`)."""
    jtj = np.asarray(jtj, np.float64)
    p = np.asarray(p, np.float64)
    dof = max(1, n_eff - spec.size)
    chi2_dof = 2.0 * cost / dof
    scale = max(1.0, chi2_dof) if birge else 1.0
    try:
        cov = np.linalg.inv(jtj) * scale
    except np.linalg.LinAlgError:
        cov = np.full_like(jtj, np.nan)
    se, ci, ok = natural_intervals(p, cov, spec)
    return dict(ok=ok, names=list(spec.names), params=spec.log_names, cov_log=cov.tolist(), se=se, ci95=ci,
                chi2_dof=chi2_dof, covariance_scale=scale)


__all__ = ["Z95", "natural_intervals", "laplace"]
