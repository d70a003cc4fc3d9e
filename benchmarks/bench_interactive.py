"""Interactive path (pyrender + baked GLSL): frames per second against ΔE2000 error.

Setup: the built-in scene (default blade and reflectance map, the ``sky``
environment 128×256×61), tables baked at rank 4 (so ranks 1–4 come from the
same bake), headless EGL — Mesa llvmpipe when there is no GPU. Three views at
800×600: the demo camera (the blade covers a few % of the frame), a
close-up in which the flat fills the frame (as appraisers look), and
``glint_sunrise``: the sun of the shared ``sunrise.exr`` (a compact source: split off as a shader cap,
:func:`jkatana.interactive.caps.sun_caps`) glinting on the flat
(:func:`validation.gl_agreement.sun_glint_view`), where ``full_no_split`` is the same frame with the
sun left in the prefiltered map.

Cases (each on both views); all but ``forward`` and ``msaa4`` use deferred shading (a G-buffer pass,
then the shader once per covered pixel, see :mod:`jkatana.interactive.glrender`):

- ``default``: what a user gets — :class:`~jkatana.interactive.glstate.ShadingState`'s defaults (today
  rank 2, roughness, blend map, three fitted taps, the caps split off), whatever they become; the
  per-view table printed at the end (and ``python -m benchmarks.bench_interactive --defaults``, this case
  alone on the three views) gives its fps, CPU time and ΔE2000 against the agreement bar (mean ≤ 1,
  p95 ≤ 2.5);
- ``full``: rank 3, roughness (prefiltered μ levels), blend map, three fitted taps;
  ``rank2``: the same at rank 2 — the default of ``jkatana view`` and of ``ShadingState``;
- ``forward``: ``full`` shaded in the forward pass (the shader on every fragment llvmpipe rasterises:
  the path before deferred shading);
- ``rank1`` / ``rank2`` / ``rank4``: spectral basis rank;
- ``one_tap``: one isotropic prefiltered tap instead of the three-tap anisotropic lobe;
  ``rank2_one_tap``: both cheaper switches (``view --rank 2 --taps 1``);
- ``five_tap``: five binomial taps along the plane of incidence instead of three;
- ``no_rough``: mirror-like (narrowest μ level); ``no_blend``: hiraji everywhere;
- ``msaa4``: ``full`` with pyrender's 4× MSAA framebuffer (what pyrender does by default).

Extra cases: ``env_f16`` / ``gbuffer_f16`` (``full`` with RGBA16F environment textures / G-buffer:
the alternatives measured and not kept, see :data:`jkatana.interactive.glstate.ENV_FORMAT`), and
``viewer`` (the windowed Viewer under Xvfb, below).

Two times per case, both honest, for two uses:

- **drawn** (``time_s``, ``fps``): :meth:`BakedOffscreenRenderer.draw` — the frame drawn and waited
  for (``glFinish``), nothing read back: what a window pays per frame (the Viewer blits it to the
  window instead, about the cost of a clear);
- **read-back** (``readback_s``, ``fps_readback``): :meth:`BakedOffscreenRenderer.render` — the same
  plus the 800×600 RGBA8 read-back into numpy (batch previews, ``view --offscreen``).

Medians of repeats; fps = 1/median. ``cpu_s``: process CPU time per drawn frame over 15 frames (user +
system, llvmpipe's threads included) — unlike the wall time it hardly depends on what else runs on the
machine; ``cpu_by_thread_s``: the same split into the main thread, llvmpipe's threads and the others
(JAX/XLA's pools, which the reference render before each case leaves behind); ``cores / cpu_s`` is the
frame rate the frame's work allows on an idle machine with perfect parallelism (an upper bound).
``ns_per_pixel_cpu``: cpu_s over the blade's pixels.
The ``empty`` view (blade behind the camera) is the fixed cost per frame (vertex processing of the
51k-triangle mesh, depth clear, colour clear, read-back). ``stages_s`` (``full`` and ``empty``): the
wall time of each pass, glFinish after each — G-buffer pass, shading pass, read-back, and ``other``
(pyrender's scene update, context switch, Python).

``viewer``: ``jkatana view --measure-fps N`` in a fresh process on a private Xvfb display (GLX,
llvmpipe): the median interval between the window's draws, flip to the X server included, with the
light turning every frame — the frame rate a user sees. ``viewer_drag_half``: the same in the
close-up at ``--drag-scale 0.5`` (what a drag costs when the user asks for half-resolution shading
while the mouse is held; full resolution returns on release); ``viewer_drag_auto``: at
``--drag-scale auto`` (the fraction that fits 60 Hz, chosen from the measured full-resolution draw;
``shaded_scale`` records it). Skipped (and said so) without Xvfb.

Where the close-up's time goes (the cost of each part of the shading, the benchmark's one-process
sequence) is recorded in ``benchmarks/reports/interactive-2026-12-02-margin/NOTES.md``.

``families`` (view ``demo_family``): the demo view at 120×90 with the hiraji from a parameter file of each fit
model (GGX, GTR, two-lobe; :data:`validation.gl_agreement.FAMILY_FILES`) over the paper's hamon, under the
built-in studio light and sun sky (quick mode: GTR under the sun only), by
:func:`validation.gl_agreement.files_agreement`: ΔE2000 against the reference renderer (the same file,
``REF_SAMPLES`` samples per pixel) beside the three times a user meets: the reference frame, the bake (the
family's tables built in a new folder, as on its first use; XLA's programs may come from the compile cache)
and the GL frame (context, upload and draw: a first frame, not the steady rate above).

Error: ΔE2000 (mean, p95) over the blade's pixels of the GL frame against the reference renderer
(:func:`validation.gl_agreement.reference_frame`: jkatana.render's reference mode, exact Fresnel,
61 bands, ``REF_SAMPLES`` samples per pixel of the unfiltered environment) at a reduced resolution
(200×150; 96×72 in quick mode) of the same view — the reference costs seconds per thousand pixels. The load average is recorded with every row: on
a shared machine the fps are lower bounds.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from benchmarks._harness import machine_facts, record, timeit
from validation import gl_agreement as A

CONFIGS = {
    "default": dict(samples=0),
    "full": dict(rank=3, rough=True, blend=True, two_tap=True, samples=0),
    "forward": dict(rank=3, rough=True, blend=True, two_tap=True, samples=0, deferred=False),
    "rank1": dict(rank=1, rough=True, blend=True, two_tap=True, samples=0),
    "rank2": dict(rank=2, rough=True, blend=True, two_tap=True, samples=0),
    "rank4": dict(rank=4, rough=True, blend=True, two_tap=True, samples=0),
    "one_tap": dict(rank=3, rough=True, blend=True, two_tap=False, samples=0),
    "rank2_one_tap": dict(rank=2, rough=True, blend=True, two_tap=False, samples=0),
    "five_tap": dict(rank=3, rough=True, blend=True, two_tap=True, taps=5, samples=0),
    "no_rough": dict(rank=3, rough=False, blend=True, two_tap=True, samples=0),
    "no_blend": dict(rank=3, rough=True, blend=False, two_tap=True, samples=0),
    "msaa4": dict(rank=3, rough=True, blend=True, two_tap=True, samples=4),
    "env_f16": dict(rank=3, rough=True, blend=True, two_tap=True, samples=0, env_format="RGBA16F"),
    "gbuffer_f16": dict(rank=3, rough=True, blend=True, two_tap=True, samples=0, gbuffer_format="RGBA16F"),
}
#: Samples per pixel of the reference frame (its noise adds to the measured ΔE2000).
REF_SAMPLES = 256
#: cases skipped in quick mode (per view)
QUICK_SKIP = {"demo": {"msaa4", "env_f16", "gbuffer_f16", "forward"}, "closeup": {"msaa4", "gbuffer_f16"},
              "glint_sunrise": set(CONFIGS) - {"default", "full", "rank2", "one_tap", "five_tap"}}
#: the agreement bar every view must meet at the defaults (ΔE2000 mean, p95)
BAR = (1.0, 2.5)
#: cases run on each view (the sun-glint view: the shading switches that matter for a cap, and the unsplit map)
VIEW_CONFIGS = {"demo": CONFIGS, "closeup": CONFIGS,
                "glint_sunrise": {**{k: CONFIGS[k] for k in ("default", "full", "rank2", "one_tap", "five_tap",
                                                             "no_rough")},
                                  "full_no_split": {**CONFIGS["full"], "split_sun": False}}}


def _log(*a):
    print("[bench_interactive]", *a, file=sys.stderr, flush=True)


def _cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _thread_cpu() -> dict:
    """CPU seconds used so far by this process's threads, grouped: ``main`` (the Python thread that issues
    the GL calls; llvmpipe's vertex stage runs here), ``llvmpipe`` (its rasteriser threads) and ``other``
    (JAX/XLA's pools and the rest). Linux ``/proc/self/task``; empty elsewhere."""
    out = {"main": 0.0, "llvmpipe": 0.0, "other": 0.0}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return {}
    tck, pid = os.sysconf("SC_CLK_TCK"), os.getpid()
    for t in tids:
        try:
            with open(f"/proc/self/task/{t}/comm") as f:
                comm = f.read().strip()
            with open(f"/proc/self/task/{t}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:                       # the thread ended meanwhile
            continue
        group = "main" if int(t) == pid else "llvmpipe" if comm.startswith("llvmpipe") else "other"
        out[group] += (int(fields[11]) + int(fields[12])) / tck           # utime + stime
    return out


def _cpu_per_frame(fn, n: int) -> tuple[float, dict]:
    """Process CPU seconds per call of ``fn`` over ``n`` calls, and the same per thread group
    (:func:`_thread_cpu`: whether anything beside the frame's own threads ran, e.g. JAX's pools after a
    reference render; clock ticks of 10 ms, so meaningful over ≥ 10 calls)."""
    c, t = _cpu(), _thread_cpu()
    for _ in range(n):
        fn()
    t1 = _thread_cpu()
    return (_cpu() - c) / n, {k: (t1[k] - t[k]) / n for k in t1}


def _stages(r, scene, n: int) -> dict:
    """Median wall time of each pass of a deferred frame (G-buffer, shading, read-back), glFinish-timed,
    and the rest of the frame (pyrender's scene update, context switch, Python)."""
    rr = r._r._renderer
    rr.time_stages = True
    try:
        runs = []
        for _ in range(n):
            t = time.perf_counter()
            r.render(scene)
            runs.append({**rr.last_stages, "total_s": time.perf_counter() - t})
    finally:
        rr.time_stages = False
    med = {k: float(np.median([x[k] for x in runs])) for k in runs[0]}
    med["other_s"] = med["total_s"] - med["gbuffer_s"] - med["shading_s"] - med["readback_s"]
    return med


def _viewer_fps(frames: int, closeup: bool, size=(800, 600), drag_scale: float = 1.0) -> dict:
    """``jkatana view --measure-fps`` under Xvfb: the window's median frame interval (or why not)."""
    import re
    import shutil

    from jkatana.interactive.commands import run_in_xvfb

    if shutil.which("Xvfb") is None:
        return {"skipped": "Xvfb not installed (Debian package xvfb)"}
    argv = (["--resolution", str(size[0]), str(size[1]), "--measure-fps", str(frames), "--drag-scale", str(drag_scale)]
            + (["--closeup"] if closeup else []))
    res = run_in_xvfb(argv, timeout=300, size=size)
    m = re.search(r"shaded at ([\d.]+)× resolution\): median interval ([\d.]+) ms = ([\d.]+) fps \(min ([\d.]+) ms\); "
                  r"the draw alone \(glFinish, no flip\) ([\d.]+) ms", res.stderr)
    if res.returncode != 0 or not m:
        return {"skipped": f"viewer failed (rc {res.returncode}): {res.stderr.strip().splitlines()[-1:]}"}
    return {"scale": float(m.group(1)), "median_s": float(m.group(2)) * 1e-3, "min_s": float(m.group(4)) * 1e-3,
            "fps": float(m.group(3)), "draw_s": float(m.group(5)) * 1e-3}


def _state_kwargs(cfg: dict) -> dict:
    """ShadingState keyword arguments of a case: only what it sets (the ``default`` case sets nothing)."""
    keys = ("rank", "rough", "blend", "two_tap", "taps")
    return {k: cfg[k] for k in keys if k in cfg}


def defaults_table(rows: list[dict]) -> str:
    """The ``default`` case per view: drawn ms and fps, CPU ms per frame, ΔE2000 against the bar, load."""
    lines = ["| view | drawn ms | fps | CPU ms/frame | ΔE2000 mean | p95 | within bar | load |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.get("case", {}).get("config") != "default" or "error" not in r:
            continue
        e = r["error"]
        ok = e["dE00_mean"] <= BAR[0] and e["dE00_p95"] <= BAR[1]
        lines.append(f"| {r['case']['view']} | {1e3 * r['time_s']['median']:.1f} | {r['fps']:.1f} | "
                     f"{1e3 * r['cpu_s']:.1f} | {e['dE00_mean']:.2f} | {e['dE00_p95']:.2f} | {'yes' if ok else 'NO'} | "
                     f"{r['loadavg_1min']:.1f} |")
    return "\n".join(lines)


def _families(quick: bool) -> list[dict]:
    """The ``families`` cases (module docstring): one row per (lobe family, light)."""
    import tempfile

    from jkatana.interactive import scene as S

    cases = [("gtr", "sun")] if quick else [(m, e) for m in A.FAMILY_FILES for e in ("studio", "sun")]
    rows = []
    for model, light in cases:
        with tempfile.TemporaryDirectory() as tmp:
            r = A.files_agreement(tmp, S.demo_view(120, 90), S.environment(light),
                                  {"hiraji": (model, A.FAMILY_FILES[model])}, samples=REF_SAMPLES)
        err = {"dE00_mean": r["mean"], "dE00_p95": r["p95"], "dE00_max": r["max"]}
        within = r["mean"] <= BAR[0] and r["p95"] <= BAR[1]
        _log(f"family {model:8s} {light:6s} ΔE mean {r['mean']:.2f} p95 {r['p95']:.2f} "
             f"({'within' if within else 'OVER'} the bar)  reference {r['reference_s']:.1f} s, bake "
             f"{r['bake_s']:.1f} s, first GL frame {r['gl_s']:.2f} s")
        rows.append(record("bench_interactive", {"view": "demo_family", "config": "default", "family": model,
                                                 "light": light, "width": 120, "height": 90},
                           time_s={"median": r["gl_s"]}, error=err, within_bar=within,
                           reference=f"jkatana.render reference mode, {REF_SAMPLES} samples, the same parameter file",
                           reference_s=r["reference_s"], bake_s=r["bake_s"], blade_pixels=r["pixels"],
                           tail_tap=r["tail"], loadavg_1min=os.getloadavg()[0]))
    return rows


def run(quick: bool = False, defaults_only: bool = False) -> list[dict]:
    from jkatana.interactive import glrender as G      # first: it chooses the GL platform (EGL)
    from jkatana.interactive import scene as S
    from jkatana.interactive.bake import cached_bake
    from jkatana.interactive.gl import describe_context

    t0 = time.perf_counter()
    sc = S.default_scene("sky")
    baked = cached_bake(sc.radiance, sc.grid, rank=4)
    bake_s = time.perf_counter() - t0
    sunrise = A.shared_environment("sunrise.exr")
    t0 = time.perf_counter()
    baked_sun = {True: cached_bake(sunrise, sc.grid, rank=4), False: cached_bake(sunrise, sc.grid, rank=4, split_sun=False)}
    _log(f"sunrise.exr {sunrise.shape[:2]}: baked/loaded in {time.perf_counter() - t0:.1f} s, "
         f"{baked_sun[True].n_caps} cap(s) split off")
    views = {"demo": sc.view, "closeup": S.closeup_view(sc.mesh),
             "glint_sunrise": A.sun_glint_view(sc.mesh, sunrise, 800, 600)}
    err_res = (96, 72) if quick else (200, 150)
    reps = 5 if quick else 15
    rows = []
    ctx = None
    from OpenGL import GL

    formats = {"RGBA32F": GL.GL_RGBA32F, "RGBA16F": GL.GL_RGBA16F}
    for vname, view in views.items():
        small = S.View(view.pose, view.yfov, *err_res)
        radiance = sunrise if vname == "glint_sunrise" else sc.radiance
        t = time.perf_counter()
        fr = A.reference_frame(radiance, small, samples=REF_SAMPLES, seed=0)
        exposure = 1.0
        if vname == "glint_sunrise":     # the sky's exposure of 1 would clip the sunrise; as the agreement tests
            from jkatana.render.film import auto_exposure

            exposure = auto_exposure(fr.xyz, fr.mask, key=0.6, percentile=75.0)
        ref = A.display255(fr.xyz, exposure)
        ref_s = time.perf_counter() - t
        _log(f"{vname}: reference {small.width}×{small.height} ({fr.mask.sum()} px) in {ref_s:.1f} s")
        for cname, cfg in VIEW_CONFIGS[vname].items():
            if (quick and cname in QUICK_SKIP.get(vname, ())) or (defaults_only and cname != "default"):
                continue
            tables = baked_sun[cfg.get("split_sun", True)] if vname == "glint_sunrise" else baked
            gbuffer_format = formats[cfg.get("gbuffer_format", "RGBA32F")]
            st = G.ShadingState(tables, sc.refl_map, **_state_kwargs(cfg), exposure=exposure,
                                env_format=formats[cfg.get("env_format", "RGBA32F")])
            r = G.BakedOffscreenRenderer(st, view.width, view.height, samples=cfg["samples"],
                                         deferred=cfg.get("deferred"), gbuffer_format=gbuffer_format)
            scene = G.build_scene(sc.mesh, view)
            ctx = ctx or describe_context()
            drawn = timeit(lambda: r.draw(scene), repeats=reps, warmup=2)
            readback = timeit(lambda: r.render(scene), repeats=max(reps // 2, 3), warmup=1)
            cpu_s, cpu_threads = _cpu_per_frame(lambda: r.draw(scene), 15)
            stages = _stages(r, scene, reps) if cname == "full" else None
            frame = r.render(scene)
            covered = int(np.any(frame != frame[0, 0], -1).sum())
            r.delete()
            r2 = G.BakedOffscreenRenderer(st, *err_res, samples=cfg["samples"], deferred=cfg.get("deferred"),
                                          gbuffer_format=gbuffer_format)
            img = r2.render(G.build_scene(sc.mesh, small))
            r2.delete()
            stats, _ = A.compare(img, ref, fr.mask & np.any(img != img[0, 0], -1))
            err = {"dE00_mean": stats["mean"], "dE00_p95": stats["p95"], "dE00_max": stats["max"]}
            fps = 1.0 / drawn["median"]
            load = os.getloadavg()[0]
            _log(f"{vname:8s} {cname:11s} drawn {1e3 * drawn['median']:5.1f} ms ({fps:5.1f} fps)  read-back "
                 f"{1e3 * readback['median']:5.1f} ms ({1 / readback['median']:5.1f} fps)  cpu "
                 f"{1e3 * cpu_s:5.1f} ms/frame (" + ", ".join(f"{k} {1e3 * v:.1f}" for k, v in cpu_threads.items())
                 + f")  ΔE mean {err['dE00_mean']:.2f} p95 {err['dE00_p95']:.2f}  "
                 f"(load {load:.1f})")
            rows.append(record("bench_interactive", {"view": vname, "config": cname, **cfg, "rank": st.rank,
                                                     "width": view.width, "height": view.height,
                                                     "caps": tables.n_caps},
                               time_s=drawn, error=err,
                               reference=f"jkatana.render reference mode, {REF_SAMPLES} samples, 61 bands, "
                                         f"{err_res[0]}×{err_res[1]}",
                               fps=fps, readback_s=readback, fps_readback=1.0 / readback["median"],
                               cpu_s=cpu_s, cpu_by_thread_s=cpu_threads, idle_fps_bound=(os.cpu_count() or 1) / cpu_s,
                               blade_pixels=covered, blade_coverage=covered / (view.width * view.height),
                               ns_per_pixel_cpu=1e9 * cpu_s / max(covered, 1), loadavg_1min=load,
                               gl=ctx, bake_s=bake_s, reference_s=ref_s,
                               lp_num_threads=os.environ.get("LP_NUM_THREADS", "default"),
                               **({"stages_s": stages} if stages else {})))
            if stages:
                _log(f"{vname:8s} {cname:11s} stages (glFinish after each): "
                     + ", ".join(f"{k[:-2]} {1e3 * v:.2f} ms" for k, v in stages.items()))
    _log("the defaults per view (800×600; ΔE2000 at " + f"{err_res[0]}×{err_res[1]}):\n" + defaults_table(rows))
    if defaults_only:
        rows.append(record("bench_interactive", {"machine": True}, **machine_facts()))
        return rows
    rows += _families(quick)
    # what the CPU time per blade pixel says about the texture fetches: rank 4 − rank 1 is 9 more
    # trilinear environment fetches per pixel (3 taps × 3 ranks)
    by = {(r_["case"]["view"], r_["case"]["config"]): r_ for r_ in rows}
    for vname in views:
        if (vname, "rank4") in by and (vname, "rank1") in by and (vname, "full") in by:
            per = (by[vname, "rank4"]["ns_per_pixel_cpu"] - by[vname, "rank1"]["ns_per_pixel_cpu"]) / 9
            _log(f"{vname}: {by[vname, 'full']['ns_per_pixel_cpu']:.0f} ns CPU per blade pixel (full); "
                 f"≈ {per:.1f} ns CPU per trilinear environment fetch per pixel (rank 4 − rank 1, 9 fetches)")
            by[vname, "full"]["ns_per_env_fetch_cpu"] = per
    # fixed cost per frame: the same renderer with the blade out of the picture
    away = S.View(S.look_at(np.array([0.0, 0.0, 5.0]), np.array([0.0, 0.0, 10.0])), sc.view.yfov, 800, 600)
    st = G.ShadingState(baked, sc.refl_map)
    r = G.BakedOffscreenRenderer(st, 800, 600)
    scene = G.build_scene(sc.mesh, away)
    drawn = timeit(lambda: r.draw(scene), repeats=reps, warmup=2)
    readback = timeit(lambda: r.render(scene), repeats=reps, warmup=1)
    cpu_s, _ = _cpu_per_frame(lambda: r.draw(scene), 15)
    stages = _stages(r, scene, reps)
    r.delete()
    _log("empty    stages (glFinish after each): " + ", ".join(f"{k[:-2]} {1e3 * v:.2f} ms" for k, v in stages.items()))
    _log(f"empty frame (vertex processing, clears): drawn {1e3 * drawn['median']:.1f} ms, with read-back "
         f"{1e3 * readback['median']:.1f} ms, cpu {1e3 * cpu_s:.1f} ms")
    rows.append(record("bench_interactive", {"view": "empty", "config": "full", "width": 800, "height": 600},
                       time_s=drawn, fps=1.0 / drawn["median"], readback_s=readback,
                       fps_readback=1.0 / readback["median"], cpu_s=cpu_s, stages_s=stages,
                       loadavg_1min=os.getloadavg()[0], gl=ctx))
    # the windowed Viewer's real frame rate (Xvfb, GLX llvmpipe, flip included)
    for vname, cname, scale in (("demo", "viewer", 1.0), ("closeup", "viewer", 1.0),
                                ("closeup", "viewer_drag_half", 0.5), ("closeup", "viewer_drag_auto", "auto")):
        n_frames = 20 if quick else 120
        res = _viewer_fps(n_frames, closeup=vname == "closeup", drag_scale=scale)
        load = os.getloadavg()[0]
        case = {"view": vname, "config": cname, "drag_scale": scale, "width": 800, "height": 600}
        if "skipped" in res:
            _log(f"viewer {vname} {cname}: skipped ({res['skipped']})")
            rows.append(record("bench_interactive", case, skipped=res["skipped"], loadavg_1min=load))
            continue
        _log(f"viewer {vname} {cname}: {res['fps']:.1f} fps at {res['scale']:.2f}× resolution (median interval {1e3 * res['median_s']:.1f} ms, min "
             f"{1e3 * res['min_s']:.1f} ms; Xvfb, flip included; the draw alone {1e3 * res['draw_s']:.1f} ms)  "
             f"(load {load:.1f})")
        rows.append(record("bench_interactive", case,
                           time_s={"median": res["median_s"], "min": res["min_s"], "max": res["median_s"],
                                   "iqr": 0.0, "repeats": n_frames},
                           fps=res["fps"], draw_s=res["draw_s"], shaded_scale=res["scale"], loadavg_1min=load,
                           platform="GLX on Xvfb (llvmpipe)"))
    rows.append(record("bench_interactive", {"machine": True}, **machine_facts()))
    return rows


if __name__ == "__main__":          # python -m benchmarks.bench_interactive [--quick] [--defaults]
    run(quick="--quick" in sys.argv, defaults_only="--defaults" in sys.argv)
