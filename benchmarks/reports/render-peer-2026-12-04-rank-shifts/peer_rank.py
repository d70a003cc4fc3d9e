"""Fresnel rank 3 vs 5 on the Mitsuba study's sphere, in one process: ``python peer_rank.py SPP ROUNDS``.

The rough Beckmann α 0.2 iron sphere of :func:`validation.mitsuba.render_jkatana` (courtyard map 256²,
256², 2×2 subpixels), the map's spectra by jkatana's own upsampling (``same_upsampling=False``: Mitsuba,
which ``ab.py``'s texel spectra need, is not installed on this machine). Per round, alternating order,
frame CPU seconds (``render_frame``, process CPU of all threads) of seeds 1 and 2 at each rank after one
warm-up frame of each; bias: rank 3 and rank 5 against full spectra (rank 0), same samples, ΔE2000 of
:func:`validation.mitsuba.compare`.
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
    import jkatana.render.frame as fm
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    spp, rounds = int(argv[0]), int(argv[1])
    orig = fm.render_frame
    box = {}

    def wrapped(*a, **k):
        c0 = time.process_time()
        f = orig(*a, **k)
        box["cpu"] = time.process_time() - c0
        box["rank"] = f.stats["fresnel_rank"]
        return f

    fm.render_frame = wrapped
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)

        def run(rank, seed):
            img, mask, _ = mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2, seed=seed,
                                             env_nodes=None, same_upsampling=False, fresnel_rank=rank)
            return img, mask, box["cpu"], box["rank"]

        imgs = {r: run(r, 1) for r in (0, 3, 5, None)}  # warm-up (compilation) and the bias frames
        assert imgs[None][3] == 3 and np.array_equal(imgs[None][0], imgs[3][0])
        mask = imgs[0][1]
        for r in (3, 5):
            e = mc.compare(imgs[0][0], imgs[r][0], mask)
            print(f"rank {r} vs full spectra, same samples, {spp} spp: ΔE2000 mean {e['dE2000_mean']:.4f} "
                  f"p99 {e.get('dE2000_p99', float('nan')):.4f}", flush=True)
        n = mc.compare(imgs[3][0], run(3, 2)[0], mask)["dE2000_mean"] / math.sqrt(2)
        print(f"noise at rank 3: ΔE(seed 1, seed 2)/√2 {n:.4f}", flush=True)
        cpu = {3: [], 5: []}
        for i in range(rounds):
            for r in ((3, 5) if i % 2 == 0 else (5, 3)):
                cpu[r].append(np.mean([run(r, s)[2] for s in (1, 2)]))
            print(f"round {i}: frame CPU rank 3 {cpu[3][-1]:.3f} rank 5 {cpu[5][-1]:.3f} s  load "
                  f"{os.getloadavg()[0]:.1f}", flush=True)
    ratio = [a / b for a, b in zip(cpu[3], cpu[5])]
    print(f"frame CPU median rank 3 {np.median(cpu[3]):.3f} [{min(cpu[3]):.3f}, {max(cpu[3]):.3f}] rank 5 "
          f"{np.median(cpu[5]):.3f} [{min(cpu[5]):.3f}, {max(cpu[5]):.3f}]; per-round ratio 3/5 median "
          f"{np.median(ratio):.3f} [{min(ratio):.3f}, {max(ratio):.3f}]")


if __name__ == "__main__":
    main(sys.argv[1:])
