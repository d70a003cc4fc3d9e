"""Reference renderer: frame time vs error per shading mode and sample count; effects off; cold start.

Studies (records follow the convention in :mod:`benchmarks`):

- ``render convergence (<scene>)``: each mode (MIS reference, the paper's
  jittered rays, low-rank spectra, prefiltered) at several sample counts, ΔE2000
  (mean, p95, p99 over the object's pixels, display-referred: the converged
  frame's 99th-percentile Y maps to display white) against a converged frame
  (the reference mode at many samples, another seed), for the default demo
  scene (blade, sky with a low sun) and a sun-dominated sphere.
- ``render effects off``: time of a plan with an effect switched off by the
  scene (mirror-only hiraji, grey environment, no hamon, no occluders) against
  the plan that traces it, on the same image (for occluders: an occluder that
  blocks nothing, so the visibility pass runs in full).
- ``render cold start``: ``jkatana demo`` in a fresh process (import + scene +
  JIT + frame + files).

Times exclude compilation (``timeit`` warm-up) except the cold start.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

import numpy as np  # noqa: E402

from benchmarks._harness import delta_e_display, record, timeit  # noqa: E402

BENCH = "render"


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


def _scenes(quick: bool):
    from jkatana.render.scene import DEMO_SCENE

    res = [200, 150] if quick else [800, 600]
    demo = json.loads(json.dumps(DEMO_SCENE))
    demo["camera"]["resolution"] = res
    sun = {"geometry": {"sphere": {"radius": 1.0}},
           "material": {"w": 0.5, "mu0": 0.05, "mu1": 0.05},
           "environment": {"type": "sky", "elevation_deg": 40.0, "azimuth_deg": 200.0, "turbidity": 2.0,
                           "resolution": [256, 512]},
           "camera": {"type": "lookat", "position": [0.0, 0.3, 3.2], "look_at": [0.0, 0.0, 0.0],
                      "fov_deg": 40.0, "resolution": res}}
    scenes = {"default (blade, low sun)": demo, "sun-dominated sphere": sun}
    if quick:  # the CI smoke run: one scene (compilation per mode dominates the time on 2 cores)
        scenes.pop("sun-dominated sphere")
    return scenes


def _de(ref, frame, mask):
    a = delta_e_display(ref.xyz[mask], frame.xyz[mask], percentile=95.0)
    b = delta_e_display(ref.xyz[mask], frame.xyz[mask], percentile=99.0)
    return {"dE2000_mean": a["dE2000_mean"], "dE2000_p95": a["dE2000_p95"], "dE2000_p99": b["dE2000_p95"],
            "dE2000_max": a["dE2000_max"]}


def run(quick: bool) -> list[dict]:
    import jax

    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scene import scene_from_dict

    rows = []
    ref_spp = 256 if quick else 1024
    sample_sets = {"reference": [4, 16, 64] if quick else [4, 16, 64, 128, 256],
                   "paper": [30] if quick else [30, 128],
                   "lowrank": [64] if quick else [16, 64, 256],
                   "prefiltered": [1]}
    for scene_name, raw in _scenes(quick).items():
        scene = scene_from_dict(raw)
        prep_ref = prepare(scene, mode="reference", samples=ref_spp)
        t0 = time.perf_counter()
        ref = render_view(prep_ref, seed=12345)
        _log(f"[render] {scene_name}: converged frame {ref_spp} spp in {time.perf_counter() - t0:.1f} s "
             f"({ref.stats['pixels_shaded']} px)")
        mask = ref.mask
        study = f"render convergence ({scene_name})"
        rows.append(record(BENCH, {"scene": scene_name, "mode": "reference", "samples": ref_spp},
                           study=study, variant=f"reference {ref_spp} spp (converged)", is_reference=True,
                           error={"dE2000_mean": 0.0}, error_metric="dE2000_mean",
                           time_s={"median": ref.timing["shade_s"], "min": ref.timing["shade_s"],
                                   "max": ref.timing["shade_s"]},
                           reference="itself", items=int(mask.sum()), resolution=raw["camera"]["resolution"]))
        for mode, counts in sample_sets.items():
            for spp in counts:
                prep = prepare(scene, mode=mode, samples=spp)
                holder = {}

                def go():
                    holder["f"] = render_view(prep, seed=1)
                    return holder["f"].xyz

                t = timeit(go, repeats=3 if quick else 5, warmup=1)
                f = holder["f"]
                err = _de(ref, f, mask)
                label = f"{mode} {spp} spp" if mode != "prefiltered" else "prefiltered"
                if mode == "lowrank":
                    label += f" (rank {scene.render['rank']})"
                rows.append(record(BENCH, {"scene": scene_name, "mode": mode, "samples": spp},
                                   study=study, variant=label, time_s=t, error=err, error_metric="dE2000_mean",
                                   reference=f"reference mode {ref_spp} spp, other seed", tolerance=1.0,
                                   items=int(mask.sum()), shade_s=f.timing["shade_s"],
                                   devices=len(jax.local_devices()), env=prep.env_info))
                _log(f"[render] {scene_name} {label}: {t['median']:.3f} s  ΔE mean {err['dE2000_mean']:.3f} "
                     f"p99 {err['dE2000_p99']:.2f}")
    rows += _effects(quick)
    if not quick:
        rows += _devices(quick)
    rows += _mitsuba(quick)
    rows += _cold_start(quick)
    return rows


def _mitsuba(quick: bool) -> list[dict]:
    """Rough (Beckmann α = 0.2) iron sphere: jkatana and Mitsuba 3 vs a converged Mitsuba frame, time and ΔE."""
    import tempfile
    from pathlib import Path

    from jkatana.render import mitsuba_check as mc

    variant = mc.mitsuba_variant()
    src = Path("/work/shared/data/envmaps/courtyard.exr")
    if variant is None or not src.is_file():
        _log("[render] Mitsuba comparison skipped (mitsuba not installed / no variant / no envmap)")
        return []
    rows = []
    size = 48 if quick else 96
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(src, Path(d) / "env.exr", 256)
        t0 = time.perf_counter()
        ref = mc.render_mitsuba(env, alpha=0.2, size=size, spp=8192 if quick else 16384, variant=variant)
        _log(f"[render] Mitsuba converged frame in {time.perf_counter() - t0:.1f} s")
        study = f"render vs Mitsuba 3 ({variant}, rough iron sphere {size}²)"
        _, mask, _ = mc.render_jkatana(env, alpha=0.2, size=size, samples=1, supersample=2)
        for spp in ([256, 1024] if quick else [256, 1024, 4096]):
            mc.render_mitsuba(env, alpha=0.2, size=size, spp=spp, variant=variant)  # JIT warm-up
            t0 = time.perf_counter()
            img = mc.render_mitsuba(env, alpha=0.2, size=size, spp=spp, variant=variant)
            dt = time.perf_counter() - t0
            err = mc.compare(ref, img, mask)
            rows.append(record(BENCH, {"renderer": f"mitsuba {variant}", "spp": spp}, study=study,
                               variant=f"Mitsuba {spp} spp", time_s={"median": dt, "min": dt, "max": dt},
                               error=err, error_metric="dE2000_mean", reference="Mitsuba converged frame"))
            _log(f"[render] Mitsuba {spp} spp: {dt:.2f} s ΔE {err['dE2000_mean']:.3f}/{err['dE2000_p99']:.2f}")
        for spp in ([16, 64] if quick else [16, 64, 256]):
            mc.render_jkatana(env, alpha=0.2, size=size, samples=spp, supersample=2)  # JIT warm-up
            img, _, shade = mc.render_jkatana(env, alpha=0.2, size=size, samples=spp, supersample=2)
            err = mc.compare(ref, img, mask)
            rows.append(record(BENCH, {"renderer": "jkatana reference", "spp": spp, "supersample": 2}, study=study,
                               variant=f"jkatana {spp} spp ×4 subpixels", time_s={"median": shade, "min": shade,
                                                                                  "max": shade},
                               error=err, error_metric="dE2000_mean", reference="Mitsuba converged frame",
                               note="time: shading only (G-buffer and env upsampling excluded)"))
            _log(f"[render] jkatana {spp} spp: {shade:.2f} s ΔE {err['dE2000_mean']:.3f}/{err['dE2000_p99']:.2f}")
    return rows


def _effects(quick: bool) -> list[dict]:
    """An effect the scene does not need, switched off, against the same image with it traced."""
    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scene import scene_from_dict

    res = [160, 120] if quick else [400, 300]
    base = {"geometry": {"sphere": {"radius": 1.0}}, "material": {"w": 1.0, "mu0": 0.05, "mu1": 0.05},
            "environment": {"type": "sky", "resolution": [128, 256]},
            "camera": {"type": "lookat", "position": [0, 0.3, 3.2], "look_at": [0, 0, 0], "resolution": res},
            "render": {"samples": 32}}
    rows = []

    def timed(prep):
        holder = {}

        def go():
            holder["f"] = render_view(prep)
            return holder["f"].xyz

        return timeit(go, repeats=3, warmup=1), holder["f"]

    cases = []
    # 1. no hamon pixels: the T–S term is not traced (vs. traced with weight 0)
    p_off = prepare(scene_from_dict(base))
    p_on = dataclasses.replace(p_off, plan=dataclasses.replace(p_off.plan, hamon=True))
    cases.append(("no hamon pixels → no Torrance–Sparrow term", p_off, p_on))
    # 2. mirror-only hiraji: one lookup instead of lobe sampling
    mirror = json.loads(json.dumps(base))
    mirror["material"] = {"w": 1.0, "mu0": 0.0, "mu1": 0.05}
    p_off = prepare(scene_from_dict(mirror))
    cases.append(("mirror-only → no lobe sampling", p_off, None))
    # 3. grey environment: one band
    grey = json.loads(json.dumps(base))
    grey["environment"] = {"type": "constant", "radiance": 1.0, "resolution": [128, 256]}
    p_off = prepare(scene_from_dict(grey))
    cases.append(("grey environment → one band", p_off, None))
    # 4. no occluders: no visibility pass at all (vs. the same image with an occluder that blocks nothing:
    #    a small box far below the horizon, so every direction is still traced and ray-cast)
    occl = json.loads(json.dumps(base))
    occl["occluders"] = [{"box": [0.01, 0.01, 0.01], "center": [0.0, -1000.0, 0.0]}]
    p_on = prepare(scene_from_dict(occl))
    cases.append(("no occluders → no visibility rays", prepare(scene_from_dict(base)), p_on))
    # 5. no point lights: none evaluated (vs. one light of zero intensity... not expressible: compare to 1 light)
    for name, off, on in cases:
        t_off, f_off = timed(off)
        row = {"effect": name, "time_off_s": t_off["median"], "plan_off": dataclasses.asdict(off.plan)}
        if on is not None:
            t_on, f_on = timed(on)
            row.update(time_on_s=t_on["median"], same_image_max_abs=float(np.max(np.abs(f_on.xyz - f_off.xyz))))
            if "visibility_rays" in f_on.timing:
                row.update(visibility_rays=f_on.timing["visibility_rays"],
                           visibility_cast_s=f_on.timing["visibility_cast_s"])
        rows.append(record(BENCH, {"study": "effects off", "effect": name}, time_s=t_off, **row))
        _log(f"[render] effect off: {name}: {row}")
    # the sampled version of the mirror case and the 61-band version of the grey case, for scale
    sampled = prepare(scene_from_dict(base))
    t_s, _ = timed(sampled)
    rows.append(record(BENCH, {"study": "effects off", "effect": "baseline: sampled μ = 0.05 hiraji, 61 bands"},
                       time_s=t_s))
    _log(f"[render] baseline sampled 61-band: {t_s['median']:.3f} s")
    return rows


def _devices(quick: bool) -> list[dict]:
    """Pixels split over 1 vs all local devices (host CPU devices = cores)."""
    import jax

    from jkatana.render.frame import render_frame
    from jkatana.render.renderer import prepare
    from jkatana.render.scene import DEMO_SCENE, scene_from_dict

    raw = json.loads(json.dumps(DEMO_SCENE))
    raw["camera"]["resolution"] = [200, 150] if quick else [800, 600]
    prep = prepare(scene_from_dict(raw), samples=16)
    from jkatana.render.renderer import camera_for

    cam = camera_for(prep.scene)
    rows = []
    for nd in sorted({1, len(jax.local_devices())}):
        t = timeit(lambda: render_frame(prep.plan, prep.material, prep.env, prep.lights, prep.geometry, cam,
                                        prep.maps, prep.cmf, n_devices=nd).xyz, repeats=3, warmup=1)
        rows.append(record(BENCH, {"study": "devices", "devices": nd, "samples": 16}, time_s=t))
        _log(f"[render] {nd} device(s): {t['median']:.3f} s")
    return rows


def _cold_start(quick: bool) -> list[dict]:
    args = ["--resolution", "200", "150"] if quick else []
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=os.path.join(d, "xla-cache"))  # truly cold
        r = subprocess.run([sys.executable, "-c", "import sys; from jkatana.cli import main; sys.exit(main())",
                            "demo", "-o", d, *args], capture_output=True, text=True, env=env)
        dt = time.perf_counter() - t0
    _log(f"[render] cold start demo: {dt:.1f} s\n{r.stdout}")
    return [record(BENCH, {"study": "cold start", "command": "jkatana demo " + " ".join(args)},
                   time_s={"median": dt, "min": dt, "max": dt}, ok=r.returncode == 0, stdout=r.stdout[-800:],
                   goal_s=60.0)]
