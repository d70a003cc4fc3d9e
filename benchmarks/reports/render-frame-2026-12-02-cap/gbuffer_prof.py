"""The G-buffer's host steps on the default view (800×600, 69 k candidate rays): median wall and process CPU
of 9 calls after 2 warm-ups, the load beside them.

``PYTHONPATH=<checkout> python benchmarks/reports/render-frame-2026-12-02-cap/gbuffer_prof.py`` (at the base
commit only ``gbuffer_mesh``, ``candidates``, ``rays`` and ``embree run`` exist).
"""
import os
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
import numpy as np  # noqa: E402

import jkatana.render.gbuffer as G  # noqa: E402
from benchmarks.bench_render import _scenes  # noqa: E402
from jkatana.render.renderer import camera_for, prepare  # noqa: E402
from jkatana.render.scenefile import scene_from_dict  # noqa: E402

prep = prepare(scene_from_dict(_scenes(False)["default (blade, low sun)"]), mode="prefiltered", samples=1,
               split_sun=True)
mesh, cam = prep.geometry, camera_for(prep.scene, 0, 1)


def T(name, f, n=9):
    f()
    f()
    rows = []
    for _ in range(n):
        c0, t0 = time.process_time(), time.perf_counter()
        f()
        rows.append((time.perf_counter() - t0, time.process_time() - c0))
    print(name, "wall %.4f cpu %.4f" % tuple(np.median(np.array(rows), 0)), "load %.1f" % os.getloadavg()[0],
          flush=True)


T("gbuffer_mesh", lambda: G.gbuffer_mesh(mesh, cam))
T("candidates", lambda: G.candidate_pixels(mesh, cam))
cand = G.candidate_pixels(mesh, cam)
T("rays", lambda: cam.rays(cand))
origin, dc = cam.rays(cand)
isect, _ = G._intersector(mesh)
o = np.broadcast_to(np.asarray(origin, np.float64), dc.shape)
T("embree run", lambda: isect._scene.run(o, np.asarray(dc, np.float64)))
if hasattr(G, "_face_table"):
    faces = G._face_table(mesh)
    T("embree + barycentrics", lambda: G._embree_first_hits(isect, origin, dc, faces))
    idx_ray, idx_tri, u, v, f = G._embree_first_hits(isect, origin, dc, faces)
    T("interpolation", lambda: G._interpolate(f, u, v, dc[idx_ray]))
