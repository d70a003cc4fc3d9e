"""cProfile of the reference frame's fixed part: ``python prof.py SPP [N]``.

The rough iron sphere of :func:`validation.mitsuba.render_jkatana` (256², 2×2 subpixels, ``env_nodes=None``),
rendered once to compile, then ``N`` frames under cProfile (each call builds its environment and material,
as the peer study does); prints the top functions by cumulative and by own time inside ``render_frame``.
"""
from __future__ import annotations

import cProfile
import os
import pstats
import sys
import tempfile

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

from pathlib import Path  # noqa: E402


def main(argv):
    import jkatana.render.frame as fm
    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    spp = int(argv[0])
    n = int(argv[1]) if len(argv) > 1 else 3
    prof = cProfile.Profile()
    orig = fm.render_frame
    on = {"v": False}

    def wrapped(*a, **k):
        if not on["v"]:
            return orig(*a, **k)
        prof.enable()
        try:
            return orig(*a, **k)
        finally:
            prof.disable()

    fm.render_frame = wrapped
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2, seed=1, env_nodes=None)
        on["v"] = True
        for i in range(n):
            mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2, seed=1 + i, env_nodes=None)
    st = pstats.Stats(prof)
    st.sort_stats("cumulative").print_stats(45)
    st.sort_stats("tottime").print_stats(30)


if __name__ == "__main__":
    main(sys.argv[1:])
