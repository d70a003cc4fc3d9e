"""ΔE of GL frames (rank 3, rank 2, one tap) against the reference, on the agreement views incl. closeup and glint."""
import sys, numpy as np
from jkatana.interactive import glrender as glr
from jkatana.interactive import scene as S, bake as B
from validation import gl_agreement as A
from jkatana.render.film import auto_exposure
mesh = S.blade(); refl = S.reflectance_map().stacked()
sky = S.environment("sky"); studio = S.environment("studio"); sun = A.shared_environment("sunrise.exr")
views = {
  "sky_orbit": (sky, S.orbit_views(mesh, 3, 200, 150, distance=0.45)[0], None),
  "studio_demo": (studio, S.demo_view(120, 90), "auto"),
  "sky_closeup": (sky, S.closeup_view(mesh, 160, 120), None),
  "sun_glint": (sun, A.sun_glint_view(mesh, sun, 160, 120), "auto"),
}
cfgs = {"rank3": dict(rank=3), "rank2": dict(rank=2), "rank2_one_tap": dict(rank=2, two_tap=False)}
for vn, (rad, view, ex) in views.items():
    fr = A.reference_frame(rad, view, samples=256, seed=0)
    exposure = auto_exposure(fr.xyz, fr.mask, key=0.6, percentile=75.0) if ex else 1.0
    ref = A.display255(fr.xyz, exposure)
    baked = B.cached_bake(rad, rank=3)
    for cn, cfg in cfgs.items():
        st = glr.ShadingState(baked, refl, exposure=exposure, **cfg)
        img, m = A.gl_frame(st, view, mesh, return_mask=True)
        s = A.compare(img, ref, fr.mask & m)[0]
        print(f"{vn:12s} {cn:14s} ΔE mean {s['mean']:.3f} p95 {s['p95']:.3f} max {s['max']:.2f} px {s['pixels']}", flush=True)
