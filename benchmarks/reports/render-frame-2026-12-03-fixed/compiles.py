"""Compilations per frame of the peer study's reference frame: ``python compiles.py SPP``.

Renders the rough iron sphere (:func:`validation.mitsuba.render_jkatana`, 256², 2×2 subpixels) three times
with ``jax_log_compiles`` on and prints how many programs each frame compiled (frames after the first: 0).
"""
from __future__ import annotations

import logging
import os
import sys
import tempfile

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")

from pathlib import Path  # noqa: E402


class Count(logging.Handler):
    def __init__(self):
        super().__init__()
        self.names = []

    def emit(self, record):
        msg = record.getMessage()
        if msg.startswith("Compiling ") or "Finished XLA compilation" in msg:
            self.names.append(msg.split(" ")[1] if msg.startswith("Compiling ") else msg[:80])


def main(argv):
    import jax

    from jkatana.shared import shared_data
    from validation import mitsuba as mc

    spp = int(argv[0]) if argv else 1
    jax.config.update("jax_log_compiles", True)
    h = Count()
    logging.getLogger("jax").addHandler(h)
    logging.getLogger("jax").setLevel(logging.WARNING)
    with tempfile.TemporaryDirectory() as d:
        env = mc.small_envmap(shared_data("envmaps", "courtyard.exr"), Path(d) / "env.exr", 256)
        for i in range(3):
            n0 = len(h.names)
            mc.render_jkatana(env, alpha=0.2, size=256, samples=spp, supersample=2, seed=1 + i, env_nodes=None)
            new = [n for n in h.names[n0:] if not n.startswith("Finished")]
            print(f"frame {i}: {len(new)} compilations", sorted(set(new))[:12], flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
