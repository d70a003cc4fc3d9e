"""A blade mesh ready for photo registration (:mod:`jkatana.maps.register`): its silhouette topology and the
surface point and normal of every texel of a map.

The mesh's vertices are welded (the blade's panels do not share vertices) so that its silhouette from a camera
centre is the set of edges between a front-facing and a back-facing triangle, exact for any closed mesh. The
texels' surface points come from rasterising the mesh's triangles in UV space (blade UVs: u along the mune by arc
length, v from mune to ha, :mod:`jkatana.shape.katana`), once per face (omote: normals toward +Z, ura: −Z).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from jkatana.errors import InputError


@dataclass
class BladeSurface:
    """A blade mesh ready for registration: its welded silhouette topology and, per face, the
    surface point and normal of every texel of an ``(H, W)`` map."""

    mesh: trimesh.Trimesh
    resolution: tuple[int, int]
    edges: np.ndarray = field(repr=False)  # (E, 2) welded vertex ids of interior edges
    edge_faces: np.ndarray = field(repr=False)  # (E, 2) the two faces of each
    border: np.ndarray = field(repr=False)  # (B, 2) edges of one face only (holes)
    wverts: np.ndarray = field(repr=False)
    fnormals: np.ndarray = field(repr=False)
    fcentres: np.ndarray = field(repr=False)
    points: dict = field(repr=False)  # side → (H, W, 3)
    normals: dict = field(repr=False)  # side → (H, W, 3)
    valid: dict = field(repr=False)  # side → (H, W) bool

    @property
    def length(self) -> float:
        return float(np.ptp(np.asarray(self.mesh.vertices)[:, 0]))

    def silhouette(self, centre: np.ndarray) -> np.ndarray:
        """3-D segments (S, 2, 3) of the silhouette seen from ``centre``: edges between a front- and a
        back-facing triangle, and the mesh's open borders."""
        front = np.einsum("ij,ij->i", self.fnormals, centre - self.fcentres) > 0
        f = front[self.edge_faces]
        sil = self.edges[f[:, 0] != f[:, 1]]
        if len(self.border):
            sil = np.concatenate([sil, self.border])
        return self.wverts[sil]


def _check_blade_uvs(mesh: trimesh.Trimesh, path) -> np.ndarray:
    uv = getattr(mesh.visual, "uv", None)
    hint = "(make it with `jkatana shape ... --uv blade`)"
    if uv is None or len(uv) != len(mesh.vertices):
        raise InputError(f"the mesh has no UVs; a map needs blade UVs {hint}", path=path, field="uv")
    uv = np.asarray(uv, np.float64)
    x = np.asarray(mesh.vertices)[:, 0]
    if not np.all(np.isfinite(uv)) or uv.min() < -1e-6 or uv.max() > 1 + 1e-6:
        raise InputError(f"UVs outside [0, 1]: not blade UVs {hint}", path=path, field="uv")
    corr = np.corrcoef(uv[:, 0], x)[0, 1] if np.std(uv[:, 0]) > 0 and np.std(x) > 0 else 0.0
    if not corr > 0.98:
        raise InputError(f"u does not run along the blade (correlation with x {corr:.2f}): not blade UVs {hint}",
                         path=path, field="uv")
    return uv


def blade_surface(mesh: trimesh.Trimesh, resolution: tuple[int, int] = (256, 1024), *, path=None) -> BladeSurface:
    """Prepare ``mesh`` (blade frame, blade UVs) for registration and texel lookup.

    Raises :class:`InputError` naming ``path`` when the UVs are not the blade's
    (u along the blade, v across, each face covering the unit square).
    """
    uv = _check_blade_uvs(mesh, path)
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    # welded topology (panels of the blade do not share vertices)
    key = np.round(V / max(float(np.ptp(V, axis=0).max()), 1e-12) * 2 ** 24).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    WF = inv[F]
    wverts = V[first]
    e = np.concatenate([WF[:, [0, 1]], WF[:, [1, 2]], WF[:, [2, 0]]])
    fid = np.tile(np.arange(len(F)), 3)
    es = np.sort(e, axis=1)
    order = np.lexsort((es[:, 1], es[:, 0]))
    es, fid = es[order], fid[order]
    same = np.all(es[1:] == es[:-1], axis=1)
    pair = np.flatnonzero(same)
    edges = es[pair]
    edge_faces = np.stack([fid[pair], fid[pair + 1]], -1)
    single = np.ones(len(es), bool)
    single[pair] = single[pair + 1] = False
    border = es[single]
    p = wverts[WF]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
    points, normals, valid = _texel_surface(mesh, uv, resolution)
    for side in ("omote", "ura"):
        if valid[side].mean() < 0.9:
            raise InputError(f"the {side} face's UVs cover {100 * valid[side].mean():.0f} % of the unit square "
                             "(blade UVs cover it on each face): make the mesh with `jkatana shape ... --uv blade`",
                             path=path, field="uv")
    return BladeSurface(mesh, tuple(resolution), edges, edge_faces, border, wverts, fn, p.mean(1),
                        points, normals, valid)


def _texel_surface(mesh, uv, resolution):
    """Rasterise the triangles in UV space: per face side, the surface point and normal of each texel centre."""
    H, W = resolution
    V = np.asarray(mesh.vertices, np.float64)
    N = np.asarray(mesh.vertex_normals, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    fn = np.asarray(mesh.face_normals, np.float64)
    t = uv[F] * [W, H] - 0.5  # texel-index space: texel (i, j) centre at (j, i)
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    area = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    out_p = {s: np.zeros((H, W, 3)) for s in ("omote", "ura")}
    out_n = {s: np.zeros((H, W, 3)) for s in ("omote", "ura")}
    out_ok = {s: np.zeros((H, W), bool) for s in ("omote", "ura")}
    side_of = np.where(fn[:, 2] >= 0, 0, 1)
    keep = np.abs(area) > 1e-9
    j0 = np.clip(np.ceil(t[..., 0].min(1)), 0, W - 1).astype(int)
    j1 = np.clip(np.floor(t[..., 0].max(1)), 0, W - 1).astype(int)
    i0 = np.clip(np.ceil(t[..., 1].min(1)), 0, H - 1).astype(int)
    i1 = np.clip(np.floor(t[..., 1].max(1)), 0, H - 1).astype(int)
    keep &= (j1 >= j0) & (i1 >= i0)
    tri = np.flatnonzero(keep)
    # candidate texels: every (triangle, texel in its box), in chunks of similar box size
    nh, nw = i1 - i0 + 1, j1 - j0 + 1
    cand_t, cand_i, cand_j = [], [], []
    for k in tri[(nh[tri] * nw[tri]) > 64]:  # big boxes (tip fans): one at a time
        ii, jj = np.mgrid[i0[k]:i1[k] + 1, j0[k]:j1[k] + 1]
        cand_t.append(np.full(ii.size, k))
        cand_i.append(ii.ravel())
        cand_j.append(jj.ravel())
    small = tri[(nh[tri] * nw[tri]) <= 64]
    for di in range(int(nh[small].max(initial=0))):
        for dj in range(int(nw[small].max(initial=0))):
            s = small[(di < nh[small]) & (dj < nw[small])]
            cand_t.append(s)
            cand_i.append(i0[s] + di)
            cand_j.append(j0[s] + dj)
    ct, ci, cj = (np.concatenate(a) for a in (cand_t, cand_i, cand_j))
    px, py = cj - t[ct, 0, 0], ci - t[ct, 0, 1]
    a = area[ct]
    b1 = (px * d2[ct, 1] - py * d2[ct, 0]) / a
    b2 = (d1[ct, 0] * py - d1[ct, 1] * px) / a
    b0 = 1 - b1 - b2
    eps = -1e-9
    inside = (b0 >= eps) & (b1 >= eps) & (b2 >= eps)
    ct, ci, cj, b = ct[inside], ci[inside], cj[inside], np.stack([b0, b1, b2], -1)[inside]
    pos = np.einsum("nk,nkd->nd", b, V[F[ct]])
    nrm = np.einsum("nk,nkd->nd", b, N[F[ct]])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    for s, name in enumerate(("omote", "ura")):
        m = side_of[ct] == s
        out_p[name][ci[m], cj[m]] = pos[m]
        out_n[name][ci[m], cj[m]] = nrm[m]
        out_ok[name][ci[m], cj[m]] = True
    return out_p, out_n, out_ok


__all__ = ["BladeSurface", "blade_surface"]
