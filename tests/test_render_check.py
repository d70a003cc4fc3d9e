"""Scene check before shading (camera inside, wrong scale, empty frame) and UV-less meshes."""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest
import trimesh

from jkatana.errors import InputError
from jkatana.render.camera import Camera
from jkatana.render.check import SceneWarning, check_scene, warn_scene
from jkatana.render.scenefile import DEMO_SCENE, scene_from_dict
from jkatana.shape.katana import default_blade, export_blade, welded


def _demo_camera(**kw):
    from jkatana.render.renderer import camera_for

    raw = copy.deepcopy(DEMO_SCENE)
    raw["camera"].update(kw)
    return camera_for(scene_from_dict(raw))


def _blade(scale=1.0):
    w = welded(default_blade())
    return trimesh.Trimesh(w.vertices * scale, w.faces, process=False)


def test_the_demo_scene_passes():
    assert check_scene(default_blade(), _demo_camera()) is None
    assert check_scene(("sphere", (0.0, 0.0, 0.0), 1.0), Camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0))) is None


def test_camera_inside_a_mm_mesh_is_named_with_the_units_fix():
    # the demo camera 0.33 m from its target, 5 mm inside a 700 m blade (the built-in one in mm)
    msg = check_scene(_blade(1000.0), _demo_camera(target=[300.0, -30.0, 0.0]))
    assert msg is not None and "inside the object" in msg and "--units mm" in msg
    # just outside it, next to a surface 1000× the camera's scale
    msg = check_scene(_blade(1000.0), _demo_camera())
    assert msg is not None and "larger than the camera's distance" in msg and "--units mm" in msg
    msg = check_scene(("sphere", (0.0, 0.0, 0.0), 1.0), Camera((0.0, 0.0, 0.5), (0.0, 0.0, 0.0)))
    assert "inside" in msg


def test_mm_mesh_seen_from_outside_is_too_large():
    cam = Camera((350.0, -20.0, 30.0), (350.0, -20.0, 0.0))  # 30 m off a 700 m blade
    msg = check_scene(_blade(1000.0), cam)
    assert msg is not None and "larger than the camera's distance" in msg and "--units mm" in msg


def test_metre_mesh_in_a_millimetre_scene_is_a_speck():
    cam = Camera((0.35, 0.0, 300.0), (0.35, 0.0, 0.0), fov_deg=30.0)
    msg = check_scene(_blade(1.0), cam)
    assert msg is not None and "millimetres" in msg


def test_empty_frame_is_named():
    cam = _demo_camera(azimuth_deg=200.0, target=[3.0, 0.0, 0.0])  # looking away from the blade
    msg = check_scene(default_blade(), cam)
    assert msg is not None and msg.startswith("no pixel covers the object")


def test_warning_is_one_scene_warning():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn_scene(_blade(1000.0), _demo_camera())
        warn_scene(default_blade(), _demo_camera())
    assert [w.category for w in caught] == [SceneWarning]


def _scene_with_mesh(tmp_path, mesh, material):
    path = tmp_path / "m.ply"
    export_blade(mesh, path)
    raw = copy.deepcopy(DEMO_SCENE)
    raw["geometry"] = {"mesh": str(path)}
    raw["material"] = material
    raw["camera"]["resolution"] = [32, 24]
    raw["render"] = {"mode": "reference", "samples": 4}
    raw["environment"]["resolution"] = [32, 64]
    return scene_from_dict(raw)


@pytest.mark.slow
def test_uv_less_mesh_renders_uniform_and_refuses_a_map(tmp_path):
    from jkatana.render.renderer import load_geometry, prepare, render_view

    bare = _blade(1.0)
    assert getattr(bare.visual, "uv", None) is None
    uniform = {"w": 1.0, "mu0": 0.05, "mu1": 0.2, "optical_constants": "Fe-Johnson"}
    scene = _scene_with_mesh(tmp_path, bare, uniform)
    frame = render_view(prepare(scene))
    assert frame.mask.sum() > 20 and np.all(np.isfinite(frame.xyz))
    with pytest.raises(InputError, match="jkatana shape MESH --uv"):
        load_geometry(_scene_with_mesh(tmp_path, bare, {"map": "builtin", "optical_constants": "Fe-Johnson"}))


@pytest.mark.slow
def test_cli_prints_the_scene_warning_as_one_line(tmp_path, capsys, monkeypatch):
    import sys

    from jkatana.cli import main

    # pytest records warnings itself: show them the way Python does outside pytest
    monkeypatch.setattr(warnings, "showwarning", lambda m, c, f, n, file=None, line=None:
                        sys.stderr.write(warnings.formatwarning(m, c, f, n, line)))
    scene = tmp_path / "s.toml"
    export_blade(_blade(1000.0), tmp_path / "mm.ply")
    scene.write_text(f"""
[geometry]
mesh = "mm.ply"
[material]
w = 1.0
mu0 = 0.05
mu1 = 0.2
[environment]
type = "constant"
resolution = [8, 16]
[camera]
type = "orbit"
target = [0.59, -0.025, 0.0]
distance = 0.33
resolution = [8, 6]
[render]
samples = 1
[output]
directory = "{tmp_path / 'out'}"
name = "f"
""")
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        main(["render", str(scene)])
    err = capsys.readouterr().err
    assert err.count("jkatana: warning: ") == 1  # one line (it may follow a progress bar's \r)
    line = err.split("jkatana: warning: ")[1].splitlines()[0]
    assert line.startswith("the camera") and "--units mm" in line
