"""Is the lobe window safe once the compact sources are split off as caps?  The peer sphere (rough Beckmann α 0.2
iron, 32², ×4 subpixels) under real HDRs of ``../shared/data/envmaps`` at 256×128, reference mode (MIS):
whole map / caps split + whole map / caps split + window k = 2 / window without the split. Noise = ΔE2000 between
two seeds / √2 at ``SPP``; bias = mean RGB ratio against the whole map without the split at ``REF_SPP``.
Run from the repository root with ``PYTHONPATH=.``: ``python window_caps.py [MAP ...]``."""
import math, os, sys, tempfile, time
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
from pathlib import Path
import numpy as np
from jkatana.shared import shared_data
from validation import mitsuba as mc

SPP, REF_SPP = 64, 1024
CONFIGS = {"whole": dict(split_sun=False, env_window=None), "caps": dict(split_sun=True, env_window=None),
           "caps+window": dict(split_sun=True, env_window=2.0), "window": dict(split_sun=False, env_window=2.0)}
maps = sys.argv[1:] or ["sunrise.exr", "sunset.exr", "courtyard.exr", "interior.exr", "city.exr"]
kw = dict(alpha=0.2, size=32, supersample=2, env_nodes=None, same_upsampling=False)
for name in maps:
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", name), Path(d) / "env.exr", 256)
        ref, m, _ = mc.render_jkatana(env, seed=100, samples=REF_SPP, **kw)
        for label, cfg in CONFIGS.items():
            t0 = time.perf_counter()
            a, _, ta = mc.render_jkatana(env, seed=1, samples=SPP, **cfg, **kw)
            b, _, tb = mc.render_jkatana(env, seed=2, samples=SPP, **cfg, **kw)
            noise = mc.compare(a, b, m)["dE2000_mean"] / math.sqrt(2)
            c = mc.compare(ref, a, m)
            ratio = (a[m].mean(0) + b[m].mean(0)) / 2 / ref[m].mean(0)
            print(f"{name:16s} {label:12s} noise {noise:.4f}  vs ref mean {c['dE2000_mean']:.4f} p99 {c['dE2000_p99']:.3f} "
                  f"max {c['dE2000_max']:.3f}  mean ratio {np.round(ratio, 4)}  shade {ta:.3f}/{tb:.3f} s", flush=True)
