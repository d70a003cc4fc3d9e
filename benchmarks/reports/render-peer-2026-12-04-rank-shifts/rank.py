"""Fresnel rank of the sampled modes: bias and CPU time. ``python rank.py OUT_DIR [W H] [SPP] [ROUNDS]``.

Two scenes in reference mode (the sampled modes' default rank is the point): the demo (built-in blade,
Hosek–Wilkie sky, low sun) and bench_render's sun-dominated sphere (sky, sun at 40°, w 0.5, μ 0.05).
1. Bias: the same seed at rank 3 (the new default), rank 5 (the old default, exact to 1e-5) and full
   spectra (rank 0): ΔE2000 (display-referred, benchmarks._harness.delta_e_display) of each against full.
2. Time: frame CPU seconds (user+sys of this process, time.process_time) and wall, ranks 3 and 5
   alternated per round after a warm-up frame of each (compilation), median and spread.
3. Profile: the frame's own timing split (G-buffer, shading, background) and the frame CPU at SPP/4 and SPP
   spp: per-sample slope and fixed intercept of a line through the two.
"""
from __future__ import annotations

import dataclasses
import json
import os
import sys
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

import numpy as np  # noqa: E402


def scenes(res):
    from jkatana.render.scenefile import DEMO_SCENE

    demo = json.loads(json.dumps(DEMO_SCENE))
    demo["camera"]["resolution"] = list(res)
    sun = {"geometry": {"sphere": {"radius": 1.0}},
           "material": {"w": 0.5, "mu0": 0.05, "mu1": 0.05},
           "environment": {"type": "sky", "elevation_deg": 40.0, "azimuth_deg": 200.0, "turbidity": 2.0,
                           "resolution": [256, 512]},
           "camera": {"type": "lookat", "position": [0.0, 0.3, 3.2], "look_at": [0.0, 0.0, 0.0],
                      "fov_deg": 40.0, "resolution": list(res)}}
    return {"demo (blade, low sun)": demo, "sun-dominated sphere": sun}


def main(argv):
    from benchmarks._harness import delta_e_display
    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scenefile import scene_from_dict

    out = argv[0]
    os.makedirs(out, exist_ok=True)
    res = (int(argv[1]), int(argv[2])) if len(argv) > 2 else (200, 150)
    spp = int(argv[3]) if len(argv) > 3 else 64
    rounds = int(argv[4]) if len(argv) > 4 else 4
    results = {}
    for name, raw in scenes(res).items():
        prep = prepare(scene_from_dict(raw), mode="reference", samples=spp)
        print(f"== {name}: {res[0]}×{res[1]}, reference {spp} spp, default plan rank "
              f"{prep.plan.fresnel_rank} (None: decided per frame)", flush=True)

        def frame(rank, samples=spp):
            p = dataclasses.replace(prep, plan=dataclasses.replace(prep.plan, fresnel_rank=rank, samples=samples))
            c0, t0 = time.process_time(), time.perf_counter()
            f = render_view(p, seed=1)
            return f, time.process_time() - c0, time.perf_counter() - t0

        default = frame(None)[0]
        frames = {r: frame(r)[0] for r in (0, 3, 5)}
        m = frames[0].mask
        r = {"default_rank": default.stats["fresnel_rank"], "bias": {}}
        assert np.array_equal(default.xyz[m], frames[3].xyz[m])
        for k in (3, 5):
            d = delta_e_display(frames[0].xyz[m], frames[k].xyz[m], percentile=99.0)
            d["dE2000_p99"] = d.pop("dE2000_p95")  # (the harness names its percentile key p95 whatever it is)
            r["bias"][k] = d
            print(f"rank {k} vs full spectra (same samples): ΔE2000 mean {d['dE2000_mean']:.4f} "
                  f"p99 {d['dE2000_p99']:.4f} max {d['dE2000_max']:.4f}", flush=True)
        # noise scale for the bias: seed 1 vs seed 2 at the default rank
        p2 = dataclasses.replace(prep, plan=dataclasses.replace(prep.plan, fresnel_rank=3))
        f2 = render_view(p2, seed=2)
        d = delta_e_display(f2.xyz[m], frames[3].xyz[m], percentile=99.0)
        r["noise_pair_over_sqrt2"] = d["dE2000_mean"] / np.sqrt(2)
        print(f"noise at {spp} spp (ΔE(seed 1, seed 2)/√2): {r['noise_pair_over_sqrt2']:.4f}", flush=True)
        cpu = {3: [], 5: []}
        wall = {3: [], 5: []}
        for i in range(rounds):
            for k in ((3, 5) if i % 2 == 0 else (5, 3)):
                f, c, w = frame(k)
                cpu[k].append(c)
                wall[k].append(w)
            print(f"round {i}: CPU rank 3 {cpu[3][-1]:.3f} rank 5 {cpu[5][-1]:.3f}  load {os.getloadavg()[0]:.1f}",
                  flush=True)
        ratio = [a / b for a, b in zip(cpu[3], cpu[5])]
        r["cpu"] = cpu
        r["wall"] = wall
        r["cpu_ratio_rank3_over_rank5"] = ratio
        print(f"frame CPU s median rank 3 {np.median(cpu[3]):.3f} [{min(cpu[3]):.3f}, {max(cpu[3]):.3f}] "
              f"rank 5 {np.median(cpu[5]):.3f} [{min(cpu[5]):.3f}, {max(cpu[5]):.3f}]; per-round ratio "
              f"median {np.median(ratio):.3f} [{min(ratio):.3f}, {max(ratio):.3f}]", flush=True)
        # profile: the frame's own split, and CPU at spp/4 vs spp (rank 3)
        q = max(1, spp // 4)
        frame(3, q)
        lo = [frame(3, q)[1] for _ in range(2)]
        f, c, _ = frame(3)
        hi = [c] + [frame(3)[1]]
        slope = (np.median(hi) - np.median(lo)) / (spp - q)
        fixed = np.median(hi) - slope * spp
        r["profile"] = {"timing": {k: v for k, v in f.timing.items() if isinstance(v, float)},
                        "cpu_lo_spp": (q, lo), "cpu_hi_spp": (spp, hi), "cpu_per_spp": slope, "cpu_fixed": fixed,
                        "pixels_shaded": f.stats.get("pixels_shaded")}
        print(f"profile (rank 3): timing " + " ".join(f"{k}={v:.3f}" for k, v in r["profile"]["timing"].items())
              + f"; CPU {q} spp {np.median(lo):.3f}, {spp} spp {np.median(hi):.3f} → fixed {fixed:.3f} s + "
              f"{slope * 1e3:.2f} ms/spp ({100 * (1 - fixed / np.median(hi)):.0f} % per-sample at {spp} spp)",
              flush=True)
        results[name] = r
    with open(os.path.join(out, "results.json"), "w") as fh:
        json.dump(results, fh, indent=1, default=float)


if __name__ == "__main__":
    main(sys.argv[1:])
