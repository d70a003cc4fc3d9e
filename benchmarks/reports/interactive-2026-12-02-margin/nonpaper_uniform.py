"""The sun-glint view of nonpaper_sun.py on a uniform map, one region at a time (w 1: GGX hiraji α 0.05 only;
w 0: Beckmann hamon α 0.12 only): ΔE2000 of the full frame, the remainder alone (GL without caps vs the reference
of the remainder map), the cap's and the remainder's shares GL / reference (linear display values, unsaturated
pixels), and the same bake through the closed-form moments rule."""
import dataclasses, tempfile, numpy as np, jax.numpy as jnp
from pathlib import Path
exec(open("benchmarks/reports/interactive-2026-12-02-margin/nonpaper_sun.py").read().split("tmp = Path")[0])
from jkatana.light.envmap import EnvMap
from jkatana.light.sun import split_compact_sources
from jkatana.spectral import DEFAULT_GRID
tmp = Path(tempfile.mkdtemp())
mesh = S.blade(); sun = A.shared_environment("sunrise.exr"); view = A.sun_glint_view(mesh, sun, 160, 120)
rem = np.asarray(split_compact_sources(EnvMap(jnp.asarray(sun, jnp.float32), DEFAULT_GRID), max_sources=4).remainder.radiance, np.float32)
def lin(x):
    c = np.asarray(x, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
for wv in (1.0, 0.0):
    d = A.render_scene(view, samples=256)
    d["material"] = {"w": wv, "mu0": 0.05, "mu1": 0.12, "optical_constants": "Fe-Johnson"}
    d["material"]["hiraji"] = params_file(tmp / "hiraji.json", "ggx", "hiraji", {"scale": 2000.0, "alpha": 0.05})
    d["material"]["hamon"] = params_file(tmp / "hamon.json", "beckmann", "hamon", {"scale": 2000.0, "alpha": 0.12})
    prep = prepare(scene_from_dict(d), env_radiance=np.asarray(sun, np.float32))
    keys = {"hiraji": prep.plan.hiraji_lobe, "hamon": prep.plan.hamon_lobe}
    fr = render_view(prep)
    frr = render_view(prepare(scene_from_dict(d), env_radiance=rem))
    exposure = auto_exposure(fr.xyz, fr.mask, key=0.6, percentile=75.0)
    ref, ref0 = A.display255(fr.xyz, exposure), A.display255(frr.xyz, exposure)
    baked = B.cached_bake(sun, rank=3, mus=LV.MU_LEVELS[2:9], lobes=region_lobes(keys))
    b0 = dataclasses.replace(baked, cap_dir=np.zeros((0, 3)), cap_radius=np.zeros((0,)), cap_q=np.zeros((0, 3, 3)))
    maps = np.asarray(prep.maps, np.float64)
    img, m = A.gl_frame(glr.ShadingState(baked, maps, exposure=exposure), view, mesh, return_mask=True)
    img0 = A.gl_frame(glr.ShadingState(b0, maps, exposure=exposure), view, mesh)
    mm = fr.mask & m
    unsat = mm & (img.max(-1) < 250) & (ref.max(-1) < 250)
    Lg, Lg0, Lr, Lr0 = (lin(x).mean(-1) for x in (img, img0, ref, ref0))
    print("w", wv, "full", A.compare(img, ref, mm)[0]["mean"], "remainder", A.compare(img0, ref0, mm)[0],
          "cap gl/ref", (Lg - Lg0)[unsat].sum() / (Lr - Lr0)[unsat].sum(), "rem gl/ref", Lg0[unsat].sum() / Lr0[unsat].sum(),
          "cap frac", (Lr - Lr0)[unsat].sum() / Lr[unsat].sum(), flush=True)
    bm = dataclasses.replace(baked, cap_kernel=np.zeros((0,)))
    imgm = A.gl_frame(glr.ShadingState(bm, maps, exposure=exposure), view, mesh)
    Lm = lin(imgm).mean(-1)
    print("moments: full", A.compare(imgm, ref, mm)[0]["mean"], "cap gl/ref", (Lm - Lg0)[unsat].sum() / (Lr - Lr0)[unsat].sum())
    # per-pixel cap ratio vs cos: where is the excess
    cr = (Lg - Lg0)[unsat]; rr = (Lr - Lr0)[unsat]
    big = rr > np.percentile(rr, 50)
    print("cap ratio on brighter half", cr[big].sum() / rr[big].sum(), "dimmer half", cr[~big].sum() / rr[~big].sum())
