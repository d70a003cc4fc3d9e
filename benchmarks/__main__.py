"""Run the benchmark suite: ``python -m benchmarks [--quick] [-o results.json]``.

Every ``bench_*.py`` module runs in a subprocess of its own (so its peak memory
and JIT cache are its own); the records and the machine's facts go into one
JSON file, written atomically. ``--report DIR`` then renders the report.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BENCH_HELP = "Run the benchmark suite (what accuracy costs in time) and write a JSON results file."


def discover() -> list[str]:
    return sorted(p.stem for p in HERE.glob("bench_*.py"))


def bench_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true", help="small sizes and few repeats (CI smoke)")
    p.add_argument("--only", nargs="*", default=None, help="benchmark module names (e.g. bench_models)")
    p.add_argument("-o", "--output", default="benchmarks/results/results.json")
    p.add_argument("--timeout", type=float, default=1800.0, help="seconds per benchmark module")


def _run_one(name: str, quick: bool) -> list[dict]:
    module = importlib.import_module(f"benchmarks.{name}")
    return module.run(quick=quick)


def bench_run(args: argparse.Namespace) -> int:
    from benchmarks._harness import machine_facts

    names = args.only or discover()
    results = {"machine": machine_facts(), "mode": "quick" if args.quick else "full",
               "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "benchmarks": {}}
    failed = []
    for name in names:
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "benchmarks", "--_child", name] + (["--quick"] if args.quick else [])
        print(f"[bench] {name} ...", flush=True)
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout,
                              cwd=HERE.parent)
        dt = time.perf_counter() - t0
        if proc.returncode != 0:
            failed.append(name)
            print(proc.stdout[-4000:], proc.stderr[-4000:], sep="\n", file=sys.stderr)
            results["benchmarks"][name] = {"error": proc.stderr[-4000:], "wall_s": dt}
            continue
        payload = json.loads(proc.stdout.strip().splitlines()[-1])
        results["benchmarks"][name] = {"records": payload, "wall_s": dt}
        print(f"[bench] {name}: {len(payload)} records in {dt:.1f} s", flush=True)
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(json.dumps(results, indent=1, default=float))
    os.replace(tmp, out)
    print(f"[bench] results: {out}")
    if failed:
        print(f"[bench] FAILED: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--_child":
        records = _run_one(argv[1], quick="--quick" in argv)
        print(json.dumps(records, default=float))
        return 0
    p = argparse.ArgumentParser(prog="python -m benchmarks", description=BENCH_HELP)
    bench_add_arguments(p)
    return bench_run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
