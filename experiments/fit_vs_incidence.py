"""The paper's open question: does the fit degrade with incidence because of the model or the rig?

Mochizuki et al. (§6.1) observe that eqs. (3)–(4) fit well at small incidence
and diverge as incidence grows. On synthetic paper-protocol campaigns
(truth: the paper's parameters, Fe-Johnson optical constants, 2 % + 20-unit
noise) we fit each region

- with the right optical constants (Fe-Johnson) and the wrong ones (Fe-Querry),
- on a perfect rig and on a rig whose sample is tilted by 0.3°,
- with the paper's two parameters, and with the tilt as a free parameter,

and plot χ²/dof and the per-incidence refits of μ against incidence. A model
error (wrong n, k) and a rig error (tilt) leave different fingerprints, which
is what a user needs to tell them apart on real data.

Usage: python experiments/fit_vs_incidence.py  → experiments/output/fit_vs_incidence.{json,md,png}
and a full report for the tilted hamon case in experiments/output/fit_vs_incidence_report/.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from jkatana.fit import FitData, Setup, fit_region, sample, write_params  # noqa: E402
from jkatana.fit.report import write_report  # noqa: E402
from jkatana.measure import synthetic  # noqa: E402
from jkatana.measure.protocol import paper_protocol  # noqa: E402
from jkatana.measure.table import write_table  # noqa: E402

OUT = Path(__file__).parent / "output"
TILT = 0.3


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    noise = synthetic.NoiseModel(relative=0.02, absolute=20.0)
    results = []
    for region in ("hiraji", "hamon"):
        for tilt in (0.0, TILT):
            table, _ = synthetic.simulate_table(paper_protocol(), region, noise=noise, tilt_deg=tilt, seed=7)
            data = FitData.from_table(table, region)
            for oc in ("Fe-Johnson", "Fe-Querry"):
                for free_tilt in (False, True):
                    f = fit_region(data, setup=Setup(optical_constants=oc), tilt=free_tilt)
                    row = dict(region=region, sim_tilt_deg=tilt, fit_optical_constants=oc, free_tilt=free_tilt,
                               values=f.values, ci95=f.laplace["ci95"], converged=f.converged,
                               chi2_dof=f.diagnostics["chi2_dof"],
                               per_incidence=[dict(incidence_deg=r["incidence_deg"], chi2_dof=r["chi2_dof"],
                                                   rms_rel=r["rms_rel"], refit=r["refit"]) for r in f.per_incidence])
                    results.append(row)
                    print(region, tilt, oc, free_tilt, f.values, round(f.diagnostics["chi2_dof"], 2),
                          [round(r["chi2_dof"], 1) for r in f.per_incidence], file=sys.stderr, flush=True)
                    if region == "hamon" and tilt and oc == "Fe-Johnson":
                        name = "tilt_free" if free_tilt else "paper_model"
                        write_table(table, OUT / "fit_vs_incidence_hamon_tilted.csv")
                        f.emcee = sample(f, seed=0)
                        p = write_params(f, OUT / f"fit_vs_incidence_hamon_tilted_{name}.json",
                                         table_path="fit_vs_incidence_hamon_tilted.csv")
                        write_report(p, OUT / f"fit_vs_incidence_report_{name}")
    (OUT / "fit_vs_incidence.json").write_text(json.dumps(results, indent=1) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    for col, region in enumerate(("hiraji", "hamon")):
        for row in results:
            if row["region"] != region:
                continue
            inc = [r["incidence_deg"] for r in row["per_incidence"]]
            chi = [r["chi2_dof"] for r in row["per_incidence"]]
            mu = [r["refit"]["values"]["mu"] if r["refit"]["values"] else np.nan for r in row["per_incidence"]]
            lo = [r["refit"]["ci95"]["mu"][0] for r in row["per_incidence"]]
            hi = [r["refit"]["ci95"]["mu"][1] for r in row["per_incidence"]]
            label = (f"tilt {row['sim_tilt_deg']:g}°, fit {row['fit_optical_constants'][3:]}"
                     + (", tilt free" if row["free_tilt"] else ""))
            ls = "-" if row["fit_optical_constants"] == "Fe-Johnson" else ":"
            mk = "s" if row["free_tilt"] else "o"
            color = "C3" if row["sim_tilt_deg"] else "C0"
            if row["free_tilt"]:
                color = "C2" if row["sim_tilt_deg"] else "C9"
            axes[0, col].plot(inc, chi, ls, marker=mk, color=color, label=label, ms=4)
            off = (0.4 if row["free_tilt"] else -0.4) + (0.15 if ls == ":" else 0)
            mu = np.array(mu)
            axes[1, col].errorbar(np.array(inc) + off, mu, yerr=[mu - np.array(lo), np.array(hi) - mu], fmt=mk,
                                  ls=ls, color=color, ms=3, capsize=2, lw=0.8)
        axes[0, col].set_yscale("log")
        axes[0, col].axhline(1, color="0.5", lw=0.6, ls="--")
        axes[0, col].set_title(f"{region}: χ²/dof of the global fit per incidence", fontsize=9)
        axes[1, col].axhline(0.05, color="0.4", lw=0.6)
        axes[1, col].set_title(f"{region}: per-incidence refit of μ (95 %), truth 0.05", fontsize=9)
        axes[1, col].set_xlabel("incidence θi (°)")
    axes[0, 0].legend(fontsize=6.5)
    fig.tight_layout()
    fig.savefig(OUT / "fit_vs_incidence.png", dpi=110)

    lines = ["# Fit quality vs incidence: model (optical constants) or rig (tilt)?", "",
             "Synthetic paper-protocol campaigns, truth: paper parameters, Fe-Johnson, noise 2 % + 20 units.", "",
             "| region | sim tilt (°) | fit n,k | tilt free | χ²/dof | χ²/dof per incidence 15…65° | μ [95 %] | tilt [95 %] |",
             "|---|---|---|---|---|---|---|---|"]
    for r in results:
        mu_ci = r["ci95"]["mu"]
        per = ", ".join(f"{p['chi2_dof']:.1f}" for p in r["per_incidence"])
        t = (f"{r['values']['tilt_deg']:.3f} [{r['ci95']['tilt_deg'][0]:.3f}, {r['ci95']['tilt_deg'][1]:.3f}]"
             if r["free_tilt"] else "—")
        lines.append(f"| {r['region']} | {r['sim_tilt_deg']:g} | {r['fit_optical_constants']} | {r['free_tilt']} | "
                     f"{r['chi2_dof']:.2f} | {per} | "
                     f"{r['values']['mu']:.5f} [{mu_ci[0]:.5f}, {mu_ci[1]:.5f}] | {t} |")
    lines += ["", "![fit vs incidence](fit_vs_incidence.png)", ""]
    (OUT / "fit_vs_incidence.md").write_text("\n".join(lines))
    print(OUT / "fit_vs_incidence.md")


if __name__ == "__main__":
    main()
