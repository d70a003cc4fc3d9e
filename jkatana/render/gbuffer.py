"""Visibility: a G-buffer from ray casting (trimesh, Embree through embreex when installed).

One primary ray per pixel centre. The G-buffer holds, per pixel, the hit
position, the interpolated shading normal (turned to face the camera), a
tangent frame (∂P/∂u Gram–Schmidt-orthogonalised against the normal), the UV
and a mask. An analytic sphere (for validation against Mitsuba and for
benchmarks) gets an exact G-buffer.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import numpy as np
import trimesh

from jkatana.errors import InputError
from jkatana.render.camera import Camera
from jkatana.render.scene import OccluderSpec


@dataclasses.dataclass
class GBuffer:
    """Per-pixel geometry of the pixels whose primary ray hits the object, and the frame's camera rays.

    The hit pixels' attributes are held compactly (one row per hit, in
    ascending flat pixel order, ``index``); the ``(H, W, ...)`` views
    (``position``, ``normal``, ``tangent``, ``uv``, ``view``; 0 outside ``mask``)
    are built on request, as are the primary ray directions ``ray`` (from the
    camera unless given), so a frame pays only for the pixels it shades.
    """

    mask: np.ndarray            # (H, W) bool
    index: np.ndarray           # (n,) flat indices of the hit pixels, ascending
    hit_position: np.ndarray    # (n, 3)
    hit_normal: np.ndarray      # (n, 3) shading normal, facing the camera
    hit_tangent: np.ndarray     # (n, 3) along +u
    hit_uv: np.ndarray          # (n, 2)
    hit_view: np.ndarray        # (n, 3) unit direction from the surface to the camera
    camera: Camera | None = None
    rays: np.ndarray | None = None  # (H, W, 3) primary ray directions, or None: from `camera` on request

    @classmethod
    def from_dense(cls, mask, position, normal, tangent, uv, view, ray) -> "GBuffer":
        """A G-buffer from ``(H, W, ...)`` arrays."""
        idx = np.flatnonzero(mask)

        def rows(a):
            return a.reshape(-1, a.shape[-1])[idx]

        return cls(mask, idx, rows(position), rows(normal), rows(tangent), rows(uv), rows(view), None, ray)

    def _dense(self, rows: np.ndarray) -> np.ndarray:
        H, W = self.mask.shape
        out = np.zeros((H * W, rows.shape[-1]), rows.dtype)
        out[self.index] = rows
        return out.reshape(H, W, -1)

    @property
    def position(self) -> np.ndarray:
        return self._dense(self.hit_position)

    @property
    def normal(self) -> np.ndarray:
        return self._dense(self.hit_normal)

    @property
    def tangent(self) -> np.ndarray:
        return self._dense(self.hit_tangent)

    @property
    def uv(self) -> np.ndarray:
        return self._dense(self.hit_uv)

    @property
    def view(self) -> np.ndarray:
        return self._dense(self.hit_view)

    @property
    def ray(self) -> np.ndarray:
        """``(H, W, 3)`` primary ray directions (for the background)."""
        if self.rays is None:
            self.rays = self.camera.rays()[1]
        return self.rays

    @property
    def coverage(self) -> float:
        return float(self.mask.mean())


def _intersector(mesh: trimesh.Trimesh):
    """``(intersector, engine)`` of ``mesh``: its own Embree intersector (``mesh.ray``, whose
    acceleration structure trimesh builds once and rebuilds only when the mesh changes) when embreex is
    installed, else trimesh's rtree-based one."""
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    except Exception:  # embreex missing: trimesh's rtree-based intersector
        from trimesh.ray.ray_triangle import RayMeshIntersector

        return RayMeshIntersector(mesh), "triangle"
    ray = getattr(mesh, "ray", None)
    return (ray if isinstance(ray, RayMeshIntersector) else RayMeshIntersector(mesh)), "embree"


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


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of ``(n, 3)`` arrays (one pass; NumPy's reduction over a length-3 axis is slow)."""
    return np.einsum("pc,pc->p", a, b)


def _face_table(mesh: trimesh.Trimesh) -> np.ndarray:
    """Per triangle, one column of a ``(30, F)`` float64 table (one gather per hit fetches all; attributes
    as rows, so that the per-hit arithmetic runs on contiguous rows): the first corner p₀ and the edges
    e₁ = p₁ − p₀, e₂ = p₂ − p₀ (rows :data:`_P0`, :data:`_E1`, :data:`_E2`), the three vertex normals
    (:data:`_VN`), the three UVs (:data:`_UV`), the face normal (:data:`_NG`) and the tangent ∂P/∂u
    (:data:`_TU`: from the UV derivatives, dP = T du + B dv, solved on the triangle; constant over it).

    Kept in the mesh's own cache (cleared by trimesh when the vertices or faces change), with the hash
    of its visual (the UVs), so a fixed mesh pays for it once and not per frame.
    """
    key = "jkatana_gbuffer_faces"
    uv_hash = hash(mesh.visual)
    cache = mesh._cache  # trimesh's per-mesh cache: verified against the mesh's data on access
    hit = cache[key] if key in cache else None
    if hit is not None and hit[0] == uv_hash:
        return hit[1]
    verts = np.asarray(mesh.vertices).view(np.ndarray)
    tri = np.asarray(mesh.faces).view(np.ndarray)
    corners = verts[tri]
    p0, e1, e2 = corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    t_uv = np.asarray(mesh.visual.uv, np.float64)[tri]
    du1, dv1 = t_uv[:, 1, 0] - t_uv[:, 0, 0], t_uv[:, 1, 1] - t_uv[:, 0, 1]
    du2, dv2 = t_uv[:, 2, 0] - t_uv[:, 0, 0], t_uv[:, 2, 1] - t_uv[:, 0, 1]
    det = du1 * dv2 - du2 * dv1
    tu = (e1 * dv2[:, None] - e2 * dv1[:, None]) / np.where(np.abs(det) > 1e-20, det, 1.0)[:, None]
    vn = np.asarray(mesh.vertex_normals).view(np.ndarray)[tri].reshape(-1, 9)
    ng = np.asarray(mesh.face_normals).view(np.ndarray)
    table = np.ascontiguousarray(np.concatenate([p0, e1, e2, vn, t_uv.reshape(-1, 6), ng, tu], -1).T, np.float64)
    cache[key] = (uv_hash, table)
    return table


#: Row slices of :func:`_face_table`.
_P0, _E1, _E2, _VN, _UV, _NG, _TU = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 18), slice(18, 24),
                                     slice(24, 27), slice(27, 30))


def _rdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of the columns of ``(3, n)`` arrays."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _rcross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of the columns of ``(3, n)`` arrays."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _embree_first_hits(isect, origin: np.ndarray, d: np.ndarray, faces: np.ndarray):
    """``(ray index, triangle index, u, v, the hit triangles' columns of faces)`` of the rays ``origin + t·d``
    that hit, in ray order (``faces``: :func:`_face_table`).

    One Embree query (Wald et al. 2014) through trimesh's scene finds each ray's
    triangle; the barycentrics ``(u, v)`` (the hit is ``(1 − u − v)·p₀ + u·p₁ + v·p₂``)
    are then solved in float64 on that triangle (Möller & Trumbore 1997), where
    Embree's own are float32 (off by up to ~1e-4 on the blade's long, thin triangles).
    The hits are those of :func:`_first_hits`, without trimesh's re-intersection of each
    ray with its triangle's plane and its barycentric solve.
    """
    o = np.broadcast_to(np.asarray(origin, np.float64), d.shape)
    prim = np.asarray(isect._scene.run(o, np.asarray(d, np.float64)), np.int64)
    idx_ray = np.flatnonzero(prim >= 0)
    idx_tri = prim[idx_ray]
    f = np.take(faces, idx_tri, axis=1)
    dr = np.ascontiguousarray(d[idx_ray].T)
    e1, e2, tv = f[_E1], f[_E2], np.asarray(origin, np.float64)[:, None] - f[_P0]
    pv = _rcross(dr, e2)
    det = _rdot(e1, pv)
    ok = np.abs(det) > 1e-300
    inv = 1.0 / np.where(ok, det, 1.0)
    u = np.where(ok, _rdot(tv, pv) * inv, 1.0 / 3.0)
    v = np.where(ok, _rdot(dr, _rcross(tv, e1)) * inv, 1.0 / 3.0)
    return idx_ray, idx_tri, u, v, f


#: Side (pixels) of the screen tiles :func:`candidate_pixels` marks.
TILE = 8


def candidate_pixels(mesh: trimesh.Trimesh, camera: Camera, tile: int = TILE) -> np.ndarray | None:
    """Flat indices of the pixels whose centre ray can hit ``mesh``, or ``None`` (every pixel).

    Primary rays share the camera's centre, so a ray can hit a triangle lying in
    front of the camera only if its pixel centre falls inside the triangle's
    perspective projection, which lies inside the projected vertices' bounding
    box (a convex polygon is the hull of its projected vertices). Each triangle
    marks the ``tile × tile`` screen tiles its box (grown by two pixels, far
    above rounding) overlaps; the pixels of marked tiles are returned. Culling
    only drops rays that miss every triangle, so the hits are those of a
    full-frame cast. ``None`` when a vertex lies on or behind the camera's plane
    (no finite projection) or when most of the screen is marked anyway.
    """
    right, up, fwd = camera.frame()
    rel = np.asarray(mesh.vertices, np.float64) - np.asarray(camera.position, np.float64)
    z = rel @ fwd
    if not len(z) or z.min() <= 1e-9 * max(float(np.abs(rel).max()), 1e-30):
        return None
    W, H = int(camera.width), int(camera.height)
    tan_half = np.tan(np.radians(camera.fov_deg) / 2)
    # pixel coordinates in the convention of Camera.rays: column c's centre ray has x = ((c + ½)/W·2 − 1)·t·a
    col = ((rel @ right) / (z * tan_half * (W / H)) + 1.0) * 0.5 * W - 0.5
    row = (1.0 - (rel @ up) / (z * tan_half)) * 0.5 * H - 0.5
    tri = np.asarray(mesh.faces).view(np.ndarray)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]

    def lo_hi(x):  # per triangle: min and max over its 3 corners (elementwise, not a reduction over a 3-axis)
        xa, xb, xc = x[a], x[b], x[c]
        return np.minimum(np.minimum(xa, xb), xc), np.maximum(np.maximum(xa, xb), xc)

    ntx, nty = -(-W // tile), -(-H // tile)
    (cmin, cmax), (rmin, rmax) = lo_hi(col), lo_hi(row)
    c0, c1 = np.floor((cmin - 2.0) / tile), np.floor((cmax + 2.0) / tile)
    r0, r1 = np.floor((rmin - 2.0) / tile), np.floor((rmax + 2.0) / tile)
    on = (c1 >= 0) & (c0 < ntx) & (r1 >= 0) & (r0 < nty)
    c0, c1 = np.clip(c0[on], 0, ntx - 1).astype(np.int64), np.clip(c1[on], 0, ntx - 1).astype(np.int64)
    r0, r1 = np.clip(r0[on], 0, nty - 1).astype(np.int64), np.clip(r1[on], 0, nty - 1).astype(np.int64)
    marked = np.zeros((nty, ntx), bool)
    sx, sy = c1 - c0, r1 - r0
    reach = int(min(max(sx.max(initial=0), sy.max(initial=0)), 7))
    for dy in range(reach + 1):  # every tile of every box up to 8 × 8 tiles, one offset at a time
        for dx in range(reach + 1):
            hit = (sx >= dx) & (sy >= dy)
            marked[r0[hit] + dy, c0[hit] + dx] = True
    big = np.nonzero((sx > 7) | (sy > 7))[0]
    if len(big) > 4096:
        return None
    for i in big:
        marked[r0[i]:r1[i] + 1, c0[i]:c1[i] + 1] = True
    if marked.mean() > 0.75:
        return None
    full = np.repeat(np.repeat(marked, tile, 0), tile, 1)[:H, :W]
    return np.flatnonzero(full)


def gbuffer_mesh(mesh: trimesh.Trimesh, camera: Camera) -> GBuffer:
    """Ray-cast ``mesh`` from ``camera`` (first hit per pixel).

    Requires per-vertex UVs (``mesh.visual.uv``); the tangent comes from the
    triangle's UV derivatives. Only the rays of :func:`candidate_pixels` are cast
    (the others provably miss).
    """
    uv_v = getattr(mesh.visual, "uv", None)
    if uv_v is None or len(uv_v) != len(mesh.vertices):
        raise InputError("mesh has no per-vertex UVs (needed for the reflectance map)", field="mesh")
    H, W = int(camera.height), int(camera.width)
    cand = candidate_pixels(mesh, camera)
    cand = np.arange(H * W) if cand is None else cand
    origin, dc = camera.rays(cand)
    isect, engine = _intersector(mesh)
    faces = _face_table(mesh)
    if engine == "embree":
        idx_ray, idx_tri, u, v, f = _embree_first_hits(isect, origin, dc, faces)
    else:
        loc, idx_ray, idx_tri = _first_hits(isect, np.broadcast_to(origin, dc.shape), dc)
        order = np.argsort(idx_ray, kind="stable")  # ascending pixel order
        idx_ray, idx_tri = idx_ray[order], idx_tri[order]
        verts = np.asarray(mesh.vertices).view(np.ndarray)  # plain arrays: trimesh's tracked arrays re-hash
        bary = trimesh.triangles.points_to_barycentric(verts[np.asarray(mesh.faces)[idx_tri]], loc[order])
        u, v, f = bary[:, 1], bary[:, 2], np.take(faces, idx_tri, axis=1)
    mask = np.zeros(H * W, bool)
    mask[cand[idx_ray]] = True
    d = dc[idx_ray]
    loc, ns, T, uvp = _interpolate(f, u, v, d)
    return GBuffer(mask.reshape(H, W), cand[idx_ray], loc, ns, T, uvp, -d, camera)


def _interpolate(f: np.ndarray, u: np.ndarray, v: np.ndarray, d: np.ndarray):
    """``(position, shading normal, tangent, uv)``, ``(n, 3|2)`` each, at barycentrics ``(u, v)`` of the hit
    triangles' columns ``f`` of :func:`_face_table`, seen along ``d (n, 3)``.

    The shading normal is the vertex normals interpolated (the face normal where they cancel), unit, turned
    to face the camera (two-sided shading: the blade is seen from both flats); the tangent is the face's
    ∂P/∂u Gram–Schmidt-orthogonalised against it (a perpendicular of the normal where ∂P/∂u is degenerate).
    """
    w = 1.0 - u - v
    loc = f[_P0] + u * f[_E1] + v * f[_E2]
    vn = f[_VN]
    ns = w * vn[0:3] + u * vn[3:6] + v * vn[6:9]
    ln = np.sqrt(_rdot(ns, ns))
    good = ln > 1e-12
    ns = np.where(good, ns / np.where(good, ln, 1.0), f[_NG])
    if not good.all():
        ns /= np.sqrt(_rdot(ns, ns))
    ns *= np.where(_rdot(ns, d.T) > 0, -1.0, 1.0)
    t_uv = f[_UV]
    uvp = w * t_uv[0:2] + u * t_uv[2:4] + v * t_uv[4:6]
    T = f[_TU] - _rdot(f[_TU], ns) * ns
    tl = np.sqrt(_rdot(T, T))
    ok = tl > 1e-12
    T = T / np.where(ok, tl, 1.0)
    T, ns = np.ascontiguousarray(T.T), np.ascontiguousarray(ns.T)
    if not ok.all():
        fallback = np.cross(ns[~ok], [0.0, 0.0, 1.0]) + 1e-9
        T[~ok] = fallback / np.linalg.norm(fallback, axis=-1, keepdims=True)
    return np.ascontiguousarray(loc.T), ns, T, np.ascontiguousarray(uvp.T)


def gbuffer_sphere(camera: Camera, center=(0.0, 0.0, 0.0), radius: float = 1.0) -> GBuffer:
    """Exact G-buffer of a sphere (UV: u = longitude / 2π, v = colatitude / π).

    A G-buffer depends on the camera and the sphere only, so one is kept per (camera, centre, radius)
    (:func:`_sphere_hits`; a batch of frames of one view pays for it once). Its arrays are read-only.
    """
    return _sphere_hits(camera, tuple(float(x) for x in np.ravel(center)), float(radius))


@functools.lru_cache(maxsize=8)
def _sphere_hits(camera: Camera, center: tuple, radius: float) -> GBuffer:
    """:func:`gbuffer_sphere`: the ray–sphere test on every primary ray (the nearer root of
    |o + t·d − c|² = r², t > 0), the hit point's attributes on the hit rows only."""
    origin, dirs = camera.rays()
    H, W, _ = dirs.shape
    oc = origin - np.asarray(center, np.float64)
    b = dirs @ oc
    c = oc @ oc - radius * radius
    disc = b * b - c
    mask = disc > 0
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    mask &= t > 0
    idx = np.flatnonzero(mask).copy()  # its own data: read-only below, not a view of a writable array
    d = dirs.reshape(-1, 3)[idx]
    pos = origin + t.reshape(-1)[idx][:, None] * d
    n = (pos - np.asarray(center)) / radius
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    u = 0.5 + np.arctan2(n[:, 0], n[:, 2]) / (2 * np.pi)
    v = np.arccos(np.clip(n[:, 1], -1, 1)) / np.pi
    tan = np.stack([n[:, 2], np.zeros_like(u), -n[:, 0]], -1)
    tl = np.linalg.norm(tan, axis=-1, keepdims=True)
    tan = np.where(tl > 1e-9, tan / np.maximum(tl, 1e-30), [1.0, 0.0, 0.0])
    gb = GBuffer(mask, idx, pos, n, tan, np.stack([u, v], -1), -d, camera, dirs)
    for a in (mask, idx, pos, n, tan, gb.hit_uv, gb.hit_view, dirs):
        a.flags.writeable = False
    return gb


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


def occluder_mesh(specs: Sequence[OccluderSpec]) -> trimesh.Trimesh | None:
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
