"""A/B frame times, same process, variants alternated. usage: ab.py ROUNDS [variant ...]"""
import os, sys, time, resource
import numpy as np
from jkatana.interactive import glrender as G
from jkatana.interactive import scene as S
from jkatana.interactive.bake import cached_bake
from validation import gl_agreement as A

def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF); return r.ru_utime + r.ru_stime

rounds = int(sys.argv[1]); names = sys.argv[2:]
sc = S.default_scene("sky")
baked = cached_bake(sc.radiance, sc.grid, rank=4)
sun = A.shared_environment("sunrise.exr")
baked_sun = cached_bake(sun, sc.grid, rank=4)
print("caps sky", baked.n_caps, "sunrise", baked_sun.n_caps, file=sys.stderr)
from OpenGL import GL
VAR = {
 "rank2_f16": dict(rank=2, env_format=GL.GL_RGBA16F), "rank2_rgb32": dict(rank=2, env_format=GL.GL_RGB32F),
 "rank2_rgb16": dict(rank=2, env_format=GL.GL_RGB16F), "rank2_r11": dict(rank=2, env_format=GL.GL_R11F_G11F_B10F),
 "full": dict(rank=3), "rank2": dict(rank=2), "one_tap": dict(rank=3, two_tap=False),
 "rank2_one_tap": dict(rank=2, two_tap=False), "nofit": dict(rank=3, fit=False),
}
views = {"closeup": (S.closeup_view(sc.mesh), baked), "demo": (sc.view, baked),
         "closeup_sun": (S.closeup_view(sc.mesh), baked_sun), "glint": (A.sun_glint_view(sc.mesh, sun, 800, 600), baked_sun)}
only = os.environ.get("VIEWS")
if only: views = {k: v for k, v in views.items() if k in only.split(",")}
rs = {}
from pathlib import Path
NEW_DIR = G.SHADER_DIR
for n in names:
    base, _, sdir = n.partition("@")
    cfg = VAR[base]
    for v, (view, b) in views.items():
        st = G.ShadingState(b, sc.refl_map, **cfg)
        r = G.BakedOffscreenRenderer(st, 800, 600, shader_dir=Path(sdir) if sdir else NEW_DIR); scene = G.build_scene(sc.mesh, view)
        for _ in range(3): r.draw(scene)
        if os.environ.get("SAVE"):
            import imageio.v3 as iio; iio.imwrite(f"/tmp/d/{n.replace('/', '_')}_{v}.png", r.render(scene))
        rs[n, v] = (r, scene)
res = {k: [] for k in rs}; cp = {k: [] for k in rs}
for _ in range(rounds):
    for k, (r, scene) in rs.items():
        r._r._platform.make_current()
        ts = []; c = cpu()
        for _ in range(5):
            t = time.perf_counter(); r.draw(scene); ts.append(time.perf_counter() - t)
        cp[k].append((cpu() - c) / 5)
        res[k].append(min(ts))
for k, v in res.items():
    print(f"{k[0][:20]:20s} {k[1]:12s} wall min {1e3*min(v):6.1f} med {1e3*np.median(v):6.1f}  cpu med {1e3*np.median(cp[k]):6.1f} ms", flush=True)
print("load", os.getloadavg())
