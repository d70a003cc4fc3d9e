"""Render a benchmark results file into a report: ``report.md``, ``headline.md`` and PNG plots.

``python -m benchmarks.report results.json -o DIR`` (or ``python -m benchmarks
... --report DIR`` right after a run). The report states the machine first,
then the status of every module, the headline table, one section per
accuracy–time study (a table and a Pareto plot of measured error against
measured time), the comparisons (ratios), and every other record in plain
tables. Studies are found generically from the record convention documented
in :mod:`benchmarks`: records that carry ``study``, ``variant`` and
``error_metric``.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

#: Default tolerance for ΔE metrics when a study gives none: ΔE2000 = 1 is about one
#: just-noticeable difference (Sharma, Wu & Dalal 2005; CIE 142-2001).
DE_JND = 1.0
#: A ΔE study's variant is "within tolerance" only if its tail is too: p95 ≤ 2.5, the
#: acceptance bar the project uses for the interactive path against the reference.
#: Without it a variant with a fine mean and visible outliers (Schlick: mean 0.84,
#: p95 4.0) would be headlined as good enough.
DE_P95_MAX = 2.5
MAX_HEADLINE_ROWS = 10


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None:
        return "–"
    if isinstance(x, bool):
        return str(x)
    if isinstance(x, (int, float)):
        if isinstance(x, float) and not math.isfinite(x):
            return str(x)
        if x == 0:
            return "0"
        ax = abs(x)
        if ax >= 1e5 or ax < 1e-3:
            return f"{x:.{digits - 1}e}"
        return f"{x:.{digits}g}"
    return str(x)


def fmt_time(s: float | None) -> str:
    """Seconds → a human unit (ns, µs, ms, s)."""
    if s is None or not isinstance(s, (int, float)) or not math.isfinite(s):
        return "–"
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6), ("ns", 1e-9)):
        if abs(s) >= scale or unit == "ns":
            return f"{s / scale:.3g} {unit}"
    return f"{s:.3g} s"  # pragma: no cover


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_") or "study"


def all_records(results: dict) -> list[dict]:
    """Every record of every module, each tagged with its module name."""
    rows = []
    for name, res in results.get("benchmarks", {}).items():
        for r in res.get("records", []) or []:
            rows.append(dict(r, benchmark=r.get("benchmark", name), _module=name))
    return rows


def studies(results: dict) -> dict[str, list[dict]]:
    """Records grouped by ``study`` (only those with ``variant`` and ``error_metric``)."""
    out: dict[str, list[dict]] = {}
    for r in all_records(results):
        if r.get("study") and r.get("variant") is not None and r.get("error_metric"):
            out.setdefault(str(r["study"]), []).append(r)
    return out


def _err(r: dict) -> float:
    v = (r.get("error") or {}).get(r["error_metric"])
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _tail(r: dict) -> float | None:
    """The p95 companion of a ΔE metric (``dE2000_mean`` → ``dE2000_p95``), if recorded."""
    metric = str(r["error_metric"])
    if not metric.lower().startswith("de"):
        return None
    key = re.sub(r"_(mean|median)$", "_p95", metric)
    v = (r.get("error") or {}).get(key) if key != metric else None
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def _within(r: dict, tol: float | None) -> bool:
    """Error ≤ tolerance and, for ΔE metrics with a recorded p95, p95 ≤ :data:`DE_P95_MAX`."""
    if tol is None or not _err(r) <= tol:
        return False
    tail = _tail(r)
    return tail is None or tail <= DE_P95_MAX


def _time(r: dict) -> float:
    try:
        return float((r.get("time_s") or {}).get("median"))
    except (TypeError, ValueError):
        return math.nan


def pareto_front(rows: list[dict]) -> list[dict]:
    """Rows not dominated in (time, error): no other row is both faster and more accurate."""
    pts = sorted((r for r in rows if math.isfinite(_err(r)) and math.isfinite(_time(r))),
                 key=lambda r: (_time(r), _err(r)))
    front, best = [], math.inf
    for r in pts:
        if _err(r) < best:
            front.append(r)
            best = _err(r)
    return front


def _tolerance(rows: list[dict]) -> float | None:
    tols = [r["tolerance"] for r in rows if isinstance(r.get("tolerance"), (int, float))]
    if tols:
        return float(min(tols))
    if rows and str(rows[0]["error_metric"]).lower().startswith("de"):
        return DE_JND
    return None


def _reference_row(rows: list[dict]) -> dict | None:
    refs = [r for r in rows if r.get("is_reference")]
    return refs[0] if refs else None


def plot_study(name: str, rows: list[dict], path: Path) -> Path:
    """Pareto plot: measured error (y, log) against measured median time (x, log).

    Error bars on time span the min–max over repeats. Points with error 0 are
    drawn on the plot's floor and marked; non-finite errors are left out and
    listed in the title's footnote.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metric = rows[0]["error_metric"]
    good = [r for r in rows if math.isfinite(_err(r)) and math.isfinite(_time(r))]
    bad = [r for r in rows if r not in good]
    pos = [_err(r) for r in good if _err(r) > 0]
    floor = (min(pos) / 10.0) if pos else 1e-6
    per_item = all(isinstance(r.get("items"), (int, float)) and r["items"] > 0 for r in good) and good
    scale = (lambda r: _time(r) / r["items"]) if per_item else _time
    fig, ax = plt.subplots(figsize=(7.0, 4.6), dpi=110)
    front = pareto_front(good)
    benches = sorted({r["benchmark"] for r in good})
    markers = dict(zip(benches, "osD^v<>p*h"))
    xs = [scale(r) for r in good if scale(r) > 0]
    x_split = math.exp(math.log(min(xs)) + 0.7 * (math.log(max(xs)) - math.log(min(xs)))) if xs else math.inf
    for r in good:
        x, y = scale(r), max(_err(r), floor)
        t = r.get("time_s") or {}
        k = (r["items"] if per_item else 1)
        xerr = [[max(x - t.get("min", _time(r)) / k, 0)], [max(t.get("max", _time(r)) / k - x, 0)]]
        on_front = r in front
        ax.errorbar([x], [y], xerr=xerr, fmt=markers.get(r["benchmark"], "o"),
                    color="C3" if on_front else "C0", ms=6 if on_front else 5, capsize=2,
                    mfc="none" if _err(r) <= 0 else None)
        label = str(r["variant"]) + (" (ref.)" if r.get("is_reference") else "") + \
            (" [err=0]" if _err(r) <= 0 else "")
        right = x >= x_split  # labels of the slowest points go to their left, inside the axes
        ax.annotate(label, (x, y), textcoords="offset points", xytext=(-5 if right else 5, 4), fontsize=7,
                    ha="right" if right else "left")
    if len(front) > 1:
        ax.step([scale(r) for r in front], [max(_err(r), floor) for r in front], where="post",
                color="C3", lw=1, alpha=0.6, label="Pareto front")
    tol = _tolerance(rows)
    if tol is not None:
        ax.axhline(tol, color="0.4", ls="--", lw=0.8, label=f"tolerance {tol:g}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.margins(x=0.25, y=0.12)  # room for the labels
    ax.set_xlabel("measured time per item (s, median)" if per_item else "measured time (s, median)")
    ax.set_ylabel(f"measured error: {metric}")
    title = f"{name}"
    if bad:
        title += f"\n(not plotted, non-finite: {', '.join(str(r['variant']) for r in bad)})"
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.25)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    from jkatana.io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


def study_table(rows: list[dict]) -> list[str]:
    """Markdown table of one study, sorted by time; every error metric measured is a column."""
    ref = _reference_row(rows)
    metrics: list[str] = []
    for r in rows:
        for k in (r.get("error") or {}):
            if k not in metrics and k != "exposure":
                metrics.append(k)
    primary = rows[0]["error_metric"]
    metrics.sort(key=lambda k: k != primary)
    per_item = any(r.get("items") for r in rows)
    head = ["variant"] + [f"**{m}**" if m == primary else m for m in metrics] + \
        ["time (median)", "spread (min–max)"] + (["per item"] if per_item else []) + \
        (["× ref. time"] if ref else []) + ["peak RSS (MiB)", "Pareto", "note"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    front = pareto_front(rows)
    for r in sorted(rows, key=lambda r: (_time(r) if math.isfinite(_time(r)) else math.inf)):
        t = r.get("time_s") or {}
        cells = [str(r["variant"]) + (" (reference)" if r.get("is_reference") else "")]
        cells += [_fmt((r.get("error") or {}).get(m)) for m in metrics]
        cells += [fmt_time(t.get("median")),
                  f"{fmt_time(t.get('min'))} – {fmt_time(t.get('max'))} (n={t.get('repeats', '–')})"]
        if per_item:
            cells.append(fmt_time(_time(r) / r["items"]) if r.get("items") else "–")
        if ref:
            cells.append(_fmt(_time(r) / _time(ref)) if _time(ref) > 0 else "–")
        cells += [_fmt(r.get("peak_rss_mb")), "★" if r in front else "",
                  str(r.get("note", "")) + (" (partial run)" if r.get("partial") else "")]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _series(r: dict) -> str | None:
    """A record's series within its study: ``series``, else its case's ``renderer`` (if any)."""
    if r.get("series"):
        return str(r["series"])
    case = r.get("case")
    return str(case["renderer"]) if isinstance(case, dict) and case.get("renderer") else None


def _time_at_error(rows: list[dict], e: float) -> float:
    """Time this series needs for error ``e``: log–log interpolation along its Pareto front."""
    front = sorted(pareto_front(rows), key=_err)
    le = [math.log(max(_err(r), 1e-300)) for r in front]
    lt = [math.log(_time(r)) for r in front]
    x = math.log(e)
    for i in range(len(front) - 1):
        if le[i] <= x <= le[i + 1]:
            f = (x - le[i]) / (le[i + 1] - le[i]) if le[i + 1] > le[i] else 0.0
            return math.exp(lt[i] + f * (lt[i + 1] - lt[i]))
    return math.nan


def equal_error_ratios(results: dict) -> list[dict]:
    """For studies with ≥ 2 series (e.g. two renderers), time ratios at equal error.

    The common error is the smallest error both series reach (the larger of their
    minima), provided it lies within both measured ranges; each series' time at
    it is interpolated (log–log) along its own Pareto front — measured points
    only, no extrapolation. **Returns:** rows with ``study, a, b, error, t_a, t_b, ratio``.
    """
    out = []
    for name, rs in studies(results).items():
        groups: dict[str, list[dict]] = {}
        for r in rs:
            if _series(r) and math.isfinite(_err(r)) and _err(r) > 0 and math.isfinite(_time(r)):
                groups.setdefault(_series(r), []).append(r)
        keys = sorted(k for k, v in groups.items() if len(v) >= 2)
        for i, a in enumerate(keys):
            for b in keys[i + 1:]:
                ea = [_err(r) for r in groups[a]]
                eb = [_err(r) for r in groups[b]]
                e = max(min(ea), min(eb))
                row = {"study": name, "a": a, "b": b, "metric": rs[0]["error_metric"], "error": e}
                if e <= min(max(ea), max(eb)):
                    ta, tb = _time_at_error(groups[a], e), _time_at_error(groups[b], e)
                    row.update(t_a=ta, t_b=tb, ratio=ta / tb if tb > 0 else math.nan)
                else:
                    row.update(t_a=math.nan, t_b=math.nan, ratio=math.nan,
                               note="no common error range: not compared (no extrapolation)")
                out.append(row)
    return out


def headline_rows(results: dict) -> list[dict]:
    """At most 10 rows: per study, the fastest variant within tolerance (or forced ``headline``)."""
    rows = []
    for name, rs in studies(results).items():
        forced = [r for r in rs if r.get("headline")]
        ref = _reference_row(rs)
        tol = _tolerance(rs)
        cand = [r for r in rs if math.isfinite(_err(r)) and math.isfinite(_time(r)) and not r.get("is_reference")]
        pick = forced
        if not pick and cand:
            within = [r for r in cand if _within(r, tol)]
            if within:
                pick = [min(within, key=_time)]
            else:
                pick = [min(cand, key=lambda r: (_err(r), _time(r)))]
        for r in pick:
            rows.append({"study": name, "variant": str(r["variant"]), "metric": r["error_metric"],
                         "error": _err(r), "tail": _tail(r), "ok": _within(r, tol), "time": _time(r),
                         "per_item": _time(r) / r["items"] if r.get("items") else None,
                         "reference": str(ref["variant"]) if ref else r.get("reference"),
                         "ref_time": _time(ref) if ref else None, "tolerance": tol})
    return rows[:MAX_HEADLINE_ROWS]


def headline_markdown(results: dict) -> str:
    """The headline table (≤ 10 rows) as Markdown, for the README."""
    rows = headline_rows(results)
    m = results.get("machine", {})
    lines = [f"Measured on {machine_line(m)} ({results.get('mode', '?')} mode).", "",
             "| study | choice | error | time | vs reference |", "|---|---|---|---|---|"]
    for h in rows:
        t = fmt_time(h["per_item"]) + " per item" if h["per_item"] is not None else fmt_time(h["time"])
        vs = "–"
        if h["ref_time"] and h["time"] > 0:
            ratio = h["ref_time"] / h["time"]
            vs = (f"{ratio:.3g}× faster than {h['reference']}" if ratio >= 1
                  else f"{1 / ratio:.3g}× slower than {h['reference']}")
        within = "" if h["tolerance"] is None else (" ✓" if h["ok"] else " ✗ above tolerance")
        tail = "" if h["tail"] is None else f" (p95 {_fmt(h['tail'])})"
        lines.append(f"| {h['study']} | {h['variant']} | {h['metric']} = {_fmt(h['error'])}{tail}{within} | {t} | {vs} |")
    if not rows:
        lines.append("| (no study records) | | | | |")
    return "\n".join(lines) + "\n"


def machine_line(m: dict) -> str:
    gpu = m.get("gpu") or "no GPU"
    ident = [f"{k} {m[key]}" for k, key in (("family", "cpu_family"), ("model", "cpu_model_number"),
                                            ("stepping", "cpu_stepping")) if m.get(key) is not None]
    if m.get("cpu_simd"):
        ident.append(m["cpu_simd"].upper())
    cpu = m.get("cpu_model") or "unknown CPU"
    cpu = f"{cpu} ({', '.join(ident)})" if ident else cpu
    peer = ""
    if m.get("mitsuba_version"):
        peer = (f", Mitsuba {m['mitsuba_version']} (Dr.Jit {m.get('drjit_version', '?')}, "
                f"LLVM {m.get('drjit_llvm') or 'not found'})")
    return (f"{cpu}, {m.get('cores_usable') or m.get('cores')} cores, "
            f"{m.get('memory_gib', '?')} GiB, JAX {m.get('jax_version', '?')} on "
            f"{m.get('jax_backend', '?')}, {gpu}{peer}")


def write_report(results: dict | str | Path, out_dir: str | Path) -> dict[str, Path]:
    """Write ``report.md``, ``headline.md`` and ``<study>.png`` plots into ``out_dir``.

    **Arguments:** `results` (a results dict or the path of a results JSON),
    `out_dir` (created if needed).

    **Returns:** ``{"report": path, "headline": path, "plots": {study: path}}``.
    """
    from jkatana.io.atomic import write_text

    if not isinstance(results, dict):
        results = json.loads(Path(results).read_text())
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    m = results.get("machine", {})
    md = ["# jkatana benchmark report: what accuracy costs in time", "",
          f"**Machine:** {machine_line(m)}.  ",
          f"Platform: {m.get('platform', '?')}, Python {m.get('python', '?')}, "
          f"JAX devices: {', '.join(m.get('jax_devices', []) or ['?'])}; "
          f"1-min load average at start {_fmt(m.get('load_avg_1min'))} (the machine is shared: "
          f"a load above the core count inflates and spreads the times).  ",
          f"**Mode:** {results.get('mode', '?')}; started {results.get('started', '?')}; "
          f"suite wall time {_fmt(results.get('wall_s'))} s of a {_fmt(results.get('budget_total_s'))} s budget.",
          "", "Every number below was measured in this run: errors against each study's "
          "reference, times as medians over repeats (spread: min–max). Reproduce with "
          f"`python -m benchmarks --{results.get('mode', 'full')} -o results.json --report DIR` "
          "(or `jkatana bench ...`).", "",
          "## Modules", "", "| module | status | records | wall (s) | budget (s) | load at start |",
          "|---|---|---|---|---|---|"]
    for name, res in results.get("benchmarks", {}).items():
        status = res.get("status", "ok" if "records" in res else "failed")
        md.append(f"| {name} | {'✅ ok' if status == 'ok' else '❌ ' + status} | "
                  f"{len(res.get('records') or [])} | {_fmt(res.get('wall_s'))} | {_fmt(res.get('budget_s'))} | "
                  f"{_fmt(res.get('load_avg_1min_at_start'))} |")
    for name, res in results.get("benchmarks", {}).items():
        if res.get("status", "ok") != "ok" and res.get("stderr_tail"):
            tail = "\n".join(res["stderr_tail"].strip().splitlines()[-8:])
            md += ["", f"<details><summary>{name}: {res.get('status')} — last lines of its output</summary>",
                   "", "```", tail, "```", "</details>"]
    headline = headline_markdown(results)
    md += ["", "## Headline", "", headline]
    plots: dict[str, Path] = {}
    groups = studies(results)
    if groups:
        md += ["## Accuracy–time studies", ""]
    for name, rows in groups.items():
        png = plot_study(name, rows, out / f"pareto_{_slug(name)}.png")
        plots[name] = png
        refs = sorted({str(r.get("reference")) for r in rows if r.get("reference")})
        tol = _tolerance(rows)
        md += [f"### {name}", "",
               f"Reference: {'; '.join(refs) or '–'}. Primary error: `{rows[0]['error_metric']}`"
               + (f"; tolerance {tol:g}." if tol is not None else "."),
               f"Modules: {', '.join(sorted({r['benchmark'] for r in rows}))}.", "",
               f"![{name}: error vs time]({png.name})", ""]
        md += study_table(rows) + [""]
    ratios = [r for r in all_records(results) if isinstance(r.get("ratio"), (int, float))]
    eq = equal_error_ratios(results)
    if ratios or eq:
        md += ["## Comparisons", "", "| comparison | ratio | module | note |", "|---|---|---|---|"]
        for c in eq:
            note = c.get("note") or (f"{c['a']} {fmt_time(c['t_a'])} vs {c['b']} {fmt_time(c['t_b'])}, "
                                     "interpolated along each one's measured Pareto front")
            md.append(f"| time of {c['a']} / time of {c['b']} at equal {c['metric']} = {_fmt(c['error'])} "
                      f"({c['study']}) | {_fmt(c['ratio'])} | (from the study) | {note} |")
        for r in ratios:
            md.append(f"| {r.get('ratio_label', r.get('case'))} | {_fmt(r['ratio'])} | {r['benchmark']} | "
                      f"{r.get('note', '')} |")
        md.append("")
    others = [r for r in all_records(results)
              if not (r.get("study") and r.get("variant") is not None and r.get("error_metric"))
              and not isinstance(r.get("ratio"), (int, float))]
    if others:
        md += ["## Other measurements", ""]
        by_mod: dict[str, list[dict]] = {}
        for r in others:
            by_mod.setdefault(r["benchmark"], []).append(r)
        for mod, rs in by_mod.items():
            md += [f"### {mod}", "", "| case | time (median) | spread | error | reference | peak RSS (MiB) |",
                   "|---|---|---|---|---|---|"]
            for r in rs:
                t = r.get("time_s") or {}
                case = ", ".join(f"{k}={_fmt(v)}" for k, v in (r.get("case") or {}).items()) \
                    if isinstance(r.get("case"), dict) else str(r.get("case"))
                err = ", ".join(f"{k}={_fmt(v)}" for k, v in (r.get("error") or {}).items()) or "–"
                md.append(f"| {case} | {fmt_time(t.get('median'))} | {fmt_time(t.get('min'))} – "
                          f"{fmt_time(t.get('max'))} | {err} | {r.get('reference', '–')} | "
                          f"{_fmt(r.get('peak_rss_mb'))} |")
            md.append("")
    report = write_text(out / "report.md", "\n".join(md) + "\n")
    head = write_text(out / "headline.md", headline)
    return {"report": Path(report), "headline": Path(head), "plots": plots}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.report", description=__doc__.splitlines()[0])
    p.add_argument("results", help="results JSON written by python -m benchmarks")
    p.add_argument("-o", "--output", default="benchmarks/results/report", help="report folder")
    args = p.parse_args(argv)
    paths = write_report(args.results, args.output)
    print(paths["report"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
