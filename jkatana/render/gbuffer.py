"""Visibility: a G-buffer from ray casting (trimesh, Embree through embreex when installed).

One primary ray per pixel centre. The G-buffer holds, per pixel, the hit
position, the interpolated shading normal (turned to face the camera), a
tangent frame (∂P/∂u Gram–Schmidt-orthogonalised against the normal), the UV
and a mask. An analytic sphere (for validation against Mitsuba and for
benchmarks) gets an exact G-buffer.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import trimesh

from jkatana.errors import InputError
from jkatana.render.camera import Camera
from jkatana.render.scene import Occluder


@dataclasses.dataclass
class GBuffer:
    """Per-pixel geometry; arrays are ``(H, W, ...)``; values outside ``mask`` are 0."""

    mask: np.ndarray        # (H, W) bool
    position: np.ndarray    # (H, W, 3)
    normal: np.ndarray      # (H, W, 3) shading normal, facing the camera
    tangent: np.ndarray     # (H, W, 3) along +u
    uv: np.ndarray          # (H, W, 2)
    view: np.ndarray        # (H, W, 3) unit direction from the surface to the camera
    ray: np.ndarray         # (H, W, 3) primary ray directions (for the background)

    @property
    def coverage(self) -> float:
        return float(self.mask.mean())


def _intersector(mesh: trimesh.Trimesh):
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        return RayMeshIntersector(mesh), "embree"
    except Exception:  # embreex missing: trimesh's rtree-based intersector
        from trimesh.ray.ray_triangle import RayMeshIntersector

        return RayMeshIntersector(mesh), "triangle"


#: Rays per intersector call. trimesh's pure-Python fallback (no embreex) holds
#: candidate arrays proportional to the rays in one call (tens of GB for a whole
#: 800×600 frame), so rays go in chunks; with Embree chunking costs nothing.
RAY_CHUNK = 1 << 15


def _first_hits(isect, o: np.ndarray, d: np.ndarray, chunk: int = RAY_CHUNK):
    """``intersects_location(..., multiple_hits=False)`` over ``chunk``-sized batches of rays."""
    locs, rays, tris = [], [], []
    for start in range(0, len(d), chunk):
        loc, idx_ray, idx_tri = isect.intersects_location(o[start:start + chunk], d[start:start + chunk],
                                                          multiple_hits=False)
        locs.append(np.asarray(loc, np.float64).reshape(-1, 3))
        rays.append(np.asarray(idx_ray, np.int64) + start)
        tris.append(np.asarray(idx_tri, np.int64))
    if not locs:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(locs), np.concatenate(rays), np.concatenate(tris)


def _any_hits(isect, o: np.ndarray, d: np.ndarray, chunk: int = RAY_CHUNK) -> np.ndarray:
    """``intersects_any`` over ``chunk``-sized batches of rays."""
    return np.concatenate([np.asarray(isect.intersects_any(o[s:s + chunk], d[s:s + chunk]), bool)
                           for s in range(0, len(d), chunk)] or [np.zeros(0, bool)])


def gbuffer_mesh(mesh: trimesh.Trimesh, camera: Camera) -> GBuffer:
    """Ray-cast ``mesh`` from ``camera`` (first hit per pixel).

    Requires per-vertex UVs (``mesh.visual.uv``); the tangent comes from the
    triangle's UV derivatives.
    """
    uv_v = getattr(mesh.visual, "uv", None)
    if uv_v is None or len(uv_v) != len(mesh.vertices):
        raise InputError("mesh has no per-vertex UVs (needed for the reflectance map)", field="mesh")
    origin, dirs = camera.rays()
    H, W, _ = dirs.shape
    d = dirs.reshape(-1, 3)
    o = np.broadcast_to(origin, d.shape)
    isect, _ = _intersector(mesh)
    loc, idx_ray, idx_tri = _first_hits(isect, o, d)
    n = H * W
    mask = np.zeros(n, bool)
    pos = np.zeros((n, 3))
    nrm = np.zeros((n, 3))
    tan = np.zeros((n, 3))
    uv = np.zeros((n, 2))
    if len(idx_ray):
        tri = mesh.faces[idx_tri]
        bary = trimesh.triangles.points_to_barycentric(mesh.vertices[tri], loc)
        vn = mesh.vertex_normals[tri]
        ns = np.einsum("pk,pkc->pc", bary, vn)
        ng = mesh.face_normals[idx_tri]
        ns = np.where(np.linalg.norm(ns, axis=-1, keepdims=True) > 1e-12, ns, ng)
        ns /= np.linalg.norm(ns, axis=-1, keepdims=True)
        # face the camera (two-sided shading: the blade is seen from both flats)
        flip = np.sum(ns * d[idx_ray], -1) > 0
        ns[flip] *= -1
        t_uv = uv_v[tri]
        uvp = np.einsum("pk,pkc->pc", bary, t_uv)
        # tangent from UV derivatives: dP = T du + B dv
        p0, p1, p2 = (mesh.vertices[tri[:, i]] for i in range(3))
        e1, e2 = p1 - p0, p2 - p0
        du1, dv1 = t_uv[:, 1, 0] - t_uv[:, 0, 0], t_uv[:, 1, 1] - t_uv[:, 0, 1]
        du2, dv2 = t_uv[:, 2, 0] - t_uv[:, 0, 0], t_uv[:, 2, 1] - t_uv[:, 0, 1]
        det = du1 * dv2 - du2 * dv1
        T = (e1 * dv2[:, None] - e2 * dv1[:, None]) / np.where(np.abs(det) > 1e-20, det, 1.0)[:, None]
        T -= np.sum(T * ns, -1, keepdims=True) * ns
        tl = np.linalg.norm(T, axis=-1, keepdims=True)
        fallback = np.cross(ns, [0.0, 0.0, 1.0]) + 1e-9
        T = np.where(tl > 1e-12, T / np.maximum(tl, 1e-30), fallback / np.linalg.norm(fallback, axis=-1, keepdims=True))
        mask[idx_ray] = True
        pos[idx_ray], nrm[idx_ray], tan[idx_ray], uv[idx_ray] = loc, ns, T, uvp
    view = np.where(mask[:, None], -d, 0.0)
    return GBuffer(mask.reshape(H, W), pos.reshape(H, W, 3), nrm.reshape(H, W, 3), tan.reshape(H, W, 3),
                   uv.reshape(H, W, 2), view.reshape(H, W, 3), dirs)


def gbuffer_sphere(camera: Camera, center=(0.0, 0.0, 0.0), radius: float = 1.0) -> GBuffer:
    """Exact G-buffer of a sphere (UV: u = longitude / 2π, v = colatitude / π)."""
    origin, dirs = camera.rays()
    H, W, _ = dirs.shape
    oc = origin - np.asarray(center, np.float64)
    b = dirs @ oc
    c = oc @ oc - radius * radius
    disc = b * b - c
    mask = disc > 0
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    mask &= t > 0
    pos = origin + t[..., None] * dirs
    n = (pos - np.asarray(center)) / radius
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    u = 0.5 + np.arctan2(n[..., 0], n[..., 2]) / (2 * np.pi)
    v = np.arccos(np.clip(n[..., 1], -1, 1)) / np.pi
    tan = np.stack([n[..., 2], np.zeros_like(u), -n[..., 0]], -1)
    tl = np.linalg.norm(tan, axis=-1, keepdims=True)
    tan = np.where(tl > 1e-9, tan / np.maximum(tl, 1e-30), [1.0, 0.0, 0.0])
    z = lambda a: np.where(mask[..., None] if a.ndim == 3 else mask, a, 0.0)  # noqa: E731
    return GBuffer(mask, z(pos), z(n), z(tan), z(np.stack([u, v], -1)), z(-dirs), dirs)


class Occluders:
    """Geometry that can block light (a stand, a second blade): shadow/visibility rays against it.

    One trimesh mesh (all occluders concatenated) with a cached intersector
    (Embree through embreex when installed). Occluders are black: they block
    light and neither emit nor reflect it (the visibility term V(x, ω) of the
    rendering equation, Kajiya 1986, without the occluders' own radiance).
    """

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh
        self.intersector, self.engine = _intersector(mesh)
        self.rays_cast = 0
        self.cast_s = 0.0

    def visible(self, origins: np.ndarray, directions: np.ndarray, max_dist: np.ndarray | None = None,
                eps: float = 1e-5) -> np.ndarray:
        """``(n,)`` float32: 1 where the ray ``origins + t·directions``, ``eps < t < max_dist``, hits nothing.

        Origins are moved by ``eps`` along the ray (no self-hits where an
        occluder touches the shaded surface). ``max_dist`` (point lights) may
        hold ``inf``.
        """
        import time

        t0 = time.perf_counter()
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-30)
        o = o + eps * d
        self.rays_cast += len(o)
        if len(o) == 0:
            return np.ones(0, np.float32)
        if max_dist is None or not np.isfinite(max_dist).any():
            hit = _any_hits(self.intersector, o, d)
            self.cast_s += time.perf_counter() - t0
            return (~np.asarray(hit, bool)).astype(np.float32)
        md = np.asarray(max_dist, np.float64).reshape(-1)
        loc, idx_ray, _ = _first_hits(self.intersector, o, d)
        blocked = np.zeros(len(o), bool)
        if len(idx_ray):
            t = np.linalg.norm(loc - o[idx_ray], axis=-1)
            blocked[idx_ray] = t < md[idx_ray] - eps
        self.cast_s += time.perf_counter() - t0
        return (~blocked).astype(np.float32)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Distance to the first occluder hit along each ray (``inf`` where none): primary visibility."""
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        dist = np.full(len(o), np.inf)
        loc, idx_ray, _ = _first_hits(self.intersector, o, d)
        if len(idx_ray):
            dist[idx_ray] = np.linalg.norm(loc - o[idx_ray], axis=-1)
        return dist


def occluder_mesh(specs: Sequence[Occluder]) -> trimesh.Trimesh | None:
    """One mesh from the scene's ``[[occluders]]`` (box, sphere or mesh file, each with a translation)."""
    parts = []
    for i, s in enumerate(specs):
        if s.kind == "box":
            m = trimesh.creation.box(extents=s.extents)
        elif s.kind == "sphere":
            m = trimesh.creation.icosphere(subdivisions=4, radius=s.radius)
        else:
            try:
                m = trimesh.load(s.mesh, force="mesh", process=False)
            except Exception as err:  # trimesh raises many types for bad files
                raise InputError(f"not a readable mesh ({err})", path=s.mesh, field=f"occluders[{i}].mesh") from None
            if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
                raise InputError("no triangles", path=s.mesh, field=f"occluders[{i}].mesh")
            m = trimesh.Trimesh(m.vertices * s.scale, m.faces, process=False)
        m.apply_translation(s.center)
        parts.append(m)
    if not parts:
        return None
    return trimesh.util.concatenate(parts) if len(parts) > 1 else parts[0]
