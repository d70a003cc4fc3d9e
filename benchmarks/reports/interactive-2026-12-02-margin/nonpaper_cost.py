"""Frame cost of the caps' kernel table: the sun-glint view of ``nonpaper_sun.py`` (GGX hiraji α 0.05, Beckmann
hamon α 0.12 under sunrise.exr, the sun split) at 800×600, the caps through the kernel table (the default for
such lobes) against the closed-form rule of the lobes' moments (the same bake without the table), and the
paper's lobes on the same view (no table: their shader is the one before the table). CPU seconds of the
process (all threads: llvmpipe's too) per frame, over 15 frames after 3 warm-up frames, alternated A/B/C
three times."""
import dataclasses, os, time
import numpy as np
from jkatana.interactive import glrender as glr
from jkatana.interactive import scene as S, bake as B, levels as LV
from jkatana.interactive.lobe_tables import region_lobes
from jkatana.render.renderer import prepare
from jkatana.render.scene import scene_from_dict
from validation import gl_agreement as A
import tempfile
from pathlib import Path

# nonpaper_sun.py's imports and params_file(), without its run
exec((Path(__file__).parent / "nonpaper_sun.py").read_text().split("tmp = Path")[0])
tmp = Path(tempfile.mkdtemp())
mesh = S.blade()
sun = A.shared_environment("sunrise.exr")
view = A.sun_glint_view(mesh, sun, 800, 600)
d = A.render_scene(view, samples=1)
d["material"]["hiraji"] = params_file(tmp / "hiraji.json", "ggx", "hiraji", {"scale": 2000.0, "alpha": 0.05})
d["material"]["hamon"] = params_file(tmp / "hamon.json", "beckmann", "hamon", {"scale": 2000.0, "alpha": 0.12})
prep = prepare(scene_from_dict(d), env_radiance=np.asarray(sun, np.float32))
keys = {"hiraji": prep.plan.hiraji_lobe, "hamon": prep.plan.hamon_lobe}
maps = np.asarray(prep.maps, np.float64)
table = B.cached_bake(sun, rank=3, mus=LV.MU_LEVELS[2:9], lobes=region_lobes(keys))
paper = B.cached_bake(sun, rank=3)
cases = {"table": glr.ShadingState(table, maps),
         "moments": glr.ShadingState(dataclasses.replace(table, cap_kernel=np.zeros((0,))), maps),
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
