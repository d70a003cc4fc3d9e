"""Range scans: read them, simulate a triangulation scanner, register and merge sections.

The paper (Mochizuki et al., §3.1, §4.1) scans the blade, sprayed matte
white, with a Konica Minolta Vivid 910 laser range finder (640×480 range
images, triangulation) in ~5 cm sections and merges them. jkatana reads real
scans through trimesh (PLY, OBJ, STL, XYZ/TXT point lists) and simulates that
scanner on any mesh, so the merge and smoothing can be checked against a known
surface.

Registration: each section comes with an unknown rigid pose. A coarse initial
alignment (the nominal stage position, optionally principal axes) is refined by
trimmed ICP: nearest neighbours (scipy cKDTree), correspondences beyond a
distance threshold dropped (so only the overlap counts), and the rigid
transform of each step solved by :func:`trimesh.registration.procrustes`
(Kabsch/Umeyama SVD). Besl & McKay, "A method for registration of 3-D
shapes", IEEE PAMI 14(2), 1992; Chetverikov et al., "The trimmed iterative
closest point algorithm", ICPR 2002.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from jkatana.errors import InputError


@dataclass
class Scan:
    """One range section: points (N, 3) in the scanner's frame, with provenance.

    `pose` maps scanner-frame points to the object frame when known (a
    simulation's ground truth, or the result of registration); `side` is +1
    for a view from +Z (omote), −1 from −Z (ura); `section` its index.
    """

    points: np.ndarray
    section: int = 0
    side: int = 1
    pose: np.ndarray | None = None
    name: str = ""
    meta: dict = field(default_factory=dict)


def _check_points(points: np.ndarray, where) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points must be (N, 3), got shape {pts.shape}", path=where)
    if len(pts) == 0:
        raise InputError("empty scan: no points", path=where)
    bad = ~np.all(np.isfinite(pts), axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} of {len(pts)} points are NaN or infinite "
                         f"(first at row {int(np.argmax(bad))})", path=where, row=int(np.argmax(bad)))
    return pts


def read_scan(path: str | Path) -> Scan:
    """Read a scan (mesh or point cloud) through trimesh; its vertices are the points.

    XYZ/TXT/CSV files are whitespace or comma separated ``x y z`` rows. Raises
    :class:`InputError` for a missing file, an empty scan, NaN points or a
    degenerate mesh (all faces of zero area).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("scan file not found", path=path)
    suffix = path.suffix.lower()
    if suffix in (".xyz", ".txt", ".csv", ".pts"):
        if not path.read_text(errors="replace").strip():
            raise InputError("empty scan: no points", path=path)
        try:
            data = np.loadtxt(path, delimiter="," if suffix == ".csv" else None, ndmin=2,
                              usecols=(0, 1, 2))
        except ValueError as err:
            raise InputError(f"not an x y z point list ({err})", path=path) from None
        if data.size == 0:
            raise InputError("empty scan: no points", path=path)
        return Scan(_check_points(data, path), name=path.name)
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as err:  # trimesh raises many kinds
        raise InputError(f"not a readable mesh or point cloud ({err})", path=path) from None
    if isinstance(loaded, trimesh.Scene):
        geoms = list(loaded.geometry.values())
        if not geoms:
            raise InputError("empty scan: the file holds no geometry", path=path)
        loaded = trimesh.util.concatenate(geoms) if len(geoms) > 1 else geoms[0]
    pts = np.asarray(getattr(loaded, "vertices", np.empty((0, 3))))
    scan = Scan(_check_points(pts, path), name=path.name)
    if isinstance(loaded, trimesh.Trimesh) and len(loaded.faces):
        if not np.any(loaded.area_faces > 1e-18):
            raise InputError(f"degenerate mesh: all {len(loaded.faces)} faces have zero area",
                             path=path)
        scan.meta["mesh"] = loaded
    return scan


# ----------------------------------------------------------------------------- simulation


def random_pose(rng: np.random.Generator, angle_deg: float, shift: float,
                centre: np.ndarray) -> np.ndarray:
    """A rigid transform: rotation by N(0, angle) about a random axis through `centre`, then a shift."""
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    angle = np.deg2rad(rng.normal(0.0, angle_deg))
    R = trimesh.transformations.rotation_matrix(angle, axis, point=centre)
    R[:3, 3] += rng.normal(0.0, shift, 3)
    return R


def simulate_scans(mesh: trimesh.Trimesh, *, section_length: float = 0.05, overlap: float = 0.012,
                   resolution: tuple[int, int] = (640, 480), noise: float = 5e-5,
                   dropout: float = 0.02, grazing_cos: float = 0.15, sides: tuple[int, ...] = (1, -1),
                   pose_angle_deg: float = 1.0, pose_shift: float = 0.002,
                   seed: int = 0) -> list[Scan]:
    """Simulate a triangulation scanner capturing ``mesh`` in sections along x.

    Each section is a ``resolution`` (W×H) range image seen along ∓Z over a
    window ``section_length + overlap`` long (parallel projection: the Vivid
    910's field at this distance is nearly telecentric over 6 cm). Depth gets
    Gaussian noise ``noise`` (m); pixels drop out at random (``dropout``) and
    where the surface is seen at grazing angles (|cos| < ``grazing_cos``), as
    a triangulation scanner loses the laser stripe there. Each section's
    points are then moved by an unknown rigid pose (rotation N(0, angle), shift
    N(0, shift)) — the blade re-clamped between sections; both sides of one
    section share that pose. Section 0 keeps the identity (the reference frame).

    **Returns:** a list of :class:`Scan` whose ``pose`` is the true transform
    scanner → object (the inverse of the perturbation).
    """
    if len(mesh.faces) == 0:
        raise InputError("cannot scan a mesh without faces", field="mesh")
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    n_sec = max(1, int(np.ceil((hi[0] - lo[0]) / section_length)))
    W, H = resolution
    scans = []
    intersector = mesh.ray
    for k in range(n_sec):
        x0 = lo[0] + k * section_length - overlap / 2
        x1 = min(lo[0] + (k + 1) * section_length, hi[0]) + overlap / 2
        inside = (mesh.vertices[:, 0] >= x0) & (mesh.vertices[:, 0] <= x1)
        if not inside.any():
            continue
        ylo, yhi = mesh.vertices[inside, 1].min() - 1e-3, mesh.vertices[inside, 1].max() + 1e-3
        xs = np.linspace(x0, x1, W)
        ys = np.linspace(ylo, yhi, H)
        gx, gy = np.meshgrid(xs, ys)
        pose_err = np.eye(4) if k == 0 else random_pose(
            rng, pose_angle_deg, pose_shift, np.array([(x0 + x1) / 2, (ylo + yhi) / 2, 0.0]))
        for side in sides:
            z0 = hi[2] + 0.1 if side > 0 else lo[2] - 0.1
            origins = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z0)], -1)
            dirs = np.broadcast_to([0.0, 0.0, -float(side)], origins.shape)
            loc, ray_idx, tri_idx = intersector.intersects_location(origins, dirs, multiple_hits=False)
            if len(loc) == 0:
                continue
            cos = np.abs(mesh.face_normals[tri_idx, 2])
            keep = (cos >= grazing_cos) & (rng.random(len(loc)) >= dropout)
            pts = loc[keep].copy()
            pts[:, 2] += rng.normal(0.0, noise, len(pts))
            pts = trimesh.transformations.transform_points(pts, pose_err)
            scans.append(Scan(pts, section=k, side=side, pose=np.linalg.inv(pose_err),
                              name=f"section{k:02d}_{'omote' if side > 0 else 'ura'}",
                              meta={"range_image": (W, H), "window": (x0, x1, ylo, yhi)}))
    if not scans:
        raise InputError("the simulated scanner saw nothing of the mesh", field="mesh")
    return scans


# ----------------------------------------------------------------------------- registration


@dataclass
class Registration:
    """Result of registering one section: transform (scanner → object), fit quality."""

    transform: np.ndarray
    rms: float
    overlap_fraction: float
    iterations: int
    converged: bool


def estimate_normals(points: np.ndarray, tree: cKDTree | None = None, k: int = 10) -> np.ndarray:
    """Unit normals from the PCA of each point's ``k`` nearest neighbours (sign arbitrary)."""
    tree = cKDTree(points) if tree is None else tree
    _, nb = tree.query(points, k=min(k, len(points)))
    q = points[nb] - points[nb].mean(1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", q, q)
    return np.linalg.eigh(cov)[1][:, :, 0]


def _point_to_plane_step(src: np.ndarray, dst: np.ndarray, n: np.ndarray,
                         alpha: float = 0.0) -> np.ndarray:
    """Small-angle rigid step minimising Σ ((R p + t − q) · n)² (Low, UNC TR04-004, 2004)."""
    c = src.mean(0)
    p = src - c
    A = np.concatenate([np.cross(p, n), n], 1)
    b = np.sum((dst - src) * n, 1)
    if alpha > 0:  # plus a weak point-to-point term: damps sliding along flat overlaps
        k = len(p)
        skew = np.zeros((k, 3, 3))
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = p[:, 2], -p[:, 1], p[:, 0]
        skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = -p[:, 2], p[:, 1], -p[:, 0]
        A2 = np.concatenate([skew, np.broadcast_to(np.eye(3), (k, 3, 3))], 2).reshape(-1, 6)
        A = np.concatenate([A, np.sqrt(alpha) * A2])
        b = np.concatenate([b, np.sqrt(alpha) * (dst - src).ravel()])
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    R = trimesh.transformations.euler_matrix(*x[:3], axes="sxyz")
    R[:3, 3] = x[3:]
    to_c, back = np.eye(4), np.eye(4)
    to_c[:3, 3], back[:3, 3] = -c, c
    return back @ R @ to_c


def trimmed_icp(moving: np.ndarray, fixed: np.ndarray, initial: np.ndarray | None = None, *,
                threshold: float = 1e-3, max_iterations: int = 100, tol: float = 1e-8,
                min_overlap: float = 0.05, max_points: int = 20000,
                seed: int = 0, name: str = "section", point_to_plane: bool = False,
                alpha: float = 0.1) -> Registration:
    """Rigidly align ``moving`` onto ``fixed`` using only pairs closer than ``threshold``.

    Each step: nearest neighbours in ``fixed`` (cKDTree), keep pairs within the
    threshold (the overlap), solve the best rigid transform with
    :func:`trimesh.registration.procrustes` (no scale, no reflection).
    Raises :class:`InputError` when fewer than ``min_overlap`` of the points
    find a partner (non-overlapping sections).
    """
    rng = np.random.default_rng(seed)
    if len(moving) > max_points:
        moving = moving[rng.choice(len(moving), max_points, replace=False)]
    tree = cKDTree(fixed)
    normals = estimate_normals(fixed, tree) if point_to_plane else None
    T = np.eye(4) if initial is None else np.asarray(initial, float).copy()
    prev = np.inf
    rms, frac, it = np.inf, 0.0, 0
    converged = False
    # coarse to fine: a wide capture radius first (the initial pose may be mm off), then
    # the working threshold, which keeps only the true overlap
    schedule = [threshold * f for f in (8.0, 4.0, 2.0)]
    for it in range(1, max_iterations + 1):
        thr = schedule[it - 1] if it <= len(schedule) else threshold
        cur = trimesh.transformations.transform_points(moving, T)
        dist, idx = tree.query(cur, distance_upper_bound=thr)
        ok = np.isfinite(dist)
        frac = float(ok.mean())
        if frac < min_overlap or ok.sum() < 6:
            raise InputError(
                f"sections do not overlap: only {frac:.1%} of its points lie within "
                f"{thr * 1e3:.2f} mm of the merged scan (need {min_overlap:.0%})", field=name)
        if point_to_plane and it > len(schedule):
            step = _point_to_plane_step(cur[ok], fixed[idx[ok]], normals[idx[ok]], alpha)
        else:
            step = trimesh.registration.procrustes(cur[ok], fixed[idx[ok]], reflection=False,
                                                   scale=False, return_cost=False)
        T = step @ T
        rms = float(np.sqrt(np.mean(dist[ok] ** 2)))
        if it > len(schedule) and abs(prev - rms) < tol:
            converged = True
            break
        prev = rms
    return Registration(T, rms, frac, it, converged)


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the first) per occupied cube of side ``voxel``."""
    if voxel <= 0:
        return points
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def register_sections(scans: list[Scan], *, threshold: float = 1e-3, voxel: float = 4e-4,
                      initial: str = "nominal") -> list[Registration]:
    """Register every section to the union of the previous ones (section 0 is the frame).

    ``voxel``: registration uses one point per cube of this side (0 = all points).
    Sections are processed in order of ``section``; the sides of one section
    are registered together (one rigid pose per section). ``initial`` is the
    coarse alignment: ``"nominal"`` (the stage's nominal position, identity)
    or ``"truth"`` (the simulation's pose: for testing the refinement only).
    Returns one :class:`Registration` per scan, in the input order.
    """
    if not scans:
        raise InputError("no scans to register", field="scans")
    by_section: dict[int, list[int]] = {}
    for i, s in enumerate(scans):
        by_section.setdefault(s.section, []).append(i)
    order = sorted(by_section)
    out: list[Registration | None] = [None] * len(scans)
    first = order[0]
    # registration runs on voxel-downsampled copies (on dense range images point-to-point ICP
    # creeps along the nearly flat blade); transforms apply to all points
    merged = [voxel_downsample(scans[i].points, voxel) for i in by_section[first]]
    for i in by_section[first]:
        out[i] = Registration(np.eye(4), 0.0, 1.0, 0, True)
    for sec in order[1:]:
        pts = np.concatenate([voxel_downsample(scans[i].points, voxel) for i in by_section[sec]])
        init = None
        if initial == "truth" and scans[by_section[sec][0]].pose is not None:
            init = scans[by_section[sec][0]].pose
        reg = trimmed_icp(pts, np.concatenate(merged), init, threshold=threshold,
                          name=f"section {sec}")
        for i in by_section[sec]:
            out[i] = reg
        merged.append(trimesh.transformations.transform_points(pts, reg.transform))
    return out  # type: ignore[return-value]


def merge(scans: list[Scan], registrations: list[Registration] | None = None) -> np.ndarray:
    """All points in the object frame (registered), stacked (N, 3)."""
    regs = registrations or [None] * len(scans)
    parts = []
    for s, r in zip(scans, regs):
        T = r.transform if r is not None else (s.pose if s.pose is not None else np.eye(4))
        parts.append(trimesh.transformations.transform_points(s.points, T))
    return np.concatenate(parts)
