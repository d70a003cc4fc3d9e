"""Converged peer sphere (48², 1024 spp × 4) with and without the window (k = 2.5): self-noise, ΔE between, mean
ratio. Run from the repository root with ``PYTHONPATH=.`` (Mitsuba installed)."""
import math, os, sys, tempfile
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
from pathlib import Path
import numpy as np
from jkatana.shared import shared_data
from validation import mitsuba as mc
with tempfile.TemporaryDirectory() as d:
    env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
    out = {}
    for k in ("0", "2.5"):
        kw = dict(alpha=0.2, size=48, samples=1024, supersample=2, env_nodes=None, env_window=float(k) or None)
        a, mask, _ = mc.render_jkatana(env, seed=100, **kw)
        b, mask, _ = mc.render_jkatana(env, seed=101, **kw)
        out[k] = (a, b)
        print(k, "self-noise", mc.compare(a, b, mask)["dE2000_mean"]/math.sqrt(2), "mean rgb", a[mask].mean(0), flush=True)
    print("window vs base", mc.compare(out["0"][0], out["2.5"][0], mask))
    print("ratio of means", out["2.5"][0][mask].mean(0)/out["0"][0][mask].mean(0))
