"""A parametric shinogi-zukuri katana from the measures a sword appraiser uses.

The blade is built as a triangle mesh in **metres** with per-vertex UVs that
share the reflectance map's parameterisation (:mod:`jkatana.maps`).

## World frame

- **Y up.** The blade lies along **+X**: the machi (where the blade meets the
  tang) is at the origin, the kissaki tip at max x (≈ ``nagasa``).
- The **edge (ha) points toward −Y**, the back (mune) toward +Y.
- The **flats face ±Z**: a camera on +Z sees the *omote* face, one on −Z the
  *ura* face.
- **Sori** curves the blade toward +Y: the mune line is a circular arc whose
  chord (machi → tip, length ``nagasa``) lies on the x axis and whose middle
  sags by ``sori`` toward −Y, so both ends turn up (torii-zori).

## UVs

``mesh.visual.uv[:, 0] = u`` ∈ [0, 1] runs along the mune line by arc length,
0 at the machi and 1 at the kissaki tip; ``uv[:, 1] = v`` ∈ [0, 1] runs across,
0 at the mune and 1 at the ha: ``v = d / haba(u)`` with ``d`` the distance from
the mune measured in the blade plane. Omote and ura carry the **same** (u, v),
so one reflectance map serves both faces. With ``nakago=True`` the tang has
u < 0 (a map lookup clamps it; the tang is not polished).

## Topology and normals

Each face (omote, ura) is three panels: mune (roof), shinogi-ji, hiraji (plus a
flat top for a mitsu-mune), a cap closes the machi end and a fan closes the tip.
Panels do not share vertices, so vertex normals are smooth on the flats and
sharp at the mune ridge, the shinogi and the edge. The mesh is watertight as a
surface: :func:`welded` merges coincident vertices (ignoring the split UVs and
normals) and the result passes ``is_watertight``.

Geometry after the usual descriptions of nihontō measurement (nagasa measured
as the straight line from the munemachi to the kissaki tip, sori as the
largest distance from that chord to the mune), e.g. Kapp, Kapp & Yoshihara,
*The Craft of the Japanese Sword* (1987); the default numbers are those of a
typical Edo-period shinogi-zukuri katana.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from jkatana.errors import InputError

MUNE_SHAPES = ("iori", "mitsu", "maru")


@dataclass(frozen=True)
class KatanaSpec:
    """Appraiser's measures of a shinogi-zukuri blade (metres).

    **Fields:**

    - `nagasa`: blade length, straight line from munemachi to kissaki tip.
    - `sori`: curvature, largest distance from that chord to the mune line.
    - `motohaba`, `sakihaba`: width (mune to ha) at the machi and at the yokote.
    - `motogasane`, `sakigasane`: thickness at the shinogi (the thickest line)
      at the machi and at the yokote. `kasane` is an alias for `motogasane`
      kept for the appraiser's usual single figure.
    - `shinogi_position`: the shinogi's distance from the mune as a fraction of
      the width (the shinogi-ji is narrower than the hiraji: ~0.25–0.35).
    - `shinogi_height`: thickness at the mune edge of the shinogi-ji as a
      fraction of the thickness at the shinogi (< 1: the shinogi stands out).
    - `niku`: convexity of the hiraji (0 flat, ~0.3 a typical hamaguri-ba).
    - `kissaki_length`: length of the point (yokote to tip) along the mune.
    - `mune`: back shape, ``"iori"`` (peaked roof), ``"mitsu"`` (three-faced)
      or ``"maru"`` (rounded); `mune_height`: depth of the roof (mune → shinogi-ji).
    - `nakago`: add a tang behind the machi (off by default); `nakago_length`,
      `nakago_width`: its length and width at the machi.
    """

    nagasa: float = 0.70
    sori: float = 0.018
    motohaba: float = 0.031
    sakihaba: float = 0.021
    kasane: float = 0.007
    sakigasane: float = 0.005
    shinogi_position: float = 0.30
    shinogi_height: float = 0.80
    niku: float = 0.30
    kissaki_length: float = 0.035
    mune: str = "iori"
    mune_height: float = 0.0018
    nakago: bool = False
    nakago_length: float = 0.21
    nakago_width: float = 0.026

    @property
    def motogasane(self) -> float:
        return self.kasane

    def validate(self) -> "KatanaSpec":
        """Raise :class:`InputError` naming the field when a measure is impossible."""
        positive = ("nagasa", "motohaba", "sakihaba", "kasane", "sakigasane", "kissaki_length",
                    "mune_height", "nakago_length", "nakago_width")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"must be a positive finite length in metres, got {value!r}",
                                 field=name)
        if not (math.isfinite(self.sori) and 0 <= self.sori < 0.25 * self.nagasa):
            raise InputError(f"must be in [0, nagasa/4), got {self.sori!r}", field="sori")
        if not 0.05 <= self.shinogi_position <= 0.6:
            raise InputError(f"must be in [0.05, 0.6], got {self.shinogi_position!r}",
                             field="shinogi_position")
        if not 0.2 <= self.shinogi_height <= 1.0:
            raise InputError(f"must be in [0.2, 1], got {self.shinogi_height!r}", field="shinogi_height")
        if not 0.0 <= self.niku <= 0.9:
            raise InputError(f"must be in [0, 0.9], got {self.niku!r}", field="niku")
        if self.kissaki_length >= 0.5 * self.nagasa:
            raise InputError("must be shorter than half the nagasa", field="kissaki_length")
        if self.mune not in MUNE_SHAPES:
            raise InputError(f"must be one of {MUNE_SHAPES}, got {self.mune!r}", field="mune")
        if self.mune_height >= self.shinogi_position * self.sakihaba:
            raise InputError("roof deeper than the shinogi-ji is wide", field="mune_height")
        return self


# ----------------------------------------------------------------------------- the mune line


@dataclass(frozen=True)
class _MuneLine:
    """Circular arc through (0, 0) and (nagasa, 0) sagging by ``sori`` (−Y)."""

    chord: float
    sori: float

    @functools.cached_property
    def radius(self) -> float:
        if self.sori <= 0:
            return math.inf
        return (self.chord**2 / 4 + self.sori**2) / (2 * self.sori)

    @functools.cached_property
    def half_angle(self) -> float:
        return 0.0 if math.isinf(self.radius) else math.asin(self.chord / (2 * self.radius))

    @functools.cached_property
    def length(self) -> float:
        return self.chord if math.isinf(self.radius) else 2 * self.radius * self.half_angle

    def frame(self, u: np.ndarray):
        """Points, unit tangents and unit edge-ward normals at arc-length fraction ``u``."""
        u = np.asarray(u, dtype=np.float64)
        if math.isinf(self.radius):
            p = np.stack([u * self.chord, np.zeros_like(u)], -1)
            t = np.broadcast_to([1.0, 0.0], p.shape).copy()
        else:
            a = (2 * u - 1) * self.half_angle
            yc = self.radius - self.sori
            p = np.stack([self.chord / 2 + self.radius * np.sin(a), yc - self.radius * np.cos(a)], -1)
            t = np.stack([np.cos(a), np.sin(a)], -1)
        n = np.stack([t[:, 1], -t[:, 0]], -1)  # tangent rotated −90°: away from the arc centre
        return p, t, n


# ----------------------------------------------------------------------------- cross-section


def _stations(spec: KatanaSpec, line: _MuneLine, n_along: int) -> np.ndarray:
    """Arc-length fractions of the rings: uniform on the body, denser toward the tip."""
    u_y = 1.0 - spec.kissaki_length / line.length
    n_k = max(8, n_along // 5)
    n_b = max(4, n_along - n_k)
    body = np.linspace(0.0, u_y, n_b, endpoint=False)
    t = np.linspace(0.0, 1.0, n_k + 1)[:-1]
    kiss = u_y + (1 - u_y) * (1 - (1 - t) ** 1.6) * 0.985
    u = np.concatenate([body, kiss])
    if spec.nakago:
        u_n = -spec.nakago_length / line.length
        n_n = max(4, int(round(n_b * spec.nakago_length / (line.length * u_y))))
        u = np.concatenate([np.linspace(u_n, 0.0, n_n, endpoint=False), [-2e-5], u])
    return u


def _widths(spec: KatanaSpec, line: _MuneLine, u: np.ndarray):
    """Width (haba), thickness at the shinogi and shinogi distance at each station."""
    u_y = 1.0 - spec.kissaki_length / line.length
    body = np.clip(u / u_y, 0.0, 1.0)
    tau = np.clip((u - u_y) / (1 - u_y), 0.0, 1.0)
    haba = spec.motohaba + (spec.sakihaba - spec.motohaba) * body
    haba = np.where(tau > 0, spec.sakihaba * (1 - tau**2), haba)  # fukura
    kas = spec.kasane + (spec.sakigasane - spec.kasane) * body
    kas = np.where(tau > 0, spec.sakigasane * (1 - tau**2) ** 0.75, kas)
    shin = spec.shinogi_position * np.where(tau > 0, spec.sakihaba * (1 - tau), haba)  # ko-shinogi
    if spec.nakago:  # the tang: narrower (machi notches), blunt, tapering
        tang = u < 0
        frac = np.clip(u / (-spec.nakago_length / line.length), 0, 1)
        haba = np.where(tang, spec.nakago_width * (1 - 0.3 * frac), haba)
        kas = np.where(tang, spec.kasane * (1 - 0.3 * frac), kas)
        shin = np.where(tang, spec.shinogi_position * haba, shin)
    return haba, kas, shin


def _panels(spec: KatanaSpec, haba, kas, shin, n_across: int):
    """(d, z≥0, v) grids of the omote panels, each (rings, cols); the ura mirrors z."""
    n_roof = max(2, n_across // 10)
    n_sj = max(3, n_across // 6)
    n_hj = max(6, n_across - n_roof - n_sj)
    scale = np.minimum(1.0, haba / spec.sakihaba)[:, None]
    m = spec.mune_height * scale  # roof depth
    h_m = 0.5 * spec.shinogi_height * kas[:, None]  # half-thickness at the roof's foot
    h_s = 0.5 * kas[:, None]
    ds = shin[:, None]
    W = haba[:, None]

    t = np.linspace(0, 1, n_roof + 1)[None, :]
    d_roof = m * t
    if spec.mune == "iori":
        z_roof = h_m * t
    elif spec.mune == "mitsu":
        z_roof = h_m * (0.55 + 0.45 * t)
    else:  # maru: a quarter ellipse, vertical at the mune
        z_roof = h_m * np.sqrt(np.clip(1 - (1 - t) ** 2, 0, 1))
    t = np.linspace(0, 1, n_sj + 1)[None, :]
    d_sj = m + (ds - m) * t
    z_sj = h_m + (h_s - h_m) * t
    t = np.linspace(0, 1, n_hj + 1)[None, :]
    t = 1 - (1 - t) ** 1.15  # slightly denser toward the shinogi
    t[:, -1] = 1.0
    d_hj = ds + (W - ds) * t
    z_hj = h_s * (1 - t) * (1 + spec.niku * t)
    z_hj[:, -1] = 0.0  # the edge closes exactly
    panels = {"mune": (d_roof, z_roof), "shinogi_ji": (d_sj, z_sj), "hiraji": (d_hj, z_hj)}
    return {k: (d, z, d / W) for k, (d, z) in panels.items()}


def build_blade(spec: KatanaSpec = KatanaSpec(), *, segments_along: int = 320,
                segments_across: int = 40) -> trimesh.Trimesh:
    """Build the blade mesh described by ``spec`` (see the module docstring for the frame).

    **Arguments:**

    - `spec`: the appraiser's measures; validated (bad values raise
      :class:`~jkatana.errors.InputError` naming the field).
    - `segments_along`: number of rings from machi to tip.
    - `segments_across`: columns across one face (mune roof + shinogi-ji + hiraji).

    **Returns:**

    A :class:`trimesh.Trimesh` in metres with ``visual.uv`` (u along, v across)
    and vertex normals split at the mune ridge, the shinogi and the edge.
    ``mesh.metadata["katana"]`` holds the spec as a dict. Default settings
    give ~ 55k triangles.
    """
    spec.validate()
    if segments_along < 16 or segments_across < 12:
        raise InputError("need segments_along >= 16 and segments_across >= 12",
                         field="segments_along" if segments_along < 16 else "segments_across")
    line = _MuneLine(spec.nagasa, spec.sori)
    u = _stations(spec, line, segments_along)
    haba, kas, shin = _widths(spec, line, u)
    P, T, N = line.frame(u)
    parts = _Parts(P, T, N, tip_xy=line.frame(np.array([1.0]))[0][0])
    panels = _panels(spec, haba, kas, shin, segments_across)
    top = _mitsu_top(panels) if spec.mune == "mitsu" else None
    for sign in (+1.0, -1.0):
        for d, z, v in panels.values():
            parts.add_panel(parts.place(d, sign * z), _uv(u, v), flip=(sign > 0))
    if top is not None:
        d, z, v = top
        parts.add_panel(parts.place(d, z), _uv(u, v), flip=False)
    _add_machi_cap(parts, panels, top, u[0], haba[0])
    mesh = parts.mesh()
    mesh.metadata["katana"] = dataclasses.asdict(spec)
    mesh.metadata["units"] = "m"
    _ = mesh.vertex_normals  # computed per panel: smooth on flats, split at ridges
    return mesh


def _mitsu_top(panels: dict):
    """The flat top of a mitsu-mune, (d, z, v) grids (rings, 3): across from the omote roof's top to the ura's."""
    h0 = panels["mune"][1][:, :1]
    t = np.linspace(0, 1, 3)[None, :]
    return np.zeros_like(h0 * t), h0 * (1 - 2 * t), np.zeros_like(h0 * t)


def _uv(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A panel's texture coordinates: u along (one per ring), v across."""
    return np.stack([np.broadcast_to(u[:, None], v.shape), v], -1)


class _Parts:
    """The blade mesh's vertices, UVs and faces as they are added, each panel placed in the mune line's frame
    (``P`` points, ``T`` tangents, ``N`` normals, one per ring) and closed by a fan to the tip."""

    def __init__(self, P, T, N, tip_xy):
        self.P, self.T, self.N, self.tip_xy = P, T, N, tip_xy
        self.verts, self.uvs, self.faces = [], [], []
        self.count = 0

    def place(self, d, z):
        """Points at distance ``d`` from the mune line along its normal, at height ``z`` off the blade's plane."""
        xy = self.P[:, None, :] + d[..., None] * self.N[:, None, :]
        return np.concatenate([xy, z[..., None]], -1)

    def add_panel(self, xyz, uv, flip):
        """Grid (rings, cols) + a fan to the tip; ``flip`` chooses the outward winding."""
        r, c = xyz.shape[:2]
        idx = self.count + np.arange(r * c).reshape(r, c)
        tip = self.count + r * c
        p00, p10, p11, p01 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
        tri = np.concatenate([np.stack([p00, p10, p11], -1).reshape(-1, 3),
                              np.stack([p00, p11, p01], -1).reshape(-1, 3)])
        last = idx[-1]
        fan = np.stack([last[:-1], np.full(c - 1, tip), last[1:]], -1)
        tri = np.concatenate([tri, fan])
        if flip:
            tri = tri[:, ::-1]
        self.verts.append(xyz.reshape(-1, 3))
        self.verts.append(np.array([[self.tip_xy[0], self.tip_xy[1], 0.0]]))
        self.uvs.append(uv.reshape(-1, 2))
        self.uvs.append(np.array([[1.0, float(np.mean(uv[-1, :, 1]))]]))
        self.faces.append(tri)
        self.count += r * c + 1

    def mesh(self) -> trimesh.Trimesh:
        """The parts as one mesh (v clipped to [0, 1]), without the zero-area fan triangles at the tip (where
        two columns meet it)."""
        V = np.concatenate(self.verts)
        F = np.concatenate(self.faces).astype(np.int64)
        UV = np.concatenate(self.uvs)
        UV[:, 1] = np.clip(UV[:, 1], 0.0, 1.0)
        mesh = trimesh.Trimesh(vertices=V, faces=F, process=False,
                               visual=trimesh.visual.TextureVisuals(uv=UV))
        area = mesh.area_faces
        if np.any(area <= 0):
            mesh.update_faces(area > 0)
        return mesh


def _add_machi_cap(parts: _Parts, panels: dict, top, u0: float, haba0: float) -> None:
    """The machi (or tang-end) cap: the first ring's cross-section, fanned from its centre, facing backward."""
    P, T, N = parts.P, parts.T, parts.N
    loop = []
    for sign in (+1.0, -1.0):
        seq = [parts.place(d, sign * z)[0] for d, z, _ in panels.values()]
        pts = np.concatenate(seq)
        loop.append(pts if sign > 0 else pts[::-1])
    if top is not None:  # ura → omote across the flat top of a mitsu-mune
        loop.append(parts.place(top[0], top[1])[0][::-1])
    loop = np.concatenate(loop)
    keep = np.ones(len(loop), bool)
    keep[1:] = np.linalg.norm(np.diff(loop, axis=0), axis=1) > 1e-12
    loop = loop[keep]
    if np.linalg.norm(loop[0] - loop[-1]) < 1e-12:
        loop = loop[:-1]
    centre = loop.mean(0)
    k, count = len(loop), parts.count
    cap = np.stack([np.full(k, count + k), count + np.arange(k), count + (np.arange(k) + 1) % k], -1)
    normal = np.cross(loop[cap[0, 1] - count] - centre, loop[cap[0, 2] - count] - centre)
    if np.dot(normal, np.r_[T[0], 0.0]) > 0:  # must face backward (−tangent)
        cap = cap[:, ::-1]
    parts.verts += [loop, centre[None]]
    d_loop = (loop[:, :2] - P[0]) @ N[0]
    parts.uvs += [np.stack([np.full(k, u0), d_loop / haba0], -1),
                  np.array([[u0, float((centre[:2] - P[0]) @ N[0] / haba0)]])]
    parts.faces.append(cap)


def welded(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy with coincident vertices merged, ignoring UVs and normals (for topology checks)."""
    out = trimesh.Trimesh(vertices=mesh.vertices.copy(), faces=mesh.faces.copy(), process=False)
    out.merge_vertices(merge_tex=True, merge_norm=True, digits_vertex=9)
    return out


@functools.lru_cache(maxsize=4)
def _cached_default(segments_along: int, segments_across: int) -> trimesh.Trimesh:
    return build_blade(KatanaSpec(), segments_along=segments_along, segments_across=segments_across)


def default_blade(*, segments_along: int = 320, segments_across: int = 40) -> trimesh.Trimesh:
    """The built-in blade (default :class:`KatanaSpec`), cached; a copy is returned."""
    return _cached_default(segments_along, segments_across).copy()


def export_blade(mesh: trimesh.Trimesh, path: str | Path) -> Path:
    """Write a blade mesh as PLY or GLB (by suffix), atomically, keeping UVs and normals."""
    from jkatana.io.atomic import atomic_path

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".glb", ".obj"):
        raise InputError("mesh output must end in .ply, .glb or .obj", path=path)
    with atomic_path(path) as tmp:
        if suffix == ".ply":
            data = mesh.export(file_type="ply", vertex_normal=True)
        elif suffix == ".obj":
            data = mesh.export(file_type="obj", include_normals=True, include_texture=True)
        else:
            data = mesh.export(file_type="glb")
        Path(tmp).write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def blade_xy(spec: KatanaSpec, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Blade-plane position (x, y) of UV coordinates (u along, v across), shape (..., 2)."""
    line = _MuneLine(spec.nagasa, spec.sori)
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    shape = np.broadcast(u, v).shape
    uf, vf = np.broadcast_to(u, shape).ravel(), np.broadcast_to(v, shape).ravel()
    P, _, N = line.frame(uf)
    haba = _widths(spec, line, uf)[0]
    return (P + (vf * haba)[:, None] * N).reshape(*shape, 2)


def blade_uv(spec: KatanaSpec, xy: np.ndarray) -> np.ndarray:
    """Inverse of :func:`blade_xy`: UVs (..., 2) of blade-plane points (x, y) (v may leave [0, 1])."""
    line = _MuneLine(spec.nagasa, spec.sori)
    xy = np.asarray(xy, float)
    x, y = xy[..., 0], xy[..., 1]
    if math.isinf(line.radius):
        u, d = x / line.chord, -y
    else:
        yc = line.radius - spec.sori
        a = np.arctan2(x - line.chord / 2, yc - y)
        u = (a / line.half_angle + 1) / 2
        d = np.hypot(x - line.chord / 2, y - yc) - line.radius
    haba = _widths(spec, line, np.ravel(u))[0].reshape(np.shape(u))
    return np.stack([u, d / np.maximum(haba, 1e-9)], -1)
