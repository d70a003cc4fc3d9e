"""The cap pass where it is taken: the default blade under the low sun, the environment turned in 8 steps
(``render_view(light=k, lights=8)``); per step the share of pixels :func:`cap_pixels` keeps, and the
frame's median CPU and shading CPU (5 frames after 2 warm-ups) with the caps on their own pass where the
share is ≤ ``CAP_PASS_MAX`` and with the one pass forced, and the largest difference of the two frames.

``PYTHONPATH=<checkout> python benchmarks/reports/render-frame-2026-12-02-cap/lights.py``
"""
import os
import time

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
import numpy as np  # noqa: E402

import jkatana.render.frame as F  # noqa: E402
from benchmarks.bench_render import _scenes  # noqa: E402
from jkatana.render.renderer import prepare, render_view  # noqa: E402
from jkatana.render.scenefile import scene_from_dict  # noqa: E402

share = {}
_orig = F._compiled_cap_pixels


def _counting(plan):
    f = _orig(plan)

    def g(env, px):
        m = f(env, px)
        share["last"] = float(np.asarray(m).mean())
        return m
    return g


F._compiled_cap_pixels = _counting
prep = prepare(scene_from_dict(_scenes(False)["default (blade, low sun)"]), mode="prefiltered", samples=1,
               split_sun=True)
for k in range(8):
    out = {}
    for name, cap in (("pass", 0.6), ("one", -1.0)):
        F.CAP_PASS_MAX = cap
        render_view(prep, light=k, lights=8, seed=1)
        render_view(prep, light=k, lights=8, seed=1)
        rows = []
        for _ in range(5):
            c0 = time.process_time()
            f = render_view(prep, light=k, lights=8, seed=1)
            rows.append((time.process_time() - c0, f.timing["shade_cpu_s"]))
        out[name] = (np.median(np.array(rows), 0), f.xyz)
    d = np.abs(out["pass"][1].astype(np.float64) - out["one"][1]).max() / out["one"][1].max()
    print(f"light {k}/8: cap share {share['last']:.3f}; frame / shading CPU s: own pass "
          f"{out['pass'][0][0]:.3f} / {out['pass'][0][1]:.3f}, one pass {out['one'][0][0]:.3f} / "
          f"{out['one'][0][1]:.3f}; max |Δ| / max {d:.1e}; load {os.getloadavg()[0]:.1f}", flush=True)
