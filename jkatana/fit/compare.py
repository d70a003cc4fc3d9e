"""Model comparison on one table: every lobe, per-incidence χ²/dof, AIC/BIC and leave-one-incidence-out error.

"Does this model hold at large incidence?" answered per model. For each model
of :data:`jkatana.fit._model.FIT_MODELS` (or a chosen subset) the same table
is fitted with the same weights (:func:`jkatana.fit.region.fit_region`), and

- χ²/dof overall and per incidence (the global fit's residuals);
- AIC = χ² + 2k and BIC = χ² + k ln n (Akaike 1974, "A new look at the
  statistical model identification", IEEE TAC 19, 716–723; Schwarz 1978,
  "Estimating the dimension of a model", Ann. Stat. 6, 461–464), with
  −2 ln L = χ² + const for Gaussian errors of the given σ; k counts the fitted
  parameters;
- leave-one-incidence-out prediction error: the model is refitted on the other
  incidences and predicts the held-out one; the error is the held-out χ² per
  point (cross-validation by groups, Stone 1974, "Cross-validatory choice and
  assessment of statistical predictions", JRSS B 36, 111–147). Every fold is
  one ``vmap`` of one compiled solver.

The selected model is the most parsimonious one with ΔAIC ≤ 4
(:func:`choose_aic`) and, separately, by the one-standard-error rule on the
leave-one-incidence-out error (:func:`choose_loio`): a lobe that nests
another (GTR nests GGX at γ = 2) wins only when the data ask for it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.fit._model import MODELS
from jkatana.fit.solve import residuals


def _loio(fit, *, solver: str = "lm", max_steps: int = 200) -> list[float]:
    """Held-out χ² per point for each incidence (refit on the others by the region fit's own compiled program, as
    the fit's per-incidence refits, :func:`jkatana.fit.quality.per_incidence`)."""
    from jkatana.fit.uncertainty import refit_each

    data, spec = fit.data, fit.spec
    w = jnp.asarray(fit.weight)
    y = jnp.asarray(np.where(data.usable, data.value, 0.0), w.dtype)
    masks = np.stack([np.isclose(data.theta_i_deg, inc) & data.usable for inc in data.incidences])
    W_train = w[None, :] * jnp.asarray(~masks, w.dtype)
    outs = refit_each(fit.terms, y, W_train, jnp.asarray(fit.p, w.dtype), spec=spec, solver=solver,
                      max_steps=max_steps)
    W_test = w[None, :] * jnp.asarray(masks, w.dtype)
    r = jax.vmap(lambda p, wk: residuals(p, (fit.terms, y, wk, spec)))(outs["p"], W_test)
    r = np.asarray(r, np.float64)
    return [float(np.sum(r[g] ** 2) / max(1, masks[g].sum())) for g in range(masks.shape[0])]


def compare_models(data, models=None, *, setup=None, **fit_kwargs) -> dict:
    """Fit every model to ``data`` (:class:`~jkatana.fit.region.FitData`) and compare (module docstring).

    Returns a dict: ``models`` (one row each: name, k, χ², χ²/dof, AIC, BIC,
    ΔAIC, ΔBIC, per-incidence χ²/dof, leave-one-incidence-out errors and
    their mean, converged, values), ``incidences``, ``best_aic``, ``best_bic``,
    ``best_loio``.
    """
    from jkatana.fit.region import Setup, fit_region

    models = list(MODELS if models is None else models)
    setup = Setup() if setup is None else setup
    fit_kwargs.setdefault("robust", False)
    rows = []
    for m in models:
        fit = fit_region(data, model=m, setup=setup, **fit_kwargs)
        n = int(fit.diagnostics["n_points"])
        k = fit.spec.size
        chi2 = 2.0 * float(fit.diagnostics["cost"])
        loio = _loio(fit, solver=fit_kwargs.get("solver", "lm"), max_steps=fit_kwargs.get("max_steps", 200))
        rows.append(dict(model=m, k=k, n=n, chi2=chi2, chi2_dof=fit.diagnostics["chi2_dof"],
                         aic=chi2 + 2 * k, bic=chi2 + k * math.log(n),
                         per_incidence_chi2_dof=[r["chi2_dof"] for r in fit.per_incidence],
                         loio=loio, loio_mean=float(np.mean(loio)),
                         loio_se=float(np.std(loio, ddof=1) / math.sqrt(len(loio))) if len(loio) > 1 else 0.0,
                         converged=bool(fit.converged),
                         values=fit.values, time_s=fit.diagnostics.get("time_s")))
    for key in ("aic", "bic"):
        best = min(r[key] for r in rows)
        for r in rows:
            r["d" + key] = r[key] - best
    incs = [float(x) for x in data.incidences]
    ks = {r["model"]: r["k"] for r in rows}
    return dict(models=rows, incidences=incs,
                best_aic=choose_aic({r["model"]: r["aic"] for r in rows}, ks),
                best_bic=min(rows, key=lambda r: r["bic"])["model"],
                best_loio=choose_loio({r["model"]: r["loio_mean"] for r in rows},
                                      {r["model"]: r["loio_se"] for r in rows}, ks),
                lowest_aic=min(rows, key=lambda r: r["aic"])["model"])


def write_comparison(result: dict, out_dir) -> Path:
    """``compare.md`` (table), ``compare.json`` and ``compare.png`` (per-incidence χ²/dof and held-out error)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jkatana.fit.params import _clean
    from jkatana.io.atomic import atomic_path, write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    incs = result["incidences"]
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
    for i, r in enumerate(result["models"]):
        ax[0].plot(incs, r["per_incidence_chi2_dof"], "o-", color=f"C{i}", label=r["model"])
        ax[1].plot(incs, r["loio"], "s--", color=f"C{i}", label=r["model"])
    for a, t in zip(ax, ("χ²/dof of the global fit, per incidence", "held-out χ² per point (leave one incidence out)")):
        a.set_yscale("log")
        a.axhline(1.0, color="0.5", lw=0.8, ls=":")
        a.set_xlabel("incidence θi (°)")
        a.set_title(t, fontsize=9)
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(out / "compare.png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    lines = ["# Model comparison", "",
             f"Selected by AIC (fewest parameters within ΔAIC ≤ {AIC_MARGIN:g}): **{result['best_aic']}** "
             f"(lowest AIC: {result['lowest_aic']}), by BIC: **{result['best_bic']}**, "
             f"by leave-one-incidence-out (one-SE rule): **{result['best_loio']}**.", "",
             "| model | k | χ²/dof | ΔAIC | ΔBIC | LOIO mean | converged | "
             + " | ".join(f"χ²/dof {a:g}°" for a in incs) + " |",
             "|---|---|---|---|---|---|---|" + "---|" * len(incs)]
    for r in result["models"]:
        lines.append(f"| {r['model']} | {r['k']} | {r['chi2_dof']:.4g} | {r['daic']:.4g} | {r['dbic']:.4g} | "
                     f"{r['loio_mean']:.4g} | {r['converged']} | "
                     + " | ".join(f"{v:.3g}" for v in r["per_incidence_chi2_dof"]) + " |")
    lines += ["", "![per-incidence quality](compare.png)", ""]
    md = out / "compare.md"
    write_text(md, "\n".join(lines))
    write_text(out / "compare.json", json.dumps(_clean(result), indent=2) + "\n")
    return md


__all__ = ["compare_models", "write_comparison"]


def select_batch(terms_by_model: dict, Y, W, incidence_masks, *, solver: str = "lm") -> dict:
    """Model selection for many campaigns at once (same geometry): AIC and leave-one-incidence-out per campaign.

    `terms_by_model`: ``{model: Terms}`` (:func:`jkatana.fit._model.prepare`);
    `Y`, `W`: ``(C, n)`` values and weights 1/σ of C campaigns;
    `incidence_masks`: ``(G, n)`` booleans, one row per incidence.
    Returns ``{"aic", "loio", "loio_se", "converged": {model: (C,)}, "k": {model: int}}``; every
    model is one ``vmap`` over campaigns (and folds) of one compiled solver.
    """
    from jkatana.fit._model import ModelSpec
    from jkatana.fit.uncertainty import _refits

    Y = jnp.asarray(Y)
    W = jnp.asarray(W, Y.dtype)
    M = jnp.asarray(np.asarray(incidence_masks), Y.dtype)
    out = {"aic": {}, "loio": {}, "converged": {}}
    for model, terms in terms_by_model.items():
        spec = ModelSpec(model)
        k = spec.size
        p_hat = jnp.zeros(k, Y.dtype)
        fits = jax.vmap(lambda y, w: _refits(terms, y, w[None, :], p_hat, spec=spec, solver=solver))(Y, W)
        p = fits["p"][:, 0]
        cost = np.asarray(fits["cost"][:, 0])
        out["aic"][model] = 2.0 * cost + 2 * k
        out["converged"][model] = np.isfinite(cost) & np.asarray(fits["solver_ok"][:, 0])

        def folds(y, w, p0):
            tr = _refits(terms, y, w[None, :] * (1.0 - M), p0, spec=spec, solver=solver)
            r = jax.vmap(lambda q, m: residuals(q, (terms, y, w * m, spec)))(tr["p"], M)
            return jnp.sum(r * r, axis=1) / jnp.maximum(jnp.sum(M, axis=1), 1.0)

        loio = np.asarray(jax.vmap(folds)(Y, W, p))
        out["loio"][model] = loio.mean(axis=1)
        out.setdefault("loio_se", {})[model] = loio.std(axis=1, ddof=1) / math.sqrt(loio.shape[1])
        out.setdefault("k", {})[model] = k
    return out


#: ΔAIC within which the model with fewer parameters is preferred (Burnham & Anderson 2002, §2.6).
AIC_MARGIN = 4.0


def choose_aic(aic: dict, k: dict, margin: float = AIC_MARGIN) -> str:
    """The model with the fewest parameters among those within ``margin`` of the lowest AIC (then lowest AIC).

    Burnham & Anderson (2002), *Model Selection and Multimodel Inference*,
    §2.6: models with ΔAIC ≤ 2 have substantial support, 4–7 considerably
    less. A nested model with one extra parameter beats the true, simpler one
    by ΔAIC > 4 only when the likelihood-ratio statistic exceeds 6 (1.4 % of
    campaigns), where the bare lowest AIC picks it in 16 %.
    """
    best = min(aic.values())
    ok = [m for m in aic if aic[m] <= best + margin]
    return min(ok, key=lambda m: (k[m], aic[m]))


def choose_loio(mean: dict, se: dict, k: dict) -> str:
    """One-standard-error rule (Breiman et al. 1984, *Classification and Regression Trees*, §3.4.3):
    the model with the fewest parameters whose held-out error is within one standard error (over
    incidences) of the best."""
    best = min(mean, key=mean.get)
    ok = [m for m in mean if mean[m] <= mean[best] + se[best]]
    return min(ok, key=lambda m: (k[m], mean[m]))


__all__ += ["select_batch", "choose_aic", "choose_loio", "AIC_MARGIN"]
