"""The peer sphere under ``sunrise.exr`` (a real HDR whose sun stays in the map: no caps split), 32², 2048 spp × 4,
whole map vs window k = 2: mean ratio, each one's noise (two seeds / √2) and ΔE between. Run from the repository
root with ``PYTHONPATH=.``."""
import math, os, tempfile
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
from pathlib import Path
import numpy as np
from jkatana.shared import shared_data
from validation import mitsuba as mc
with tempfile.TemporaryDirectory() as d:
    env = mc.small_envmap(shared_data("envmaps", "sunrise.exr"), Path(d) / "env.exr", 256)
    kw = dict(alpha=0.2, size=32, samples=2048, supersample=2, env_nodes=None, same_upsampling=False)
    a, m, _ = mc.render_jkatana(env, seed=1, env_window=None, **kw)
    a2, m, _ = mc.render_jkatana(env, seed=2, env_window=None, **kw)
    b, m, _ = mc.render_jkatana(env, seed=3, env_window=2.0, **kw)
    b2, m, _ = mc.render_jkatana(env, seed=4, env_window=2.0, **kw)
    print("finite", np.isfinite(b).all(), "mean ratio", b[m].mean(0) / a[m].mean(0))
    print("noise whole", mc.compare(a, a2, m)["dE2000_mean"] / math.sqrt(2), "noise window", mc.compare(b, b2, m)["dE2000_mean"] / math.sqrt(2), "between", mc.compare(a, b, m)["dE2000_mean"])
