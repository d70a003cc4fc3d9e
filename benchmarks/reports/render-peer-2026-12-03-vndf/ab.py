"""A/B of the reference frame's cost: ``python ab.py SPP [REPEATS] [key=value ...]``.

The rough iron sphere of :func:`validation.mitsuba.render_jkatana` (256², 2×2 subpixels,
``env_nodes=None``), the environment built once; per call the frame's CPU and wall seconds
(``render_frame``, after one warm-up) and the noise ΔE2000(seed 1, seed 2)/√2. Extra
``key=value`` arguments replace :class:`~jkatana.render.plan.Plan` fields (ints, else strings).
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
    import dataclasses

    import jax.numpy as jnp

    import jkatana.render.frame as fm
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    spp = int(argv[0])
    reps = int(argv[1]) if len(argv) > 1 else 3
    over = dict(a.split("=") for a in argv[2:])
    orig = fm.render_frame
    box = {}

    def wrapped(plan, *a, **k):
        if over:
            plan = dataclasses.replace(plan, **{kk: int(v) if v.lstrip("-").isdigit() else v
                                                for kk, v in over.items()})
        box.setdefault("plans", []).append(plan)
        c0, t0 = time.process_time(), time.perf_counter()
        f = orig(plan, *a, **k)
        box["cpu"], box["wall"] = time.process_time() - c0, time.perf_counter() - t0
        box["frame"] = f
        return f

    fm.render_frame = wrapped
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        imgs, cpus, walls = {}, [], []
        for rep in range(reps + 1):
            for seed in (1, 2):
                img, mask, _ = mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2, seed=seed,
                                                 env_nodes=None)
                imgs[seed] = img
                if rep:
                    cpus.append(box["cpu"])
                    walls.append(box["wall"])
        noise = mc.compare(imgs[1], imgs[2], mask)["dE2000_mean"] / math.sqrt(2)
        t = box["frame"].timing
        print(f"spp {spp} {over} rank {box['frame'].timing.get('fresnel_rank')}: noise {noise:.4f} "
              f"CPU {np.median(cpus):.3f} (min {min(cpus):.3f}) wall {np.median(walls):.3f} "
              f"(min {min(walls):.3f}) load {os.getloadavg()[0]:.2f}  timing "
              + " ".join(f"{k}={v:.3f}" for k, v in t.items() if isinstance(v, float)), flush=True)
        np.save(Path(os.environ.get("AB_OUT", "/tmp")) / f"ab_{spp}.npy", imgs[1])


if __name__ == "__main__":
    main(sys.argv[1:])
