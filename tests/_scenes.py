"""Shared test scaffolding: the small sphere-under-sky scene and how to run ``jkatana`` in a child
process (command-line tests); a uniform disc pasted into a map (the sun tests).

The scene is a unit sphere with the built-in paper material under a 16 × 32 Hosek–Wilkie sky, seen by an
orbit camera; tests choose its resolution, samples and (optionally) its wavelength grid, and some edit
single lines of the text (so its lines are kept exactly as written here).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

from jkatana.light.envmap import texel_directions_np, texel_solid_angles_np

ROOT = Path(__file__).resolve().parents[1]

#: ``jkatana`` as a child process, as the installed console script calls it (the checkout's code: see
#: :func:`cli_env`).
CLI = [sys.executable, "-c", "import sys; from jkatana.cli import main; sys.exit(main())"]

_SCENE = """
[geometry]
sphere = {radius = 1.0}
[material]
w = 0.5
mu0 = 0.05
mu1 = 0.1
[environment]
type = "sky"
resolution = [16, 32]
[camera]
type = "orbit"
target = [0, 0, 0]
distance = 4.0
elevation_deg = 10
fov_deg = 35
resolution = [%d, %d]
%s[render]
samples = %d
[output]
directory = "out"
name = "f"
"""


def sphere_scene(width: int, height: int, samples: int, *, spectral: tuple[float, float, float] | None = None
                 ) -> str:
    """Scene TOML text of the test sphere: ``width × height`` pixels, ``samples`` per pixel, on the
    wavelength grid ``spectral = (start, stop, step)`` in nm (``None``: the scene default grid)."""
    grid = "" if spectral is None else "[spectral]\nstart = %r\nstop = %r\nstep = %r\n" % tuple(map(float, spectral))
    return _SCENE % (width, height, grid, samples)


def cli_env() -> dict[str, str]:
    """Environment of a ``jkatana`` child process: this checkout first on ``PYTHONPATH`` (so a child runs
    the code under test), and two host devices unless ``XLA_FLAGS`` is already set (as the tests' own)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    return env


def paste_disc(L, s, radius, spectrum, sub=16):
    """Add a uniform disc (texel averages by ``sub × sub`` supersampling in θ, φ with sin θ weights)."""
    H, W = L.shape[:2]
    d = texel_directions_np(H, W)
    near = np.arccos(np.clip(d @ s, -1, 1)) < radius + 3 * math.pi / H
    t = (np.arange(sub) + 0.5) / sub
    cover = np.zeros((H, W))
    for j, i in zip(*np.nonzero(near)):
        th = (j + t) * math.pi / H
        ph = ((i + t) / W - 0.5) * 2 * math.pi
        th, ph = np.meshgrid(th, ph, indexing="ij")
        dd = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], -1)
        inside = np.arccos(np.clip(dd @ s, -1, 1)) < radius
        cover[j, i] = (inside * np.sin(th)).sum() / np.sin(th).sum()
    out = L + cover[..., None] * spectrum
    return out, (cover * texel_solid_angles_np(H, W)).sum()
