"""UV parameterisations of a mesh for the reflectance map, and how much they stretch.

- :func:`blade_uvs`: the built-in blade's convention (:mod:`jkatana.shape.katana`) on any mesh in
  the blade frame — u the arc-length fraction along the mune line (0 at the machi, 1 at the tip),
  v the distance from the mune over the local width (0 at the mune, 1 at the ha), the same (u, v)
  on both flats so that one map serves both.
- :func:`xatlas_uvs`: a general chart unwrap and packing by xatlas (Young, github.com/jpcy/xatlas,
  after Lévy et al., "Least squares conformal maps", SIGGRAPH 2002) for anything that is not a blade.
- :func:`uv_stretch`: the parameterisation's L2 stretch (Sander, Snyder, Gortler & Hoppe,
  "Texture mapping progressive meshes", SIGGRAPH 2001).
"""

from __future__ import annotations

import numpy as np
import trimesh


def _mune_line(v: np.ndarray, bins: int = 120) -> np.ndarray:
    """The mune line as a dense (x, y) polyline from the machi to the tip, in the blade frame.

    The highest vertex (max y) of each slab along x, smoothed by a quartic
    least-squares fit y(x) (a blade's sori is a smooth arc).
    """
    x, y = v[:, 0], v[:, 1]
    x0, x1 = 0.0, float(x.max())
    edges = np.linspace(x0, x1, bins + 1)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    ok = (x >= x0)
    order = np.lexsort((-y[ok], idx[ok]))
    first = np.unique(idx[ok][order], return_index=True)[1]
    top = np.flatnonzero(ok)[order[first]]
    coef = np.polynomial.polynomial.polyfit(x[top], y[top], 4)
    xs = np.linspace(x0, x1, 4001)
    return np.stack([xs, np.polynomial.polynomial.polyval(xs, coef)], -1)


def blade_uvs(mesh: trimesh.Trimesh, *, bins: int = 400) -> np.ndarray:
    """Per-vertex (u, v) of a mesh in the blade frame, in the built-in blade's convention.

    u: arc-length fraction of the foot point on the mune line; v: the distance
    from the mune line (in the blade plane) over the blade's local width, the
    largest such distance among the vertices at that u.
    """
    from scipy.spatial import cKDTree

    v3 = np.asarray(mesh.vertices)
    line = _mune_line(v3)
    seg = np.diff(line, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=-1))])
    _, j = cKDTree(line).query(v3[:, :2])
    j = np.clip(j, 0, len(seg) - 1)
    # foot point on segment j (and the one before, whichever is closer)
    best_t = np.zeros(len(v3))
    best_d = np.full(len(v3), np.inf)
    best_j = j.copy()
    for jj in (np.maximum(j - 1, 0), j):
        a, d = line[jj], seg[jj]
        t = np.clip(np.sum((v3[:, :2] - a) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-30), 0, 1)
        dist = np.linalg.norm(v3[:, :2] - (a + t[:, None] * d), axis=-1)
        better = dist < best_d
        best_t, best_d, best_j = np.where(better, t, best_t), np.where(better, dist, best_d), \
            np.where(better, jj, best_j)
    arc = s[best_j] + best_t * np.linalg.norm(seg[best_j], axis=-1)
    u = arc / s[-1]
    # signed distance: toward −Y of the line's normal is toward the ha
    d = seg[best_j] / np.maximum(np.linalg.norm(seg[best_j], axis=-1, keepdims=True), 1e-30)
    normal = np.stack([d[:, 1], -d[:, 0]], -1)
    foot = line[best_j] + best_t[:, None] * seg[best_j]
    dist = np.sum((v3[:, :2] - foot) * normal, -1)
    # the outline: in each slab of u, the vertex farthest from the mune, at its own u
    edges = np.linspace(0, 1, bins + 1)
    k = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, bins - 1)
    order = np.lexsort((-dist, k))
    first = order[np.unique(k[order], return_index=True)[1]]
    first = first[dist[first] > 0]
    haba = np.interp(u, u[first], dist[first])
    vv = np.clip(dist / np.maximum(haba, 1e-12), 0.0, 1.0)
    return np.stack([np.clip(u, 0.0, 1.0), vv], -1)


def xatlas_uvs(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy of ``mesh`` cut along xatlas's chart seams, with its packed UVs in [0, 1]²."""
    import xatlas

    vmap, faces, uvs = xatlas.parametrize(np.asarray(mesh.vertices, np.float32),
                                          np.asarray(mesh.faces, np.uint32))
    out = trimesh.Trimesh(np.asarray(mesh.vertices)[vmap], faces.astype(np.int64), process=False,
                          visual=trimesh.visual.TextureVisuals(uv=np.asarray(uvs, np.float64)))
    return out


def uv_stretch(mesh: trimesh.Trimesh) -> tuple[float, float]:
    """``(median, p95)`` L2 stretch of the UVs (Sander et al. 2001) after one scale per UV axis: 1 = isometric.

    Per triangle, Sₛ = ∂p/∂s and Sₜ = ∂p/∂t (Sander et al.'s formulas); the
    UV axes are first scaled by the area-weighted median |Sₛ| and |Sₜ| (a
    blade's map is deliberately longer along u than across v); each
    triangle's L2 stretch is sqrt((|Sₛ|² + |Sₜ|²)/2) and the surface-area
    weighted median and 95th percentile are returned (Sander et al.'s mean
    over the surface is dominated by the few near-collapsed triangles of a cap
    or a tip fan). Triangles of zero UV area are left out.
    """
    uv = np.asarray(mesh.visual.uv, np.float64)
    p = np.asarray(mesh.vertices)[mesh.faces]
    t = uv[mesh.faces]
    A3 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=-1) / 2
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    Auv = (d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]) / 2
    ok = np.abs(Auv) > 1e-12 * max(float(np.abs(Auv).max()), 1e-300)
    if not ok.any():
        return float("inf"), float("inf")
    d1, d2, Auv, q = d1[ok], d2[ok], Auv[ok, None], p[ok]
    Ss = np.linalg.norm(((q[:, 1] - q[:, 0]) * d2[:, 1:2] - (q[:, 2] - q[:, 0]) * d1[:, 1:2]) / (2 * Auv), axis=-1)
    St = np.linalg.norm(((q[:, 2] - q[:, 0]) * d1[:, 0:1] - (q[:, 1] - q[:, 0]) * d2[:, 0:1]) / (2 * Auv), axis=-1)
    w = A3[ok]

    def wquantile(x, q):
        o = np.argsort(x)
        c = np.cumsum(w[o])
        return max(float(x[o][min(np.searchsorted(c, q * c[-1]), len(x) - 1)]), 1e-300)

    per = np.sqrt(((Ss / wquantile(Ss, 0.5)) ** 2 + (St / wquantile(St, 0.5)) ** 2) / 2)
    return wquantile(per, 0.5), wquantile(per, 0.95)
