"""The benchmark runner and report, end to end with real subprocesses, real JAX and real PNGs."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

TINY = '''
"""A tiny real study: exact Fresnel vs Schlick for iron on 61 bands."""
import numpy as np


def run(quick):
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from benchmarks._harness import record, timeit
    from jkatana.models import fresnel_conductor, fresnel_schlick, normal_incidence
    from jkatana.spectral import DEFAULT_GRID, load_optical_constants

    n, k = load_optical_constants("Fe-Johnson").on_grid(DEFAULT_GRID)
    cos = jnp.linspace(0.0, 1.0, 4096)[:, None]
    exact = jax.jit(lambda c: fresnel_conductor(c, n, k))
    f0 = normal_incidence(n, k)
    schlick = jax.jit(lambda c: fresnel_schlick(c, f0))
    ref = np.asarray(exact(cos))
    rows = []
    for name, fn, is_ref in (("exact", exact, True), ("Schlick", schlick, False)):
        t = timeit(lambda: fn(cos), repeats=3)
        err = float(np.max(np.abs(np.asarray(fn(cos)) - ref)))
        rows.append(record("bench_tiny", {"variant": name}, time_s=t, error={"F_max_abs": err},
                           reference="exact", study="tiny fresnel", variant=name,
                           error_metric="F_max_abs", is_reference=is_ref, items=4096))
    rows.append(record("bench_tiny", {"what": "plain"}, time_s=t))
    return rows
'''

FAILING = '''
def run(quick):
    raise RuntimeError("this benchmark is broken on purpose")
'''

SLOW = '''
import time


def run(quick):
    from benchmarks._harness import record
    rows = [record("bench_slow", {"step": 1}, time_s={"median": 0.5, "min": 0.5, "max": 0.5, "iqr": 0.0,
                                                      "repeats": 1})]
    time.sleep(120)
    return rows
'''


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / f"{name}.py"
    p.write_text(textwrap.dedent(text))
    return p


def test_runner_and_report_end_to_end(tmp_path):
    tiny = _write(tmp_path, "bench_tiny", TINY)
    broken = _write(tmp_path, "bench_broken", FAILING)
    out = tmp_path / "results.json"
    rep = tmp_path / "report"
    proc = subprocess.run([sys.executable, "-m", "benchmarks", "--quick", "--only", str(tiny), str(broken),
                           "-o", str(out), "--report", str(rep)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    # the broken module fails the run (exit 1) but does not stop the others
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert "FAILED: bench_broken (failed)" in proc.stderr
    results = json.loads(out.read_text())
    m = results["machine"]
    assert m["cores"] >= 1 and m["jax_backend"] and m["jax_version"] and "gpu" in m
    assert results["mode"] == "quick"
    assert results["benchmarks"]["bench_broken"]["status"] == "failed"
    assert "broken on purpose" in results["benchmarks"]["bench_broken"]["stderr_tail"]
    tiny_res = results["benchmarks"]["bench_tiny"]
    assert tiny_res["status"] == "ok" and tiny_res["wall_s"] <= tiny_res["budget_s"]
    recs = {r["variant"]: r for r in tiny_res["records"] if "study" in r}
    assert set(recs) == {"exact", "Schlick"}
    for r in recs.values():
        assert r["time_s"]["min"] <= r["time_s"]["median"] <= r["time_s"]["max"] and r["peak_rss_mb"] > 0
    assert recs["exact"]["error"]["F_max_abs"] == 0.0
    schlick_err = recs["Schlick"]["error"]["F_max_abs"]
    assert 0.01 < schlick_err < 0.5  # Schlick is a visible approximation for iron

    from benchmarks.report import _fmt, fmt_time, machine_line

    md = (rep / "report.md").read_text()
    assert machine_line(m) in md and m.get("cpu_model", "unknown CPU") in md
    # the CPU's generation, not only its (possibly bare) name, is in the report
    for word, key in (("family", "cpu_family"), ("model", "cpu_model_number"), ("stepping", "cpu_stepping")):
        if m.get(key) is not None:
            assert f"{word} {m[key]}" in md
    if m.get("cpu_simd"):
        assert m["cpu_simd"].upper() in md
    assert "bench_broken" in md and "failed" in md and "broken on purpose" in md
    # the numbers in the study table are the measured ones
    assert _fmt(schlick_err) in md
    assert fmt_time(recs["Schlick"]["time_s"]["median"]) in md
    assert (rep / "headline.md").read_text().strip() in md
    assert "| tiny fresnel | Schlick |" in (rep / "headline.md").read_text()
    png = rep / "pareto_tiny_fresnel.png"
    assert f"]({png.name})" in md

    import matplotlib.image as mpimg

    img = mpimg.imread(png)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 300
    assert np.ptp(img[..., :3]) > 0.5  # not a blank image


def test_machine_line_names_the_peers_toolchain():
    """A ratio against Mitsuba depends on the LLVM Dr.Jit compiles with, so the report's machine line names it
    when Mitsuba is installed, and says nothing of Mitsuba when it is not."""
    from benchmarks._harness import peer_facts
    from benchmarks.report import machine_line

    base = {"cpu_model": "AMD EPYC", "cores": 2, "memory_gib": 23.5, "jax_version": "0.10.2", "jax_backend": "cpu"}
    line = machine_line(base | {"mitsuba_version": "3.9.1", "drjit_version": "1.5.0", "drjit_llvm": "19.1.7"})
    assert line.endswith("no GPU, Mitsuba 3.9.1 (Dr.Jit 1.5.0, LLVM 19.1.7)")
    assert machine_line(base | {"mitsuba_version": "3.9.1", "drjit_version": "1.5.0", "drjit_llvm": None}).endswith(
        "LLVM not found)")
    assert "Mitsuba" not in machine_line(base)
    facts = peer_facts()  # this environment's own: empty without Mitsuba, its versions with it
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        assert facts == {}
    else:
        assert facts["mitsuba_version"] == mitsuba.__version__ and facts["drjit_version"]


def test_timeout_keeps_partial_records(tmp_path):
    from benchmarks.__main__ import run_module

    slow = _write(tmp_path, "bench_slow", SLOW)
    res = run_module(str(slow), quick=True, budget=8.0)
    assert res["status"] == "timeout"
    assert res["wall_s"] < 60
    assert len(res["records"]) == 1 and res["records"][0]["partial"] is True


def test_pareto_front_and_headline():
    from benchmarks.report import headline_rows, pareto_front

    def rec(v, t, e, **kw):
        return dict(benchmark="b", study="s", variant=v, error_metric="dE2000_mean",
                    time_s={"median": t}, error={"dE2000_mean": e}, **kw)

    rows = [rec("ref", 10.0, 0.0, is_reference=True), rec("a", 1.0, 2.0), rec("b", 2.0, 0.5),
            rec("c", 3.0, 0.9), rec("nan", 0.1, float("nan"))]
    assert [r["variant"] for r in pareto_front(rows)] == ["a", "b", "ref"]
    head = headline_rows({"benchmarks": {"b": {"records": rows}}})
    # the fastest variant within the ΔE JND (1.0): b, 5× faster than the reference
    assert [(h["variant"], h["ref_time"] / h["time"]) for h in head] == [("b", 5.0)]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["bench_spectral", "bench_precision"])
def test_owned_benchmarks_quick(tmp_path, name):
    out = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, "-m", "benchmarks", "--quick", "--only", name, "-o", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    recs = json.loads(out.read_text())["benchmarks"][name]["records"]
    ref = [r for r in recs if r.get("is_reference")]
    assert ref and all(r["error"]["dE2000_mean"] < 1e-3 for r in ref)
    assert all(r["time_s"]["median"] > 0 for r in recs)


def test_equal_error_ratio_interpolates_measured_points_only():
    from benchmarks.report import equal_error_ratios

    def rec(series, t, e):
        return dict(benchmark="b", study="s", variant=f"{series} {t}", error_metric="dE2000_mean",
                    time_s={"median": t}, error={"dE2000_mean": e}, case={"renderer": series})

    rows = [rec("A", 1.0, 4.0), rec("A", 4.0, 1.0), rec("B", 2.0, 2.0), rec("B", 8.0, 0.5)]
    (c,) = equal_error_ratios({"benchmarks": {"b": {"records": rows}}})
    # common error = max(min errors) = 1.0; A takes 4 s there; B (log–log between (2 s, 2), (8 s, 0.5)) 4 s
    assert c["error"] == 1.0 and c["t_a"] == pytest.approx(4.0) and c["t_b"] == pytest.approx(4.0)
    assert c["ratio"] == pytest.approx(1.0)
    rows = [rec("A", 1.0, 4.0), rec("A", 4.0, 3.0), rec("B", 2.0, 2.0), rec("B", 8.0, 0.5)]
    (c,) = equal_error_ratios({"benchmarks": {"b": {"records": rows}}})
    assert np.isnan(c["ratio"]) and "no common error range" in c["note"]


def test_the_library_never_imports_validation_or_benchmarks():
    """jkatana's import graph (every import statement, also inside functions) stays out of the
    checkout-only packages, and the wheel ships the library alone."""
    import ast
    import tomllib

    offenders = []
    for path in sorted((ROOT / "jkatana").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            offenders += [f"{path.relative_to(ROOT)}: {n}" for n in names
                          if n.split(".")[0] in ("benchmarks", "validation", "experiments", "tests")]
    assert offenders == []
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["tool"]["setuptools"]["packages"]["find"]["include"] == ["jkatana*"]


def test_jkatana_bench_outside_a_checkout_is_one_line(monkeypatch, capsys):
    import jkatana.cli as cli

    monkeypatch.setattr(cli, "_checkout_root", lambda: None)
    assert cli.main(["bench", "--quick"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "source checkout" in err[0]


def test_compare_classifies_errors_and_times(tmp_path):
    """Back-to-back comparison: identical / float32-rounding / differing errors, time ratio, unmatched records."""
    from benchmarks.compare import compare, main

    def res(records, status="ok"):
        return {"benchmarks": {"bench_x": {"status": status, "wall_s": 1.0, "records": records}}}

    def rec(case, err, t):
        return {"case": {"c": case}, "error": {"dE": err}, "time_s": {"median": t}}

    before = res([rec(1, 0.5, 1.0), rec(2, 0.5, 1.0), rec(3, 0.5, 1.0), rec(4, 0.5, 1.0)])
    after = res([rec(1, 0.5, 2.0), rec(2, 0.5 * (1 + 1e-7), 1.0), rec(3, 0.6, 0.5), rec(5, 0.5, 1.0)])
    out = compare(before, after)
    got = {r["key"].split("|")[1].strip(): (r["agreement"], r["ratio"]) for r in out["rows"]}
    assert got == {'{"c": 1}': ("identical", 2.0), '{"c": 2}': ("float32", 1.0), '{"c": 3}': ("differ", 0.5)}
    m = out["modules"]["bench_x"]
    assert (m["identical"], m["float32"], m["with_errors"], m["median_ratio"]) == (1, 1, 3, 1.0)
    assert len(m["only_before"]) == 1 and len(m["only_after"]) == 1
    (tmp_path / "b.json").write_text(json.dumps(before))
    (tmp_path / "a.json").write_text(json.dumps(after))
    assert main([str(tmp_path / "b.json"), str(tmp_path / "a.json"), "-o", str(tmp_path / "cmp")]) == 0
    text = (tmp_path / "cmp" / "compare.md").read_text()
    assert "**differ**" in text and "| bench_x | ok → ok |" in text
