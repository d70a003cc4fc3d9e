"""CPU ms per 800x600 frame (process CPU time, llvmpipe threads included) per view, per variant: a shader
directory, or old:DIR for the committed glrender ($OLD_GLRENDER) with that directory.

usage: prof.py VARIANT_DIR[,VARIANT_DIR...] [--cfg k=v ...]
Each variant is a shader directory (A/B in one process, alternated, min over rounds of the per-round median)."""
import os, sys, time
import numpy as np
from jkatana.interactive import glrender as G
from jkatana.interactive import scene as S
from jkatana.interactive.bake import cached_bake
from validation import gl_agreement as A
from jkatana.interactive import glprograms as _P
if os.environ.get("NOCHECK"):
    _P.BakedProgram.check_uniforms = lambda self: None

dirs = sys.argv[1].split(",")
OLD = None
if any(d.startswith("old:") for d in dirs):      # the committed glrender, for A/B in one process
    import importlib.util
    spec = importlib.util.spec_from_file_location("glrender_old", os.environ.get("OLD_GLRENDER", "/tmp/jkv/glrender_old.py"))
    OLD = importlib.util.module_from_spec(spec); spec.loader.exec_module(OLD); OLD._EGL_LIVE = G._EGL_LIVE
cfg = dict(a.split("=") for a in sys.argv[2:])
cfg = {k: (int(v) if v.isdigit() else v) for k, v in cfg.items()}
views_wanted = os.environ.get("VIEWS", "demo,closeup,glint").split(",")
sc = S.default_scene("sky")
baked = cached_bake(sc.radiance, sc.grid, rank=4)
sunrise = A.shared_environment("sunrise.exr")
bsun = cached_bake(sunrise, sc.grid, rank=4)
views = {"demo": (sc.view, baked), "closeup": (S.closeup_view(sc.mesh), baked),
         "glint": (A.sun_glint_view(sc.mesh, sunrise, 800, 600), bsun),
         "empty": (S.View(S.look_at(np.array([0.0, 0.0, 5.0]), np.array([0.0, 0.0, 10.0])), sc.view.yfov, 800, 600), baked)}
N = int(os.environ.get("N", "10")); ROUNDS = int(os.environ.get("ROUNDS", "3"))
out = {}
for vn in views_wanted:
    view, b = views[vn]
    rs = []
    for d in dirs:
        st = G.ShadingState(b, sc.refl_map, **cfg)
        M = OLD if d.startswith("old:") else G
        r = M.BakedOffscreenRenderer(st, 800, 600, shader_dir=d.removeprefix("old:"))
        scene = M.build_scene(sc.mesh, view)
        for _ in range(3):
            r.draw(scene)
        rs.append((d, r, scene))
    res = {d: [] for d in dirs}
    for _ in range(ROUNDS * N):                   # variants alternate frame by frame
        for d, r, scene in rs:
            c = time.process_time(); r.draw(scene); res[d].append(time.process_time() - c)
    frames = [r.render(scene) for d, r, scene in rs]
    for d, r, scene in rs:
        r.delete()
    for d, f in zip(dirs[1:], frames[1:]):
        diff = np.abs(f.astype(int) - frames[0].astype(int)).max(-1)
        print(f"{vn:8s} {d}: frame vs {dirs[0]}: {(diff > 0).sum()} px differ, max {diff.max()}")
    for d in dirs:
        x = 1e3 * np.asarray(res[d])
        print(f"{vn:8s} {d:34s} cpu p10 {np.percentile(x, 10):6.2f}  p25 {np.percentile(x, 25):6.2f}  median {np.median(x):6.2f} ms/frame ({len(x)} frames)  load {os.getloadavg()[0]:.2f}", flush=True)
