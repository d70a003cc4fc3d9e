"""Where does the rough-sphere difference between jkatana and Mitsuba 3 come from? Noise vs bias.

Renders the rough (Beckmann α = 0.2) iron sphere of :mod:`jkatana.render.mitsuba_check`
with Mitsuba 3 at two seeds (their difference estimates Mitsuba's own noise) and
with jkatana, caches the frames under ``experiments/output/mitsuba/cache`` and
prints per-channel ratios over the sphere and ΔE2000 for each pairing.

    python experiments/mitsuba_rough_bias.py --size 64 --spp 4096 --samples 1024
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jkatana.render import mitsuba_check as mc  # noqa: E402

OUT = Path(__file__).resolve().parent / "output" / "mitsuba"
CACHE = OUT / "cache"
ENV = Path("/work/shared/data/envmaps/courtyard.exr")


def cached(name, fn):
    CACHE.mkdir(parents=True, exist_ok=True)
    p = CACHE / f"{name}.npz"
    if p.is_file():
        d = np.load(p)
        return {k: d[k] for k in d.files}
    t0 = time.perf_counter()
    out = fn()
    out["seconds"] = np.float64(time.perf_counter() - t0)
    np.savez(p, **out)
    print(f"  {name}: {out['seconds']:.1f} s (load {os.getloadavg()[0]:.2f})", file=sys.stderr)
    return out


def env_small():
    p = CACHE / "env256.exr"
    if not p.is_file():
        CACHE.mkdir(parents=True, exist_ok=True)
        mc.small_envmap(ENV, p, width=256)
    return p


def mitsuba(alpha, size, spp, seed):
    env = env_small()
    tag = "smooth" if alpha is None else f"a{alpha}"
    return cached(f"mi_{tag}_{size}_{spp}_s{seed}",
                  lambda: {"rgb": mc.render_mitsuba(env, alpha=alpha, size=size, spp=spp, seed=seed)})["rgb"]


def jkatana(alpha, size, samples, supersample=3, nodes=None, seed=0, **kw):
    env = env_small()
    name = f"jk_{'smooth' if alpha is None else f'a{alpha}'}_{size}_{samples}_x{supersample}_n{nodes}_s{seed}"
    kw.update(env_nodes=nodes, seed=seed)

    def go():
        rgb, mask, _ = mc.render_jkatana(env, alpha=alpha, size=size, samples=samples, supersample=supersample, **kw)
        return {"rgb": rgb, "mask": mask}

    d = cached(name, go)
    return d["rgb"], d["mask"].astype(bool)


def channel_report(label, a, b, mask):
    from scipy.ndimage import binary_erosion

    m = binary_erosion(mask)
    r = a[m].sum(0) / b[m].sum(0)
    err = mc.compare(a, b, mask)
    print(f"{label:40s} sum ratio R,G,B = {r[0]:.4f} {r[1]:.4f} {r[2]:.4f}   "
          f"ΔE mean {err['dE2000_mean']:.3f} p95 {err['dE2000_p95']:.2f} p99 {err['dE2000_p99']:.2f}")
    return err


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=1024)
    ap.add_argument("--alpha", type=float, default=0.2)
    ap.add_argument("--nodes", type=int, default=0, help="0: Mitsuba's texel spectra at our centres (uncompensated)")
    ap.add_argument("--supersample", type=int, default=3)
    a = ap.parse_args()
    alpha = None if a.alpha <= 0 else a.alpha
    m0 = mitsuba(alpha, a.size, a.spp, 0)
    m1 = mitsuba(alpha, a.size, a.spp, 1)
    jk, mask = jkatana(alpha, a.size, a.samples, a.supersample, nodes=a.nodes or None)
    print(f"load {os.getloadavg()}")
    channel_report("mitsuba s0 vs s1 (noise)", m0, m1, mask)
    channel_report("mitsuba s0 vs jkatana", m0, jk, mask)
    channel_report("mitsuba s1 vs jkatana", m1, jk, mask)
    channel_report("mitsuba mean(s0,s1) vs jkatana", 0.5 * (m0 + m1), jk, mask)


if __name__ == "__main__":
    main()
