"""Why the full benchmark's one-process sequence draws slower than `--defaults` alone: the default close-up
and demo view timed (15 drawn frames after 2 warm-ups, median wall; process CPU; CPU per thread group from
/proc/self/task) at steps of the full benchmark's sequence.

usage: seq.py STEP[,STEP...]   steps: measure | ref (a reference frame, JAX) | sleep | cases (the demo's
other 13 cases' renderers made, drawn 20×, deleted, as the benchmark does) | gc"""
import os, sys, time, collections, gc
import numpy as np
from jkatana.interactive import glrender as G
from jkatana.interactive import scene as S
from jkatana.interactive.bake import cached_bake
from validation import gl_agreement as A
from benchmarks import bench_interactive as B


def threads():
    out = collections.Counter(); n = collections.Counter()
    tck = os.sysconf("SC_CLK_TCK")
    for t in os.listdir("/proc/self/task"):
        try:
            comm = open(f"/proc/self/task/{t}/comm").read().strip()
            f = open(f"/proc/self/task/{t}/stat").read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        key = "llvmpipe" if comm.startswith("llvmpipe") else comm
        out[key] += (int(f[11]) + int(f[12])) / tck; n[key] += 1
    return out, n


sc = S.default_scene("sky")
baked = cached_bake(sc.radiance, sc.grid, rank=4)
views = {"demo": sc.view, "closeup": S.closeup_view(sc.mesh)}


def measure(tag):
    for vn, view in views.items():
        st = G.ShadingState(baked, sc.refl_map)
        r = G.BakedOffscreenRenderer(st, 800, 600)
        scene = G.build_scene(sc.mesh, view)
        for _ in range(2):
            r.draw(scene)
        t0, n0 = threads(); c0 = time.process_time(); w = []
        for _ in range(15):
            t = time.perf_counter(); r.draw(scene); w.append(time.perf_counter() - t)
        c1 = time.process_time(); t1, n1 = threads()
        r.delete()
        per = {k: 1e3 * (t1[k] - t0.get(k, 0)) / 15 for k in t1 if t1[k] - t0.get(k, 0) > 0}
        print(f"{tag:14s} {vn:8s} wall median {1e3 * np.median(w):5.1f} ms  cpu {1e3 * (c1 - c0) / 15:5.1f} ms/frame  "
              f"threads {dict(n1)}  cpu by thread group ms/frame {{{', '.join(f'{k}: {v:.1f}' for k, v in per.items())}}}  "
              f"load {os.getloadavg()[0]:.2f}", flush=True)


def ref():
    small = S.View(views["closeup"].pose, views["closeup"].yfov, 200, 150)
    t = time.perf_counter(); A.reference_frame(sc.radiance, small, samples=256, seed=0)
    print(f"reference in {time.perf_counter() - t:.1f} s", flush=True)


def cases():
    for cname, cfg in B.CONFIGS.items():
        if cname == "default":
            continue
        st = G.ShadingState(baked, sc.refl_map, **B._state_kwargs(cfg))
        r = G.BakedOffscreenRenderer(st, 800, 600, samples=cfg["samples"], deferred=cfg.get("deferred"))
        scene = G.build_scene(sc.mesh, views["demo"])
        for _ in range(20):
            r.draw(scene)
        r.delete()
        r2 = G.BakedOffscreenRenderer(st, 200, 150, samples=cfg["samples"], deferred=cfg.get("deferred"))
        r2.render(G.build_scene(sc.mesh, views["demo"])); r2.delete()
    print("cases done", flush=True)


for i, step in enumerate(sys.argv[1].split(",")):
    {"measure": lambda: measure(f"{i}:after " + (sys.argv[1].split(',')[i - 1] if i else "start")),
     "ref": ref, "sleep": lambda: time.sleep(3), "cases": cases, "gc": gc.collect}[step]()
