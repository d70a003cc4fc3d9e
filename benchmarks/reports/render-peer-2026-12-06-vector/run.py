"""Re-run this report's study: ``python benchmarks/reports/render-peer-2026-12-06-vector/run.py [OUT_DIR]``.

Runs :func:`benchmarks.bench_render._mitsuba` at 256² (full mode's configurations and sample counts)
and writes ``results.json`` (with the machine's facts) and the rendered report (``report.md``, plots)
into ``OUT_DIR`` (default: this directory). Run it on an idle machine; the repository root on
``PYTHONPATH``.
"""

from __future__ import annotations

import os
import sys
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

from pathlib import Path  # noqa: E402


def main(argv: list[str]) -> int:
    from benchmarks._harness import _json_default, machine_facts
    from benchmarks.bench_render import _mitsuba
    from benchmarks.report import write_report
    from jkatana.io.atomic import write_text

    out = Path(argv[0]) if argv else Path(__file__).parent
    out.mkdir(parents=True, exist_ok=True)
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    rows = _mitsuba(False, size=256)
    results = {"mode": "full (Mitsuba study only, 256²)", "machine": machine_facts(),
               "run": {"wall_s": time.perf_counter() - t0, "load_avg_1min_start": load0,
                       "load_avg_1min_end": os.getloadavg()[0]},
               "benchmarks": {"render": {"records": rows}}}
    import json

    write_text(out / "results.json", json.dumps(results, indent=1, default=_json_default))
    write_report(results, out / "report")
    print(f"[render-peer] {time.perf_counter() - t0:.0f} s; results in {out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
