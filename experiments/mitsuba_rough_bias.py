"""Where does the rough-sphere difference between jkatana and Mitsuba 3 come from? Noise vs bias.

Renders the rough (Beckmann α = 0.2) iron sphere of :mod:`validation.mitsuba`
with Mitsuba 3 at two seeds (their difference estimates Mitsuba's own noise) and
with jkatana, caches the frames under ``experiments/output/mitsuba/cache`` and
prints per-channel ratios over the sphere and ΔE2000 for each pairing.

    python experiments/mitsuba_rough_bias.py            # 64², Mitsuba 16384 spp, jkatana 256 samples
    python experiments/mitsuba_rough_bias.py --gallery  # also the gallery copy of the figure

Frames are cached by their settings only: delete ``experiments/output/mitsuba/cache``
after changing either renderer. Run times of past runs: ``experiments/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from validation import mitsuba as mc  # noqa: E402
from jkatana.shared import shared_data

OUT = Path(__file__).resolve().parent / "output" / "mitsuba"
CACHE = OUT / "cache"
ENV = shared_data("envmaps", "courtyard.exr")


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
    print(f"{label:44s} sums R,G,B {r[0]:.4f} {r[1]:.4f} {r[2]:.4f}   "
          f"ΔE mean {err['dE2000_mean']:.3f} p95 {err['dE2000_p95']:.2f} p99 {err['dE2000_p99']:.2f}")
    return err


def delta_e_image(rgb_ref, rgb, mask):
    """Per-pixel display-referred ΔE2000 (:func:`jkatana.spectral.delta_e_display`; the p99 Y of the reference's
    pixels in ``mask`` → white)."""
    from jkatana.spectral import delta_e_display, reference_exposure
    from jkatana.spectral.colorimetry import xyz_to_rgb_matrix

    to_xyz = np.linalg.inv(xyz_to_rgb_matrix("ITU-R BT.709"))
    a, b = rgb_ref @ to_xyz.T, rgb @ to_xyz.T
    stats, de = delta_e_display(a, b, exposure=reference_exposure(a[mask]), return_de=True)
    return np.where(mask, de, np.nan), stats["exposure"]


def figure(rows, path, dpi=90):
    """One row per (label, Mitsuba, jkatana, mask): both frames, ΔE2000, and Mitsuba/jkatana − 1 per channel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.ndimage import binary_erosion

    from jkatana.io.atomic import atomic_path
    from jkatana.spectral.colorimetry import encode

    fig, axes = plt.subplots(len(rows), 6, figsize=(17, 3.2 * len(rows) + 0.6), squeeze=False)
    for ax_row, (label, mi_img, jk_img, mask) in zip(axes, rows):
        m = binary_erosion(mask)
        de, exposure = delta_e_image(mi_img, jk_img, m)
        err = mc.compare(mi_img, jk_img, mask)
        for ax, img, title in ((ax_row[0], mi_img, "Mitsuba 3"), (ax_row[1], jk_img, "jkatana")):
            ax.imshow(np.clip(encode(np.clip(img * exposure, 0, 1), "sRGB"), 0, 1), interpolation="nearest")
            ax.set_title(title, fontsize=9)
        im = ax_row[2].imshow(de, cmap="magma", vmin=0, vmax=2, interpolation="nearest")
        ax_row[2].set_title(f"ΔE2000 (mean {err['dE2000_mean']:.2f}, p99 {err['dE2000_p99']:.2f})", fontsize=9)
        fig.colorbar(im, ax=ax_row[2], fraction=0.046)
        for c, name in enumerate("RGB"):
            ratio = np.where(m, mi_img[..., c] / np.maximum(jk_img[..., c], 1e-12) - 1.0, np.nan)
            tot = mi_img[m][:, c].sum() / jk_img[m][:, c].sum() - 1.0
            im = ax_row[3 + c].imshow(100 * ratio, cmap="RdBu_r", vmin=-4, vmax=4, interpolation="nearest")
            ax_row[3 + c].set_title(f"{name}: Mitsuba/jkatana − 1 [%] (sum {100 * tot:+.2f} %)", fontsize=9)
            fig.colorbar(im, ax=ax_row[3 + c], fraction=0.046)
        ax_row[0].set_ylabel(label, fontsize=9)
        for ax in ax_row:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle("Iron sphere under the courtyard map (256×128), 64², jkatana vs Mitsuba 3.9.1", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    print(f"wrote {path}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16384, help="Mitsuba spp of the rough frames")
    ap.add_argument("--samples", type=int, default=256, help="jkatana samples of the rough frame")
    ap.add_argument("--nodes", type=int, default=mc.ENV_NODES)
    ap.add_argument("--gallery", action="store_true", help="also write experiments/gallery/mitsuba_rough_sphere.png")
    ap.add_argument("--gallery-dpi", type=int, default=55)
    a = ap.parse_args()
    print(f"load average before: {os.getloadavg()}")
    rough = 0.2
    m0, m1 = mitsuba(rough, a.size, a.spp, 0), mitsuba(rough, a.size, a.spp, 1)
    jk, mask = jkatana(rough, a.size, a.samples, nodes=a.nodes)
    jk_s1, _ = jkatana(rough, a.size, a.samples, nodes=a.nodes, seed=1)
    jk_hi, _ = jkatana(rough, a.size, 4 * a.samples, nodes=a.nodes)
    jk_old, _ = jkatana(rough, a.size, a.samples, nodes=None)
    print(f"-- rough Beckmann α = {rough}, Mitsuba {a.spp} spp, jkatana {a.samples} samples × 9 subpixels")
    channel_report("Mitsuba seed 0 vs seed 1 (its noise)", m0, m1, mask)
    channel_report("jkatana seed 0 vs seed 1 (its noise)", jk, jk_s1, mask)
    channel_report(f"jkatana {4 * a.samples} vs {a.samples} samples", jk_hi, jk, mask)
    channel_report("Mitsuba s0 vs jkatana (the test)", m0, jk, mask)
    channel_report("Mitsuba mean(s0, s1) vs jkatana", 0.5 * (m0 + m1), jk, mask)
    channel_report(f"Mitsuba mean(s0, s1) vs jkatana {4 * a.samples}", 0.5 * (m0 + m1), jk_hi, mask)
    channel_report("Mitsuba s0 vs jkatana, uncompensated map", m0, jk_old, mask)
    # noise-corrected per-pixel bias: E[(m̄ − jk)²] − var(m̄), var(m̄) = E[(m0 − m1)²]/4 (jkatana's own noise kept)
    from scipy.ndimage import binary_erosion

    e = binary_erosion(mask)
    mbar = 0.5 * (m0 + m1)
    norm = mbar[e].mean(0)
    for label, j in (("matched map", jk_hi), ("uncompensated map", jk_old)):
        d2 = (((mbar - j)[e] / norm) ** 2).mean(0)
        nv = (((m0 - m1)[e] / norm) ** 2).mean(0) / 4
        print(f"per-pixel RMS (m̄ − jkatana)/mean, {label}: {np.sqrt(d2).round(4)}; "
              f"after Mitsuba's noise: {np.sqrt(np.maximum(d2 - nv, 0)).round(4)}")
    print("-- smooth")
    s0, s1, s1k = mitsuba(None, a.size, 4096, 0), mitsuba(None, a.size, 4096, 1), mitsuba(None, a.size, 1024, 0)
    sj3, smask = jkatana(None, a.size, 1, 3, nodes=a.nodes)
    sj, _ = jkatana(None, a.size, 1, 6, nodes=a.nodes)
    sj_old, _ = jkatana(None, a.size, 1, 6, nodes=None)
    channel_report("Mitsuba 4096 seed 0 vs seed 1", s0, s1, smask)
    channel_report("Mitsuba 1024 vs jkatana 3×3 subpixels", s1k, sj3, smask)
    channel_report("Mitsuba 4096 vs jkatana 3×3 subpixels", s0, sj3, smask)
    channel_report("Mitsuba 4096 vs jkatana 6×6 (the test)", s0, sj, smask)
    channel_report("Mitsuba mean(s0, s1) vs jkatana 6×6", 0.5 * (s0 + s1), sj, smask)
    channel_report("Mitsuba 4096 vs jkatana 6×6, uncompensated map", s0, sj_old, smask)
    print(f"load average after: {os.getloadavg()}")
    rows = [(f"rough α 0.2, matched map ({a.nodes} nodes/texel)", m0, jk, mask),
            ("rough α 0.2, uncompensated map", m0, jk_old, mask),
            ("smooth, matched map (Mitsuba 4096 spp, 6×6)", s0, sj, smask),
            ("smooth, uncompensated map (6×6)", s0, sj_old, smask)]
    figure(rows, OUT / "rough_sphere.png")
    if a.gallery:
        figure(rows, Path(__file__).resolve().parent / "gallery" / "mitsuba_rough_sphere.png", dpi=a.gallery_dpi)


if __name__ == "__main__":
    main()
