"""Shared test scaffolding for the command-line tests: the small sphere-under-sky scene and how to run
``jkatana`` in a child process.

The scene is a unit sphere with the built-in paper material under a 16 × 32 Hosek–Wilkie sky, seen by an
orbit camera; tests choose its resolution, samples and (optionally) its wavelength grid, and some edit
single lines of the text (so its lines are kept exactly as written here).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

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
