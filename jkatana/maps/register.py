"""Reflectance maps from real photos of a curved blade: each photo registered on the blade's mesh.

The paper's fifth stage (Mochizuki et al., "A Rendering Method for Japanese
Swords Based on Measured Data") maps the brightness of a diffuse-lit photo
onto the blade as eq. 5's weight w. A real photo is not an axis-aligned
rectangle of the blade: the blade is curved (sori), seen in perspective and
rolled, over a background, under uneven light, often in overlapping sections
and on both faces. This module takes such photos and the blade's mesh (blade
UVs: u along the mune by arc length, v from mune to ha, see
:mod:`jkatana.shape.katana`) and builds the map texel by texel.

## Registration: the mesh's silhouette fitted to the photo's outline

For each photo a pinhole camera (rotation, translation, focal length in
pixels; principal point at the image centre, no lens distortion) is found by
fitting the mesh's silhouette to the blade's outline in the photo, as an
iterative closest point fit over the silhouette (the silhouette-based pose
estimation of Rosenhahn, Brox & Weickert, "Three-dimensional shape knowledge
for joint image segmentation and pose tracking", IJCV 2007, without its
level-set segmentation; point matching after Besl & McKay, "A method for
registration of 3-D shapes", PAMI 1992):

1. the blade is segmented against the background: a smooth fit of the
   background's brightness (a bivariate polynomial in log brightness, refitted
   without outliers), then
   pixels that differ from it by more than six robust sigmas of its noise
   (at least 15 %), the largest connected region, holes filled (the
   hamon/hiraji transition crosses the background's level inside the blade);
2. the outline: the midpoints between in/out pixel pairs, except along the
   image's border (a section photo's blade runs out of the frame);
3. the mesh's silhouette for a camera centre: the edges between a
   front-facing and a back-facing triangle of the welded mesh (exact for
   any closed mesh, view dependent), sampled every pixel of their projection;
4. ICP: nearest outline point of each projected silhouette sample and
   nearest silhouette sample of each outline point; the 7 camera parameters
   then minimise the pairs' distances along the outline's normal (point to
   line: Chen & Medioni, "Object modelling by registration of multiple range
   images", 1992; point-to-point pairs slide along the blade's long sides
   and converge slowly exactly where the pose is least constrained), by
   Levenberg–Marquardt with Huber weights; pairs re-found, repeated;
5. start: the outline's principal axis, its ends (a pointed kissaki, a
   square machi) and width give the initial poses for both faces and both
   directions of the blade; after a short fit the best (and the second, when
   within twice its residual) are refined and the lower residual wins; the face is where the camera ended up;
6. a section whose blade runs out of both sides of the frame shows no end:
   a circular blade slides along itself without changing its outline, so the
   slide is found from the photo's content instead, as the shift along u that
   best matches the hamon already mapped from the other photos
   (normalised cross-correlation in the overlap), then refined by ICP.

*What the outline does not pin down well:* the blade's long sides are
nearly parallel, so a stretch along the blade (a turn about the vertical
axis, a focal length traded against distance) changes the outline only at
the ends and through the width's taper. On the whole-blade Mitsuba photo
(2000 px along the blade, 10° off the normal) the recovered camera puts the
texels within 1.9 px of where the true camera does (0.65 mm along the blade,
less across), while its focal length is 15 % off (2922 px against 3429 px):
give ``--focal-mm`` from the photo's EXIF where the focal length itself
matters.

*Why this, and not a differentiable silhouette in JAX:* the unknowns are 7
numbers per photo and the silhouette is a set of mesh edges that changes
discretely with the view; closest-point matching with a small numeric
Jacobian converges in a few dozen projections of a few thousand points, with
the mesh's own silhouette (any scanned blade, not only the parametric one),
and needs neither a soft rasteriser nor autodiff through visibility.
*Why project the mesh into the photo (texel → pixel) and not the photo onto
the mesh (pixel → texel):* every texel gets a value or is marked unseen, each
with its viewing angle, and overlapping photos are blended on one grid;
pixels splatted onto texels leave holes where a photo is coarser than the map.

The texels' surface points come from rasterising the mesh's triangles in UV
space, once per face (omote: normals toward +Z, ura: −Z). A texel is seen by
a photo where its point faces the camera (cos θ > :data:`MIN_COS`), projects
inside the blade's outline (eroded by 2 pixels, away from mixed edge pixels)
and inside the frame. The blade is convex across its section, so a front
facing point is not hidden by another part of it.

## Light and exposure

Photo brightness is divided by the light reaching the blade: a flat-field
photo (a grey card under the same light and camera) when given, scaled so the
background reads 1, else the smooth background fit. The result is brightness
relative to the background, the same in every photo whatever its exposure;
left-over exposure differences are removed by one gain per photo (least
squares over the median log ratios in each overlap).

## Blending

Texels seen by several photos take the mean weighted by how squarely each
sees them (cos θ of the view to the surface normal) times a feather that
falls to 0 at a photo's frame border (no seams where a section ends). With
the blade layout the omote and ura share (u, v) (one map serves both faces),
so photos of both faces blend into the same texels; the report gives their
disagreement. w is linear in the relative brightness between a dark and a
bright level taken around Otsu's threshold of the blended brightness (see
:mod:`jkatana.maps.mosaic`); texels no photo sees take the built-in map's
values and confidence 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh

from jkatana.errors import InputError

#: Texels seen at more than ~78° from their normal are not used.
MIN_COS = 0.2
#: Registration fails above this RMS outline residual (pixels).
MAX_RESIDUAL_PX = 3.0
#: Width (pixels) of the feather that fades a photo out at its frame border.
FEATHER_PX = 40.0


# ----------------------------------------------------------------------------- camera


@dataclass
class Camera:
    """Pinhole camera: ``x = f · (R X + t)_xy / (R X + t)_z + (cx, cy)``; image x right, y down."""

    rotvec: np.ndarray
    t: np.ndarray
    f: float
    cx: float
    cy: float

    @property
    def R(self) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        return Rotation.from_rotvec(self.rotvec).as_matrix()

    @property
    def centre(self) -> np.ndarray:
        return -self.R.T @ self.t

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) and depths (N,) of world points (N, 3)."""
        Xc = X @ self.R.T + self.t
        z = Xc[:, 2]
        zz = np.where(np.abs(z) > 1e-9, z, 1e-9)
        return np.stack([self.f * Xc[:, 0] / zz + self.cx, self.f * Xc[:, 1] / zz + self.cy], -1), z

    def params(self) -> np.ndarray:
        return np.concatenate([self.rotvec, self.t, [math.log(self.f)]])

    @classmethod
    def from_params(cls, p: np.ndarray, cx: float, cy: float) -> "Camera":
        return cls(np.asarray(p[:3], float), np.asarray(p[3:6], float), float(math.exp(p[6])), cx, cy)

    def off_normal_deg(self, normal=(0.0, 0.0, 1.0)) -> float:
        """Angle between the optical axis and the flat's normal (either face), degrees."""
        fwd = self.R[2]
        return math.degrees(math.acos(min(1.0, abs(float(fwd @ np.asarray(normal))))))


# ----------------------------------------------------------------------------- the mesh


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


# ----------------------------------------------------------------------------- photo: light and outline


def _poly_terms(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    return np.stack([x ** i * y ** j for i in range(degree + 1) for j in range(degree + 1 - i)], -1)


def background_fit(y: np.ndarray, exclude: np.ndarray | None = None, *, degree: int = 3,
                   step: int = 8) -> np.ndarray:
    """Smooth background brightness: a degree-``degree`` polynomial in (x, y) fitted to log brightness,
    refitted three times without pixels more than 3 robust sigmas off (the blade) and ``exclude``."""
    H, W = y.shape
    ys, xs = np.mgrid[0:H:step, 0:W:step]
    val = np.log(np.maximum(y[::step, ::step], 1e-6))
    sx, sy = 2 * xs / W - 1, 2 * ys / H - 1
    A = _poly_terms(sx.ravel(), sy.ravel(), degree)
    ok = np.ones(val.size, bool) if exclude is None else ~exclude[::step, ::step].ravel()
    ok &= np.isfinite(val.ravel())
    for _ in range(4):
        coef, *_ = np.linalg.lstsq(A[ok], val.ravel()[ok], rcond=None)
        res = val.ravel() - A @ coef
        sig = 1.4826 * np.median(np.abs(res[ok] - np.median(res[ok])))
        ok &= np.abs(res) < 3 * max(sig, 1e-3)
        if exclude is not None:
            ok &= ~exclude[::step, ::step].ravel()
    gy, gx = np.mgrid[0:H, 0:W]
    out = np.empty((H, W))
    for r0 in range(0, H, 256):  # rows in chunks: (rows·W, terms) stays small
        sl = slice(r0, min(H, r0 + 256))
        out[sl] = np.exp(_poly_terms(2 * gx[sl] / W - 1, 2 * gy[sl] / H - 1, degree) @ coef)
    return out


def _padded(op, a: np.ndarray, n: int = 8, **kw) -> np.ndarray:
    """A morphological ``op`` on ``a`` extended by its edge values, so a blade that runs out of the frame
    is not eroded (or closed) against the frame's border."""
    return op(np.pad(a, n, mode="edge"), **kw)[n:-n, n:-n]


@dataclass
class PhotoOutline:
    """The blade found in a photo: its mask, outline points and the light it was lit by."""

    mask: np.ndarray
    edge: np.ndarray  # (P, 2) outline points (x, y), frame border excluded
    normal: np.ndarray  # (P, 2) their outward unit normals
    light: np.ndarray  # (H, W) light estimate: photo / light = brightness relative to the background
    axis: np.ndarray  # unit principal axis (x, y)
    centroid: np.ndarray
    width_px: float
    length_px: float
    ends: dict  # "+" / "-": end point (x, y) along the axis, or None where the blade leaves the frame


def find_blade(y: np.ndarray, *, flat: np.ndarray | None = None, path=None) -> PhotoOutline:
    """Segment the blade against the background (see the module docstring); :class:`InputError` when no
    blade-like (long, narrow, single) object stands out."""
    from scipy import ndimage

    H, W = y.shape
    light = background_fit(y)
    r = ndimage.gaussian_filter(y / light - 1.0, 0.7)
    rough = np.abs(r) > 0.35
    lab, n = ndimage.label(_padded(ndimage.binary_opening, rough, iterations=2))
    if n == 0:
        raise InputError("no blade-like object against the background (nothing stands out of it)", path=path)
    sizes = ndimage.sum_labels(np.ones_like(lab), lab, np.arange(1, n + 1))
    big = lab == (1 + int(np.argmax(sizes)))
    big = ndimage.binary_fill_holes(_padded(ndimage.binary_closing, big, iterations=3))
    if flat is not None:
        light = flat * np.median((y / flat)[~ndimage.binary_dilation(big, iterations=8)])
    else:
        light = background_fit(y, exclude=ndimage.binary_dilation(big, iterations=8))
    r = y / light - 1.0
    bg = ~ndimage.binary_dilation(big, iterations=8)
    noise = 1.4826 * float(np.median(np.abs(r[bg] - np.median(r[bg])))) if bg.any() else 0.0
    # a pixel is the blade's where it differs from the background by more than the noise allows:
    # the mune roof reads about half the background, the ha's last pixel is dark, the hamon bright
    threshold = max(0.15, 6.0 * noise)
    sel = ndimage.median_filter(np.abs(r), size=3) > threshold if noise > 0.05 else np.abs(r) > threshold
    mask = ndimage.binary_fill_holes(_padded(ndimage.binary_closing, sel, iterations=3)
                                     | _padded(ndimage.binary_erosion, big, iterations=3))
    mask = _padded(ndimage.binary_opening, mask, iterations=1)
    lab, n = ndimage.label(mask)
    if n == 0:
        raise InputError("no blade-like object against the background", path=path)
    if n > 1:
        mask = lab == (1 + int(np.argmax(ndimage.sum_labels(np.ones_like(lab), lab, np.arange(1, n + 1)))))
    ys, xs = np.nonzero(mask)
    if len(xs) < 500:
        raise InputError("no blade-like object against the background", path=path)
    c = np.array([xs.mean(), ys.mean()])
    cov = np.cov(np.stack([xs - c[0], ys - c[1]]))
    evals, evecs = np.linalg.eigh(cov)
    axis = evecs[:, 1]
    along = (xs - c[0]) * axis[0] + (ys - c[1]) * axis[1]
    across = -(xs - c[0]) * axis[1] + (ys - c[1]) * axis[0]
    length = float(np.ptp(along))
    # width: the median extent across in slices along the axis
    bins = np.clip(((along - along.min()) / max(length, 1) * 64).astype(int), 0, 63)
    idx = np.arange(64)
    cnt = np.bincount(bins, minlength=64)
    span = ndimage.maximum(across, bins, idx) - ndimage.minimum(across, bins, idx)
    widths = np.asarray(span)[cnt > 3]
    width = float(np.median(widths)) if widths.size else 0.0
    if width < 3 or length < 5 * width:
        raise InputError(f"no blade-like object against the background (the object found is "
                         f"{length:.0f}×{width:.0f} px: not long and narrow)", path=path)
    # outline: midpoints of in/out pixel pairs, away from the frame border
    pts = []
    for dy, dx in ((0, 1), (1, 0)):
        a, b = mask[: H - dy, : W - dx], mask[dy:, dx:]
        yy, xx = np.nonzero(a != b)
        pts.append(np.stack([xx + 0.5 * dx, yy + 0.5 * dy], -1))
    edge = np.concatenate(pts).astype(np.float64)
    border = (edge[:, 0] < 2) | (edge[:, 0] > W - 3) | (edge[:, 1] < 2) | (edge[:, 1] > H - 3)
    edge = edge[~border]
    # outward normals of the outline, from the gradient of the smoothed mask
    sm = ndimage.gaussian_filter(mask.astype(np.float64), 2.0)
    gy, gx = np.gradient(sm)
    xi, yi = np.clip(np.round(edge[:, 0]).astype(int), 0, W - 1), np.clip(np.round(edge[:, 1]).astype(int), 0, H - 1)
    nrm = -np.stack([gx[yi, xi], gy[yi, xi]], -1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    touches = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
    ends = {}
    for sign in (1, -1):
        k = np.argmax(sign * along)
        p = np.array([xs[k], ys[k]], float)
        near_border = p[0] < 3 or p[0] > W - 4 or p[1] < 3 or p[1] > H - 4
        ends["+" if sign > 0 else "-"] = None if (near_border and touches.any()) else p
    return PhotoOutline(mask, edge, nrm, light, axis, c, width, length, ends)


# ----------------------------------------------------------------------------- registration


@dataclass
class Registration:
    """A photo's recovered camera, its face, and the outline residual (RMS pixels)."""

    camera: Camera
    side: str
    residual_px: float
    outline_points: int
    ends_seen: int


def _sample_silhouette(surface: BladeSurface, cam: Camera, W: int, H: int, spacing: float = 1.0):
    seg = surface.silhouette(cam.centre)
    a, za = cam.project(seg[:, 0])
    b, zb = cam.project(seg[:, 1])
    ok = (za > 0) & (zb > 0)
    seg, a, b = seg[ok], a[ok], b[ok]
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / spacing)).astype(int)
    idx = np.repeat(np.arange(len(seg)), n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
    X = seg[idx, 0] + frac[:, None] * (seg[idx, 1] - seg[idx, 0])
    x = a[idx] + frac[:, None] * (b[idx] - a[idx])
    inside = (x[:, 0] > 2) & (x[:, 0] < W - 3) & (x[:, 1] > 2) & (x[:, 1] < H - 3)
    return X[inside], x[inside]


def outline_residual(surface: BladeSurface, cam: Camera, edge: np.ndarray, W: int, H: int) -> float:
    """RMS distance (pixels) from the photo's outline points to the projected silhouette (sampled at 0.25 px)."""
    from scipy.spatial import cKDTree

    _, x = _sample_silhouette(surface, cam, W, H, spacing=0.25)
    if len(x) < 10:
        return float("inf")
    d, _ = cKDTree(x).query(edge)
    return float(np.sqrt(np.mean(d ** 2)))


def _robust_gauss_newton(res, q0: np.ndarray, *, iterations: int, scale: float = 1.0) -> np.ndarray:
    """Levenberg–Marquardt on ``res`` with Huber weights (iteratively reweighted least squares; Huber 1964)
    and a forward-difference Jacobian: a few unknowns, many residuals, so the 7×7 normal equations are solved
    directly (scipy's trust-region solver spends its time in an SVD of the whole Jacobian)."""
    q = np.asarray(q0, float).copy()
    lam = 1e-3

    def cost(r):
        a = np.abs(r)
        return float(np.sum(np.where(a < scale, 0.5 * a * a, scale * (a - 0.5 * scale))))

    r = res(q)
    c = cost(r)
    for _ in range(iterations):
        h = 1e-7 * np.maximum(np.abs(q), 1e-2)
        J = np.stack([(res(q + h[k] * np.eye(len(q))[k]) - r) / h[k] for k in range(len(q))], -1)
        w = np.minimum(1.0, scale / np.maximum(np.abs(r), 1e-12))
        A = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        for _ in range(8):
            dq = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), g)
            r_new = res(q + dq)
            c_new = cost(r_new)
            if c_new <= c:
                q, r, c = q + dq, r_new, c_new
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        else:
            break
    return q


def _icp(surface: BladeSurface, cam: Camera, edge: np.ndarray, normal: np.ndarray, W: int, H: int, *,
         iterations: int,
         gate: float, focal_prior: float | None, points=None, fix_focal: bool = False) -> Camera:
    from scipy.spatial import cKDTree

    tree_e = cKDTree(edge)
    p = cam.params()
    f0 = math.log(cam.f) if focal_prior is None else math.log(focal_prior)
    for it in range(iterations):
        cam = Camera.from_params(p, cam.cx, cam.cy)
        X, x = _sample_silhouette(surface, cam, W, H, spacing=1.0)
        if len(x) < 20:
            break
        d1, i1 = tree_e.query(x)
        m1 = d1 < gate
        d2, i2 = cKDTree(x).query(edge)
        m2 = d2 < gate
        src = np.concatenate([X[m1], X[i2[m2]]])
        dst = np.concatenate([edge[i1[m1]], edge[m2]])
        nrm = np.concatenate([normal[i1[m1]], normal[m2]])
        if len(src) < 20:
            break
        sub = np.linspace(0, len(src) - 1, min(len(src), 2500)).astype(int)
        src, dst, nrm = src[sub], dst[sub], nrm[sub]

        def res(q):
            c = Camera.from_params(q if not fix_focal else np.r_[q, p[6]], cam.cx, cam.cy)
            r = np.einsum("ij,ij->i", c.project(src)[0] - dst, nrm)  # point to line (the outline's tangent)
            extra = []
            if points is not None:
                extra.append(3.0 * (c.project(points[1])[0] - points[0]).ravel())
            if not fix_focal:
                extra.append([0.3 * (q[6] - f0) * math.sqrt(len(src))])
            return np.concatenate([r, *extra]) if extra else r

        q0 = p[:6] if fix_focal else p
        q = _robust_gauss_newton(res, q0, iterations=6)
        p_new = np.r_[q, p[6]] if fix_focal else q
        step = np.abs(p_new - p).max()
        p = p_new
        gate = max(3.0, 0.6 * gate)
        if step < 1e-7 and gate <= 3.0:
            break
    return Camera.from_params(p, cam.cx, cam.cy)


def _initial_cameras(surface: BladeSurface, out: PhotoOutline, W: int, H: int, f: float, sides):
    """Candidate starting cameras: each face × each direction of the blade along the outline's axis,
    anchored at a visible end (or, with none, at several points along the blade)."""
    from scipy.spatial.transform import Rotation

    V = np.asarray(surface.mesh.vertices)
    L = surface.length
    Pm = surface.points["omote"]
    habas = np.linalg.norm(Pm[0, :, :2] - Pm[-1, :, :2], axis=1)  # the blade's width at each texel column
    Wt = len(habas)

    def depth(u_end: float | None) -> float:
        """Distance at which the mesh's width matches the outline's: at the middle of the visible part,
        found by a fixed point (the visible length in metres depends on the distance)."""
        Z = f * float(np.median(habas)) / max(out.width_px, 1.0)
        for _ in range(6):
            D = 0.5 * out.length_px * Z / f / L
            u = 0.5 if u_end is None else (D if u_end == 0 else 1 - D)
            Z = f * float(habas[int(np.clip(u * Wt, 0, Wt - 1))]) / max(out.width_px, 1.0)
        return Z

    cands = []
    for side in sides:
        s = 1.0 if side == "omote" else -1.0
        for sign in (1.0, -1.0):
            d = sign * out.axis  # image direction of the blade's +X (toward the tip)
            phi = math.atan2(s * d[1], d[0])
            ex = np.array([math.cos(phi), math.sin(phi), 0.0])
            ez = np.array([0.0, 0.0, -s])
            ey = np.cross(ez, ex)
            R = np.stack([ex, ey, ez])
            tip_end = out.ends["+" if sign > 0 else "-"]
            machi_end = out.ends["-" if sign > 0 else "+"]
            anchors = []
            tipX = V[np.argmax(V[:, 0])]
            machiX = np.array([0.0, float(np.median(V[np.abs(V[:, 0]) < 0.01 * L][:, 1])), 0.0])
            if tip_end is not None and machi_end is not None:
                Z = f * float(np.linalg.norm(tipX - machiX)) / max(float(np.linalg.norm(tip_end - machi_end)), 1.0)
                anchors.append((0.5 * (tipX + machiX), 0.5 * (tip_end + machi_end), Z))
            elif tip_end is not None:
                anchors.append((tipX, tip_end, depth(1)))
            elif machi_end is not None:
                anchors.append((machiX, machi_end, depth(0)))
            else:
                Z = depth(None)
                for uc in (0.2, 0.35, 0.5, 0.65, 0.8):
                    j = int(uc * (Wt - 1))
                    anchors.append((surface.points[side][len(Pm) // 2, j], out.centroid, Z))
            for X0, x0, Z in anchors:
                pc = np.array([Z * (x0[0] - (W - 1) / 2) / f, Z * (x0[1] - (H - 1) / 2) / f, Z])
                t = pc - R @ X0
                cands.append((side, Camera(Rotation.from_matrix(R).as_rotvec(), t, f, (W - 1) / 2, (H - 1) / 2)))
    return cands


def register_photo(surface: BladeSurface, out: PhotoOutline, shape: tuple[int, int], *,
                   focal_px: float | None = None, side: str | None = None, points=None, path=None) -> Registration:
    """Fit the mesh's silhouette to the photo's outline (see the module docstring)."""
    H, W = shape
    f = focal_px if focal_px else 1.2 * max(W, H)
    sides = (side,) if side else ("omote", "ura")
    if points is not None:
        sides = (side or "omote",)
    tried = []
    for sd, cam in _initial_cameras(surface, out, W, H, f, sides):
        cam = _icp(surface, cam, out.edge, out.normal, W, H, iterations=6, gate=max(40.0, 2 * out.width_px),
                   focal_prior=f, points=points, fix_focal=True)
        tried.append((outline_residual(surface, cam, out.edge, W, H), sd, cam))
    tried.sort(key=lambda c: c[0])
    best = None
    # the two best starts refined to the end (the second only when its short fit is close to the first's)
    for r, sd, cam in [c for c in tried[:2] if c[0] < 2 * tried[0][0] + 1.0]:
        cam = _icp(surface, cam, out.edge, out.normal, W, H, iterations=40, gate=max(20.0, 4 * r), focal_prior=f,
                   points=points, fix_focal=focal_px is not None)
        r = outline_residual(surface, cam, out.edge, W, H)
        if best is None or r < best[0]:
            best = (r, sd, cam)
    r, sd, cam = best
    sd = "omote" if cam.centre[2] > 0 else "ura"  # where the camera ended up (a start may turn over)
    if side and sd != side:
        raise InputError(f"registration did not converge on the {side} face (the outline fits the {sd})",
                         path=path)
    if not np.isfinite(r) or r > MAX_RESIDUAL_PX:
        raise InputError(f"registration did not converge: the mesh's outline stays {r:.1f} px RMS from the "
                         f"blade's (limit {MAX_RESIDUAL_PX:g} px); is it this blade? Give --focal-mm or --points",
                         path=path)
    return Registration(cam, sd, r, len(out.edge), sum(e is not None for e in out.ends.values()))
