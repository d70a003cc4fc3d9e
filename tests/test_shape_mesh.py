"""Any mesh through ``jkatana shape``: units, blade frame, cleaning, smoothing, UVs, report."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import trimesh

from jkatana.shape.katana import default_blade, export_blade, welded
from jkatana.shape.mesh import clean_mesh, guess_units, prepare_mesh, smooth_mesh
from jkatana.shape.uv import blade_uvs, uv_stretch, xatlas_uvs
from jkatana.shared import shared_data


@pytest.mark.parametrize("extents, suffix, unit", [
    ((0.70, 0.04, 0.007), ".ply", "m"),
    ((700.0, 44.0, 7.0), ".obj", "mm"),
    ((8.25, 2.95, 0.69), ".obj", "cm"),
    ((700.0, 44.0, 7.0), ".glb", "m"),   # glTF: metres by specification, whatever the size
])
def test_units_are_guessed_from_size_and_said(extents, suffix, unit):
    got, reason = guess_units(np.array(extents), suffix)
    assert got == unit
    assert ("--units" in reason) == (suffix != ".glb")


def test_clean_merges_drops_and_fills_small_holes():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    tri = sphere.vertices[sphere.faces]
    # a triangle soup (every vertex repeated), one degenerate face, three faces cut out (one hole)
    soup = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)
    keep = np.ones(len(soup.faces), bool)
    keep[[0]] = False
    faces = np.concatenate([soup.faces[keep], [[0, 0, 1]]])
    broken = trimesh.Trimesh(soup.vertices, faces, process=False)
    assert not broken.is_watertight
    m, info = clean_mesh(broken)
    assert info["merged_vertices"] == len(soup.vertices) - len(sphere.vertices)
    assert info["dropped_faces"] == 1 and info["holes_filled"] == 1 and info["holes_left"] == 0
    assert m.is_watertight and m.volume > 0
    assert abs(m.volume - sphere.volume) < 0.01 * sphere.volume
    # a hole larger than the limit stays open and is counted
    _, info = clean_mesh(broken, max_hole_edges=2)
    assert info["holes_filled"] == 0 and info["holes_left"] == 1


def test_smoothing_reduces_noise_and_holds_creases():
    box = trimesh.creation.box([1.0, 1.0, 1.0]).subdivide().subdivide().subdivide()
    box.merge_vertices()
    rng = np.random.default_rng(0)
    noisy = box.copy()
    normals = noisy.vertex_normals
    corner = np.all(np.isclose(np.abs(box.vertices), 0.5), axis=1)
    noise = rng.normal(0, 0.004, len(box.vertices))
    noise[corner] = 0.0
    noisy.vertices = box.vertices + normals * noise[:, None]
    flat = ~np.any(np.isclose(np.abs(box.vertices), 0.5, atol=0.13).sum(1, keepdims=True) > 1, axis=1)

    def off_plane(m):  # distance of flat-face vertices from their face plane
        v = m.vertices[flat]
        return np.abs(np.abs(v).max(1) - 0.5)

    before = off_plane(noisy).mean()
    info = smooth_mesh(noisy, iterations=10, crease_deg=30.0)
    assert info["pinned"] > 0
    assert off_plane(noisy).mean() < 0.5 * before
    # corners (on 90° creases) are held exactly: the box keeps its size
    np.testing.assert_allclose(noisy.vertices[corner], box.vertices[corner])


def test_uv_stretch_is_one_for_an_isometry_and_grows_with_distortion():
    plane = trimesh.creation.box([1.0, 0.5, 1e-3]).subdivide()
    top = plane.vertices[:, 2] > 0
    faces = plane.faces[np.all(top[plane.faces], axis=1)]
    m = trimesh.Trimesh(plane.vertices, faces, process=False)
    m.remove_unreferenced_vertices()
    uv = m.vertices[:, :2] - m.vertices[:, :2].min(0)
    m.visual = trimesh.visual.TextureVisuals(uv=uv / uv.max(0))
    med, p95 = uv_stretch(m)
    assert med == pytest.approx(1.0, abs=1e-9) and p95 == pytest.approx(1.0, abs=1e-9)
    bent = m.copy()
    bent.visual = trimesh.visual.TextureVisuals(uv=np.stack([uv[:, 0] ** 2, uv[:, 1]], -1))
    assert uv_stretch(bent)[1] > 1.2


def _blade_in_mm_without_uvs() -> trimesh.Trimesh:
    """The built-in blade exported, rescaled to millimetres, moved and turned, re-meshed without UVs."""
    w = welded(default_blade())
    m = trimesh.Trimesh(w.vertices * 1000.0, w.faces, process=False)
    T = trimesh.transformations.random_rotation_matrix(np.random.default_rng(1).random(3))
    T[:3, 3] = [100.0, -50.0, 20.0]
    m.apply_transform(T)
    return m


def test_blade_in_mm_recovers_units_frame_and_uvs():
    from scipy.spatial import cKDTree

    ref = default_blade()
    mesh, rep = prepare_mesh(_blade_in_mm_without_uvs(), source="blade.ply", suffix=".ply")
    assert rep.units == "mm" and rep.uv == "blade" and rep.frame.startswith("blade")
    dist, idx = cKDTree(ref.vertices).query(mesh.vertices)
    assert dist.max() < 1e-4  # the built-in frame, to 0.1 mm
    duv = np.abs(mesh.visual.uv - ref.visual.uv[idx])
    body = ref.visual.uv[idx][:, 0] < 0.99
    assert np.abs(duv[:, 0]).max() < 1e-4
    assert np.percentile(duv[body, 1], 99) < 0.01 and duv[:, 1].mean() < 0.01


@pytest.mark.slow
def test_blade_uv_layout_renders_the_procedural_hamon_as_before(tmp_path):
    """ΔE2000 between the built-in blade and its mm, UV-less re-mesh after ``shape``: mean ≤ 1."""
    import colour

    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scenefile import DEMO_SCENE, scene_from_dict

    mesh, _ = prepare_mesh(_blade_in_mm_without_uvs(), source="blade.ply", suffix=".ply")
    export_blade(mesh, tmp_path / "blade.ply")

    def render(path):
        raw = copy.deepcopy(DEMO_SCENE)
        raw["geometry"] = {"mesh": path}
        raw["camera"]["resolution"] = [160, 120]
        raw["render"] = {"mode": "prefiltered", "samples": 16}
        return render_view(prepare(scene_from_dict(raw)))

    f0, f1 = render("builtin:katana"), render(str(tmp_path / "blade.ply"))
    both = f0.mask & f1.mask
    assert both.sum() > 0.98 * f0.mask.sum()
    k = 0.6 / np.percentile(f0.xyz[..., 1][f0.mask], 75)
    de = colour.delta_E(colour.XYZ_to_Lab(f0.xyz * k), colour.XYZ_to_Lab(f1.xyz * k), method="CIE 2000")
    assert de[both].mean() <= 1.0
    # without the blade UVs (a general unwrap) the hamon lands elsewhere: the check can fail
    other = xatlas_uvs(mesh)
    export_blade(other, tmp_path / "other.ply")
    f2 = render(str(tmp_path / "other.ply"))
    de2 = colour.delta_E(colour.XYZ_to_Lab(f0.xyz * k), colour.XYZ_to_Lab(f2.xyz * k), method="CIE 2000")
    assert de2[f0.mask & f2.mask].mean() > 2.0


def test_hammer_scan_through_the_cli(tmp_path, capsys):
    """The shared photogrammetry scan (CC BY 4.0, Andrea Spognetta): units said, frame kept, xatlas UVs."""
    from jkatana.cli import main

    src = shared_data("scans", "hammer", "hammer.obj")
    out = tmp_path / "hammer.ply"
    assert main(["shape", str(src), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "units: cm (assumed" in err and "--units" in err
    rep = json.loads((tmp_path / "hammer_shape.json").read_text())
    assert rep["units"] == "cm" and rep["frame"].startswith("kept") and rep["uv"] == "xatlas"
    assert max(rep["extents_m"]) == pytest.approx(0.0825, rel=0.01)
    assert rep["uv_stretch"][0] < 1.1 and rep["uv_stretch"][1] < 1.5
    m = trimesh.load(out, process=False)
    assert m.visual.uv.shape == (len(m.vertices), 2)
    assert (tmp_path / "hammer_preview.png").stat().st_size > 10_000
    # --units overrides; the built-in katana's fit refuses it (one line, exit 2, no output)
    assert main(["shape", str(src), "--units", "mm", "-o", str(tmp_path / "mm.ply")]) == 0
    assert "units: mm (given)" in capsys.readouterr().err
    assert main(["shape", str(src), "--katana-fit", "-o", str(tmp_path / "k.ply")]) == 2
    assert "not a fit" in capsys.readouterr().err and not (tmp_path / "k.ply").exists()


def test_point_list_needs_a_fit_mode(tmp_path, capsys):
    from jkatana.cli import main

    (tmp_path / "p.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
    assert main(["shape", str(tmp_path / "p.xyz"), "-o", str(tmp_path / "o.ply")]) == 2
    assert "--height-field" in capsys.readouterr().err


def test_blade_uvs_keep_both_flats_on_one_map():
    mesh, _ = prepare_mesh(_blade_in_mm_without_uvs(), source="b", suffix=".ply")
    uv = blade_uvs(mesh)
    z = mesh.vertices[:, 2]
    from scipy.spatial import cKDTree

    omote, ura = z > 1e-4, z < -1e-4
    mirrored = mesh.vertices[ura] * [1.0, 1.0, -1.0]
    dist, j = cKDTree(mirrored).query(mesh.vertices[omote])
    near = dist < 1e-4  # an ura vertex opposite this omote vertex: the same (u, v)
    assert near.mean() > 0.75  # the rest: the machi cap (no mirror vertex within 0.1 mm)
    body = near & (uv[omote, 0] < 0.99)  # at the tip vertices crowd closer than 0.1 mm
    np.testing.assert_allclose(uv[omote][body], uv[ura][j[body]], atol=1e-3)
    assert uv[omote, 0].min() < 0.01 and uv[omote, 0].max() > 0.99
