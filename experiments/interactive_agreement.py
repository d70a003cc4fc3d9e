"""GL interactive path vs the project's reference renderer (jkatana.render): 3 environments × 4 views.

For each built-in environment (``sky``: default; ``sun``: sun-dominated;
``studio``: two softboxes) and four views (the demo camera, an orbit view of
the whole blade from the left, one from the right, and a "glint" view in the
mirror direction of the environment's key light), renders

- the reference: :mod:`jkatana.render` in ``reference`` mode (MIS of lobe and
  environment sampling, exact conductor Fresnel, 61 bands, float32), twice with
  two seeds of ``--samples`` each; their mean is the reference, their
  difference measures its Monte-Carlo noise;
- the GL frame (EGL, no MSAA, deferred shading) at rank 3, and the attributions:
  rank 4 (what the low-rank Fresnel costs), the moment-matched taps (``fit=False``: what the fitted
  taps gain) and one isotropic prefiltered tap (what the anisotropic three-tap lobe gains),

with the same camera, the same spectral environment (both look it up with
:func:`jkatana.light.envmap.direction_to_uv`) and ONE fixed exposure: the
reference's auto exposure (Y at the blade's 75th percentile → 0.6), computed
once and used by both displays. ΔE2000 over the pixels both call blade, the GL
frame as it is displayed (8 bits) against the reference's unrounded display values.

Saves, per case, ``GL | reference | ΔE×25`` (PNG; background grey in the ΔE
panel; ``*_moments.png`` the same with the moment-matched taps) and ``summary.json``.

Run: ``python experiments/interactive_agreement.py [-o experiments/output/interactive] [--res 240 180]``

Results of past runs: ``experiments/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout's validation/ package


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("-o", "--output", default="experiments/output/interactive")
    ap.add_argument("--res", type=int, nargs=2, default=(240, 180))
    ap.add_argument("--samples", type=int, default=128, help="per seed; the reference averages two seeds")
    ap.add_argument("--views", nargs="+", default=["demo", "left", "right", "glint"])
    ap.add_argument("--envs", nargs="+", default=["sky", "sun", "studio"])
    args = ap.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)

    from PIL import Image

    from jkatana.interactive import glrender as G
    from jkatana.interactive import scene as S
    from jkatana.interactive.bake import cached_bake
    from jkatana.render.film import auto_exposure
    from jkatana.spectral import display8
    from validation import gl_agreement as A

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
            fa = A.reference_frame(rad, view, samples=args.samples, seed=0)
            fb = A.reference_frame(rad, view, samples=args.samples, seed=1)
            ref_s = time.perf_counter() - t
            xyz = 0.5 * (fa.xyz + fb.xyz)
            exposure = auto_exposure(xyz, fa.mask, key=0.6, percentile=75.0)
            ref = A.display255(xyz, exposure)
            row = {"env": env_name, "view": vname, "exposure": exposure, "reference_s": round(ref_s, 1),
                   "reference": f"jkatana.render reference mode, 2 × {args.samples} spp"}
            # Monte-Carlo noise of the 2-seed mean: ΔE between the two halves / 2 (independent, equal variance)
            half, _ = A.compare(A.display255(fa.xyz, exposure), A.display255(fb.xyz, exposure), fa.mask)
            row["reference_noise_est"] = {k: (v / 2 if k != "pixels" else v) for k, v in half.items()}
            for tag, rank, two, fit in (("rank3", 3, True, True), ("moments", 3, True, False), ("rank4", 4, True, True),
                                        ("one_tap", 3, False, False)):
                st = G.ShadingState(baked, refl, exposure=exposure, rank=rank, two_tap=two, fit=fit)
                img, gl_mask = A.gl_frame(st, view, mesh, return_mask=True)
                m = fa.mask & gl_mask
                row[tag], de = A.compare(img, ref, m)
                row[tag]["silhouette_disagreement_px"] = int((fa.mask ^ gl_mask).sum())
                if tag in ("rank3", "moments"):
                    diff = np.clip(de * 25, 0, 255).astype(np.uint8)[..., None].repeat(3, -1)
                    diff[~m] = 40
                    suffix = "" if tag == "rank3" else "_moments"
                    Image.fromarray(np.concatenate([img, display8(xyz, exposure=exposure), diff], 1)).save(
                        out / f"{env_name}_{vname}{suffix}.png")
            summary.append(row)
            print(f"{env_name:7s} {vname:6s} px={row['rank3']['pixels']:6d}  rank3 ΔE mean "
                  f"{row['rank3']['mean']:.2f} p95 {row['rank3']['p95']:.2f} max {row['rank3']['max']:.1f} | moments "
                  f"mean {row['moments']['mean']:.2f} p95 {row['moments']['p95']:.2f} | rank4 "
                  f"mean {row['rank4']['mean']:.2f} | one-tap mean {row['one_tap']['mean']:.2f} p95 "
                  f"{row['one_tap']['p95']:.2f} | ref noise mean {row['reference_noise_est']['mean']:.2f} "
                  f"p95 {row['reference_noise_est']['p95']:.2f}  (ref {ref_s:.0f} s)", flush=True)
            summary_path.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
