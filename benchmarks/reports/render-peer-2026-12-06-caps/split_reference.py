"""Reference mode with the compact sources split off as caps (sampled by MIS, each cap with its own cone
strategy) against the whole map, under the real HDRs of ``../shared/data/envmaps`` (256×128): noise, shading
time, noise² × time and the mean against a converged whole-map frame. The peer sphere (rough Beckmann α 0.2 iron),
``SIZE``², 2×2 subpixels. Run from the repository root with ``PYTHONPATH=.``: ``python split_reference.py [MAP ...]``."""
import math, os, sys, tempfile
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
from pathlib import Path
import numpy as np
from jkatana.shared import shared_data
from validation import mitsuba as mc

SIZE, SPP, REF_SPP, REPS = 128, 8, 512, 4
maps = sys.argv[1:] or ["sunrise.exr", "pedestrian_overpass_1k.hdr", "interior.exr", "city.exr", "forest.exr",
                        "courtyard.exr"]
kw = dict(alpha=0.2, size=SIZE, supersample=2, env_nodes=None, same_upsampling=False, fresnel_rank=3)
print(f"size {SIZE}², {SPP} spp × 4 subpixels; reference {REF_SPP} spp whole map; shading s = median of {REPS - 1} "
      f"runs after the first", flush=True)
for name in maps:
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", name), Path(d) / "env.exr", 256)
        ref, m, _ = mc.render_jkatana(env, seed=100, samples=REF_SPP, **kw)
        rows = {}
        for split in (False, True):
            ts, imgs = [], []
            for r in range(REPS):
                img, _, t = mc.render_jkatana(env, seed=1 + r % 2, samples=SPP, split_sun=split, **kw)
                ts.append(t)
                imgs.append(img)
            t = float(np.median(ts[1:]))
            noise = mc.compare(imgs[0], imgs[1], m)["dE2000_mean"] / math.sqrt(2)
            err = mc.compare(ref, imgs[0], m)
            ratio = (imgs[0][m].mean(0) + imgs[1][m].mean(0)) / 2 / ref[m].mean(0)
            rows[split] = (noise, t)
            print(f"{name:28s} {'caps ' if split else 'whole'} noise {noise:.4f}  vs ref mean {err['dE2000_mean']:.4f} "
                  f"p99 {err['dE2000_p99']:.3f} max {err['dE2000_max']:.3f}  mean ratio {np.round(ratio, 4)}  "
                  f"shade {t * 1e3:.1f} ms  noise²·t {noise ** 2 * t * 1e3:.3f}", flush=True)
        (n0, t0), (n1, t1) = rows[False], rows[True]
        print(f"{name:28s} caps / whole: noise {n1 / n0:.3f}, time {t1 / t0:.3f}, efficiency "
              f"(whole noise²·t ÷ caps') {n0 ** 2 * t0 / (n1 ** 2 * t1):.2f}", flush=True)
