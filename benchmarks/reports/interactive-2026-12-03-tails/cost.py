"""Frame cost of the tail tap: the sun-glint view of agree.py at 800×600 (GGX hiraji α 0.05, Beckmann hamon α 0.12,
sunrise.exr, sun split, caps through the kernel table), the bake with the tail tap against the same bake with
taps.tap_fit's three taps and no tail (the frame before), and the paper's lobes on the same view. CPU seconds of
the process (all threads) per frame over 15 frames after 3 warm-ups, alternated three times."""
import dataclasses, os, time, tempfile
from pathlib import Path
import numpy as np, jax.numpy as jnp
here = Path(__file__).resolve().parents[1] / "interactive-2026-12-02-margin"
exec((here / "nonpaper_sun.py").read_text().split("tmp = Path")[0])
from jkatana.interactive.tables import cached_tap_fit
from jkatana.interactive.taps import resolved_taps
from jkatana.models import Conductor
from jkatana.spectral import DEFAULT_GRID
tmp = Path(tempfile.mkdtemp())
mesh = S.blade(); sun = A.shared_environment("sunrise.exr"); view = A.sun_glint_view(mesh, sun, 800, 600)
d = A.render_scene(view, samples=1)
d["material"]["hiraji"] = params_file(tmp / "hiraji.json", "ggx", "hiraji", {"scale": 2000.0, "alpha": 0.05})
d["material"]["hamon"] = params_file(tmp / "hamon.json", "beckmann", "hamon", {"scale": 2000.0, "alpha": 0.12})
prep = prepare(scene_from_dict(d), env_radiance=np.asarray(sun, np.float32))
keys = {"hiraji": prep.plan.hiraji_lobe, "hamon": prep.plan.hamon_lobe}
maps = np.asarray(prep.maps, np.float64)
mus = LV.MU_LEVELS[2:9]
tailed = B.cached_bake(sun, rank=3, mus=mus, lobes=region_lobes(keys))
t3, _, _ = cached_tap_fit(Conductor.from_table("Fe-Johnson", DEFAULT_GRID, dtype=jnp.float64), mus, 64, None, region_lobes(keys))
before = dataclasses.replace(tailed, taps=resolved_taps(t3, tailed.spread, tailed.mus, sun.shape[0]),
                             tail=np.zeros_like(tailed.tail))
paper = B.cached_bake(sun, rank=3)
cases = {"tail tap": glr.ShadingState(tailed, maps), "three taps": glr.ShadingState(before, maps),
         "paper lobes": glr.ShadingState(paper, maps)}
scene = glr.build_scene(mesh, view)
out = {k: [] for k in cases}
for rep in range(3):
    for name, st in cases.items():
        r = glr.BakedOffscreenRenderer(st, 800, 600)
        for _ in range(3):
            r.render(scene)
        c, t = time.process_time(), time.perf_counter()
        for _ in range(15):
            r.render(scene)
        out[name].append(((time.process_time() - c) / 15 * 1e3, (time.perf_counter() - t) / 15 * 1e3))
        r.delete()
print("load", os.getloadavg())
for name, v in out.items():
    v = np.array(v)
    print(f"{name:12s} CPU ms/frame {' '.join(f'{x:.1f}' for x in v[:, 0])} (median {np.median(v[:, 0]):.1f}); "
          f"wall {np.median(v[:, 1]):.1f} ms")
