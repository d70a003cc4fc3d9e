"""Noise and shading time of the peer sphere per environment window: ``python ab_window.py SPP WINDOWS [DENSITY]``.

``SPP``: comma-separated lobe samples per subpixel, or ``lobe:env`` pairs (``8,8:16``); ``WINDOWS``: comma-separated
``Plan.env_window`` values (``none`` = the whole map); ``DENSITY``: the environment sampler's texel weight,
``max`` (the renderer's) or ``bilinear``. The study's sphere (rough Beckmann α 0.2 iron, courtyard map 256×128,
256², 2×2 subpixels, Mitsuba's spectral envmap at its texel centres); noise = ΔE2000(seed 1, seed 2)/√2, shading
seconds of seeds 1 (second call) and 2. Run from the repository root with ``PYTHONPATH=.`` (Mitsuba installed).
"""
from __future__ import annotations

import math
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")


def main(spps: str, windows: str, density: str = "max") -> None:
    from jkatana.light.sampling import EnvSampler
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    if density != "max":
        build = EnvSampler.build.__func__

        def bilinear_build(cls, env, **kw):
            kw["bilinear"] = True
            return build(cls, env, **kw)

        EnvSampler.build = classmethod(bilinear_build)
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        for w in windows.split(","):
            k = None if w == "none" else float(w)
            for sp in spps.split(","):
                spp, es = (int(x) for x in (sp.split(":") if ":" in sp else (sp, sp)))
                imgs, ts = {}, []
                for seed in (1, 1, 2):
                    img, mask, shade_s = mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2,
                                                           seed=seed, env_nodes=None, env_samples=es, env_window=k)
                    imgs[seed] = img
                    ts.append(shade_s)
                noise = mc.compare(imgs[1], imgs[2], mask)["dE2000_mean"] / math.sqrt(2)
                print(f"window {w} density {density} lobe:env {spp}:{es}: noise {noise:.4f} "
                      f"shade {ts[1]:.3f} {ts[2]:.3f} s", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
