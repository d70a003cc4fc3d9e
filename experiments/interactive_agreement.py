"""GL interactive path vs the per-pixel JAX reference: three environments × four views.

For each built-in environment (``sky``: default; ``sun``: sun-dominated;
``studio``: two softboxes) and three views (the demo camera, an orbit view of
the whole blade from the left, one from the right, and a "glint" view in the
mirror direction of the environment's key light), renders the GL frame
(EGL, no MSAA) and the reference (:func:`jkatana.interactive.reference.shade`:
exact Fresnel, 61 bands, lobe quadrature over the unfiltered environment) on
the same ray-cast G-buffer camera, and reports ΔE2000 over the blade's pixels.
Saves, per case, ``gl | reference | ΔE×25`` side by side (PNG), and a JSON summary.

It also attributes the residual: the same GL frame with rank 4 (the low-rank
Fresnel error is what changes), and with one isotropic prefiltered tap instead
of the two-tap anisotropic lobe (the split-sum lobe-shape error).

Run: ``python experiments/interactive_agreement.py [-o experiments/out/interactive] [--res 240 180]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("-o", "--output", default="experiments/out/interactive")
    ap.add_argument("--res", type=int, nargs=2, default=(240, 180))
    ap.add_argument("--views", nargs="+", default=["demo", "left", "right", "glint"])
    ap.add_argument("--envs", nargs="+", default=["sky", "sun", "studio"])
    args = ap.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)

    from PIL import Image

    from jkatana.interactive import glrender as G
    from jkatana.interactive import reference as R
    from jkatana.interactive import scene as S
    from jkatana.interactive.bake import cached_bake

    W, H = args.res
    mesh = S.blade()
    refl = S.reflectance_map().stacked()
    orbit = S.orbit_views(mesh, 3, W, H, distance=0.45)
    summary_path = out / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else []
    for env_name in args.envs:
        rad = S.environment(env_name)
        baked = cached_bake(rad, rank=4)
        views = {"demo": S.demo_view(W, H), "left": orbit[0], "right": orbit[2],
                 "glint": S.glint_view(mesh, S.KEY_LIGHT[env_name], W, H)}
        for vname in args.views:
            view = views[vname]
            summary = [r for r in summary if (r["env"], r["view"]) != (env_name, vname)]
            t = time.perf_counter()
            gb = R.gbuffer(mesh, view)
            xyz = R.shade(gb, view, rad, refl, n_phi=20, n_psi=28)
            ref_s = time.perf_counter() - t
            exposure = 1.0
            ref = R.display8(xyz, exposure)
            m = gb["mask"]
            row = {"env": env_name, "view": vname, "pixels": int(m.sum()), "reference_s": round(ref_s, 1)}
            for tag, rank, two in (("rank3", 3, True), ("rank4", 4, True), ("one_tap", 3, False)):
                st = G.ShadingState(baked, refl, exposure=exposure, rank=rank, two_tap=two)
                r = G.BakedOffscreenRenderer(st, W, H)
                img = r.render(G.build_scene(mesh, view))
                r.delete()
                de = R.delta_e_2000(img, ref)
                row[tag] = {"mean": float(de[m].mean()), "p95": float(np.percentile(de[m], 95)),
                            "max": float(de[m].max())}
                if tag == "rank3":
                    diff = np.clip(de * 25, 0, 255).astype(np.uint8)[..., None].repeat(3, -1)
                    diff[~m] = 40
                    Image.fromarray(np.concatenate([img, ref, diff], 1)).save(out / f"{env_name}_{vname}.png")
            summary.append(row)
            print(f"{env_name:7s} {vname:6s} px={row['pixels']:6d}  rank3 ΔE mean {row['rank3']['mean']:.2f} "
                  f"p95 {row['rank3']['p95']:.2f} max {row['rank3']['max']:.1f} | rank4 mean "
                  f"{row['rank4']['mean']:.2f} p95 {row['rank4']['p95']:.2f} | one-tap mean "
                  f"{row['one_tap']['mean']:.2f} p95 {row['one_tap']['p95']:.2f}  (ref {ref_s:.0f} s)", flush=True)
            (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
