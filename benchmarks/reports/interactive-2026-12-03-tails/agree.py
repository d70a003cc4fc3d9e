"""The sun-glint view of the slow test (GGX hiraji α 0.05, Beckmann hamon α 0.12 from parameter files, sunrise.exr,
sun split, 160×120) against jkatana.render's reference (256 spp): the GL frame with
the tail tap (the bake's default now) and the same bake without it (tail weight 0: the three taps of taps.tap_fit,
the frame before), rank 2 and 3; the remainder alone (no caps) vs the reference of the remainder map, and its
share GL/reference on unsaturated pixels. The reference renders are cached in /tmp (REF_CACHE). PNGs: SAVE=dir."""
import dataclasses, os, tempfile
from pathlib import Path
import numpy as np, jax.numpy as jnp
here = Path(__file__).resolve().parents[1] / "interactive-2026-12-02-margin"
exec((here / "nonpaper_sun.py").read_text().split("tmp = Path")[0])
from jkatana.light.envmap import EnvMap
from jkatana.light.sun import split_compact_sources
from jkatana.spectral import DEFAULT_GRID
tmp = Path(tempfile.mkdtemp())
mesh = S.blade(); sun = A.shared_environment("sunrise.exr"); view = A.sun_glint_view(mesh, sun, 160, 120)
rem = np.asarray(split_compact_sources(EnvMap(jnp.asarray(sun, jnp.float32), DEFAULT_GRID), max_sources=4).remainder.radiance, np.float32)
d = A.render_scene(view, samples=256)
d["material"]["hiraji"] = params_file(tmp / "hiraji.json", "ggx", "hiraji", {"scale": 2000.0, "alpha": 0.05})
d["material"]["hamon"] = params_file(tmp / "hamon.json", "beckmann", "hamon", {"scale": 2000.0, "alpha": 0.12})
prep = prepare(scene_from_dict(d), env_radiance=np.asarray(sun, np.float32))
keys = {"hiraji": prep.plan.hiraji_lobe, "hamon": prep.plan.hamon_lobe}
cache = Path(os.environ.get("REF_CACHE", "/tmp/jk-b-ref.npz"))
if cache.exists():
    z = np.load(cache); xyz, mask, xyz_rem = z["xyz"], z["mask"], z["xyz_rem"]
else:
    fr = render_view(prep); xyz, mask = np.asarray(fr.xyz), np.asarray(fr.mask)
    xyz_rem = np.asarray(render_view(prepare(scene_from_dict(d), env_radiance=rem)).xyz)
    np.savez(cache, xyz=xyz, mask=mask, xyz_rem=xyz_rem)
if os.environ.get("REF_ONLY"):
    raise SystemExit(0)
exposure = auto_exposure(xyz, mask, key=0.6, percentile=75.0)
ref, ref_rem = A.display255(xyz, exposure), A.display255(xyz_rem, exposure)
def lin(x):
    c = np.asarray(x, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
maps = np.asarray(prep.maps, np.float64)
baked = B.cached_bake(sun, rank=3, mus=LV.MU_LEVELS[2:9], lobes=region_lobes(keys))
print("tail weight: hiraji mean", baked.tail[0, ..., 2].mean(), "hamon mean", baked.tail[1, ..., 2].mean())
for name, bk in (("tail tap", baked), ("three taps (before)", dataclasses.replace(baked, tail=np.zeros_like(baked.tail)))):
    # "before" keeps the tail fit's three taps; the three-tap table of tap_fit is the frame before
    if name.startswith("three"):
        from jkatana.interactive.tables import cached_tap_fit
        from jkatana.interactive.taps import resolved_taps
        from jkatana.models import Conductor
        cond = Conductor.from_table("Fe-Johnson", DEFAULT_GRID, dtype=jnp.float64)
        t3, _, _ = cached_tap_fit(cond, LV.MU_LEVELS[2:9], 64, None, region_lobes(keys))
        bk = dataclasses.replace(bk, taps=resolved_taps(t3, bk.spread, bk.mus, sun.shape[0]))
    for rank in (2, 3):
        st = glr.ShadingState(bk, maps, exposure=exposure, rank=rank)
        img, m = A.gl_frame(st, view, mesh, return_mask=True)
        b0 = dataclasses.replace(bk, cap_dir=np.zeros((0, 3)), cap_radius=np.zeros((0,)), cap_q=np.zeros((0, rank if False else bk.rank, 3)), cap_kernel=np.zeros((0,)))
        img0 = A.gl_frame(glr.ShadingState(b0, maps, exposure=exposure, rank=rank), view, mesh)
        mm = mask & m
        unsat = mm & (img.max(-1) < 250) & (ref.max(-1) < 250)
        s = A.compare(img, ref, mm)[0]
        s0 = A.compare(img0, ref_rem, mm)[0]
        share = lin(img0).mean(-1)[unsat].sum() / lin(ref_rem).mean(-1)[unsat].sum()
        print(f"{name:20s} rank {rank}: full ΔE2000 mean {s['mean']:.3f} p95 {s['p95']:.3f} ({s['pixels']} px) | "
              f"remainder alone mean {s0['mean']:.3f} p95 {s0['p95']:.3f}, GL/ref {share:.3f}", flush=True)
        if os.environ.get("SAVE") and rank == 2:
            import imageio.v3 as iio
            out = Path(os.environ["SAVE"]); out.mkdir(exist_ok=True, parents=True)
            tag = "tail" if name == "tail tap" else "before"
            de = A.compare(img, ref, mm)[1]
            iio.imwrite(out / f"glint-{tag}.png", np.concatenate([img[..., :3].astype(np.uint8), ref[..., :3].astype(np.uint8),
                        np.repeat(np.clip(np.nan_to_num(de) * 40, 0, 255)[..., None], 3, -1).astype(np.uint8)], 1))
