"""Interactive path (pyrender + baked GLSL): frames per second against ΔE2000 error.

Setup: the built-in scene (default blade and reflectance map, the ``sky``
environment 128×256×61), tables baked at rank 4 (so ranks 1–4 come from the
same bake), headless EGL — Mesa llvmpipe when there is no GPU. Two views at
800×600: the demo camera (the blade covers a few % of the frame) and a
close-up in which the flat fills the frame (as appraisers look).

Cases (each on both views); all but ``forward`` and ``msaa4`` use deferred shading (a G-buffer pass,
then the shader once per covered pixel, see :mod:`jkatana.interactive.glrender`):

- ``full``: rank 3, roughness (prefiltered μ levels), blend map — the default;
- ``forward``: ``full`` shaded in the forward pass (the shader on every fragment llvmpipe rasterises:
  the path before deferred shading; the windowed Viewer still draws this way);
- ``rank1`` / ``rank2`` / ``rank4``: spectral basis rank;
- ``one_tap``: one isotropic prefiltered tap instead of the three-tap anisotropic lobe;
- ``five_tap``: five binomial taps along the plane of incidence instead of three;
- ``no_rough``: mirror-like (narrowest μ level); ``no_blend``: hiraji everywhere;
- ``msaa4``: ``full`` with pyrender's 4× MSAA framebuffer (what pyrender does by default).

Time: one ``OffscreenRenderer.render`` call (draw + shade + read-back of the
800×600 RGB frame), median of repeats; fps = 1/median. ``cpu_s``: process CPU
time per frame (user + system, llvmpipe's threads included) — unlike the wall
time it hardly depends on what else runs on the machine; ``cores / cpu_s`` is
the frame rate the frame's work allows on an idle machine with perfect
parallelism (an upper bound). Error: ΔE2000 (mean,
p95) over the blade's pixels of the GL frame against the direct per-pixel JAX
evaluation (:mod:`jkatana.interactive.reference`: exact Fresnel, 61 bands,
lobe quadrature of the unfiltered environment) at a reduced resolution
(200×150; 96×72 in quick mode) of the same view — the reference costs seconds
per thousand pixels. The load average is recorded: on a shared machine the
fps are lower bounds.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from benchmarks._harness import machine_facts, record, timeit

CONFIGS = {
    "full": dict(rank=3, rough=True, blend=True, two_tap=True, samples=0),
    "forward": dict(rank=3, rough=True, blend=True, two_tap=True, samples=0, deferred=False),
    "rank1": dict(rank=1, rough=True, blend=True, two_tap=True, samples=0),
    "rank2": dict(rank=2, rough=True, blend=True, two_tap=True, samples=0),
    "rank4": dict(rank=4, rough=True, blend=True, two_tap=True, samples=0),
    "one_tap": dict(rank=3, rough=True, blend=True, two_tap=False, samples=0),
    "five_tap": dict(rank=3, rough=True, blend=True, two_tap=True, taps=5, samples=0),
    "no_rough": dict(rank=3, rough=False, blend=True, two_tap=True, samples=0),
    "no_blend": dict(rank=3, rough=True, blend=False, two_tap=True, samples=0),
    "msaa4": dict(rank=3, rough=True, blend=True, two_tap=True, samples=4),
}


def _log(*a):
    print("[bench_interactive]", *a, file=sys.stderr, flush=True)


def _cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _cpu_per_frame(fn, n: int) -> float:
    c = _cpu()
    for _ in range(n):
        fn()
    return (_cpu() - c) / n


def run(quick: bool = False) -> list[dict]:
    from jkatana.interactive import glrender as G
    from jkatana.interactive import reference as R
    from jkatana.interactive import scene as S
    from jkatana.interactive.bake import cached_bake
    from jkatana.interactive.gl import describe_context

    t0 = time.perf_counter()
    sc = S.default_scene("sky")
    baked = cached_bake(sc.radiance, sc.grid, rank=4)
    bake_s = time.perf_counter() - t0
    views = {"demo": sc.view, "closeup": S.closeup_view(sc.mesh)}
    err_res = (96, 72) if quick else (200, 150)
    reps = 5 if quick else 15
    rows = []
    ctx = None
    for vname, view in views.items():
        small = S.View(view.pose, view.yfov, *err_res)
        t = time.perf_counter()
        gb = R.gbuffer(sc.mesh, small)
        ref = R.display8(R.shade(gb, small, sc.radiance, sc.refl_map, n_phi=16, n_psi=24))
        ref_s = time.perf_counter() - t
        _log(f"{vname}: reference {small.width}×{small.height} ({gb['mask'].sum()} px) in {ref_s:.1f} s")
        for cname, cfg in CONFIGS.items():
            if quick and cname in ("rank2", "msaa4") and vname == "demo":
                continue
            st = G.ShadingState(baked, sc.refl_map, rank=cfg["rank"], rough=cfg["rough"], blend=cfg["blend"],
                                two_tap=cfg["two_tap"], taps=cfg.get("taps", 3))
            r = G.BakedOffscreenRenderer(st, view.width, view.height, samples=cfg["samples"],
                                         deferred=cfg.get("deferred"))
            scene = G.build_scene(sc.mesh, view)
            ctx = ctx or describe_context()
            tm = timeit(lambda: r.render(scene), repeats=reps, warmup=2)
            cpu_s = _cpu_per_frame(lambda: r.render(scene), 5)
            frame = r.render(scene)
            coverage = float(np.any(frame != frame[0, 0], -1).mean())
            r.delete()
            r2 = G.BakedOffscreenRenderer(st, *err_res, samples=cfg["samples"], deferred=cfg.get("deferred"))
            img = r2.render(G.build_scene(sc.mesh, small))
            r2.delete()
            de = R.delta_e_2000(img, ref)[gb["mask"]]
            err = {"dE00_mean": float(de.mean()), "dE00_p95": float(np.percentile(de, 95)),
                   "dE00_max": float(de.max())}
            fps = 1.0 / tm["median"]
            _log(f"{vname:8s} {cname:9s} {fps:6.1f} fps  cpu {1e3 * cpu_s:5.1f} ms/frame  ΔE mean "
                 f"{err['dE00_mean']:.2f} p95 {err['dE00_p95']:.2f}  (load {os.getloadavg()[0]:.1f})")
            rows.append(record("bench_interactive", {"view": vname, "config": cname, **cfg,
                                                     "width": view.width, "height": view.height},
                               time_s=tm, error=err,
                               reference=f"per-pixel JAX quadrature, 61 bands, {err_res[0]}×{err_res[1]}",
                               fps=fps, cpu_s=cpu_s, idle_fps_bound=(os.cpu_count() or 1) / cpu_s,
                               blade_coverage=coverage, loadavg_1min=os.getloadavg()[0],
                               gl=ctx, bake_s=bake_s, reference_s=ref_s,
                               lp_num_threads=os.environ.get("LP_NUM_THREADS", "default")))
    # fixed cost per frame: the same renderer with the blade out of the picture (clear + read-back)
    away = S.View(S.look_at(np.array([0.0, 0.0, 5.0]), np.array([0.0, 0.0, 10.0])), sc.view.yfov, 800, 600)
    st = G.ShadingState(baked, sc.refl_map)
    r = G.BakedOffscreenRenderer(st, 800, 600)
    scene = G.build_scene(sc.mesh, away)
    tm = timeit(lambda: r.render(scene), repeats=reps, warmup=2)
    cpu_s = _cpu_per_frame(lambda: r.render(scene), 5)
    r.delete()
    _log(f"empty frame (vertex processing, clears, read-back): {1e3 * tm['median']:.1f} ms, cpu {1e3 * cpu_s:.1f} ms")
    rows.append(record("bench_interactive", {"view": "empty", "config": "full", "width": 800, "height": 600},
                       time_s=tm, fps=1.0 / tm["median"], cpu_s=cpu_s, loadavg_1min=os.getloadavg()[0], gl=ctx))
    rows.append(record("bench_interactive", {"machine": True}, **machine_facts()))
    return rows
