"""``fit-2026-12-05-idle/seeds.py`` (ten campaigns per lobe, wall and CPU ms of ``fit_program``) on a chosen pool.

``JKATANA_XLA_THREADS`` (default 1, the fit commands' pool; ``all`` for JAX's default, one per core) sizes XLA's
thread pool before JAX's backend starts (:func:`jkatana.runtime.xla_threads`); each output line is prefixed with
it. Run from the repository root: ``.venv/bin/python benchmarks/reports/fit-2026-12-05-pool/seeds.py [models...]``.
"""
import builtins
import os
import runpy
import sys

sys.path.insert(0, os.getcwd())
from jkatana.runtime import xla_threads  # noqa: E402

POOL = os.environ.get("JKATANA_XLA_THREADS", "1")
xla_threads(POOL)
_print = builtins.print
builtins.print = lambda *a, **k: _print(f"pool {POOL:3s}", *a, **k)
runpy.run_path(os.path.join(os.path.dirname(__file__), "..", "fit-2026-12-05-idle", "seeds.py"), run_name="__main__")
