"""A look at a measurement table: value against receiving angle, per region and incidence.

One panel per region; one curve per incidence setting θi, with ±2σ error bars,
on a logarithmic value axis (the lobe spans several decades between the
specular peak and the tails). A second table (e.g. a simulation's
``truth.csv`` or a fit's prediction) is drawn as thin lines over it.
Rows with saturated photosites are marked with a red ×.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jkatana.io.atomic import atomic_path
from jkatana.measure.table import MeasurementTable



def _save(fig, path: str | Path, title: str | None) -> Path:
    """Optional suptitle, tight layout, atomic PNG write, close the figure."""
    import matplotlib.pyplot as plt

    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path

def plot_table(table: MeasurementTable, path: str | Path, *, overlay: MeasurementTable | None = None,
               overlay_label: str = "truth", title: str | None = None, log: bool = True) -> Path:
    """Write a PNG of ``table`` (module docstring); ``overlay`` is drawn as lines. Returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    regions = table.regions()
    fig, axes = plt.subplots(1, max(1, len(regions)), figsize=(6.2 * max(1, len(regions)), 4.6), squeeze=False)
    cmap = plt.get_cmap("viridis")
    incid = table.incidences()
    for ax, region in zip(axes[0], regions):
        for j, ti in enumerate(incid):
            sel = table.select(region=region, incidence_deg=ti)
            if not len(sel):
                continue
            order = np.argsort(sel.theta_r_deg)
            colour = cmap(j / max(1, len(incid) - 1))
            y = sel.value[order]
            ax.errorbar(sel.theta_r_deg[order], y, yerr=2 * sel.sigma[order], fmt="o", ms=2.2, lw=0.8,
                        color=colour, label=f"θi = {ti:g}°")
            sat = sel.n_saturated[order] > 0
            if sat.any():
                ax.plot(sel.theta_r_deg[order][sat], y[sat], "x", color="red", ms=6)
            if overlay is not None:
                ov = overlay.select(region=region, incidence_deg=ti)
                o = np.argsort(ov.theta_r_deg)
                ax.plot(ov.theta_r_deg[o], ov.value[o], "-", color=colour, lw=0.9, alpha=0.9)
        if log:
            positive = table.value[(table.region == region) & (table.value > 0)]
            if positive.size:
                ax.set_yscale("log")
                ax.set_ylim(max(positive.min() * 0.5, positive.max() * 1e-7), positive.max() * 2)
        ax.set_xlabel("receiving angle θr (degrees)")
        ax.set_ylabel("green value ρg (camera units)")
        ax.set_title(region + ("" if overlay is None else f"   (points: measured ±2σ, lines: {overlay_label})"),
                     fontsize=10)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="incidence", title_fontsize=7)
    return _save(fig, path, title)


def plot_residuals(table: MeasurementTable, reference: MeasurementTable, path: str | Path,
                   title: str | None = None) -> Path:
    """Normalised residuals (value − reference)/σ against θr, per region (rows matched by capture, region)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = {(c, r): v for c, r, v in zip(reference.capture, reference.region, reference.value)}
    regions = table.regions()
    fig, axes = plt.subplots(1, len(regions), figsize=(6.2 * len(regions), 3.6), squeeze=False)
    for ax, region in zip(axes[0], regions):
        sel = table.select(region=region)
        z = np.array([(v - ref[(c, region)]) / s if s > 0 else np.nan
                      for c, v, s in zip(sel.capture, sel.value, sel.sigma)])
        sc = ax.scatter(sel.theta_r_deg, z, c=sel.theta_i_deg, s=4, cmap="viridis")
        ax.axhline(0, color="k", lw=0.6)
        for k in (-2, 2):
            ax.axhline(k, color="grey", lw=0.5, ls="--")
        ax.set_xlabel("receiving angle θr (degrees)")
        ax.set_ylabel("(measured − reference) / σ")
        ok = np.isfinite(z)
        ax.set_title(f"{region}: χ²/n = {np.mean(z[ok] ** 2):.3f} over {ok.sum()} rows", fontsize=10)
        fig.colorbar(sc, ax=ax, label="θi (degrees)")
    return _save(fig, path, title)


__all__ = ["plot_table", "plot_residuals"]
