"""The environment's memory estimate (:mod:`jkatana.render.memory`): a map that cannot fit is refused in one line,
before work, naming its size and the estimate; the estimate of a map that fits is near its measured peak.

The large map is a 6000×3000 half-float EXR of one constant colour, written scanline block by scanline block
(a few MB, a second or two): the refusal reads its header only, so no case here decodes it.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from tests._scenes import CLI, cli_env

HDR_1K = Path(__file__).resolve().parents[2] / "shared" / "data" / "envmaps" / "pedestrian_overpass_1k.hdr"

_SCENE = """
[environment]
type = "{kind}"
path = "{path}"
[camera]
type = "orbit"
target = [0.45, -0.022, 0.0]
distance = 0.28
azimuth_deg = 20.0
elevation_deg = -40.0
roll_deg = 25.0
fov_deg = 30.0
resolution = [{w}, {h}]
[render]
mode = "prefiltered"
samples = 4
[output]
directory = "out"
name = "f"
"""


def write_constant_exr(path: Path, width: int, height: int, value: float = 0.5) -> Path:
    """An RGB half-float EXR of one colour (ZIP), written in 16-row blocks so that writing it stays cheap."""
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(width, height, 3, oiio.HALF)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    block = np.full((16, width, 3), value, np.float16)
    for y in range(0, height, 16):
        assert out.write_scanlines(y, min(y + 16, height), 0, block[: min(16, height - y)]), out.geterror()
    out.close()
    return path


@pytest.fixture(scope="module")
def big_scene(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("big")
    exr = write_constant_exr(folder / "big6k.exr", 6000, 3000)
    scene = folder / "scene.toml"
    scene.write_text(_SCENE.format(kind="exr", path=exr, w=400, h=300))
    return scene


def test_header_size_without_decoding(big_scene):
    from jkatana.render.memory import image_resolution

    t0 = time.perf_counter()
    assert image_resolution(big_scene.parent / "big6k.exr") == (3000, 6000)
    assert time.perf_counter() - t0 < 1.0
    assert image_resolution(big_scene) is None  # not an image: the reader reports it later


@pytest.mark.parametrize("argv", [
    ["render", "{scene}", "-o", "{out}", "--mode", "prefiltered"],
    # the other commands in the slow stage (each is a CLI start with JAX; the everyday suite keeps one)
    pytest.param(["render", "{scene}", "-o", "{out}", "--mode", "reference"], marks=pytest.mark.slow),
    pytest.param(["view", "{scene}", "--offscreen", "--frames", "1", "-o", "{out}"], marks=pytest.mark.slow),
    pytest.param(["light", "--max-memory", "2G", "prefilter", "{scene}"], marks=pytest.mark.slow),
], ids=["render-prefiltered", "render-reference", "view", "light-prefilter"])
def test_large_map_refused_in_one_line(big_scene, tmp_path, argv):
    out = tmp_path / "out"
    argv = [a.format(scene=big_scene, out=out) for a in argv]
    if argv[0] != "light":
        argv += ["--max-memory", "2G"]
    env = cli_env()
    env["JKATANA_CACHE"] = str(tmp_path / "cache")
    t0 = time.perf_counter()
    r = subprocess.run(CLI + argv, capture_output=True, text=True, env=env, timeout=120)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2, r.stderr
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    line = lines[0]
    for needle in ("environment.path", "6000×3000", "big6k.exr", "allowed by --max-memory"):
        assert needle in line, (needle, line)
    estimate = float(re.search(r"needs about ([\d.]+) GiB", line).group(1))
    # streamed (jkatana.render.streamed, the bake's for view): a few hundred bytes a texel, over the 2 GiB allowed
    assert 2 < estimate < 8, line
    assert time.perf_counter() - t0 < 60
    assert not out.exists() and not (tmp_path / "cache").exists()


def test_fitting_map_not_refused_by_estimate():
    """The 1k shared map under the default budget: the estimate is a few GiB, not a refusal."""
    from jkatana.render.memory import environment_bytes
    from jkatana.render.scenefile import scene_from_dict

    scene = scene_from_dict({"environment": {"type": "hdr", "path": str(HDR_1K)}})
    est = environment_bytes(scene.environment, scene.spectral.grid.size)
    assert 0.5 * 2 ** 30 < est < 3 * 2 ** 30


_PEAK = """
import json, resource, subprocess, sys
r = subprocess.run({argv!r}, capture_output=True, text=True, env={env!r})
peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
print(json.dumps({{"rc": r.returncode, "peak": peak, "err": r.stderr[-2000:]}}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("command", ["render", "view"])
def test_estimate_near_measured_peak(tmp_path, command):
    """A first use of the 1k shared HDR on an empty cache: the estimate is within a factor 1.5 of the peak RSS."""
    from jkatana.render.memory import check_environment_memory
    from jkatana.render.scenefile import load_scene

    scene_path = tmp_path / "scene.toml"
    scene_path.write_text(_SCENE.format(kind="hdr", path=HDR_1K, w=400, h=300))
    scene = load_scene(scene_path)
    if command == "render":
        argv = CLI + ["render", str(scene_path), "-o", str(tmp_path / "out")]
        from jkatana.render.commands import check_render_memory

        estimate = check_render_memory(scene)
    else:
        argv = CLI + ["view", str(scene_path), "--offscreen", "--frames", "1", "-o", str(tmp_path / "out")]
        estimate = check_environment_memory(scene, interactive=True)
    env = cli_env()
    env["JKATANA_CACHE"] = str(tmp_path / "cache")
    env["JAX_COMPILATION_CACHE_DIR"] = str(tmp_path / "cache" / "jax")
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(_PEAK.format(argv=argv, env=env))],
                       capture_output=True, text=True, timeout=900)
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["rc"] == 0, res["err"]
    assert res["peak"] / 1.5 < estimate < res["peak"] * 1.5, (estimate / 2 ** 30, res["peak"] / 2 ** 30)
