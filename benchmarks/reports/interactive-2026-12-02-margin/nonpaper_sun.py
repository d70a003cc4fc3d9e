"""A sun (split cap) on regions holding non-paper lobes: GGX hiraji (α 0.05) and Beckmann hamon (α 0.12) from
parameter files, under the shared sunrise.exr with its sun split off, at the sun-glint view (160×120, as the
agreement tests): ΔE2000 of the GL frame against jkatana.render's reference mode (256 spp, the same files),
with and without the split; the paper's tables on the same maps for contrast."""
import json, os, sys, tempfile, time
from pathlib import Path
import numpy as np
import jax.numpy as jnp
from jkatana.interactive import glrender as glr
from jkatana.interactive import scene as S, bake as B, levels as LV
from jkatana.interactive.lobe_tables import region_lobes
from jkatana.fit._model import FIT_MODELS
from jkatana.render.film import auto_exposure
from jkatana.render.renderer import prepare, render_view
from jkatana.render.scene import scene_from_dict
from validation import gl_agreement as A


def params_file(path, model, region, values):
    fm = FIT_MODELS[model]
    lobe = fm.build(jnp.asarray(fm.shape_from_natural(values))).to_params()
    path.write_text(json.dumps({"format": "jkatana-params/1", "region": region, "model": model, "lobe": lobe,
                                "values": values, "optical_constants": "Fe-Johnson", "converged": True}))
    return str(path)


tmp = Path(tempfile.mkdtemp())
mesh = S.blade()
sun = A.shared_environment("sunrise.exr")
w, h = (int(x) for x in os.environ.get("RES", "160x120").split("x"))
view = A.sun_glint_view(mesh, sun, w, h)
d = A.render_scene(view, samples=256)
d["material"]["hiraji"] = params_file(tmp / "hiraji.json", "ggx", "hiraji", {"scale": 2000.0, "alpha": 0.05})
d["material"]["hamon"] = params_file(tmp / "hamon.json", "beckmann", "hamon", {"scale": 2000.0, "alpha": 0.12})
t = time.perf_counter()
prep = prepare(scene_from_dict(d), env_radiance=np.asarray(sun, np.float32))
keys = {"hiraji": prep.plan.hiraji_lobe, "hamon": prep.plan.hamon_lobe}
fr = render_view(prep)
print(f"reference {w}×{h} in {time.perf_counter() - t:.1f} s; lobes {keys['hiraji'][0]}, {keys['hamon'][0]}", flush=True)
exposure = auto_exposure(fr.xyz, fr.mask, key=0.6, percentile=75.0)
ref = A.display255(fr.xyz, exposure)
maps = np.asarray(prep.maps, np.float64)
mus = LV.MU_LEVELS[2:9]
for name, lobes, levels, split in (("files, sun split", region_lobes(keys), mus, True),
                                   ("files, no split", region_lobes(keys), mus, False),
                                   ("paper tables, sun split", region_lobes(), LV.MU_LEVELS, True)):
    t = time.perf_counter()
    baked = B.cached_bake(sun, rank=3, mus=levels, lobes=lobes, split_sun=split)
    for rank in (2, 3):
        st = glr.ShadingState(baked, maps, exposure=exposure, rank=rank)
        img, m = A.gl_frame(st, view, mesh, return_mask=True)
        s, de = A.compare(img, ref, fr.mask & m)
        # the glint: pixels whose reference is within 1 stop of the brightest
        Y = fr.xyz[..., 1]
        glint = fr.mask & m & (Y >= 0.5 * Y[fr.mask].max())
        print(f"{name:24s} rank {rank} caps {baked.n_caps}: ΔE2000 mean {s['mean']:.3f} p95 {s['p95']:.3f} max {s['max']:.2f} "
              f"({s['pixels']} px; glint {glint.sum()} px mean {de[glint].mean():.2f})  bake {time.perf_counter() - t:.0f} s",
              flush=True)
        if os.environ.get("SAVE") and rank == 2:
            import imageio.v3 as iio
            scale = np.clip(de * 255.0 / 10.0, 0, 255)
            iio.imwrite(Path(os.environ["SAVE"]) / f"nonpaper-{name.split(',')[0].split()[0]}-{int(split)}.png",
                        np.concatenate([np.clip(ref, 0, 255), img, np.stack([scale] * 3, -1)], 1).astype(np.uint8))
if os.environ.get("DEBUG"):
    baked = B.cached_bake(sun, rank=3, mus=mus, lobes=region_lobes(keys), split_sun=True)
    st = glr.ShadingState(baked, maps, exposure=exposure)
    img, m = A.gl_frame(st, view, mesh, return_mask=True)
    s, de = A.compare(img, ref, fr.mask & m)
    mm = fr.mask & m
    print("mask px", fr.mask.sum(), m.sum(), mm.sum(), "de pct", np.percentile(de[mm], [10, 50, 75, 90, 99]))
    ys, xs = np.nonzero(mm & (de > 5))
    print("bad rows", np.unique(ys), "cols", xs.min(), xs.max())
    print("ref vs gl at bad", ref[ys[:5], xs[:5]], img[ys[:5], xs[:5]])
    print("wmap at bad", maps[..., 0].mean())
