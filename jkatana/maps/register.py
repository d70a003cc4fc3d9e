"""Reflectance maps from real photos of a curved blade: each photo registered on the blade's mesh.

The paper's fifth stage (Mochizuki et al., "A Rendering Method for Japanese
Swords Based on Measured Data") maps the brightness of a diffuse-lit photo
onto the blade as eq. 5's weight w. A real photo is not an axis-aligned
rectangle of the blade: the blade is curved (sori), seen in perspective and
rolled, over a background, under uneven light, often in overlapping sections
and on both faces. This module takes such photos and the blade's mesh (blade
UVs: u along the mune by arc length, v from mune to ha, see
:mod:`jkatana.shape.katana`) and builds the map texel by texel.

The pieces: :mod:`jkatana.maps.outline` (the blade in a photo, steps 1–2 below), :mod:`jkatana.maps.surface`
(the mesh's silhouette topology and texels) and this module (the camera and its fit, steps 3–6).

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
from dataclasses import dataclass

import numpy as np

from jkatana.errors import InputError
from jkatana.maps.outline import PhotoOutline
from jkatana.maps.surface import BladeSurface

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
