"""In-process A/B of the lobe sampler: ``python ab_vndf.py SPP ROUNDS``.

The scene of ``ab.py`` (rough Beckmann α 0.2 iron sphere, courtyard map, 256², 2×2 subpixels); per
round, alternating, the frame with Beckmann sampled by its visible normals (the default) and by D cos φ
(the lobe's ``sample_h`` with the D cos φ pdf, as before the visible-normal sampler), each compiled
afresh (``jax.clear_caches``) and timed after one warm-up: frame CPU seconds of seeds 1 and 2 and the
noise ΔE2000(seed 1, seed 2)/√2. One process, so both variants see the same load.
"""
from __future__ import annotations

import math
import os
import sys
import tempfile
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def main(argv):
    import jax

    import jkatana.render.frame as fm
    from jkatana.models import lobes
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    spp, rounds = int(argv[0]), int(argv[1])
    orig = fm.render_frame
    box = {}

    def wrapped(*a, **k):
        c0 = time.process_time()
        f = orig(*a, **k)
        box["cpu"] = time.process_time() - c0
        return f

    fm.render_frame = wrapped
    B = lobes.Beckmann
    vndf = (B.sample_facet, B.pdf)
    dcos = (lobes.Lobe.sample_facet, lobes._Microfacet.pdf)
    res = {"visible": [], "D cos": []}
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        for r in range(rounds):
            for name, (sf, pdf) in (("visible", vndf), ("D cos", dcos)):
                B.sample_facet, B.pdf = sf, pdf
                jax.clear_caches()
                imgs, cpus = {}, []
                for seed in (1, 1, 2):  # the first: compilation and warm-up
                    img, mask, _ = mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2,
                                                     seed=seed, env_nodes=None)
                    imgs[seed] = img
                    cpus.append(box["cpu"])
                noise = mc.compare(imgs[1], imgs[2], mask)["dE2000_mean"] / math.sqrt(2)
                res[name].append((noise, np.mean(cpus[1:])))
                print(f"round {r} {name:8s} spp {spp}: noise {noise:.4f} CPU {np.mean(cpus[1:]):.3f} "
                      f"load {os.getloadavg()[0]:.2f}", flush=True)
    for name, v in res.items():
        n, c = np.array(v).T
        print(f"{name:8s} spp {spp}: noise {n.mean():.4f} CPU median {np.median(c):.3f} min {c.min():.3f} "
              f"noise²×CPU {n.mean() ** 2 * np.median(c):.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
