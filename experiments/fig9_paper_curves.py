"""The paper's Fig. 9 from its fitted parameters: both models against receiving angle.

Mochizuki et al. fit eq. (1) (hiraji: χ = 79000, μ0 = 0.05) and eq. (2)
(hamon: β = 43000, μ1 = 0.05) to the camera's green channel at incidences
15°, 25°, …, 65° and plot value against receiving angle (their Fig. 9). This
script draws the same curves from jkatana's models with iron's optical
constants (Johnson & Christy 1974 by default):

- solid: the **green-band value** in camera units, ρ = (C/E) @ w with
  w = E s Δλ / Σ E s Δλ (``jkatana.measure.camera.band_weights``; D65 source,
  the measured green channel of colour-science's "Nikon 5100 (NPL)" camera,
  as the paper's Canon 40D curve is not public);
- dotted: the same model at the single wavelength 550 nm, for comparison.

Markers show the specular angle θr = θi and the half maximum predicted by the
paper's D: facet angle φ = ±μ, i.e. θr = θi ± 2μ. Writes
``experiments/output/fig9_paper_curves.png``.

Run: ``python experiments/fig9_paper_curves.py [--out DIR] [--table Fe-Querry]``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from jkatana.io.atomic import atomic_path  # noqa: E402
from jkatana.models import Conductor, Hamon, Hiraji, in_plane, paper_models  # noqa: E402
from jkatana.spectral import DEFAULT_GRID  # noqa: E402

INCIDENCES_DEG = (15, 25, 35, 45, 55, 65)
OUT_DIR = Path(__file__).resolve().parent / "output"


def curves(table: str = "Fe-Johnson", n_angles: int = 1801):
    """Model values against receiving angle θr ∈ [0°, 90°] for each incidence.

    **Returns:** ``(theta_r_deg, {incidence: {"hiraji"|"hamon": {"green": (n,), "550": (n,)}}})``.
    """
    from jkatana.measure.camera import band_weights, green_sensitivity
    from jkatana.spectral import illuminant

    grid = DEFAULT_GRID
    cond = Conductor.from_table(table, grid)
    w = jnp.asarray(band_weights(illuminant("D65", grid), green_sensitivity(grid), grid))
    i550 = int(np.argmin(np.abs(grid.wavelengths - 550.0)))
    hiraji, hamon = paper_models()
    theta_r = np.linspace(0.0, 90.0, n_angles)

    @jax.jit
    def evaluate(theta_i):
        L, V = in_plane(jnp.full(theta_r.shape, theta_i), jnp.asarray(np.deg2rad(theta_r)))
        out = {}
        for name, model in (("hiraji", hiraji), ("hamon", hamon)):
            c = model.camera(L, V, cond)
            out[name] = {"green": c @ w, "550": c[:, i550]}
        return out

    result = {}
    for ti in INCIDENCES_DEG:
        result[ti] = jax.tree_util.tree_map(np.asarray, evaluate(jnp.asarray(math.radians(ti))))
    return theta_r, result


def plot(theta_r, result, path: Path, *, table: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), sharey=False, constrained_layout=True)
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, len(INCIDENCES_DEG)))
    titles = {"hiraji": "hiraji, eq. (1): χ = 79000, μ0 = 0.05",
              "hamon": "hamon, eq. (2): β = 43000, μ1 = 0.05"}
    mu = {"hiraji": Hiraji().mu, "hamon": Hamon().mu}
    for ax, name in zip(axes, ("hiraji", "hamon")):
        for colour, ti in zip(colours, INCIDENCES_DEG):
            g = result[ti][name]["green"]
            ax.plot(theta_r, g, color=colour, lw=1.6, label=f"θi = {ti}°")
            ax.plot(theta_r, result[ti][name]["550"], color=colour, lw=0.9, ls=":")
            peak = float(g.max())
            ax.plot([ti], [np.interp(ti, theta_r, g)], "o", color=colour, ms=3.5)
            dth = math.degrees(2 * float(mu[name]))
            ax.plot([ti - dth, ti + dth], [peak / 2, peak / 2], "|", color=colour, ms=9, mew=1.4)
        ax.set_title(titles[name])
        ax.set_xlabel("receiving angle θr (°)")
        ax.set_ylabel("camera green value ρg (camera units)")
        ax.set_xlim(0, 90)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    diff = max(float(np.max(np.abs(result[ti][m]["550"] / np.maximum(result[ti][m]["green"], 1e-300) - 1.0)
                                   [result[ti][m]["green"] > 0.01 * result[ti][m]["green"].max()]))
               for ti in INCIDENCES_DEG for m in ("hiraji", "hamon"))
    axes[1].legend(loc="upper left", fontsize=8, title_fontsize=8,
                   title=f"solid: green band; dotted: 550 nm\n(550 nm within {100 * diff:.1f} % of the band)")
    fig.suptitle(f"Paper's Fig. 9 from its fitted parameters (iron: {table}); "
                 "dots: specular θr = θi, bars: θi ± 2μ (facet angle ±μ, the predicted half maximum)",
                 fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)
    return path


def main(argv: list[str] | None = None, out_dir: Path | str | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default=None, help=f"output folder (default {OUT_DIR})")
    p.add_argument("--table", default="Fe-Johnson", help="optical constants: Fe-Johnson or Fe-Querry")
    p.add_argument("--angles", type=int, default=1801, help="receiving-angle samples over 0–90°")
    args = p.parse_args([] if argv is None else argv)
    out = Path(args.out or out_dir or OUT_DIR)
    theta_r, result = curves(args.table, args.angles)
    path = plot(theta_r, result, out / "fig9_paper_curves.png", table=args.table)
    for ti in INCIDENCES_DEG:
        h, t = result[ti]["hiraji"]["green"], result[ti]["hamon"]["green"]
        print(f"θi = {ti:2d}°: hiraji peak {h.max():8.0f} at θr = {theta_r[h.argmax()]:.2f}°, "
              f"hamon peak {t.max():8.0f} at θr = {theta_r[t.argmax()]:.2f}°", file=sys.stderr)
    print(path)
    return path


if __name__ == "__main__":
    main(sys.argv[1:])
