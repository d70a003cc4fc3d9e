"""Mitsuba 3 alone, the study's scene (rough iron sphere, courtyard map 256×128, 256²), multijitter + direct:
wall and process CPU of repeated ``render_mitsuba`` calls (kernels cached after the first call of each spp), and
user/system CPU with page faults of one call. Compare with the same configuration's times in earlier studies'
``results.json``. Run from the repository root: ``.venv/bin/python benchmarks/reports/render-peer-2026-12-05-idle/mitsuba_repeat.py``.
"""
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.getcwd())
from jkatana.shared import shared_data  # noqa: E402
from validation import mitsuba as mc  # noqa: E402

env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(tempfile.mkdtemp()) / "env.exr", 256)
variant = mc.mitsuba_variant()


def call(spp, seed):
    t0, c0 = time.perf_counter(), time.process_time()
    mc.render_mitsuba(env, alpha=0.2, size=256, spp=spp, variant=variant, seed=seed, sampler="multijitter",
                      integrator="direct")
    return time.perf_counter() - t0, time.process_time() - c0


for spp in (64, 256):
    for seed in (1, 2, 2, 3, 2):
        w, c = call(spp, seed)
        print(f"{variant} multijitter+direct {spp} spp seed {seed}: wall {w:.3f} s, CPU {c:.3f} s, "
              f"load {os.getloadavg()[0]:.2f}", flush=True)
r0 = resource.getrusage(resource.RUSAGE_SELF)
w, c = call(64, 2)
r1 = resource.getrusage(resource.RUSAGE_SELF)
print(f"64 spp seed 2 again: user {r1.ru_utime - r0.ru_utime:.3f} s, sys {r1.ru_stime - r0.ru_stime:.3f} s, "
      f"minor faults {r1.ru_minflt - r0.ru_minflt}, major {r1.ru_majflt - r0.ru_majflt}")
