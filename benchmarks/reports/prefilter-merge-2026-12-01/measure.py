"""Before/after measurements of the merged prefilter, one part per process (run from a checkout):

    PYTHONPATH=<checkout> python measure.py render|bake|gl OUT_DIR [--shared DIR]

- ``render``: the renderer's ``prefiltered`` mode on the default demo scene (200×150, as
  ``bench_render --quick``): environment build (prefilter) time, frame time (median of 3 after a warm-up)
  and ΔE2000 mean/p95/p99 against the converged reference (reference mode, 256 spp, seed 12345: computed
  once into ``--shared`` and reused by both checkouts).
- ``bake``: the interactive bake of ``pedestrian_overpass_1k.hdr`` (``cached_bake`` into an empty cache:
  first-bake time and the process's peak RSS, VmHWM), then the levels at their own resolution
  (``_bake``) saved as float64 for the old-vs-new comparison (``compare``).
- ``gl``: the GL agreement numbers of ``tests/test_interactive.py`` (sky orbit view vs reference 256 spp;
  the studio demo view vs reference 256 spp, auto exposure), each bake into an empty cache.
- ``compare BEFORE_DIR AFTER_DIR``: level-by-level differences of the bakes and of the rendered frames.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _vmhwm_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def render(out: Path, shared: Path) -> dict:
    os.environ["JKATANA_CACHE"] = tempfile.mkdtemp()
    from benchmarks._harness import delta_e_display, timeit
    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scene import DEMO_SCENE, scene_from_dict

    raw = json.loads(json.dumps(DEMO_SCENE))
    raw["camera"]["resolution"] = [200, 150]
    scene = scene_from_dict(raw)
    ref_path = shared / "render_reference.npz"
    if not ref_path.exists():
        t = time.perf_counter()
        ref = render_view(prepare(scene, mode="reference", samples=256), seed=12345)
        np.savez(ref_path, xyz=ref.xyz, mask=ref.mask, seconds=time.perf_counter() - t)
    with np.load(ref_path) as z:
        ref_xyz, mask = z["xyz"], z["mask"]
    t = time.perf_counter()
    prep = prepare(scene, mode="prefiltered", samples=1)
    t_prep = time.perf_counter() - t
    holder = {}

    def go():
        holder["f"] = render_view(prep, seed=1)
        return holder["f"].xyz

    tf = timeit(go, repeats=3, warmup=1)
    f = holder["f"]
    a = delta_e_display(ref_xyz[mask], f.xyz[mask], percentile=95.0)
    b = delta_e_display(ref_xyz[mask], f.xyz[mask], percentile=99.0)
    np.savez(out / "render_prefiltered.npz", xyz=f.xyz)
    return {"prepare_s": t_prep, "frame_s": tf["median"], "frame_s_min": tf["min"],
            "dE2000_mean": a["dE2000_mean"], "dE2000_p95": a["dE2000_p95"], "dE2000_p99": b["dE2000_p95"],
            "pixels": int(mask.sum()), "env_info": str(prep.env_info)}


def bake(out: Path, shared: Path) -> dict:
    from jkatana.interactive import bake as B
    from jkatana.models import Conductor
    from jkatana.render.renderer import load_environment
    from jkatana.render.scene import scene_from_dict
    from jkatana.shared import shared_data

    scene = scene_from_dict({"environment": {"type": "hdr", "path": str(shared_data("envmaps",
                                                                                       "pedestrian_overpass_1k.hdr"))}})
    grid = scene.spectral.grid
    rad = np.asarray(load_environment(scene, grid))
    base = _vmhwm_mb()
    with tempfile.TemporaryDirectory() as cache:
        t = time.perf_counter()
        B.cached_bake(rad, grid, cache_dir=cache)
        first = time.perf_counter() - t
        peak = _vmhwm_mb()
        import jax
        import jax.numpy as jnp

        dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
        t = time.perf_counter()
        _, levels = B._bake(np.asarray(rad, np.float64), grid, conductor=Conductor.from_table("Fe-Johnson", grid,
                            dtype=dt), rank=3, mus=B.MU_LEVELS, colourspace="sRGB", transfer=None,
                            cache_dir=cache)
        again = time.perf_counter() - t
    np.savez(out / "bake_levels.npz", **{f"level{k}": lv for k, lv in enumerate(levels)})
    return {"first_bake_s": first, "peak_rss_mb": peak, "rss_before_bake_mb": base, "bake_again_s": again,
            "shape": list(rad.shape), "levels": [list(lv.shape) for lv in levels]}


def gl(out: Path, shared: Path) -> dict:
    os.environ["JKATANA_CACHE"] = tempfile.mkdtemp()
    sys.path.insert(0, os.environ.get("PYTHONPATH", "."))
    from jkatana.interactive import bake as B
    from jkatana.interactive import glrender as glr
    from jkatana.interactive import scene as S
    from jkatana.render.film import auto_exposure
    from validation import gl_agreement as A

    res = {}
    # sky orbit view (test_gl_frame_agrees_with_the_reference_renderer_under_the_sky)
    sc = S.default_scene("sky", 200, 150)
    sc.view = S.orbit_views(sc.mesh, 3, 200, 150, distance=0.45)[0]
    baked = B.cached_bake(sc.radiance, sc.grid, rank=3)
    st = glr.ShadingState(baked, sc.refl_map)
    img = A.gl_frame(st, sc.view, sc.mesh)
    p = shared / "gl_sky_ref.npz"
    if not p.exists():
        fr = A.reference_frame(sc.radiance, sc.view, samples=256, seed=0)
        np.savez(p, xyz=fr.xyz, mask=fr.mask)
    with np.load(p) as z:
        xyz, m = z["xyz"], z["mask"]
    ref = A.display255(xyz, st.exposure)
    drawn = np.any(img != img[0, 0], axis=-1)
    res["sky"] = A.compare(img, ref, m & drawn)[0]
    # studio demo view (test_gl_frame_agrees_with_jkatana_render)
    view = S.demo_view(120, 90)
    rad = S.environment("studio")
    p = shared / "gl_studio_ref.npz"
    if not p.exists():
        fr = A.reference_frame(rad, view, samples=256, seed=0)
        np.savez(p, xyz=fr.xyz, mask=fr.mask)
    with np.load(p) as z:
        xyz, m = z["xyz"], z["mask"]
    exposure = auto_exposure(xyz, m, key=0.6, percentile=75.0)
    ref = A.display255(xyz, exposure)
    st = glr.ShadingState(B.cached_bake(rad, rank=3), S.reflectance_map().stacked(), exposure=exposure)
    img, gl_mask = A.gl_frame(st, view, S.blade(), return_mask=True)
    res["studio"] = A.compare(img, ref, m & gl_mask)[0]
    return res


def compare(before: Path, after: Path) -> dict:
    out = {"bake_levels": []}
    with np.load(before / "bake_levels.npz") as a, np.load(after / "bake_levels.npz") as b:
        for k in range(len(a.files)):
            x, y = a[f"level{k}"], b[f"level{k}"]
            if x.shape != y.shape:
                out["bake_levels"].append({"level": k, "shapes": [list(x.shape), list(y.shape)]})
                continue
            d = np.abs(y - x)
            big = np.abs(x) > 1e-3 * np.abs(x).max()
            out["bake_levels"].append({"level": k, "shape": list(x.shape),
                                       "max_abs_over_max": float(d.max() / np.abs(x).max()),
                                       "max_rel": float((d[big] / np.abs(x[big])).max()),
                                       "p99_rel": float(np.percentile(d[big] / np.abs(x[big]), 99))})
    pa, pb = before / "render_prefiltered.npz", after / "render_prefiltered.npz"
    if pa.exists() and pb.exists():
        with np.load(pa) as a, np.load(pb) as b:
            x, y = a["xyz"], b["xyz"]
            big = x[..., 1] > 1e-3 * x[..., 1].max()
            out["render_frame_Y_max_rel"] = float((np.abs(y - x)[..., 1][big] / x[..., 1][big]).max())
    return out


if __name__ == "__main__":
    what = sys.argv[1]
    if what == "compare":
        print(json.dumps(compare(Path(sys.argv[2]), Path(sys.argv[3])), indent=1))
        sys.exit(0)
    out = Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    shared = Path(sys.argv[sys.argv.index("--shared") + 1]) if "--shared" in sys.argv else out
    shared.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    res = {"render": render, "bake": bake, "gl": gl}[what](out, shared)
    res["load"] = os.getloadavg()
    res["wall_s"] = time.perf_counter() - t0
    (out / f"{what}.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res))
