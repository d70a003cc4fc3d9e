"""Any mesh into the render pipeline: units, blade frame, cleaning, smoothing, UVs.

A user's own scan (photogrammetry, structured light) arrives in unknown units
and an arbitrary frame, with duplicated vertices, slivers and small holes, and
usually without texture coordinates. :func:`prepare_mesh` turns it into a mesh
the renderer reads:

- **Units.** glTF is metres by specification (Khronos glTF 2.0, §3.4); OBJ,
  PLY and STL carry no unit, so :func:`guess_units` picks the first of m, cm,
  mm whose reading puts the longest side in the range of a hand-held object
  (5 cm … 3 m) and says so; ``units=`` overrides it.
- **Frame.** A blade-like mesh (one long, one thin axis) is turned into the
  built-in blade's frame (:mod:`jkatana.shape.katana`): principal axes
  (PCA of the area-weighted surface), long axis → X with the narrower end (the
  kissaki) at +X, the thick side (the mune) toward +Y and the thin one (the
  ha) toward −Y, the flats facing ±Z; then the chord from the machi's mune
  point to the tip is laid on the X axis with the machi at the origin.
- **Cleaning.** Coincident vertices merged, degenerate and duplicate faces
  dropped, boundary loops of at most ``max_hole_edges`` edges closed by a fan
  around their centroid, face winding made consistent (trimesh's repair);
  vertices split along creases so that normals are smooth on faces and sharp
  on ridges (:func:`trimesh.graph.smooth_shade`).
- **Smoothing** (optional): Taubin's λ|μ filter (Taubin, "A signal processing
  approach to fair surface design", SIGGRAPH 1995) through
  :func:`trimesh.smoothing.filter_taubin`, with the vertices of creases
  (dihedral angle above ``crease_deg``) held in place so ridges stay sharp.
- **UVs.** ``"blade"``: the built-in blade's convention, u the arc-length
  fraction along the mune line (0 at the machi, 1 at the tip), v the distance
  from the mune over the local width (0 at the mune, 1 at the ha), the same
  (u, v) on both flats so one reflectance map serves both; ``"xatlas"``: a
  general chart unwrap and packing by xatlas (Young, github.com/jpcy/xatlas,
  after Lévy et al., "Least squares conformal maps", SIGGRAPH 2002) for
  anything that is not a blade; ``"none"``: no UVs (uniform materials only).

:func:`~jkatana.shape.uv.uv_stretch` reports the parameterisation's L2 stretch (Sander, Snyder,
Gortler & Hoppe, "Texture mapping progressive meshes", SIGGRAPH 2001): 1 for
an isometry up to one scale per UV axis, larger the more the UVs stretch.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from jkatana.errors import InputError
from jkatana.shape.uv import blade_uvs, uv_stretch, xatlas_uvs

UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "in": 0.0254}
HAND_HELD_M = (0.05, 3.0)
MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


@dataclass
class ShapeReport:
    """What :func:`prepare_mesh` did, for the user: sizes, the unit assumed and why, frame, UVs."""

    source: str
    vertices_in: int
    faces_in: int
    extents_in: list[float]
    units: str
    units_reason: str
    extents_m: list[float] = field(default_factory=list)
    frame: str = "kept"
    transform: list[list[float]] = field(default_factory=list)
    cleaning: dict = field(default_factory=dict)
    smoothing: dict = field(default_factory=dict)
    uv: str = "none"
    uv_stretch: tuple[float, float] | None = None
    vertices_out: int = 0
    faces_out: int = 0
    seconds: float = 0.0

    def lines(self) -> list[str]:
        ex = " × ".join(f"{e:.4g}" for e in self.extents_in)
        exm = " × ".join(f"{e * 1e3:.1f}" for e in self.extents_m)
        c = self.cleaning
        out = [f"{self.source}: {self.vertices_in} vertices, {self.faces_in} faces, principal extents {ex} (file units)",
               f"units: {self.units} ({self.units_reason}); size {exm} mm",
               f"frame: {self.frame}"]
        if c:
            out.append(f"cleaned: {c['merged_vertices']} vertices merged, {c['dropped_faces']} degenerate/"
                       f"duplicate faces dropped, {c['holes_filled']} holes filled, "
                       f"{c['holes_left']} boundary loops left open")
        if self.smoothing:
            s = self.smoothing
            out.append(f"smoothed: Taubin, {s['iterations']} iterations, {s['pinned']} crease vertices held")
        stretch = "" if self.uv_stretch is None else f", L2 stretch median {self.uv_stretch[0]:.3f}, 95th percentile {self.uv_stretch[1]:.3f}"
        out.append(f"UVs: {self.uv}{stretch}; {self.vertices_out} vertices, {self.faces_out} faces")
        return out


# ----------------------------------------------------------------------------- reading, units


def read_mesh(path: str | Path) -> trimesh.Trimesh:
    """One triangle mesh from a file trimesh reads (scenes are concatenated in their world frame)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("mesh file not found", path=path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"not a mesh file (expected one of {', '.join(MESH_SUFFIXES)})", path=path)
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for bad files
        raise InputError(f"not a readable mesh ({type(err).__name__}: {err})", path=path) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError("no triangles in the file", path=path)
    if not np.all(np.isfinite(mesh.vertices)):
        bad = int(np.argmax(~np.all(np.isfinite(mesh.vertices), axis=1)))
        raise InputError(f"vertex {bad} is NaN or infinite", path=path, row=bad)
    return mesh


def guess_units(extents, suffix: str = "") -> tuple[str, str]:
    """``(unit, reason)``: the unit a file's numbers are most likely in, and why.

    glTF is metres by specification. Otherwise the first of m, cm, mm that puts
    the longest side within :data:`HAND_HELD_M`; metres when none does.
    """
    longest = float(np.max(extents))
    if suffix.lower() in (".glb", ".gltf"):
        return "m", "glTF is in metres by specification"
    for unit in ("m", "cm", "mm"):
        size = longest * UNITS[unit]
        if HAND_HELD_M[0] <= size <= HAND_HELD_M[1]:
            others = [u for u in ("m", "cm", "mm") if u != unit]
            return unit, (f"assumed: the file states none; longest side {longest:.4g} reads as "
                          f"{size:.3g} m in {unit} (a hand-held object), not {others[0]} or {others[1]}; "
                          f"give --units if wrong")
    return "m", (f"assumed: the file states none and no unit puts the longest side {longest:.4g} within "
                 f"{HAND_HELD_M[0]}–{HAND_HELD_M[1]} m; give --units")


# ----------------------------------------------------------------------------- cleaning


def _boundary_loops(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    """Closed boundary loops (vertex index cycles) of a mesh; open chains are skipped."""
    import networkx as nx

    edges = mesh.edges_sorted
    single = trimesh.grouping.group_rows(edges, require_count=1)
    if len(single) == 0:
        return []
    g = nx.Graph()
    g.add_edges_from(edges[single])
    loops = []
    for comp in nx.connected_components(g):
        sub = g.subgraph(comp)
        if all(d == 2 for _, d in sub.degree()):
            cyc = [e[0] for e in nx.find_cycle(sub)]
            loops.append(np.asarray(cyc, np.int64))
    return loops


def clean_mesh(mesh: trimesh.Trimesh, *, max_hole_edges: int = 32) -> tuple[trimesh.Trimesh, dict]:
    """Merged vertices, no degenerate or duplicate faces, small holes closed, consistent winding."""
    m = trimesh.Trimesh(mesh.vertices.copy(), mesh.faces.copy(), process=False)
    n_v = len(m.vertices)
    m.merge_vertices(digits_vertex=max(3, 8 - int(math.floor(math.log10(max(m.scale, 1e-12))))))
    merged = n_v - len(m.vertices)
    n_f = len(m.faces)
    m.update_faces(m.nondegenerate_faces(height=1e-9 * m.scale))
    m.update_faces(m.unique_faces())
    m.remove_unreferenced_vertices()
    dropped = n_f - len(m.faces)
    loops = _boundary_loops(m)
    small = [lp for lp in loops if len(lp) <= max_hole_edges]
    if small:
        V, F = [m.vertices], [m.faces]
        nxt = len(m.vertices)
        # orient each fan like the face that owns the loop's first edge
        edge_face = {tuple(e): f for e, f in zip(m.edges, m.edges_face)}
        for lp in small:
            a, b = int(lp[0]), int(lp[1])
            ring = lp if (b, a) in edge_face else lp[::-1]  # hole edges run opposite to the mesh's
            c = m.vertices[ring].mean(0)
            V.append(c[None])
            F.append(np.stack([np.roll(ring, -1), ring, np.full(len(ring), nxt)], -1))
            nxt += 1
        m = trimesh.Trimesh(np.concatenate(V), np.concatenate(F), process=False)
    trimesh.repair.fix_winding(m)
    if m.is_watertight and m.volume < 0:
        m.invert()
    return m, {"merged_vertices": int(merged), "dropped_faces": int(dropped),
               "holes_filled": len(small), "holes_left": len(loops) - len(small)}


def smooth_mesh(mesh: trimesh.Trimesh, *, iterations: int = 10, crease_deg: float = 30.0) -> dict:
    """Taubin λ|μ smoothing in place, holding the vertices of creases sharper than ``crease_deg``."""
    if iterations <= 0:
        return {}
    import scipy.sparse as sp

    angles = mesh.face_adjacency_angles
    crease = mesh.face_adjacency_edges[angles > math.radians(crease_deg)]
    pinned = np.unique(crease)
    # umbrella operator whose crease rows are the identity: those vertices do not move
    lap = trimesh.smoothing.laplacian_calculation(mesh, equal_weight=True).tolil()
    for i in pinned:
        lap.rows[i], lap.data[i] = [int(i)], [1.0]
    trimesh.smoothing.filter_taubin(mesh, lamb=0.5, nu=0.53, iterations=int(iterations),
                                    laplacian_operator=sp.csr_matrix(lap))
    return {"iterations": int(iterations), "pinned": int(len(pinned)), "crease_deg": crease_deg}


# ----------------------------------------------------------------------------- blade frame


def _surface_samples(mesh: trimesh.Trimesh, n: int = 20000) -> np.ndarray:
    """Area-uniform surface points (fixed seed): PCA of these does not depend on vertex density."""
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=0)
    return np.asarray(pts)


def principal_extents(mesh: trimesh.Trimesh) -> np.ndarray:
    """Extents along the principal axes of the surface (longest first): independent of the file's frame."""
    pts = _surface_samples(mesh, 5000)
    _, _, vt = np.linalg.svd(pts - pts.mean(0), full_matrices=False)
    v = np.asarray(mesh.vertices) @ vt.T
    return np.ptp(v, axis=0)


def is_blade_like(extents_sorted) -> bool:
    """One axis ≥ 5× the next and the thinnest ≤ ½ of the middle one: a blade's proportions."""
    a, b, c = sorted(extents_sorted, reverse=True)
    return bool(a >= 5 * b and c <= 0.5 * b)


def _end_width(p: np.ndarray, at_max: bool, frac: float = 0.06) -> float:
    x = p[:, 0]
    lo, hi = x.min(), x.max()
    L = hi - lo
    sel = x >= hi - frac * L if at_max else x <= lo + frac * L
    return float(np.ptp(p[sel, 1])) if sel.sum() > 2 else 0.0


def blade_frame(mesh: trimesh.Trimesh) -> tuple[np.ndarray, str]:
    """4×4 transform into the built-in blade's frame (see the module docstring) and a description."""
    pts = _surface_samples(mesh)
    c = pts.mean(0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    R = vt.copy()  # rows: long, width, thin
    p = (pts - c) @ R.T
    # the narrow end is the tip: +X
    if _end_width(p, at_max=False) < _end_width(p, at_max=True):
        R[0] *= -1
        p[:, 0] *= -1
    # across: the thin side (ha) toward −Y, judged by the thickness near each side in the middle third
    x = p[:, 0]
    mid = np.abs(x - np.median(x)) < np.ptp(x) / 6
    q = p[mid]
    y0, y1 = np.percentile(q[:, 1], [2, 98])
    t = (q[:, 1] - y0) / max(y1 - y0, 1e-12)
    thick_hi = np.ptp(q[t > 0.8, 2]) if (t > 0.8).sum() > 2 else 0.0
    thick_lo = np.ptp(q[t < 0.2, 2]) if (t < 0.2).sum() > 2 else 0.0
    if thick_hi < thick_lo:
        R[1] *= -1
    R[2] = np.cross(R[0], R[1])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ c
    # chord: machi's mune point → tip on the X axis, machi at the origin
    v = trimesh.transform_points(mesh.vertices, T)
    x = v[:, 0]
    L = np.ptp(x)
    tip = v[np.argmax(x)]
    end = x <= x.min() + 0.02 * L
    machi = v[end][np.argmax(v[end, 1])]
    d = tip[:2] - machi[:2]
    a = math.atan2(d[1], d[0])
    Rz = trimesh.transformations.rotation_matrix(-a, [0, 0, 1])
    Tm = trimesh.transformations.translation_matrix([-machi[0], -machi[1], -machi[2]])
    T = Rz @ Tm @ T
    desc = (f"blade: long axis → +X (tip at +X, length {math.hypot(*d):.4g}), thick side (mune) → +Y, "
            "flats → ±Z, machi's mune point at the origin")
    return T, desc


# ----------------------------------------------------------------------------- pipeline


def prepare_mesh(mesh: trimesh.Trimesh, *, source: str = "mesh", suffix: str = "", units: str = "auto",
                 frame: str = "auto", clean: bool = True, smooth: int = 0, crease_deg: float = 20.0,
                 uv: str = "auto", max_hole_edges: int = 32) -> tuple[trimesh.Trimesh, ShapeReport]:
    """A user's mesh → metres, blade frame (or kept), cleaned, optionally smoothed, with UVs.

    **Arguments:**

    - `units`: ``"auto"`` (:func:`guess_units`) or one of :data:`UNITS`.
    - `frame`: ``"auto"`` (blade frame when :func:`is_blade_like`), ``"blade"`` (always) or ``"keep"``.
    - `uv`: ``"auto"`` (``"blade"`` in the blade frame, else ``"xatlas"``), ``"blade"``, ``"xatlas"``
      or ``"none"``.
    - `crease_deg`: edges whose faces meet at more than this angle are creases: held by the
      smoothing and given split vertices (sharp normals), as the built-in blade's panels are.
    """
    t0 = time.perf_counter()
    ext = principal_extents(mesh)
    if units == "auto":
        unit, reason = guess_units(ext, suffix)
    elif units in UNITS:
        unit, reason = units, "given"
    else:
        raise InputError(f"unknown unit {units!r} (one of {', '.join(UNITS)}, auto)", field="units")
    rep = ShapeReport(source, len(mesh.vertices), len(mesh.faces), ext.tolist(), unit, reason)
    m = trimesh.Trimesh(mesh.vertices * UNITS[unit], mesh.faces, process=False)
    if clean:
        m, rep.cleaning = clean_mesh(m, max_hole_edges=max_hole_edges)
    if frame not in ("auto", "blade", "keep"):
        raise InputError(f"unknown frame {frame!r} (auto, blade, keep)", field="frame")
    blade = frame == "blade" or (frame == "auto" and is_blade_like(principal_extents(m)))
    T = np.eye(4)
    if blade:
        T, rep.frame = blade_frame(m)
        m.apply_transform(T)
    else:
        rep.frame = "kept (the file's own axes)" + ("" if frame == "keep" else
                                                    ": not blade-like (no axis ≥ 5× the others)")
    rep.transform = (T @ np.diag([UNITS[unit]] * 3 + [1.0])).tolist()
    if smooth:
        rep.smoothing = smooth_mesh(m, iterations=smooth, crease_deg=crease_deg)
    # vertices split along creases: smooth normals on the flats, sharp at ridges (shinogi, edge)
    m = trimesh.graph.smooth_shade(m, angle=math.radians(crease_deg), facet_minarea=None)
    m = trimesh.Trimesh(m.vertices, m.faces, process=False)
    if uv == "auto":
        uv = "blade" if blade else "xatlas"
    if uv == "blade":
        if not blade:
            raise InputError("blade UVs need the blade frame (not --keep-frame)", field="uv")
        m.visual = trimesh.visual.TextureVisuals(uv=blade_uvs(m))
    elif uv == "xatlas":
        m = xatlas_uvs(m)
    elif uv != "none":
        raise InputError(f"unknown UV method {uv!r} (auto, blade, xatlas, none)", field="uv")
    rep.uv = uv
    if uv != "none":
        rep.uv_stretch = uv_stretch(m)
    m.metadata["units"] = "m"
    rep.extents_m = np.asarray(m.extents).tolist()
    rep.vertices_out, rep.faces_out = len(m.vertices), len(m.faces)
    rep.seconds = time.perf_counter() - t0
    return m, rep


def preview_png(mesh: trimesh.Trimesh, path: str | Path, title: str = "", credit: str = "") -> Path:
    """A two-panel PNG: the mesh seen along its thinnest axis (shaded by its normals) and its UV layout.

    `credit` is printed under the picture (a scan's licence may require attribution on every image).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from jkatana.io.atomic import atomic_path

    v = np.asarray(mesh.vertices)
    ax_thin = int(np.argmin(mesh.extents))
    a, b = [i for i in range(3) if i != ax_thin]
    if mesh.extents[a] < mesh.extents[b]:
        a, b = b, a
    fn = mesh.face_normals
    shade = 0.25 + 0.75 * np.abs(fn[:, ax_thin] * 0.8 + fn[:, b] * 0.6)
    order = np.argsort(v[mesh.faces][:, :, ax_thin].mean(1))
    uv = getattr(mesh.visual, "uv", None)
    has_uv = uv is not None and len(uv) == len(v)
    fig, axes = plt.subplots(1, 2 if has_uv else 1, figsize=(12, 4.5), squeeze=False)
    ax = axes[0, 0]
    tri = v[mesh.faces][order][:, :, [a, b]]
    ax.add_collection(PolyCollection(tri, facecolors=plt.cm.gray(shade[order]), edgecolors="none"))
    ax.set_xlim(v[:, a].min(), v[:, a].max())
    ax.set_ylim(v[:, b].min(), v[:, b].max())
    ax.set_aspect("equal")
    ax.set_xlabel(f"{'xyz'[a]} (m)")
    ax.set_ylabel(f"{'xyz'[b]} (m)")
    ax.set_title(title or "mesh")
    if has_uv:
        ax = axes[0, 1]
        t = np.asarray(uv)[mesh.faces]
        step = max(1, len(t) // 40000)
        ax.add_collection(PolyCollection(t[::step], facecolors="none", edgecolors="k", linewidths=0.1))
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_xlabel("u")
        ax.set_ylabel("v")
        ax.set_title("UV layout")
    fig.tight_layout()
    if credit:
        fig.text(0.01, 0.005, credit, fontsize=7, color="0.3")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path
