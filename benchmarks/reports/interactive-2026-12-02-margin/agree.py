"""ΔE2000 (mean / p95) of GL frames against jkatana.render (reference mode, 256 spp) on every agreement view
(the tests' and bench_interactive's), per shader directory and ShadingState settings.

usage: agree.py DIR[,DIR...] [k=v ...]   (references cached in $REFCACHE, default /tmp/jk_refs)"""
import os, sys, pathlib
import numpy as np
from jkatana.interactive import glrender as glr
from jkatana.interactive import scene as S, bake as B
from validation import gl_agreement as A
from jkatana.render.film import auto_exposure
from jkatana.interactive import glprograms as _P
if os.environ.get("NOCHECK"):
    _P.BakedProgram.check_uniforms = lambda self: None

dirs = sys.argv[1].split(",")
cfg = {k: (int(v) if v.isdigit() else v) for k, v in (a.split("=") for a in sys.argv[2:])}
cache = pathlib.Path(os.environ.get("REFCACHE", "/tmp/jk_refs")); cache.mkdir(exist_ok=True)
mesh = S.blade(); refl = S.reflectance_map().stacked()
sky = S.environment("sky"); studio = S.environment("studio"); sun = A.shared_environment("sunrise.exr")
sc = S.default_scene("sky")
views = {
    "sky_orbit": (sky, S.orbit_views(mesh, 3, 200, 150, distance=0.45)[0], None),
    "studio_demo": (studio, S.demo_view(120, 90), "auto"),
    "sky_closeup": (sky, S.closeup_view(mesh, 160, 120), None),
    "sun_glint": (sun, A.sun_glint_view(mesh, sun, 160, 120), "auto"),
    "bench_demo": (sky, S.View(sc.view.pose, sc.view.yfov, 200, 150), None),
    "bench_closeup": (sky, S.closeup_view(mesh, 200, 150), None),
    "bench_glint": (sun, A.sun_glint_view(mesh, sun, 200, 150), "auto"),
}
want = os.environ.get("AVIEWS")
bakes = {}
for vn, (rad, view, ex) in views.items():
    if want and vn not in want.split(","):
        continue
    f = cache / f"{vn}.npz"
    if f.exists():
        z = np.load(f); xyz, mask = z["xyz"], z["mask"]
    else:
        fr = A.reference_frame(rad, view, samples=256, seed=0)
        xyz, mask = fr.xyz, fr.mask
        np.savez(f, xyz=xyz, mask=mask)
    exposure = auto_exposure(xyz, mask, key=0.6, percentile=75.0) if ex else 1.0
    ref = A.display255(xyz, exposure)
    key = id(rad)
    if key not in bakes:
        bakes[key] = B.cached_bake(rad, rank=3)
    for d in dirs:
        st = glr.ShadingState(bakes[key], refl, exposure=exposure, **cfg)
        r = glr.BakedOffscreenRenderer(st, view.width, view.height, shader_dir=d)
        img = r.render(glr.build_scene(mesh, view), mask=True)
        m = r.last_mask.copy(); r.delete()
        s = A.compare(img, ref, mask & m)[0]
        ok = "ok" if s["mean"] <= 1 and s["p95"] <= 2.5 else "FAIL"
        print(f"{vn:13s} {os.path.basename(d.rstrip('/')):10s} ΔE mean {s['mean']:.3f} p95 {s['p95']:.3f} max {s['max']:.2f} {ok}", flush=True)
