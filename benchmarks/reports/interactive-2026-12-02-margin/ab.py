"""CPU ms per 800x600 frame (process CPU, llvmpipe threads included) of shader-directory variants, alternated
frame by frame in one process (so that the machine's load hits every variant alike), and their frames'
difference from the first variant's.

usage: VIEWS=closeup,demo,glint N=20 ROUNDS=3 ab.py DIR[,DIR...]"""
import os, sys, time
import numpy as np
from jkatana.interactive import glrender as G
from jkatana.interactive import scene as S
from jkatana.interactive.bake import cached_bake
from validation import gl_agreement as A

dirs = sys.argv[1].split(",")
sc = S.default_scene("sky")
baked = cached_bake(sc.radiance, sc.grid, rank=4)
views_wanted = os.environ.get("VIEWS", "closeup").split(",")
views = {"demo": lambda: (sc.view, baked), "closeup": lambda: (S.closeup_view(sc.mesh), baked)}
if "glint" in views_wanted:
    sunrise = A.shared_environment("sunrise.exr")
    bsun = cached_bake(sunrise, sc.grid, rank=4)
    views["glint"] = lambda: (A.sun_glint_view(sc.mesh, sunrise, 800, 600), bsun)
N = int(os.environ.get("N", "20")); ROUNDS = int(os.environ.get("ROUNDS", "3"))
for vn in views_wanted:
    view, b = views[vn]()
    rs = []
    for d in dirs:
        st = G.ShadingState(b, sc.refl_map)
        r = G.BakedOffscreenRenderer(st, 800, 600, shader_dir=d)
        scene = G.build_scene(sc.mesh, view)
        for _ in range(3):
            r.draw(scene)
        rs.append((d, r, scene))
    cpu = {d: [] for d in dirs}; wall = {d: [] for d in dirs}
    for _ in range(ROUNDS * N):
        for d, r, scene in rs:
            c = time.process_time(); t = time.perf_counter(); r.draw(scene)
            wall[d].append(time.perf_counter() - t); cpu[d].append(time.process_time() - c)
    frames = [r.render(scene) for d, r, scene in rs]
    for d, r, scene in rs:
        r.delete()
    for d, f in zip(dirs, frames):
        diff = np.abs(f.astype(int) - frames[0].astype(int)).max(-1)
        x = 1e3 * np.asarray(cpu[d]); y = 1e3 * np.asarray(wall[d])
        print(f"{vn:8s} {os.path.basename(d.rstrip('/')):22s} cpu p25 {np.percentile(x, 25):6.2f} median {np.median(x):6.2f}"
              f"  wall p25 {np.percentile(y, 25):6.2f} median {np.median(y):6.2f} ms  | {(diff > 0).sum()} px differ, "
              f"max {diff.max()}  load {os.getloadavg()[0]:.2f}", flush=True)
