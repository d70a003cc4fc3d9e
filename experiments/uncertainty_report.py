"""Calibration of jkatana's 95 % intervals: Laplace and emcee over many synthetic campaigns.

Each campaign is the paper's protocol (6 incidences, 1188 captures) simulated
with the paper's parameters and a camera noise model (2 % relative + a floor
of 20 camera units); the region is fitted (closed-form start, optimistix LM,
noise model estimated from the table), and we count how often the Laplace and
the emcee 95 % intervals contain the truth. Binomial standard error of a
coverage c over N campaigns: sqrt(c(1−c)/N) ≈ 1.5 % at N = 200.

Usage: python experiments/uncertainty_report.py [--campaigns 200] [--regions hiraji hamon] [--no-emcee]
Writes experiments/output/uncertainty_report.{json,md,png}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from jkatana.fit import FitData, fit_region, sample  # noqa: E402
from jkatana.measure import synthetic  # noqa: E402
from jkatana.measure.protocol import paper_protocol  # noqa: E402

OUT = Path(__file__).parent / "output"
TRUTH = {"hiraji": {"chi": 79000.0, "mu": 0.05}, "hamon": {"beta": 43000.0, "mu": 0.05}}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--campaigns", type=int, default=200)
    ap.add_argument("--regions", nargs="+", default=["hiraji", "hamon"])
    ap.add_argument("--no-emcee", action="store_true")
    ap.add_argument("--emcee-regions", nargs="+", default=None)
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    noise = synthetic.NoiseModel(relative=0.02, absolute=20.0)
    results = {}
    for region in args.regions:
        do_emcee = not args.no_emcee and (args.emcee_regions is None or region in args.emcee_regions)
        rec = {"laplace": {n: [] for n in TRUTH[region]}, "emcee": {n: [] for n in TRUTH[region]},
               "width_ratio": {n: [] for n in TRUTH[region]}, "converged": 0, "emcee_long_enough": 0,
               "emcee_time_s": [], "fit_time_s": []}
        t_start = time.perf_counter()
        for c in range(args.campaigns):
            table, _ = synthetic.simulate_table(paper_protocol(), region, noise=noise, seed=10_000 + c)
            t0 = time.perf_counter()
            f = fit_region(FitData.from_table(table, region), per_incidence=False)
            rec["fit_time_s"].append(time.perf_counter() - t0)
            rec["converged"] += int(f.converged)
            for n, v in TRUTH[region].items():
                lo, hi = f.laplace["ci95"][n]
                rec["laplace"][n].append(bool(lo <= v <= hi))
            if do_emcee:
                em = sample(f, seed=c, keep_samples=0)
                rec["emcee_time_s"].append(em["diagnostics"]["time_s"])
                rec["emcee_long_enough"] += int(em["diagnostics"]["long_enough"])
                for n, v in TRUTH[region].items():
                    elo, ehi = em["ci95"][n]
                    rec["emcee"][n].append(bool(elo <= v <= ehi))
                    lo, hi = f.laplace["ci95"][n]
                    rec["width_ratio"][n].append((ehi - elo) / (hi - lo))
            if (c + 1) % 20 == 0:
                print(f"{region}: {c + 1}/{args.campaigns} campaigns, {time.perf_counter() - t_start:.0f} s",
                      file=sys.stderr, flush=True)
        summary = {"campaigns": args.campaigns, "converged": rec["converged"],
                   "fit_time_median_s": float(np.median(rec["fit_time_s"]))}
        for method in ("laplace", "emcee"):
            summary[method] = {n: (float(np.mean(h)) if h else None) for n, h in rec[method].items()}
        if do_emcee:
            summary["emcee_long_enough"] = rec["emcee_long_enough"]
            summary["emcee_time_median_s"] = float(np.median(rec["emcee_time_s"]))
            summary["emcee_over_laplace_width"] = {n: float(np.median(v)) for n, v in rec["width_ratio"].items()}
        results[region] = summary
        print(json.dumps({region: summary}, indent=1), file=sys.stderr)
    previous = OUT / "uncertainty_report.json"
    if previous.exists():  # keep regions from an earlier run that this run did not redo
        old = json.loads(previous.read_text())
        results = {**{k: v for k, v in old.items() if k not in results}, **results}
        results = {k: results[k] for k in ("hiraji", "hamon") if k in results}
    (OUT / "uncertainty_report.json").write_text(json.dumps(results, indent=2) + "\n")
    lines = ["# Interval calibration (95 %) over synthetic paper-protocol campaigns", "",
             "| region | campaigns | converged | param | Laplace coverage | emcee coverage | emcee/Laplace width |",
             "|---|---|---|---|---|---|---|"]
    for region, s in results.items():
        for n in TRUTH[region]:
            em = s["emcee"][n]
            wr = (s.get("emcee_over_laplace_width") or {}).get(n)
            lines.append(f"| {region} | {s['campaigns']} | {s['converged']} | {n} | {s['laplace'][n]:.3f} | "
                         f"{'—' if em is None else f'{em:.3f}'} | {'—' if wr is None else f'{wr:.3f}'} |")
    (OUT / "uncertainty_report.md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    labels, lap, emc = [], [], []
    for region, s in results.items():
        for n in TRUTH[region]:
            labels.append(f"{region}\n{n}")
            lap.append(s["laplace"][n])
            emc.append(s["emcee"][n] if s["emcee"][n] is not None else np.nan)
    x = np.arange(len(labels))
    ax.bar(x - 0.18, lap, 0.36, label="Laplace")
    ax.bar(x + 0.18, emc, 0.36, label="emcee")
    ax.axhspan(0.93, 0.97, color="C2", alpha=0.2, label="93–97 % target")
    ax.axhline(0.95, color="k", lw=0.8)
    ax.set_ylim(0.85, 1.0)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylabel("coverage of the 95 % interval")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(OUT / "uncertainty_report.png", dpi=110)
    print(OUT / "uncertainty_report.md")


if __name__ == "__main__":
    main()
