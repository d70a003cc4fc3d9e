"""The sun-glint view of nonpaper_sun.py split into the cap's share and the remainder's, in both renderers:
the reference with the remainder map only (the sun split off by split_compact_sources) against the GL frame
with the caps dropped from the bake, and the cap's share (full − remainder, linear display values, pixels
unsaturated in both) GL / reference."""
import dataclasses
import jax.numpy as jnp
import numpy as np

exec(open("benchmarks/reports/interactive-2026-12-02-margin/nonpaper_sun.py").read().split("maps = np.asarray")[0])
maps = np.asarray(prep.maps, np.float64)
from jkatana.interactive import levels as LV
from jkatana.light.envmap import EnvMap
from jkatana.light.sun import split_compact_sources
from jkatana.spectral import DEFAULT_GRID
baked = B.cached_bake(sun, rank=3, mus=LV.MU_LEVELS[2:9], lobes=region_lobes(keys), split_sun=True)
rem = np.asarray(split_compact_sources(EnvMap(jnp.asarray(sun, jnp.float32), DEFAULT_GRID), max_sources=4).remainder.radiance, np.float32)
frr = render_view(prepare(scene_from_dict(d), env_radiance=rem))
b0 = dataclasses.replace(baked, cap_dir=np.zeros((0, 3)), cap_radius=np.zeros((0,)), cap_q=np.zeros((0, 3, 3)))
img0, m0 = A.gl_frame(glr.ShadingState(b0, maps, exposure=exposure), view, mesh, return_mask=True)
img, m = A.gl_frame(glr.ShadingState(baked, maps, exposure=exposure), view, mesh, return_mask=True)
mm = fr.mask & m
print("full", A.compare(img, ref, mm)[0])
print("remainder only", A.compare(img0, A.display255(frr.xyz, exposure), mm)[0])
# the cap's share in linear display values (sRGB decoded)
def lin(x):
    c = np.asarray(x, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
Lg, Lg0 = lin(img).mean(-1), lin(img0).mean(-1)
Lr, Lr0 = lin(ref).mean(-1), lin(A.display255(frr.xyz, exposure)).mean(-1)
unsat = mm & (img.max(-1) < 250) & (ref.max(-1) < 250)
capg, capr = Lg - Lg0, Lr - Lr0
print("unsat px", unsat.sum(), "cap share gl/ref", capg[unsat].sum() / capr[unsat].sum(), "remainder gl/ref", Lg0[unsat].sum() / Lr0[unsat].sum())
print("cap fraction of ref", capr[unsat].sum() / Lr[unsat].sum())
