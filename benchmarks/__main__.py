"""Run the benchmark suite: ``python -m benchmarks [--quick|--full] [--only ...] [-o results.json] [--report DIR]``.

Every ``bench_*.py`` module runs in a subprocess of its own (so its peak memory
and JIT cache are its own) under a wall-clock budget the runner enforces; the
records, each module's status (ok / failed / timeout), wall time and budget,
and the machine's facts go into one JSON file, written atomically.
``--report DIR`` then renders the report (:mod:`benchmarks.report`).
A module that fails or overruns is reported and the others still run; the
exit status is 1 if any failed.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BENCH_HELP = "Run the benchmark suite (what accuracy costs in time) and write a JSON results file."

#: Whole-suite wall-clock budgets (s): full mode must fit in 30 min on 2 cores.
TOTAL_BUDGET = {"quick": 900.0, "full": 1680.0}


def discover() -> list[str]:
    """Names of the ``bench_*.py`` modules beside this file, sorted."""
    return sorted(p.stem for p in HERE.glob("bench_*.py"))


def _module_path(name: str) -> Path:
    """``bench_x`` → ``benchmarks/bench_x.py``; a path to a ``.py`` file is taken as is."""
    return Path(name).resolve() if name.endswith(".py") else HERE / f"{name}.py"


def bench_add_arguments(p: argparse.ArgumentParser) -> None:
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="small sizes and few repeats (CI smoke, minutes)")
    mode.add_argument("--full", action="store_true", help="full sizes (the default); the suite fits in 30 min")
    p.add_argument("--only", nargs="*", default=None, help="benchmark module names (e.g. bench_models) or paths to your own bench_*.py files")
    p.add_argument("-o", "--output", default="benchmarks/results/results.json", help="results JSON path")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="after the run, write report.md, headline.md and plots into DIR")
    p.add_argument("--budget-total", type=float, default=None,
                   help="wall-clock seconds for the whole suite, shared among modules "
                        f"(default {TOTAL_BUDGET['quick']:.0f} quick, {TOTAL_BUDGET['full']:.0f} full)")
    p.add_argument("--timeout", type=float, default=None,
                   help="cap on any one module's budget in seconds (default: none beyond its share)")
    p.add_argument("--allow-timeout", action="store_true",
                   help="exit 0 when modules only ran out of their time budget (their partial records "
                        "and the timeout are still recorded and reported); a module that errors "
                        "still fails the run. For smoke runs on a slow or shared machine (CI).")


def _pump(stream, sink, tail: collections.deque) -> None:
    for line in iter(stream.readline, ""):
        tail.append(line)
        sink.write(line)
        sink.flush()
    stream.close()


def run_module(name: str, *, quick: bool, budget: float, cwd: Path = HERE.parent) -> dict:
    """Run one benchmark module in a subprocess under ``budget`` seconds.

    **Returns:** ``{"status": "ok"|"failed"|"timeout", "records": [...], "wall_s",
    "budget_s", "returncode", "stderr_tail"}``. A timed-out module keeps the
    records it made before the deadline, marked ``"partial": true``.
    """
    with tempfile.TemporaryDirectory(prefix=f"jkbench-{Path(name).stem}-") as tmp:
        out_path = Path(tmp) / "records.json"
        partial_path = Path(tmp) / "partial.jsonl"
        env = dict(os.environ, JKATANA_BENCH_PARTIAL=str(partial_path),
                   JKATANA_BENCH_BUDGET_S=f"{budget:.1f}")
        target = str(Path(name).resolve()) if name.endswith(".py") else name
        cmd = [sys.executable, "-m", "benchmarks", "--_child", target, "--_out", str(out_path)]
        cmd += ["--quick"] if quick else []
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, start_new_session=True)
        tail: collections.deque = collections.deque(maxlen=60)
        pumps = [threading.Thread(target=_pump, args=(proc.stdout, sys.stderr, tail), daemon=True),
                 threading.Thread(target=_pump, args=(proc.stderr, sys.stderr, tail), daemon=True)]
        for t in pumps:
            t.start()
        timed_out = False
        try:
            proc.wait(timeout=budget)
        except subprocess.TimeoutExpired:
            timed_out = True
            try:
                os.killpg(proc.pid, 9)  # the child's own session: it and only its children
            except ProcessLookupError:
                pass
            proc.wait()
        for t in pumps:
            t.join(timeout=5)
        wall = time.perf_counter() - t0
        result = {"wall_s": round(wall, 2), "budget_s": round(budget, 1), "returncode": proc.returncode,
                  "stderr_tail": "".join(tail)[-4000:]}
        if not timed_out and proc.returncode == 0 and out_path.exists():
            result.update(status="ok", records=json.loads(out_path.read_text()))
            result.pop("stderr_tail")
            return result
        records = []
        if partial_path.exists():
            for line in partial_path.read_text().splitlines():
                try:
                    records.append(dict(json.loads(line), partial=True))
                except ValueError:
                    pass
        result.update(status="timeout" if timed_out else "failed", records=records)
        return result


def bench_run(args: argparse.Namespace) -> int:
    from benchmarks._harness import machine_facts
    from jkatana.io.limits import number

    # budgets checked before any work, as every command's numbers: a budget of 0 s or less starts modules
    # that can only time out
    number(args.budget_total, "--budget-total", lo=0, lo_open=True)
    number(args.timeout, "--timeout", lo=0, lo_open=True)
    mode = "quick" if args.quick else "full"
    names = args.only or discover()
    unknown = [n for n in names if not (_module_path(n)).exists()]
    if unknown:
        print(f"[bench] unknown benchmark module(s): {', '.join(unknown)}; known: {', '.join(discover())}",
              file=sys.stderr)
        return 2
    total = args.budget_total if args.budget_total is not None else TOTAL_BUDGET[mode]
    results = {"machine": machine_facts(), "mode": mode, "budget_total_s": total,
               "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "benchmarks": {}}
    failed = []
    t_suite = time.perf_counter()
    try:
        from tqdm import tqdm
        progress = tqdm(names, desc="bench", unit="module", file=sys.stderr)
    except ImportError:  # pragma: no cover
        progress = names
    for i, name in enumerate(progress):
        remaining = total - (time.perf_counter() - t_suite)
        budget = max(remaining / (len(names) - i), 5.0)
        if args.timeout is not None:
            budget = min(budget, args.timeout)
        print(f"[bench] {name} (budget {budget:.0f} s) ...", file=sys.stderr, flush=True)
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
        res = run_module(name, quick=args.quick, budget=budget)
        res["load_avg_1min_at_start"] = load
        key = Path(name).stem if name.endswith(".py") else name
        results["benchmarks"][key] = res
        msg = f"[bench] {key}: {res['status']}, {len(res['records'])} records in {res['wall_s']:.1f} s"
        print(msg, file=sys.stderr, flush=True)
        if res["status"] != "ok":
            failed.append(f"{key} ({res['status']})")
    results["wall_s"] = round(time.perf_counter() - t_suite, 2)
    results["failed"] = failed
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    from jkatana.io.atomic import write_text

    from benchmarks._harness import _json_default

    write_text(out, json.dumps(results, indent=1, default=_json_default))
    print(f"[bench] results: {out} ({results['wall_s']:.0f} s)", file=sys.stderr)
    if args.report:
        from benchmarks.report import write_report

        paths = write_report(results, args.report)
        print(f"[bench] report: {paths['report']}", file=sys.stderr)
    if failed:
        print(f"[bench] FAILED: {', '.join(failed)}", file=sys.stderr)
        errors = [k for k, r in results["benchmarks"].items() if r["status"] not in ("ok", "timeout")]
        if args.allow_timeout and not errors:
            print("[bench] only time-budget overruns (--allow-timeout): exit 0", file=sys.stderr)
            return 0
        return 1
    return 0


def _child(argv: list[str]) -> int:
    import importlib

    from benchmarks._harness import _json_default
    from jkatana.io.atomic import write_text

    name = argv[argv.index("--_child") + 1]
    out = argv[argv.index("--_out") + 1]
    if name.endswith(".py"):
        import importlib.util

        spec = importlib.util.spec_from_file_location(Path(name).stem, name)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    else:
        module = importlib.import_module(f"benchmarks.{name}")
    records = module.run(quick="--quick" in argv)
    write_text(out, json.dumps(records, default=_json_default))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--_child":
        return _child(argv)
    p = argparse.ArgumentParser(prog="python -m benchmarks", description=BENCH_HELP)
    bench_add_arguments(p)
    return bench_run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
