"""Fit quality per incidence angle — the paper's open question (SPEC §4).

Mochizuki et al. report that the models fit well at small incidence and drift
as incidence grows, without saying whether the model or the rig is to blame.
For each incidence θi this module reports, for the *global* fit:

- ``chi2_dof``: Σ r²/n over that incidence's points (r the noise-weighted
  residual); ≈ 1 where the model and the noise model are right;
- ``rms_rel``: RMS of (model − data)/peak of that incidence (a unitless misfit);

and a *refit* of that incidence alone (same model and options) with its
Laplace 95 % intervals, so a drift of μ or of the scale with incidence is
visible with error bars. The refits share the full table's arrays with the
other incidences' weights set to 0, so they run the region fit's own compiled
program (:func:`jkatana.fit.uncertainty.refit_each`).
"""

from __future__ import annotations

import numpy as np

from jkatana.fit._model import to_natural
from jkatana.fit.laplace import laplace
from jkatana.fit.solve import verdict, weighted_residuals


def per_incidence(fit, *, solver: str = "lm", max_steps: int = 200, refit: bool = True) -> list[dict]:
    """Per-incidence quality and refits for a :class:`~jkatana.fit.region.RegionFit`."""
    data, spec, terms = fit.data, fit.spec, fit.terms
    w = np.asarray(fit.weight)
    y = np.where(data.usable, data.value, 0.0).astype(w.dtype)
    r = np.asarray(weighted_residuals(fit.p.astype(w.dtype), terms, y, w, spec))
    m = fit.model()
    incs = data.incidences
    masks = np.stack([np.isclose(data.theta_i_deg, inc) & data.usable for inc in incs])
    rows = []
    for inc, mk in zip(incs, masks):
        nk = int(mk.sum())
        peak = float(np.max(np.abs(data.value[mk]))) if nk else float("nan")
        rows.append(dict(incidence_deg=float(inc), n=nk,
                         chi2_dof=float(np.sum(r[mk] ** 2) / max(1, nk)),
                         rms_rel=float(np.sqrt(np.mean(((m[mk] - data.value[mk]) / peak) ** 2))) if nk else None,
                         max_abs_rel=float(np.max(np.abs(m[mk] - data.value[mk])) / peak) if nk else None))
    if not refit:
        return rows
    from jkatana.fit.uncertainty import refit_each

    # the region fit's own compiled program, once per incidence (as leave-one-incidence-out in jkatana.fit.compare)
    W = np.where(masks, w[None, :], 0.0)
    outs = refit_each(terms, y, W, fit.p.astype(w.dtype), spec=spec, solver=solver, max_steps=max_steps)
    for i, row in enumerate(rows):
        o = {k: v[i] for k, v in outs.items()}
        ok, reasons = verdict(o, np.dtype(w.dtype))
        lap = laplace(o["jtj"], float(o["cost"]), row["n"], o["p"], spec)
        ok = ok and lap["ok"]
        if not lap["ok"]:
            reasons.append("Laplace covariance is singular")
        finite = np.all(np.isfinite(o["p"]))
        row["refit"] = dict(values=to_natural(o["p"], spec) if finite else None, ci95=lap["ci95"],
                            se=lap["se"], chi2_dof=lap["chi2_dof"], converged=bool(ok), reasons=reasons)
    return rows


__all__ = ["per_incidence"]
