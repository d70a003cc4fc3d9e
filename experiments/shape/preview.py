"""Flat-shaded previews of the built-in blade and its default reflectance map (PNGs)."""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection

from jkatana.maps import default_map
from jkatana.shape import default_blade, KatanaSpec, build_blade

OUT = Path(__file__).resolve().parents[1] / "output"


def shade(ax, mesh, view=np.array([0.0, 0.0, 1.0]), light=np.array([0.3, 0.6, 1.0]),
          axes=(0, 1), colours=None, zoom=None):
    V, F = mesh.vertices, mesh.faces
    n = mesh.face_normals
    light = light / np.linalg.norm(light)
    depth = V[F].mean(1) @ view
    facing = n @ view > 0
    lam = np.clip(n @ light, 0, 1) * 0.8 + 0.2
    col = np.repeat(lam[:, None], 3, 1) if colours is None else colours * lam[:, None]
    order = np.argsort(depth)
    order = order[facing[order]]
    polys = V[F[order]][:, :, list(axes)]
    ax.add_collection(PolyCollection(polys, facecolors=np.clip(col[order], 0, 1), edgecolors="none"))
    lo, hi = polys.reshape(-1, 2).min(0), polys.reshape(-1, 2).max(0)
    if zoom is not None:
        lo, hi = zoom
    ax.set_xlim(lo[0], hi[0]); ax.set_ylim(lo[1], hi[1]); ax.set_aspect("equal")


def main(out: Path = OUT) -> None:
    out.mkdir(parents=True, exist_ok=True)
    mesh = default_blade()
    m = default_map()
    uv = mesh.visual.uv[mesh.faces].mean(1)
    s = m.sample(uv[:, 0], uv[:, 1])
    w = s["w"][:, None]
    colours = w * np.array([0.55, 0.6, 0.68]) + (1 - w) * np.array([0.95, 0.95, 0.93])
    fig, axs = plt.subplots(3, 1, figsize=(14, 8), gridspec_kw={"height_ratios": [2, 1.3, 1.3]})
    shade(axs[0], mesh, colours=colours)
    axs[0].set_title(f"built-in blade, omote (+Z), {len(mesh.faces)} triangles; colour = default map w "
                     "(blue-grey hiraji, white hamon)")
    shade(axs[1], mesh, colours=colours, zoom=((0.6, -0.045), (0.705, 0.0)))
    axs[1].set_title("kissaki: yokote, ko-shinogi, fukura")
    shade(axs[2], mesh, zoom=((-0.005, -0.035), (0.1, 0.002)))
    axs[2].set_title("machi end (flat shading shows the shinogi ridge)")
    for ax in axs:
        ax.set_xlabel("x [m]"); ax.set_ylabel("y [m]")
    fig.tight_layout(); fig.savefig(out / "shape_blade_preview.png", dpi=110); plt.close(fig)

    # cross-sections of the three mune shapes at the machi
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.5))
    for ax, mune in zip(axs, ("iori", "mitsu", "maru")):
        b = build_blade(KatanaSpec(mune=mune))
        sl = b.section(plane_origin=[0.2, 0, 0], plane_normal=[1, 0, 0])
        for e in sl.discrete:
            ax.plot(e[:, 1] * 1000, e[:, 2] * 1000, "k-")
        ax.set_aspect("equal"); ax.set_title(f"{mune}-mune, section at x = 0.2 m")
        ax.set_xlabel("y [mm] (mune +, ha −)"); ax.set_ylabel("z [mm]")
    fig.tight_layout(); fig.savefig(out / "shape_cross_sections.png", dpi=110); plt.close(fig)

    fig, axs = plt.subplots(3, 1, figsize=(14, 7))
    ext = (0, 1, 1, 0)
    for ax, (name, a, cmap) in zip(axs, (("w", m.w, "gray_r"), ("mu0", m.mu0, "viridis"),
                                         ("mu1", m.mu1, "viridis"))):
        im = ax.imshow(a, extent=ext, aspect="auto", cmap=cmap, interpolation="nearest")
        ax.set_ylabel("v (0 mune → 1 ha)"); ax.set_title(f"default map: {name}")
        fig.colorbar(im, ax=ax, fraction=0.02)
    axs[-1].set_xlabel("u (0 machi → 1 kissaki tip)")
    fig.tight_layout(); fig.savefig(out / "maps_default_map.png", dpi=110); plt.close(fig)
    print("wrote", out, file=sys.stderr)


if __name__ == "__main__":
    main()
