"""Shading seconds and noise of the peer sphere: ``python shade_time.py SPP[,SPP...] [WINDOW]``.

The study's sphere (rough Beckmann α 0.2 iron, courtyard map 256×128 as Mitsuba's spectral envmap, 256², 2×2
subpixels, Fresnel rank chosen by the frame); ``WINDOW``: ``Plan.env_window`` (default 2, ``none`` = the whole
map). Per sample count: the frame's shading seconds (min and median of four calls after a first, compiling,
call) and the noise ΔE2000(seed 1, seed 2)/√2. Run from the repository root with ``PYTHONPATH=.`` (Mitsuba
installed) on an idle machine; one process per configuration compared, so that none inherits another's caches.
"""
from __future__ import annotations

import math
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")


def main(spps: str, window: str = "2") -> None:
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    win = None if window == "none" else float(window)
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        for spp in (int(s) for s in spps.split(",")):
            imgs, ts = {}, []
            for seed in (1, 1, 1, 1, 1, 2):
                img, mask, shade_s = mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2,
                                                       seed=seed, env_nodes=None, env_window=win)
                imgs[seed] = img
                ts.append(shade_s)
            noise = mc.compare(imgs[1], imgs[2], mask)["dE2000_mean"] / math.sqrt(2)
            runs = sorted(ts[1:5])
            print(f"window {window} spp {spp}: noise {noise:.4f} shade min {runs[0]:.3f} median {runs[1]:.3f} s",
                  flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
