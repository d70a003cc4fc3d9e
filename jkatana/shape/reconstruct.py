"""Scan → smoothed mesh: Bezier height fields over the blade's UVs or a scan's own view plane.

Two paths:

- :func:`reconstruct_blade`: merged scan points of a blade whose outline
  measures are known (a :class:`~jkatana.shape.katana.KatanaSpec`) → each face
  (omote z ≥ 0, ura z < 0) is a height field z(u, v) over the blade's own
  UVs, with patch breaks on the shinogi and the roof's foot so that those
  creases stay sharp; the tessellated mesh's UVs are the reflectance map's.
- :func:`smooth_height_field`: any single-view scan (a range image, a
  triangulated scan mesh) → a height field over its principal plane (PCA),
  UVs normalised to the bounding box.

:func:`surface_error` measures a mesh against a reference mesh (RMS and
Hausdorff distance, both directions, via :func:`trimesh.proximity.closest_point`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from jkatana.errors import InputError
from jkatana.shape.bezier import BezierSurface, FitInfo, fit_bezier, grid_mesh
from jkatana.shape.katana import KatanaSpec, blade_uv, blade_xy


@dataclass
class Reconstruction:
    mesh: trimesh.Trimesh
    surfaces: dict[str, BezierSurface]
    info: dict[str, FitInfo]


def reconstruct_blade(points: np.ndarray, spec: KatanaSpec = KatanaSpec(), *, degree: int = 3,
                      patches: tuple[int, int] = (40, 6), smoothness: float = 1e-5,
                      resolution: tuple[int, int] = (320, 40)) -> Reconstruction:
    """Fit both faces of a merged blade scan and tessellate a closed mesh with the map's UVs.

    **Arguments:**

    - `points`: (N, 3) registered scan points in the blade frame (metres); refused
      (:class:`InputError`) unless 90 % of them lie within the outline and thickness of `spec`.
    - `spec`: the blade's outline measures (for the UV parameterisation).
    - `degree`, `patches`: Bezier degree and patch count (along u, across v
      between the creases; the v breaks always include the roof foot and the shinogi).
    - `smoothness`: second-difference weight (see :func:`~jkatana.shape.bezier.fit_bezier`).
    - `resolution`: tessellation rings along u and columns across v per face.
    """
    pts = np.asarray(points, float)
    uv, inside = _blade_uv_of_scan(pts, spec)
    roof = spec.mune_height / (0.5 * (spec.motohaba + spec.sakihaba))
    vb = [0.0, roof, spec.shinogi_position]
    vb += list(np.linspace(spec.shinogi_position, 1.0, max(2, patches[1]) + 1)[1:])
    ub = np.linspace(0.0, 1.0, patches[0] + 1)
    surfaces, info = {}, {}
    for name, sel in (("omote", pts[:, 2] >= 0), ("ura", pts[:, 2] < 0)):
        m = inside & sel
        if m.sum() < 100:
            raise InputError(f"only {int(m.sum())} scan points on the {name} face", field="points")
        surf, fi = fit_bezier(uv[m, 0], np.clip(uv[m, 1], 0, 1), pts[m, 2], degree=degree,
                              breaks_s=ub, breaks_t=vb, smoothness=smoothness)
        surfaces[name], info[name] = surf, fi
    mesh = _closed_blade_mesh(spec, surfaces, vb, resolution)
    return Reconstruction(mesh, surfaces, info)


def _blade_uv_of_scan(pts: np.ndarray, spec: KatanaSpec):
    """The scan points' blade UVs and which lie within the outline; :class:`InputError` unless they are finite
    (N, 3) points, 90 % of them within the outline and the thickness of ``spec``."""
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise InputError(f"need (N, 3) points, got {pts.shape}", field="points")
    if not np.all(np.isfinite(pts)):
        raise InputError("points contain NaN or infinite values", field="points")
    uv = blade_uv(spec, pts[:, :2])
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= 1) & (uv[:, 1] >= -0.02) & (uv[:, 1] <= 1.02)
    thin = np.abs(pts[:, 2]) <= spec.kasane
    fits = float(np.mean(inside & thin))
    if fits < 0.9:
        ext = " × ".join(f"{e:.3g}" for e in np.ptp(pts, axis=0))
        raise InputError(f"only {100 * fits:.0f}% of the scan points lie within the built-in katana's "
                         f"outline (scan extents {ext} m; the katana is {spec.nagasa:g} m along +X, edge "
                         f"toward −Y, flats ±Z): not a fit. For any mesh run `jkatana shape MESH` "
                         f"without --katana-fit", field="points")
    return uv, inside


def _closed_blade_mesh(spec: KatanaSpec, surfaces: dict, vb, resolution: tuple[int, int]) -> trimesh.Trimesh:
    """Both faces' height fields tessellated over the blade's UVs (columns on the v breaks, so the creases stay
    sharp), joined at the mune and the edge, closed by a cap at the machi and a fan at the tip."""
    n_u, n_v = resolution
    u = np.linspace(0, 1, n_u)
    u[-1] = 1 - 1e-4  # the tip ring collapses; keep it a hair short and close with a point
    v = np.sort(np.unique(np.concatenate([np.linspace(0, 1, n_v), vb])))
    U, Vv = np.meshgrid(u, v, indexing="ij")
    xy = blade_xy(spec, U, Vv)
    zo = surfaces["omote"](U.ravel(), Vv.ravel()).reshape(U.shape)
    zu = surfaces["ura"](U.ravel(), Vv.ravel()).reshape(U.shape)
    # the faces meet at the mune and the edge: close them at their mean height there
    for col in (0, -1):
        mid = 0.5 * (zo[:, col] + zu[:, col])
        zo[:, col] = zu[:, col] = mid
    uvg = np.stack([U, Vv], -1)
    vo, fo, uo = grid_mesh(np.concatenate([xy, zo[..., None]], -1), uvg, flip=True)
    vu, fu, uu = grid_mesh(np.concatenate([xy, zu[..., None]], -1), uvg, flip=False)
    V = np.concatenate([vo, vu])
    F = np.concatenate([fo, fu + len(vo)])
    UV = np.concatenate([uo, uu])
    R, C = U.shape
    # machi cap: the first ring's loop (omote mune→ha, ura ha→mune) fanned to its centre
    ring_o = np.arange(C)
    ring_u = len(vo) + np.arange(C)[::-1]
    loop = np.concatenate([ring_o, ring_u[1:-1]])
    centre = len(V)
    V = np.concatenate([V, V[loop].mean(0, keepdims=True)])
    UV = np.concatenate([UV, [[0.0, 0.5]]])
    cap = np.stack([np.full(len(loop), centre), np.roll(loop, -1), loop], -1)
    # tip: fan both last rings to the tip point
    tip = len(V)
    tip_xy = blade_xy(spec, np.array([1.0]), np.array([0.0]))[0]
    z_tip = 0.5 * (zo[-1].mean() + zu[-1].mean())
    V = np.concatenate([V, [[tip_xy[0], tip_xy[1], z_tip]]])
    UV = np.concatenate([UV, [[1.0, 0.5]]])
    last_o = (R - 1) * C + np.arange(C)
    last_u = len(vo) + last_o
    fan = np.concatenate([np.stack([last_o[:-1], np.full(C - 1, tip), last_o[1:]], -1)[:, ::-1],
                          np.stack([last_u[:-1], np.full(C - 1, tip), last_u[1:]], -1)])
    F = np.concatenate([F, cap, fan])
    mesh = trimesh.Trimesh(V, F, process=False, visual=trimesh.visual.TextureVisuals(uv=UV))
    mesh.merge_vertices(merge_tex=False, merge_norm=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if mesh.volume < 0:
        mesh.invert()
    mesh.metadata["units"] = "m"
    return mesh


def principal_frame(points: np.ndarray) -> np.ndarray:
    """A 4×4 transform taking points to their PCA frame (z = least-variance axis, toward the viewer)."""
    c = points.mean(0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    R = vt.copy()
    if np.linalg.det(R) < 0:
        R[2] *= -1
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ c
    return T


def smooth_height_field(points: np.ndarray, *, degree: int = 3, patches: tuple[int, int] = (12, 12),
                        smoothness: float = 1e-4, resolution: int = 120,
                        frame: np.ndarray | None = None, mask_radius: float | None = None,
                        creases_y: list[float] = ()):
    """Fit a single-view scan as a height field over its principal plane; returns (mesh, surface, info).

    Grid cells farther than ``mask_radius`` (default: 2 × the median point
    spacing × grid ratio) from any scan point are dropped, so holes and the
    outline stay open rather than being filled by the smoothness term.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 16:
        raise InputError(f"need at least 16 (N, 3) points, got {pts.shape}", field="points")
    if not np.all(np.isfinite(pts)):
        raise InputError("points contain NaN or infinite values", field="points")
    T = principal_frame(pts) if frame is None else frame
    local = trimesh.transformations.transform_points(pts, T)
    lo, hi = local[:, :2].min(0), local[:, :2].max(0)
    if np.any(hi - lo <= 0):
        raise InputError("degenerate scan: the points span no area", field="points")
    s = (local[:, 0] - lo[0]) / (hi[0] - lo[0])
    t = (local[:, 1] - lo[1]) / (hi[1] - lo[1])
    bt = np.linspace(0, 1, patches[1] + 1)
    for y in creases_y:
        c = (y - lo[1]) / (hi[1] - lo[1])
        if 0 < c < 1:
            inner = np.arange(1, len(bt) - 1)
            if len(inner):
                bt[inner[np.argmin(np.abs(bt[inner] - c))]] = c
    bt = np.unique(bt)
    surf, info = fit_bezier(s, t, local[:, 2], degree=degree, patches=patches, smoothness=smoothness,
                            breaks_s=np.linspace(0, 1, patches[0] + 1), breaks_t=bt)
    aspect = (hi[1] - lo[1]) / (hi[0] - lo[0])
    n_s, n_t = resolution, max(2, int(round(resolution * aspect)))
    S, Tt = np.meshgrid(np.linspace(0, 1, n_s), np.linspace(0, 1, n_t), indexing="ij")
    Z = surf(S.ravel(), Tt.ravel()).reshape(S.shape)
    XY = np.stack([lo[0] + S * (hi[0] - lo[0]), lo[1] + Tt * (hi[1] - lo[1])], -1)
    local_grid = np.concatenate([XY, Z[..., None]], -1)
    V, F, UV = grid_mesh(local_grid, np.stack([S, Tt], -1), flip=False)
    tree = cKDTree(local[:, :2])
    if mask_radius is None:
        spacing = np.median(tree.query(local[:: max(1, len(local) // 2000), :2], k=2)[0][:, 1])
        mask_radius = 2.0 * max(spacing, (hi[0] - lo[0]) / n_s)
    near = tree.query(V[:, :2], distance_upper_bound=mask_radius)[0] < np.inf
    F = F[near[F].all(1)]
    world = trimesh.transformations.transform_points(V, np.linalg.inv(T))
    mesh = trimesh.Trimesh(world, F, process=False, visual=trimesh.visual.TextureVisuals(uv=UV))
    mesh.remove_unreferenced_vertices()
    return mesh, surf, info


def point_error(points: np.ndarray, reference: trimesh.Trimesh) -> dict[str, float]:
    """RMS and max distance (metres) from points to a reference surface."""
    _, d, _ = trimesh.proximity.closest_point(reference, np.asarray(points, float))
    return {"rms": float(np.sqrt(np.mean(d**2))), "max": float(d.max()),
            "p50": float(np.median(d)), "p90": float(np.percentile(d, 90)), "n": int(len(d))}


def surface_error(mesh: trimesh.Trimesh, reference: trimesh.Trimesh, *, samples: int = 20000,
                  seed: int = 0) -> dict[str, float]:
    """Symmetric distances (metres) between two surfaces from area-uniform samples of both.

    ``rms`` is the RMS over both directions, ``hausdorff`` the larger of the
    two one-sided maxima (sampled, so a slight underestimate).
    """
    a = trimesh.sample.sample_surface(mesh, samples, seed=seed)[0]
    b = trimesh.sample.sample_surface(reference, samples, seed=seed + 1)[0]
    ea, eb = point_error(a, reference), point_error(b, mesh)
    return {"rms": float(np.sqrt(0.5 * (ea["rms"] ** 2 + eb["rms"] ** 2))),
            "hausdorff": max(ea["max"], eb["max"]), "mesh_to_ref_max": ea["max"],
            "ref_to_mesh_max": eb["max"]}
