"""Fit report: a Markdown page with PNG plots from a parameter file (and its table).

Plots (matplotlib, Agg):

- ``fit_per_incidence.png`` — measured vs model against the receiving angle,
  one panel per incidence (the layout of the paper's Fig. 9), log and linear;
- ``residuals.png`` — noise-weighted residuals vs receiving angle, per incidence;
- ``quality_vs_incidence.png`` — χ²/dof and RMS misfit per incidence, and the
  per-incidence refits of scale and μ with their 95 % intervals;
- ``corner.png`` — the emcee posterior (corner package, Foreman-Mackey 2016)
  with the Laplace 95 % intervals overlaid, when the file has an emcee section.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jkatana.errors import InputError


def _table_path(d: dict, params_path: Path, table=None) -> Path | None:
    if table is not None:
        return Path(table)
    t = (d.get("data") or {}).get("table")
    if not t:
        return None
    p = Path(t)
    if not p.is_absolute() and not p.exists():
        p = params_path.parent / p
    return p


def _refit_from_params(d: dict, table_path: Path):
    """Rebuild the fit's arrays (no solve) to plot the model at the file's values."""
    import math

    from jkatana.fit._model import ModelSpec, from_natural, prepare
    from jkatana.fit.region import Setup, default_model, load_fit_data

    data = load_fit_data(table_path, d["region"], (d.get("data") or {}).get("channel"))
    setup = Setup.from_dict(d)
    opts = d.get("options") or {}
    inst = opts.get("instrument")
    instrument = None if not inst else (math.radians(inst["source_radius_deg"]),
                                        math.radians(inst["aperture_radius_deg"]), int(inst["points"]))
    spec = ModelSpec(d.get("model") or default_model(d["region"]), bool(opts.get("tilt")), bool(opts.get("floor")),
                     instrument)
    n, k = setup.nk()
    terms = prepare(spec.model, data.theta_i_deg, data.theta_r_deg, n, k, setup.weights(),
                    azimuth_deg=data.azimuth_deg)
    p = from_natural(d["values"], spec)
    return data, spec, terms, p


def write_report(params_path, out_dir, *, table=None) -> Path:
    """Write ``out_dir/report.md`` and its PNGs; returns the Markdown path."""
    import json

    import matplotlib

    matplotlib.use("Agg")

    from jkatana.fit._model import SCALE_NAME, SHAPE_NAMES
    from jkatana.fit.params import read_params
    from jkatana.io.atomic import write_text

    params_path = Path(params_path)
    P = read_params(params_path)
    d = P.raw
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = _Figures(out)
    names = SCALE_NAME[P.model], SHAPE_NAMES[P.model][0]
    tpath = _table_path(d, params_path, table)
    if tpath is not None:
        if not tpath.exists():
            raise InputError("table named in the parameter file not found (pass --table)", path=tpath,
                             field="data.table")
        data, m, sig = _model_and_sigma(d, tpath)
        _plot_per_incidence(figs, P, data, m, sig)
        _plot_peak_zoom(figs, P, data, m, sig)
    rows = d.get("per_incidence") or []
    if rows:
        _plot_quality(figs, P, d, rows, names)
    em = d.get("emcee")
    if em and em.get("samples"):
        _plot_corner(figs, d, em)
    lines = _summary_lines(P, d) + _interval_lines(d) + _incidence_lines(rows, names)
    lines += [""] + [f"![{f}]({f})" for f in figs.names] + [""]
    md = out / "report.md"
    write_text(md, "\n".join(lines))
    write_text(out / "params.json", json.dumps(d, indent=2) + "\n")
    return md


class _Figures:
    """The report's PNGs: each written atomically into the report's folder, its name kept for the page."""

    def __init__(self, out: Path):
        self.out, self.names = out, []

    def save(self, fig, name: str, tight: bool = False) -> None:
        import matplotlib.pyplot as plt

        from jkatana.io.atomic import atomic_path

        with atomic_path(self.out / name) as tmp:
            fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight" if tight else None)
        plt.close(fig)
        self.names.append(name)


def _model_and_sigma(d: dict, tpath: Path):
    """The table's data, the model at the file's values and each point's σ: the table's per-row σ where the fit
    used it, else the file's noise model at the model."""
    import jax.numpy as jnp

    from jkatana.fit._model import green
    from jkatana.measure.noise import NoiseModel

    data, spec, terms, p = _refit_from_params(d, tpath)
    m = np.asarray(green(jnp.asarray(p), terms, spec))
    nz = (d.get("diagnostics") or {}).get("noise") or {}
    # the fitter uses a table's per-row σ when it has one; a file without diagnostics (written by the
    # API) therefore means the table's σ when the table has it
    if data.has_sigma and nz.get("sigma", "per-row (given)") == "per-row (given)":
        sig = np.where(data.usable, data.sigma, np.inf)
    else:
        noise = NoiseModel(**{k: nz[k] for k in ("relative", "absolute", "shot") if k in nz})
        sig = np.asarray(noise.sigma(jnp.asarray(m)))
    return data, m, sig


def _incidence(data, m, sig, inc):
    """One incidence's receiving angles, values, model and σ, in order of receiving angle."""
    mk = np.isclose(data.theta_i_deg, inc)
    o = np.argsort(data.theta_r_deg[mk])
    return data.theta_r_deg[mk][o], data.value[mk][o], m[mk][o], sig[mk][o]


def _plot_per_incidence(figs: _Figures, P, data, m, sig) -> None:
    """``fit_per_incidence.png`` (measured vs model, the paper's Fig. 9 layout, log inset) and ``residuals.png``."""
    import matplotlib.pyplot as plt

    incs = data.incidences
    ncol = min(3, len(incs))
    nrow = int(np.ceil(len(incs) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), squeeze=False)
    fig2, axes2 = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.0 * nrow), squeeze=False, sharey=True)
    for ax, ax2, inc in zip(axes.flat, axes2.flat, incs):
        tr, y, mm, sg = _incidence(data, m, sig, inc)
        ax.plot(tr, y, ".", ms=2.5, color="0.3", label="measured")
        ax.plot(tr, mm, "-", color="C3", lw=1.2, label="model")
        ax.set_title(f"θi = {inc:g}°", fontsize=9)
        ax.set_xlabel("receiving angle θr (°)", fontsize=8)
        ax.set_ylabel("green ρg", fontsize=8)
        pk = tr[np.argmax(mm)]
        ax.set_xlim(pk - 12, pk + 12)
        ins = ax.inset_axes([0.62, 0.55, 0.36, 0.4])
        ins.semilogy(tr, np.clip(y, 1e-3 * np.max(y), None), ".", ms=1, color="0.3")
        ins.semilogy(tr, np.clip(mm, 1e-3 * np.max(y), None), "-", color="C3", lw=0.8)
        ins.tick_params(labelsize=5)
        ax2.plot(tr, (mm - y) / sg, ".", ms=2, color="C0")
        ax2.axhline(0, color="k", lw=0.6)
        for s_ in (-2, 2):
            ax2.axhline(s_, color="0.6", lw=0.5, ls="--")
        ax2.set_title(f"θi = {inc:g}°", fontsize=9)
        ax2.set_xlabel("θr (°)", fontsize=8)
        ax2.set_ylabel("(model − data)/σ", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="upper left")
    for ax in list(axes.flat)[len(incs):] + list(axes2.flat)[len(incs):]:
        ax.axis("off")
    fig.suptitle(f"{P.region}: measured vs model ({P.model}, {P.optical_constants})", fontsize=10)
    fig.tight_layout()
    figs.save(fig, "fit_per_incidence.png")
    fig2.suptitle(f"{P.region}: normalised residuals (±2σ dashed)", fontsize=10)
    fig2.tight_layout()
    figs.save(fig2, "residuals.png")


def _plot_peak_zoom(figs: _Figures, P, data, m, sig) -> None:
    """``peak_zoom.png``: where the lobe lives, ±(4 widths, at least 1°) around each incidence's model peak,
    log scale, with the normalised residuals below."""
    import matplotlib.pyplot as plt

    incs = data.incidences
    half = max(1.0, 4.0 * float(np.degrees(P.mu)))
    fig3, axes3 = plt.subplots(2, len(incs), figsize=(3.0 * len(incs), 5.2), squeeze=False, sharex="col")
    for j, inc in enumerate(incs):
        tr, y, mm, sg = _incidence(data, m, sig, inc)
        pk = tr[np.argmax(mm)]
        z = np.abs(tr - pk) <= half
        top = max(float(np.max(np.abs(y[z]))) if z.any() else 1.0, 1e-300)
        a = axes3[0, j]
        a.semilogy(tr[z], np.clip(y[z], 1e-6 * top, None), ".", ms=3, color="0.3", label="measured")
        a.semilogy(tr[z], np.clip(mm[z], 1e-6 * top, None), "-", color="C3", lw=1.0, label="model")
        a.set_title(f"θi = {inc:g}°", fontsize=9)
        b = axes3[1, j]
        b.plot(tr[z], ((mm - y) / sg)[z], ".", ms=3, color="C0")
        b.axhline(0, color="k", lw=0.6)
        b.set_xlabel("θr (°)", fontsize=8)
    axes3[0, 0].set_ylabel("value (log)", fontsize=8)
    axes3[1, 0].set_ylabel("(model − data)/σ", fontsize=8)
    axes3[0, 0].legend(fontsize=7)
    fig3.suptitle(f"{P.region}: around the peak (±{half:.2g}°), model {P.model}", fontsize=10)
    fig3.tight_layout()
    figs.save(fig3, "peak_zoom.png")


def _plot_quality(figs: _Figures, P, d: dict, rows: list, names: tuple[str, str]) -> None:
    """``quality_vs_incidence.png``: χ²/dof and RMS misfit per incidence, and the per-incidence refits of the
    scale and the width with their 95 % intervals against the global fit's."""
    import matplotlib.pyplot as plt

    inc = np.array([r["incidence_deg"] for r in rows])
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.6))
    ax[0].plot(inc, [r["chi2_dof"] for r in rows], "o-")
    ax[0].axhline(1.0, color="0.5", lw=0.8, ls="--")
    ax[0].set_yscale("log")
    ax[0].set_xlabel("incidence θi (°)")
    ax[0].set_ylabel("χ²/dof of the global fit")
    ax0b = ax[0].twinx()
    ax0b.plot(inc, [r["rms_rel"] for r in rows], "s--", color="C1", ms=4)
    ax0b.set_ylabel("RMS misfit / peak", color="C1")
    for name, axj in zip(names, ax[1:]):
        _plot_refits(axj, d, rows, inc, name)
    fig.suptitle(f"{P.region}: fit quality and parameters vs incidence", fontsize=10)
    fig.tight_layout()
    figs.save(fig, "quality_vs_incidence.png")


def _plot_refits(axj, d: dict, rows: list, inc, name: str) -> None:
    """One parameter's per-incidence refits (95 %; the unconverged as crosses) over the global fit's band."""
    v = [((r.get("refit") or {}).get("values") or {}).get(name, np.nan) for r in rows]
    ci = [((r.get("refit") or {}).get("ci95") or {}).get(name, [np.nan, np.nan]) for r in rows]
    v = np.array(v, float)
    lo = np.array([c[0] if c[0] is not None else np.nan for c in ci], float)
    hi = np.array([c[1] if c[1] is not None else np.nan for c in ci], float)
    conv = np.array([bool((r.get("refit") or {}).get("converged")) for r in rows])
    axj.errorbar(inc[conv], v[conv], yerr=[v[conv] - lo[conv], hi[conv] - v[conv]], fmt="o", capsize=3,
                 label="per-incidence refit (95 %)")
    if (~conv).any():
        axj.plot(inc[~conv], v[~conv], "x", color="C3", label="refit NOT converged")
    gv = d["values"][name]
    glo, ghi = ((d.get("laplace") or {}).get("ci95") or {}).get(name) or (None, None)
    if glo is not None and ghi is not None:
        axj.axhspan(glo, ghi, color="C2", alpha=0.25)
    axj.axhline(gv, color="C2", lw=1, label="global fit (95 %)")
    axj.set_xlabel("incidence θi (°)")
    axj.set_ylabel(name)
    axj.legend(fontsize=7)


def _plot_corner(figs: _Figures, d: dict, em: dict) -> None:
    """``corner.png``: the emcee posterior (corner package, Foreman-Mackey 2016), Laplace 95 % overlaid."""
    import corner

    S = np.asarray(em["samples"], float)
    names = em["names"]
    fig = corner.corner(S, labels=names, quantiles=[0.025, 0.5, 0.975], show_titles=True,
                        title_fmt=".4g", title_kwargs=dict(fontsize=8))
    axes = np.array(fig.axes).reshape(len(names), len(names))
    for i, n in enumerate(names):
        lo, hi = ((d.get("laplace") or {}).get("ci95") or {}).get(n) or (None, None)
        if lo is not None and hi is not None:
            axes[i, i].axvspan(lo, hi, color="C2", alpha=0.2)
    fig.suptitle("emcee posterior (Laplace 95 % in green)", fontsize=9, y=1.0)
    figs.save(fig, "corner.png", tight=True)


def _num(x) -> str:
    return "—" if x is None else f"{x:.6g}"


def _summary_lines(P, d: dict) -> list[str]:
    """The page's title and the fit's summary: model, convergence, points, χ²/dof, noise, misfit flag."""
    diag = d.get("diagnostics") or {}
    mis = d.get("misfit") or {}
    lines = [f"# jkatana fit report — {P.region}", "",
             f"- model: **{P.model}** (lobe {(d.get('lobe') or {}).get('lobe', P.model)}), optical constants "
             f"**{P.optical_constants}**, camera {d.get('camera')}, light {d.get('light')}",
             f"- converged: **{P.converged}**" + ("" if P.converged else
                                                  " — " + "; ".join(diag.get("reasons", []))),
             f"- points: {diag.get('n_points', '—')}, χ²/dof = {_num(diag.get('chi2_dof'))}, "
             f"solver {diag.get('solver', '—')}, {diag.get('steps', '—')} steps",
             f"- noise model: {diag.get('noise', '—')}"]
    if mis:
        lines.append(f"- {'**' + mis['note'] + '**' if mis.get('flag') else mis.get('note')}")
    return lines


def _interval_lines(d: dict) -> list[str]:
    """Each parameter's value and its 95 % interval by every method the file holds; the emcee chain's health."""
    em = d.get("emcee")
    methods = [("Laplace", d.get("laplace")), ("robust (sandwich)", d.get("robust")),
               ("bootstrap", d.get("bootstrap")), ("emcee", em)]
    methods = [(k, v) for k, v in methods if v and v.get("ci95")]
    lines = ["", "| parameter | value | " + " | ".join(f"{k} 95 %" for k, _ in methods) + " |",
             "|---|---|" + "---|" * len(methods)]
    for name, v in d["values"].items():
        cells = []
        for _, m_ in methods:
            ci = m_["ci95"].get(name) or [None, None]
            cells.append(f"[{_num(ci[0])}, {_num(ci[1])}]")
        lines.append(f"| {name} | {_num(v)} | " + " | ".join(cells) + " |")
    if em:
        dg = em["diagnostics"]
        lines += ["", f"emcee: {dg['walkers']} walkers × {dg['steps']} steps, burn-in {dg['burn_in']}, "
                      f"thin {dg['thin']}, acceptance {dg['acceptance_fraction']:.2f}, "
                      f"τ = {[round(t, 1) for t in dg['tau']]}, n_eff ≈ {dg['n_eff']:.0f}, "
                      f"chain long enough (N > 50 τ): **{dg['long_enough']}**"]
    return lines


def _incidence_lines(rows: list, names: tuple[str, str]) -> list[str]:
    """The per-incidence table: points, χ²/dof, RMS misfit and the refits of the scale and the width."""
    if not rows:
        return []
    scale_name, width_name = names
    lines = ["", "## Per incidence", "",
             f"| θi (°) | n | χ²/dof | RMS/peak | refit {scale_name} [95 %] | refit {width_name} [95 %] | converged |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        rf = r.get("refit") or {}
        vals, ci = rf.get("values") or {}, rf.get("ci95") or {}

        def cell(nm):
            if nm not in vals:
                return "—"
            lo, hi = ci.get(nm, [None, None])
            return f"{vals[nm]:.5g} [{lo:.5g}, {hi:.5g}]" if lo is not None else f"{vals[nm]:.5g}"
        lines.append(f"| {r['incidence_deg']:g} | {r['n']} | {r['chi2_dof']:.3g} | {r['rms_rel']:.3g} | "
                     f"{cell(scale_name)} | {cell(width_name)} | {rf.get('converged')} |")
    return lines


__all__ = ["write_report"]
