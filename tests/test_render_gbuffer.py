"""G-buffer ray casting: Embree and trimesh's pure-Python fallback agree, in chunks."""

from __future__ import annotations

import platform

import numpy as np
import pytest
import trimesh

from jkatana.render import gbuffer as gb
from jkatana.render.camera import Camera


def _embree() -> None:
    """Embree is a dependency on x86-64 (``pyproject.toml``): missing there it fails the test; on other machines,
    where nothing installs it, the test is skipped."""
    if platform.machine() in ("x86_64", "AMD64"):
        import embreex  # noqa: F401
    else:
        pytest.importorskip("embreex")


def _uv_sphere():
    mesh = trimesh.creation.uv_sphere(radius=0.5, count=[24, 24])
    v = mesh.vertices / 0.5
    uv = np.stack([0.5 + np.arctan2(v[:, 0], -v[:, 2]) / (2 * np.pi), np.arccos(np.clip(v[:, 1], -1, 1)) / np.pi], -1)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
    return mesh


def test_chunked_fallback_matches_embree(monkeypatch):
    _embree()
    mesh = _uv_sphere()
    cam = Camera(position=(0.0, 0.3, 2.0), fov_deg=40.0, width=48, height=36)
    ref = gb.gbuffer_mesh(mesh, cam)  # Embree, one chunk
    assert ref.mask.sum() > 200

    from trimesh.ray.ray_triangle import RayMeshIntersector

    monkeypatch.setattr(gb, "_intersector", lambda m: (RayMeshIntersector(m), "triangle"))
    monkeypatch.setattr(gb, "RAY_CHUNK", 97)  # many uneven chunks: the ray indices must be offset right
    monkeypatch.setattr(gb._first_hits, "__defaults__", (97,))
    alt = gb.gbuffer_mesh(mesh, cam)
    # silhouette pixels may differ by the two intersectors' edge rules; the interior must match
    assert np.mean(ref.mask != alt.mask) < 0.01
    both = ref.mask & alt.mask
    np.testing.assert_allclose(alt.position[both], ref.position[both], atol=1e-5)
    np.testing.assert_allclose(alt.uv[both], ref.uv[both], atol=1e-5)


def test_embree_hits_equal_trimesh_first_hits_to_float64_rounding(monkeypatch):
    """The G-buffer from Embree's triangle ids with float64 barycentrics equals the one from trimesh's
    ``intersects_location`` (same Embree scene, its own plane intersection and barycentric solve), on the
    same rays: same pixels, attributes to float64 rounding."""
    _embree()
    mesh = _uv_sphere()
    cam = Camera(position=(0.0, 0.3, 2.0), look_at=(0.1, 0.0, 0.0), fov_deg=40.0, width=64, height=48)
    got = gb.gbuffer_mesh(mesh, cam)
    real = gb._intersector
    monkeypatch.setattr(gb, "_intersector", lambda m: (real(m)[0], "trimesh-locations"))
    want = gb.gbuffer_mesh(mesh, cam)
    assert want.mask.sum() > 500
    np.testing.assert_array_equal(got.index, want.index)
    for name in ("hit_position", "hit_normal", "hit_tangent", "hit_uv", "hit_view"):
        np.testing.assert_allclose(getattr(got, name), getattr(want, name), rtol=0, atol=1e-12, err_msg=name)


def _full_frame(monkeypatch, mesh, cam):
    """The G-buffer of a cast of every pixel's ray (no culling)."""
    with monkeypatch.context() as m:
        m.setattr(gb, "candidate_pixels", lambda mesh, camera: None)
        return gb.gbuffer_mesh(mesh, cam)


@pytest.mark.parametrize("position, look_at, fov", [
    ((0.0, 0.3, 2.0), (0.0, 0.0, 0.0), 40.0),    # the whole sphere in view
    ((0.0, 0.1, 0.8), (0.6, 0.0, 0.0), 60.0),    # cut by the frame's edge
    ((0.0, 0.0, 0.3), (0.0, 0.0, 0.0), 90.0),    # a vertex behind the camera: no culling, same frame
])
def test_culled_cast_equals_full_frame(monkeypatch, position, look_at, fov):
    _embree()
    mesh = _uv_sphere()
    cam = Camera(position=position, look_at=look_at, fov_deg=fov, width=64, height=48)
    full = _full_frame(monkeypatch, mesh, cam)
    got = gb.gbuffer_mesh(mesh, cam)
    assert full.mask.sum() > 50
    for name in ("mask", "index", "hit_position", "hit_normal", "hit_tangent", "hit_uv", "hit_view",
                 "position", "normal", "view", "uv", "ray"):
        np.testing.assert_array_equal(getattr(got, name), getattr(full, name), err_msg=name)


def test_candidates_cover_every_hit_and_cull():
    """Every pixel whose ray hits lies in a marked tile, and most of an off-centre frame is culled."""
    mesh = _uv_sphere()
    cam = Camera(position=(0.0, 0.3, 3.0), look_at=(0.4, 0.0, 0.0), fov_deg=40.0, width=80, height=60)
    cand = gb.candidate_pixels(mesh, cam)
    assert cand is not None and len(cand) < 0.6 * 80 * 60
    hit = np.flatnonzero(gb.gbuffer_mesh(mesh, cam).mask)
    assert np.isin(hit, cand).all()
    # the camera's rays of a subset are the full frame's, bit for bit
    np.testing.assert_array_equal(cam.rays(cand)[1], cam.rays()[1].reshape(-1, 3)[cand])


def test_dense_views_zero_outside_mask():
    mesh = _uv_sphere()
    g = gb.gbuffer_mesh(mesh, Camera(position=(0.0, 0.3, 2.0), fov_deg=40.0, width=32, height=24))
    assert g.position.shape == (24, 32, 3) and g.uv.shape == (24, 32, 2)
    assert not g.normal[~g.mask].any() and np.allclose(np.linalg.norm(g.normal[g.mask], axis=-1), 1.0)
    np.testing.assert_array_equal(g.view[g.mask], -g.ray[g.mask])


def test_face_table_follows_the_mesh_and_its_uvs():
    """The per-triangle table the G-buffer interpolates from is cached with the mesh: new UVs or moved
    vertices give the G-buffer of a fresh mesh with the same data, not the cached one's."""
    _embree()
    cam = Camera(position=(0.0, 0.3, 2.0), fov_deg=40.0, width=40, height=30)

    def fresh(mesh):
        m = trimesh.Trimesh(np.array(mesh.vertices), np.array(mesh.faces), process=False)
        m.visual = trimesh.visual.TextureVisuals(uv=np.array(mesh.visual.uv))
        return gb.gbuffer_mesh(m, cam)

    mesh = _uv_sphere()
    first = gb.gbuffer_mesh(mesh, cam)
    mesh.visual.uv = 0.5 * np.asarray(mesh.visual.uv)
    again = gb.gbuffer_mesh(mesh, cam)
    np.testing.assert_allclose(again.hit_uv, 0.5 * first.hit_uv, rtol=1e-12, atol=1e-15)
    mesh.vertices = np.asarray(mesh.vertices) * 1.2
    moved, want = gb.gbuffer_mesh(mesh, cam), fresh(mesh)
    assert moved.mask.sum() > first.mask.sum()
    for name in ("index", "hit_position", "hit_normal", "hit_tangent", "hit_uv"):
        np.testing.assert_array_equal(getattr(moved, name), getattr(want, name), err_msg=name)
