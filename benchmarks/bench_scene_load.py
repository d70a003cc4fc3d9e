"""A user's own environment and scan: first bake, second scene load, ``jkatana shape``.

Cases (each in a fresh subprocess with an empty cache folder, so its peak RSS is its own):

- ``bake``: the interactive path's first :func:`jkatana.interactive.bake.cached_bake` of a new HDR
  (the shared 1k ``pedestrian_overpass_1k.hdr``; full run: also that map resampled to 2k, 1024×2048),
  time and peak RSS, the cache entry's size, and the time to read it back;
- ``scene_load``: :func:`jkatana.render.renderer.prepare` of a scene with that HDR, first and second
  time (the second reads the environment cache, :mod:`jkatana.light.cache`);
- ``shape``: ``jkatana shape`` on the shared hammer scan (CC BY 4.0, Andrea Spognetta): units, xatlas UVs.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

_BAKE = """
import json, resource, sys, time, numpy as np
from pathlib import Path
from jkatana.render.scenefile import scene_from_dict
from jkatana.render.renderer import load_environment
from jkatana.interactive.bake import cached_bake
scene = scene_from_dict({{"environment": {{"type": "hdr", "path": {hdr!r}}}}})
grid = scene.spectral.grid
rad = np.asarray(load_environment(scene, grid))
if {scale} > 1:
    rad = rad.repeat({scale}, 0).repeat({scale}, 1)
t = time.perf_counter(); cached_bake(rad, grid, cache_dir={cache!r}); first = time.perf_counter() - t
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
t = time.perf_counter(); cached_bake(rad, grid, cache_dir={cache!r}); again = time.perf_counter() - t
size = sum(p.stat().st_size for p in Path({cache!r}).rglob("baked-*.npz")) / 2**20
print(json.dumps({{"first_s": first, "reload_s": again, "peak_rss_mb": peak, "cache_mb": size,
                   "shape": list(rad.shape)}}))
"""

_LOAD = """
import json, os, time
os.environ["JKATANA_CACHE"] = {cache!r}
from jkatana.render.scenefile import scene_from_dict
from jkatana.render.renderer import prepare
scene = scene_from_dict({{"environment": {{"type": "hdr", "path": {hdr!r}}}}})
out = []
for _ in range(2):
    t = time.perf_counter(); p = prepare(scene); out.append(time.perf_counter() - t)
print(json.dumps({{"first_s": out[0], "second_s": out[1]}}))
"""


def _run(code: str, timeout: float = 1200.0) -> dict:
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                       timeout=timeout)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


def run(quick: bool) -> list[dict]:
    from benchmarks._harness import record
    from jkatana.shared import shared_data

    hdr = str(shared_data("envmaps", "pedestrian_overpass_1k.hdr"))
    records = []
    for scale, name in ((1, "1k"),) if quick else ((1, "1k"), (2, "2k (1k resampled ×2)")):
        with tempfile.TemporaryDirectory() as cache:
            res = _run(_BAKE.format(hdr=hdr, scale=scale, cache=cache))
        records.append(record("bench_scene_load", {"stage": "first_bake", "hdr": name, "shape": res["shape"]},
                              time_s={"median": res["first_s"]}, first_bake_s=round(res["first_s"], 2),
                              reload_s=round(res["reload_s"], 2), case_peak_rss_mb=round(res["peak_rss_mb"], 1),
                              cache_mb=round(res["cache_mb"], 1)))
        print(f"bench_scene_load: bake {name}: {res['first_s']:.1f} s, peak {res['peak_rss_mb']:.0f} MB, "
              f"cache {res['cache_mb']:.1f} MB, reload {res['reload_s']:.2f} s", file=sys.stderr)
    with tempfile.TemporaryDirectory() as cache:
        res = _run(_LOAD.format(hdr=hdr, cache=cache))
    records.append(record("bench_scene_load", {"stage": "scene_load", "hdr": "1k"},
                          time_s={"median": res["second_s"]}, first_s=round(res["first_s"], 2),
                          second_s=round(res["second_s"], 3)))
    print(f"bench_scene_load: prepare 1k HDR scene: first {res['first_s']:.1f} s, second {res['second_s']:.2f} s",
          file=sys.stderr)
    import time

    from jkatana.shape.mesh import prepare_mesh, read_mesh

    src = shared_data("scans", "hammer", "hammer.obj")
    t = time.perf_counter()
    mesh, rep = prepare_mesh(read_mesh(src), source=Path(src).name, suffix=".obj")
    dt = time.perf_counter() - t
    records.append(record("bench_scene_load", {"stage": "shape", "mesh": "hammer.obj (CC BY 4.0, A. Spognetta)"},
                          time_s={"median": dt}, units=rep.units, uv=rep.uv, uv_stretch=rep.uv_stretch,
                          faces=rep.faces_out))
    print(f"bench_scene_load: shape hammer.obj {dt:.2f} s ({rep.units}, {rep.uv}, stretch {rep.uv_stretch})",
          file=sys.stderr)
    return records
