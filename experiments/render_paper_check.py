"""Does the paper's hamon show? The demo blade rendered with the paper's exact parameters.

Mochizuki et al. fitted, on one blade at their goniometer, hiraji χ = 79000,
μ0 = 0.05 rad and hamon β = 43000, μ1 = 0.05 rad (§6.1). This script renders the
built-in blade with *those* values, uniform over each region (no hada grain),
the built-in notare/gunome hamon line deciding where each region is, under the
demo's Hosek–Wilkie sky and camera (:data:`jkatana.render.scenefile.DEMO_SCENE`), in
two conventions:

- **normalised** (no ``calibration``): each lobe integrates to the Fresnel
  reflectance (perfect mirror of reflectance F as μ → 0). χ and β drop out, and
  with μ0 = μ1 the two regions are the same material: the hamon cannot show.
- **calibrated** with K = χ: f_r scaled by χ/K and β/K, so the hiraji's lobe
  peak tends to F and the hamon's is β/χ = 0.54 of it — darker, not softer.

A third frame, ``all_hiraji`` (w = 1 everywhere, normalised), is the geometric
baseline: the same two pixel sets, the same material, so its hamon/ji ratio is
what position alone does (the edge side's normals tilt further down and
mirror lower sky). A region's material contrast is its ratio over that baseline.

For each it writes ``experiments/output/render_paper_check_<convention>.png``
(plus the same frame with the built-in map, μ1 = 0.2 rad, for comparison) and
prints the mean display luminance (Rec. 709 luma of the sRGB-encoded PNG, 0–1)
and the mean linear Y of hiraji pixels (w = 1 on the ji, between the shinogi
and the hamon) and of hamon pixels (w = 0), and their ratio.

Run: ``python experiments/render_paper_check.py [--quick]`` (``--quick``: 400×300, 16 spp).

Results of past runs: ``experiments/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

import numpy as np  # noqa: E402

from jkatana.maps.reflectance_map import PAPER_PARAMETERS, default_map  # noqa: E402
from jkatana.render.film import display  # noqa: E402
from jkatana.spectral.colorimetry import luminance_weights  # noqa: E402
from jkatana.render.frame import gbuffer  # noqa: E402
from jkatana.render.renderer import camera_for, exposure_for, prepare, render_view, write_outputs  # noqa: E402
from jkatana.render.scenefile import DEMO_SCENE, scene_from_dict  # noqa: E402

OUT = Path(__file__).resolve().parent / "output"
#: v of the shinogi on the built-in blade (KatanaSpec.shinogi_position): the ji starts below it.
SHINOGI_V = 0.30


def regions(prep, rmap) -> tuple[np.ndarray, np.ndarray]:
    """Boolean (H, W) masks of hiraji (w = 1, v past the shinogi) and hamon (w = 0) pixels of ``rmap``."""
    gb = gbuffer(prep.geometry, camera_for(prep.scene))
    w = rmap.sample(gb.uv[..., 0], gb.uv[..., 1])["w"]  # the same (u, v) lookup as the frame's maps
    v = gb.uv[..., 1]
    return gb.mask & (w > 0.999) & (v > SHINOGI_V + 0.03), gb.mask & (w < 1e-3)


def stats(prep, frame, exposure, rmap) -> dict:
    rgb = display(frame.xyz, prep.scene.film.colourspace, prep.scene.film.transfer, exposure=exposure)
    luma = rgb @ luminance_weights("sRGB")  # luma of the display values (BT.709 weights)
    ji, ha = regions(prep, rmap)
    Y = frame.xyz[..., 1]
    return {"ji_px": int(ji.sum()), "hamon_px": int(ha.sum()),
            "ji_luma": float(luma[ji].mean()), "hamon_luma": float(luma[ha].mean()),
            "ji_Y": float(Y[ji].mean()), "hamon_Y": float(Y[ha].mean())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="400×300, 16 spp")
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    p = PAPER_PARAMETERS
    # the built-in hamon line, but the paper's parameters, uniform: no hada grain, μ1 = μ0 = 0.05
    paper = default_map(hada_strength=0.0, hamon_mu=p["mu1"])
    paper.mu0[:] = p["mu0"]
    paper.mu1[:] = p["mu1"]
    paper.meta["source"] = "paper parameters (Mochizuki et al. §6.1), uniform, built-in hamon line"
    map_path = paper.write(out / "render_paper_check_map.exr")
    # baseline: hiraji material everywhere (w = 1), to separate the material from where the pixels are
    # (the hamon lies near the edge, whose hiraji normals tilt further and mirror lower sky/ground)
    allji = copy.deepcopy(paper)
    allji.w[:] = 1.0
    allji_path = allji.write(out / "render_paper_check_map_allji.exr")

    cases = {
        "all_hiraji": {"map": str(allji_path)},
        "normalised": {"map": str(map_path)},
        "calibrated": {"map": str(map_path), "calibration": p["chi"]},
        "builtin_map": {"map": "builtin"},
    }
    rows = []
    for name, mat in cases.items():
        raw = copy.deepcopy(DEMO_SCENE)
        raw["material"] = {**raw["material"], **mat}
        if args.quick:
            raw["camera"]["resolution"] = [400, 300]
        raw["output"] = {"directory": str(out), "name": f"render_paper_check_{name}"}
        t = time.perf_counter()
        prep = prepare(scene_from_dict(raw), samples=16 if args.quick else None)
        frame = render_view(prep)
        ex = exposure_for(prep, frame)
        paths = write_outputs(prep, frame, out / f"render_paper_check_{name}")
        s = stats(prep, frame, ex, paper)
        rows.append((name, s))
        print(f"{name:12s} {time.perf_counter() - t:5.1f} s  wrote {paths['png']}", file=sys.stderr)

    print("convention    ji px  hamon px   ji luma  hamon luma  hamon/ji luma   ji Y       hamon Y    hamon/ji Y")
    for name, s in rows:
        print(f"{name:12s} {s['ji_px']:6d} {s['hamon_px']:9d}   {s['ji_luma']:.3f}     {s['hamon_luma']:.3f}"
              f"       {s['hamon_luma'] / s['ji_luma']:.3f}        {s['ji_Y']:.3e}  {s['hamon_Y']:.3e}"
              f"  {s['hamon_Y'] / s['ji_Y']:.3f}")
    print("(luma: Rec. 709 weights on the sRGB-encoded display values after each frame's auto exposure; "
          "Y: linear CIE Y before exposure; all_hiraji = paper hiraji material everywhere, normalised: the "
          "geometric baseline of the two pixel sets; builtin_map = the demo's map, hamon μ1 = 0.2 rad, hada grain)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
