"""Per-stage wall and CPU of warmed prefiltered frames (the two sun-dominated views), as in NOTES.md.

``PYTHONPATH=<checkout> python benchmarks/reports/render-frame-2026-12-02-cap/prof.py [default] [glint]``:
5 timed frames after 2 warm-ups, medians (wall, process CPU of all threads, and each stage of
``Frame.timing``), the load beside them. ``ab.sh`` runs it alternately at the base commit's tree and
at this branch.
"""
import os
import sys
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
import numpy as np  # noqa: E402

from benchmarks.bench_render import _scenes  # noqa: E402
from jkatana.render.renderer import prepare, render_view  # noqa: E402
from jkatana.render.scenefile import scene_from_dict  # noqa: E402

NAMES = {"default": "default (blade, low sun)", "glint": "sun glint (blade, sunrise.exr)"}
scenes = _scenes(False)
for w in sys.argv[1:] or list(NAMES):
    prep = prepare(scene_from_dict(scenes[NAMES[w]]), mode="prefiltered", samples=1, split_sun=True)
    render_view(prep, seed=1)
    render_view(prep, seed=1)
    rows = []
    for _ in range(5):
        c0, t0 = time.process_time(), time.perf_counter()
        f = render_view(prep, seed=1)
        rows.append((time.perf_counter() - t0, time.process_time() - c0, f.timing))
    stages = {k: round(float(np.median([r[2][k] for r in rows])), 4) for k in rows[0][2]}
    print(w, f"wall {np.median([r[0] for r in rows]):.3f} cpu {np.median([r[1] for r in rows]):.3f}", stages,
          "load", round(os.getloadavg()[0], 2), flush=True)
