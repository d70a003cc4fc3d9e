"""Compare two benchmark results files run back to back: errors identical?, time after/before per study.

``python -m benchmarks.compare before.json after.json -o DIR`` writes ``DIR/compare.md``: per module its
status and wall time in both runs, then every record present in both (matched by module and ``case``)
with its error fields before and after — *identical* when every error value agrees to 1e-12
relative, *float32 rounding* to 1e-5 — and the ratio of median times after/before; per study (module) the median ratio. Records
only in one run are listed by name. A refactoring that claims "behaviour unchanged" should show
identical errors wherever the computation is the same (same seeds) and time ratios within run-to-run
noise; the quick mode's single timings make ±30 % per record ordinary, so the per-module median is the
number to read.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

from benchmarks.report import all_records, fmt_time
from jkatana.io.atomic import write_text

#: Relative difference below which two error values count as identical (the last bits of float64 sums).
IDENTICAL_RTOL = 1e-12
#: Relative difference below which two error values agree to float32 rounding (a reordered float32 sum).
FLOAT32_RTOL = 1e-5


def _key(r: dict) -> str:
    return r["_module"] + " | " + json.dumps(r.get("case", {}), sort_keys=True, default=str)


def _errors(r: dict) -> dict[str, float]:
    out = {}
    for k, v in (r.get("error") or {}).items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            out[k] = float(v)
    return out


def _median_time(r: dict) -> float:
    try:
        return float((r.get("time_s") or {}).get("median"))
    except (TypeError, ValueError):
        return math.nan


def _same(a: float, b: float, rtol: float = IDENTICAL_RTOL) -> bool:
    if math.isnan(a) and math.isnan(b):
        return True
    return abs(a - b) <= rtol * max(abs(a), abs(b), 1e-300)


def _agreement(eb: dict[str, float], ea: dict[str, float], common: list[str]) -> str | None:
    """``"identical"`` (≤ 1e-12 relative), ``"float32"`` (≤ 1e-5), ``"differ"``; ``None`` without errors."""
    if not common:
        return None
    if all(_same(eb[m], ea[m]) for m in common):
        return "identical"
    if all(_same(eb[m], ea[m], FLOAT32_RTOL) for m in common):
        return "float32"
    return "differ"


def compare(before: dict, after: dict) -> dict:
    """Matched records with error agreement and time ratio, plus per-module summaries."""
    rb = {_key(r): r for r in all_records(before)}
    ra = {_key(r): r for r in all_records(after)}
    rows = []
    for k in sorted(rb.keys() & ra.keys()):
        eb, ea = _errors(rb[k]), _errors(ra[k])
        common = sorted(eb.keys() & ea.keys())
        agreement = _agreement(eb, ea, common)
        rel = max((abs(ea[m] - eb[m]) / max(abs(ea[m]), abs(eb[m]), 1e-300) for m in common
                   if not (math.isnan(ea[m]) or math.isnan(eb[m]))), default=math.nan)
        tb, ta = _median_time(rb[k]), _median_time(ra[k])
        ratio = ta / tb if tb > 0 and ta > 0 else math.nan
        rows.append({"key": k, "module": ra[k]["_module"], "errors_before": {m: eb[m] for m in common},
                     "errors_after": {m: ea[m] for m in common}, "agreement": agreement, "max_rel_diff": rel,
                     "time_before": tb, "time_after": ta, "ratio": ratio})
    modules = {}
    for name in sorted(set(before.get("benchmarks", {})) | set(after.get("benchmarks", {}))):
        mine = [r for r in rows if r["module"] == name]
        ratios = [r["ratio"] for r in mine if not math.isnan(r["ratio"])]
        with_err = [r for r in mine if r["agreement"] is not None]
        b, a = before.get("benchmarks", {}).get(name, {}), after.get("benchmarks", {}).get(name, {})
        modules[name] = {"status": (b.get("status", "absent"), a.get("status", "absent")),
                         "wall_s": (b.get("wall_s"), a.get("wall_s")), "matched": len(mine),
                         "with_errors": len(with_err), "identical": sum(r["agreement"] == "identical" for r in with_err),
                         "float32": sum(r["agreement"] == "float32" for r in with_err),
                         "median_ratio": statistics.median(ratios) if ratios else math.nan,
                         "only_before": sorted(k for k in rb.keys() - ra.keys() if rb[k]["_module"] == name),
                         "only_after": sorted(k for k in ra.keys() - rb.keys() if ra[k]["_module"] == name)}
    return {"rows": rows, "modules": modules}


def _num(x: float) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.4g}"


def markdown(before: dict, after: dict, result: dict) -> str:
    mb, ma = before.get("machine", {}), after.get("machine", {})
    lines = ["# Benchmarks back to back: after / before", "",
             f"- before: started {before.get('started')}, load {_num(mb.get('load_avg_1min'))}, "
             f"wall {_num(before.get('wall_s'))} s",
             f"- after: started {after.get('started')}, load {_num(ma.get('load_avg_1min'))}, "
             f"wall {_num(after.get('wall_s'))} s", "",
             "| module | status before → after | wall s | records matched | errors identical | to float32 rounding "
             "| median time after/before |",
             "|---|---|---|---|---|---|---|"]
    for name, m in result["modules"].items():
        lines.append(f"| {name} | {m['status'][0]} → {m['status'][1]} | {_num(m['wall_s'][0])} → {_num(m['wall_s'][1])} "
                     f"| {m['matched']} | {m['identical']}/{m['with_errors']} | {m['float32']}/{m['with_errors']} "
                     f"| {_num(m['median_ratio'])} |")
    lines += ["", "## Records whose errors differ", "", "| record | error before | error after | max relative difference | time after/before |",
              "|---|---|---|---|---|"]
    for r in result["rows"]:
        if r["agreement"] == "differ":
            fb = ", ".join(f"{k} {_num(v)}" for k, v in r["errors_before"].items())
            fa = ", ".join(f"{k} {_num(v)}" for k, v in r["errors_after"].items())
            lines.append(f"| {r['key']} | {fb} | {fa} | {_num(r['max_rel_diff'])} | {_num(r['ratio'])} |")
    lines += ["", "## Every matched record", "", "| record | errors | time before | time after | after/before |",
              "|---|---|---|---|---|"]
    for r in result["rows"]:
        same = {"identical": "identical", "float32": "float32 rounding", "differ": "**differ**",
                None: "(no error)"}[r["agreement"]]
        lines.append(f"| {r['key']} | {same} | {fmt_time(r['time_before'])} | {fmt_time(r['time_after'])} "
                     f"| {_num(r['ratio'])} |")
    for name, m in result["modules"].items():
        for side in ("only_before", "only_after"):
            if m[side]:
                lines += ["", f"## {name}: records {side.replace('_', ' ')}", ""] + [f"- {k}" for k in m[side]]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.compare", description=__doc__.splitlines()[0])
    p.add_argument("before", help="results JSON of the earlier code")
    p.add_argument("after", help="results JSON of the later code, run right after on the same machine")
    p.add_argument("-o", "--output", default="benchmarks/results/compare", help="folder for compare.md")
    args = p.parse_args(argv)
    before = json.loads(Path(args.before).read_text())
    after = json.loads(Path(args.after).read_text())
    out = Path(args.output) / "compare.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text(out, markdown(before, after, compare(before, after)))
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
