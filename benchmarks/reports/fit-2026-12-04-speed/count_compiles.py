"""XLA compilations and process CPU of `jkatana fit` run in-process, then a second fit of another table.

``python count_compiles.py TABLE_A TABLE_B [fit flags ...]`` (from a checkout, its .venv). Runs
``jkatana fit TABLE_A --region hiraji`` (plus the flags) through ``jkatana.cli.main``, then the same on
TABLE_B (same shape) in the same process. Every XLA compilation (``compiler.compile_or_get_cached``:
persistent-cache hits included, since those still lower and look up) is recorded with the program's name
and the innermost jkatana frame that caused it. Prints, per call: the compilation count, the process
CPU (user+sys) and a table of the compilations grouped by program and caller. Set ``JKATANA_CACHE`` to an
empty folder for a first call with an empty persistent cache.
"""
import collections
import os
import sys
import tempfile
import time
import traceback

from jax._src import compiler

records = []
_orig = compiler.compile_or_get_cached


def _hook(backend, computation, *a, **k):
    from jax._src.interpreters import mlir  # noqa: F401

    name = str(computation.operation.attributes["sym_name"]).strip('"')
    where = "?"
    for fr in reversed(traceback.extract_stack()[:-1]):
        if "/jkatana/" in fr.filename and "/site-packages/" not in fr.filename:
            where = f"{fr.filename.split('/jkatana/')[-1]}:{fr.lineno} {fr.name}"
            break
    t0 = time.process_time()
    out = _orig(backend, computation, *a, **k)
    records.append((name, where, time.process_time() - t0))
    return out


compiler.compile_or_get_cached = _hook

from jkatana.cli import main  # noqa: E402


def run(table, extra, label):
    start = len(records)
    out = os.path.join(tempfile.mkdtemp(), "p.json")
    c0, w0 = time.process_time(), time.perf_counter()
    rc = main(["fit", table, "--region", "hiraji", "-o", out, *extra])
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    mine = records[start:]
    print(f"== {label}: {table} rc={rc} compilations={len(mine)} cpu={cpu:.2f}s wall={wall:.2f}s "
          f"compile-cpu={sum(r[2] for r in mine):.2f}s load={os.getloadavg()[0]:.2f}", flush=True)
    groups, secs = collections.Counter(), collections.Counter()
    for n, w, s in mine:
        groups[n, w] += 1
        secs[n, w] += s
    print("  count  cpu-s  program                      caller (innermost jkatana frame)")
    for key, c in sorted(groups.items(), key=lambda kv: -secs[kv[0]]):
        print(f"  {c:5d}  {secs[key]:5.2f}  {key[0]:28s} {key[1]}")
    return len(mine), cpu


a, b, *extra = sys.argv[1:]
run(a, extra, "first fit")
run(b, extra, "second fit, another table of the same shape")
