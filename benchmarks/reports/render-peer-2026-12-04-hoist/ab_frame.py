"""Frame A/B on the peer sphere, both variants in one process: ``python ab_frame.py VARIANTS SPP ROUNDS``.

``VARIANTS`` from ``ab_shade.PATCHES`` (``base`` = the checkout; ``old-all`` = the shader helpers as they were
before 7846511). The sphere of ``../render-peer-2026-12-04-beckmann/ab_halley.py``: rough Beckmann α 0.2 iron,
courtyard 256², 256², 2×2 subpixels, Mitsuba's own spectral envmap (``same_upsampling=True``, as the study).
Per round and variant (order alternated): patch, clear the jit caches, render seeds 1, 1, 2 (the first
compiles), frame CPU s = process CPU of ``render_frame`` (mean of the last two), noise ΔE2000(seed 1, seed 2)/√2.
"""
from __future__ import annotations

import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
import ab_shade  # noqa: E402  (sets nothing; PATCHES and apply/restore)

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")


def main(names, spp, rounds):
    import jax

    import jkatana.render.frame as fm
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    orig = fm.render_frame
    box = {}

    def wrapped(*a, **k):
        c0 = time.process_time()
        f = orig(*a, **k)
        box["cpu"] = time.process_time() - c0
        return f

    fm.render_frame = wrapped
    res = {n: [] for n in names}
    print(f"variants {names}, spp {spp}, rounds {rounds}; load {os.getloadavg()[0]:.2f}", flush=True)
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        for r in range(rounds):
            for name in (names if r % 2 == 0 else names[::-1]):
                saved = ab_shade.apply(name)
                try:
                    jax.clear_caches()
                    imgs, cpus = {}, []
                    for seed in (1, 1, 2):
                        img, mask, _ = mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2,
                                                         seed=seed, env_nodes=None, same_upsampling=True)
                        imgs[seed] = img
                        cpus.append(box["cpu"])
                finally:
                    ab_shade.restore(saved)
                noise = mc.compare(imgs[1], imgs[2], mask)["dE2000_mean"] / math.sqrt(2)
                res[name].append((noise, np.mean(cpus[1:])))
                print(f"round {r} {name:8s} spp {spp}: noise {noise:.4f} frame CPU {np.mean(cpus[1:]):.3f} s "
                      f"load {os.getloadavg()[0]:.2f}", flush=True)
    base = np.array(res[names[0]])[:, 1]
    for n in names:
        nz, c = np.array(res[n]).T
        ratio = c / base
        print(f"{n:8s} spp {spp}: noise {nz.mean():.4f} frame CPU median {np.median(c):.3f} [{c.min():.3f}, "
              f"{c.max():.3f}] s; per-round ratio to {names[0]} median {np.median(ratio):.3f} "
              f"[{ratio.min():.3f}, {ratio.max():.3f}]")


if __name__ == "__main__":
    main(sys.argv[1].split(","), int(sys.argv[2]), int(sys.argv[3]))
