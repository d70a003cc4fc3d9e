"""Several registered photos → one reflectance map: light and exposure removed, overlaps blended, w.

The steps and their reasons are in :mod:`jkatana.maps.register`'s docstring
(registration, light, blending); this module runs them over a set of photos:

1. each photo: the blade's outline (:func:`~jkatana.maps.outline.find_blade`),
   its light (flat field or background fit), its camera
   (:func:`~jkatana.maps.register.register_photo`);
2. each photo's relative brightness sampled at every texel it sees, with its
   weight cos θ × feather;
3. sections that show neither end of the blade slid along u to where their
   content matches the photos that do (:func:`_slide`);
4. texels where a photo shows a mirror glint of the light (far brighter than
   its hamon) dropped from that photo (:func:`_drop_glints`); one gain per
   photo from the overlaps; photos of the same face whose
   overlaps disagree are refused (photos of different blades);
5. the weighted blend, then w: Otsu's threshold of the relative
   brightness (Otsu 1979) splits hiraji from hamon; w = 1 at and below the
   dark class's 90th percentile, 0 at and above the bright class's 10th,
   linear in between (the paper's rule, eq. 5's w from brightness, with levels
   that ignore the noisy tails of both classes);
6. texels no photo sees: the built-in map's values (:func:`default_map`),
   confidence 0.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jkatana.errors import InputError
from jkatana.maps.reflectance_map import PAPER_PARAMETERS, ReflectanceMap, default_map
from jkatana.maps.outline import PhotoOutline, find_blade
from jkatana.maps.register import (FEATHER_PX, MIN_COS, Camera, Registration, _icp, outline_residual,
                                   register_photo)
from jkatana.maps.surface import BladeSurface

#: Same-face photos are refused as photos of different blades (:func:`_check_same_blade`) where the course
#: of their hamon lines correlates less than this along the blade, or the hamon's share of the width differs
#: by more than ``MAX_DISAGREEMENT`` in the median column. Measured on the Mitsuba photos: one blade's
#: overlapping sections 0.55–0.82 and 2.5 %; the built-in hamon against the choji pattern −0.01 and 4.2 %.
MIN_LINE_CORRELATION = 0.3
MAX_DISAGREEMENT = 0.06


@dataclass
class PhotoView:
    """One photo after registration: its samples on the texel grid (per face)."""

    path: str
    shape: tuple[int, int]
    outline: PhotoOutline
    reg: Registration
    value: np.ndarray  # (H, W) relative brightness at the texels it sees (its registered face)
    weight: np.ndarray  # (H, W) cos θ × feather, 0 where unseen
    cos: np.ndarray  # (H, W)
    gain: float = 1.0
    slide_texels: int = 0
    glints: int = 0


@dataclass
class MosaicResult:
    map: ReflectanceMap
    confidence: np.ndarray
    seen: np.ndarray
    views: list
    summary: str
    report: dict = field(default_factory=dict)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    H, W = img.shape
    x = np.clip(x, 0, W - 1.000001)
    y = np.clip(y, 0, H - 1.000001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)


def sample_texels(surface: BladeSurface, cam: Camera, side: str, rel: np.ndarray, mask: np.ndarray):
    """(value, weight, cos) on the texel grid of ``side`` as seen by ``cam`` (0 weight where unseen)."""
    from scipy import ndimage

    Hm, Wm = surface.resolution
    H, W = rel.shape
    inner = ndimage.binary_erosion(mask, iterations=2)
    P = surface.points[side].reshape(-1, 3)
    N = surface.normals[side].reshape(-1, 3)
    ok = surface.valid[side].ravel().copy()
    x, z = cam.project(P)
    view = cam.centre - P
    cos = np.einsum("ij,ij->i", N, view) / np.maximum(np.linalg.norm(view, axis=1), 1e-12)
    ok &= (z > 0) & (cos > MIN_COS)
    ok &= (x[:, 0] >= 0) & (x[:, 0] <= W - 1) & (x[:, 1] >= 0) & (x[:, 1] <= H - 1)
    xi = np.clip(np.round(x).astype(int), 0, [W - 1, H - 1])
    ok &= inner[xi[:, 1], xi[:, 0]]
    value = np.zeros(len(P))
    value[ok] = _bilinear(rel, x[ok, 0], x[ok, 1])
    edge = np.minimum.reduce([x[:, 0], W - 1 - x[:, 0], x[:, 1], H - 1 - x[:, 1]])
    feather = np.clip(edge / FEATHER_PX, 0, 1)
    weight = np.where(ok, cos * feather, 0.0)
    return value.reshape(Hm, Wm), weight.reshape(Hm, Wm), np.where(ok, cos, 0.0).reshape(Hm, Wm)


def _prefilter(rel: np.ndarray, sigma: float = 0.7) -> np.ndarray:
    """A Gaussian of ``sigma`` pixels before point sampling: about a texel's footprint along the blade at the
    resolutions used here (2000 px over 1024 texels), so the samples average the photo's noise rather than
    alias it."""
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(rel, sigma)


def _ncc(a, b, m):
    if m.sum() < 50:
        return -np.inf
    a, b = a[m], b[m]
    a, b = a - a.mean(), b - b.mean()
    return float(a @ b / max(np.sqrt((a @ a) * (b @ b)), 1e-12))


def _slide(view: PhotoView, ref_val: np.ndarray, ref_w: np.ndarray) -> int:
    """The shift along u (texels) at which ``view``'s log brightness best matches the reference
    (normalised cross-correlation over the shared texels, at least 5 % of the grid's columns)."""
    H, W = view.value.shape
    seen = view.weight > 0
    cols = np.flatnonzero(seen.any(0))
    if len(cols) == 0:
        return 0
    rows = slice(0, H, 4)  # every 4th row: the hamon's line varies along u, not much within 4 texels across
    a = np.log(np.maximum(view.value[rows], 1e-4))
    b = np.log(np.maximum(ref_val[rows], 1e-4))
    seen, ref_seen = seen[rows], ref_w[rows] > 0

    def score(s: int) -> float:
        m = np.roll(seen, s, axis=1) & ref_seen
        if m.any(0).sum() < 0.05 * W:
            return -np.inf
        return _ncc(np.roll(a, s, axis=1), b, m)

    lo, hi = -int(cols[0]), W - 1 - int(cols[-1])
    coarse = max(range(lo, hi + 1, 4), key=score, default=0)  # every 4th shift, then the neighbours
    return max(range(max(lo, coarse - 4), min(hi, coarse + 4) + 1), key=score, default=coarse)


def _camera_slid(surface: BladeSurface, view: PhotoView, shift: int) -> Camera:
    """A camera that sees the blade ``shift`` texels further along u where ``view``'s camera sees it:
    the blade point at the middle of the photo's seen texels moved to its shifted texel, the camera
    turned about the flat's normal by the change of the blade's direction."""
    from scipy.spatial.transform import Rotation

    cam = view.reg.camera
    side = view.reg.side
    H, W = surface.resolution
    cols = np.flatnonzero((view.weight > 0).any(0))
    j0 = int(cols[len(cols) // 2])
    j1 = int(np.clip(j0 + shift, 1, W - 2))
    P = surface.points[side]
    i = H // 2
    X0, X1 = P[i, j0], P[i, j1]
    t0 = P[i, min(j0 + 1, W - 1)] - P[i, max(j0 - 1, 0)]
    t1 = P[i, min(j1 + 1, W - 1)] - P[i, max(j1 - 1, 0)]
    ang = math.atan2(t1[1], t1[0]) - math.atan2(t0[1], t0[0])
    Rz = Rotation.from_rotvec([0.0, 0.0, ang]).as_matrix()
    R_new = cam.R @ Rz.T  # world direction t1 maps where t0 did
    x0c = cam.R @ X0 + cam.t  # camera coordinates of the old point
    t_new = x0c - R_new @ X1
    return Camera(Rotation.from_matrix(R_new).as_rotvec(), t_new, cam.f, cam.cx, cam.cy)


#: A texel brighter than this many times the 90th percentile of the photo's bright (hamon) class is a
#: glint: the mirror-like hiraji reflecting the light itself, which says nothing of w.
GLINT_FACTOR = 3.0


def _drop_glints(view: PhotoView) -> None:
    """Texels where the photo shows a mirror glint of the light (far brighter than any hamon: the camera
    sits in the light's mirror direction there) are not seen by that photo; their count is reported."""
    from jkatana.maps.photo import otsu_threshold

    seen = view.weight > 0
    vals = view.value[seen]
    if vals.size < 100:
        return
    t = otsu_threshold(np.minimum(vals, np.percentile(vals, 95)))
    bright = vals[vals > t]
    if bright.size < 10:
        return
    glint = seen & (view.value > GLINT_FACTOR * np.percentile(bright, 90))
    view.glints = int(glint.sum())
    view.weight = np.where(glint, 0.0, view.weight)
    view.cos = np.where(glint, 0.0, view.cos)


def _levels(values: np.ndarray) -> tuple[float, float]:
    """(dark, bright) relative brightness: Otsu's split, then the dark class's 90th and the bright class's
    10th percentile (a mune roof that mirrors some light stays in the dark class: w = 1). Values above the
    99th percentile enter Otsu's histogram at that percentile: a mirror glint of the light on the hiraji
    (a camera far off the normal) is a few texels far brighter than the hamon, and would otherwise split
    off alone, leaving hamon and hiraji in one class."""
    from jkatana.maps.photo import otsu_threshold

    t = otsu_threshold(np.minimum(values, np.percentile(values, 99)))  # a glint's few texels do not set it
    lo, hi = values[values <= t], values[values > t]
    if lo.size < 10 or hi.size < 10:
        raise InputError("the photos show no hiraji/hamon contrast on the blade (one brightness class)",
                         field="photo")
    return float(np.percentile(lo, 90)), float(np.percentile(hi, 10))


def build_map(photos: list[tuple[str, np.ndarray]], surface: BladeSurface, *, flats: list | None = None,
              focal_px: list | None = None, sides: list | None = None, points: dict | None = None,
              dark: float | None = None, bright: float | None = None, hiraji: dict | None = None,
              hamon: dict | None = None, progress: bool = True) -> MosaicResult:
    """Register each ``(path, luminance)`` photo on ``surface`` and blend them into a map (module docstring)."""
    from tqdm import tqdm

    n = len(photos)
    views: list[PhotoView] = []
    for k, (path, y) in enumerate(tqdm(photos, desc="registering photos", file=sys.stderr, disable=not progress)):
        pts = points[Path(path).name] if points and Path(path).name in points else None
        views.append(_register_view(surface, path, y, flats[k] if flats else None,
                                    focal_px[k] if focal_px else None, (sides[k] if sides else None), pts))
    _slide_unanchored(surface, views, [y for _, y in photos])
    _gains(views)
    _check_same_blade(views)
    value, wsum = _blend(views)
    seen = wsum > 0
    Hm, Wm = surface.resolution
    if not seen.any():
        raise InputError("no photo sees the blade's texels", field="photo")
    if dark is None or bright is None:
        d, b = _levels(value[seen])
        dark = d if dark is None else dark
        bright = b if bright is None else bright
    if not bright > dark:
        raise InputError(f"need bright > dark, got dark={dark:g}, bright={bright:g}", field="--bright")
    w_seen = np.clip((bright - value) / (bright - dark), 0.0, 1.0)
    base = default_map((Hm, Wm))
    w = np.where(seen, w_seen, base.w)
    p = {**PAPER_PARAMETERS, **(hiraji or {}), **(hamon or {})}
    full = lambda x: np.full((Hm, Wm), x, np.float32)  # noqa: E731
    pick = lambda name: np.where(seen, full(p[name]), getattr(base, name))  # noqa: E731
    conf = 1.0 - np.prod([1.0 - v.weight for v in views], axis=0)
    conf = np.where(seen, conf, 0.0)
    residuals = [v.reg.residual_px for v in views]
    unseen = 100.0 * (1 - seen.mean())
    m = ReflectanceMap(w=w, mu0=pick("mu0"), chi=pick("chi"), mu1=pick("mu1"), beta=pick("beta"),
                       meta={"source": ", ".join(Path(v.path).name for v in views), "dark": float(dark),
                             "bright": float(bright), "registration_rms_px": float(max(residuals)),
                             "unseen_percent": float(unseen)})
    report = _report(views, dark, bright, unseen)
    return MosaicResult(m, conf.astype(np.float32), seen, views, _summary(views, n, unseen), report)


def _register_view(surface: BladeSurface, path, y: np.ndarray, flat, focal_px, side, pts) -> PhotoView:
    """One photo found (outline, light), registered on the blade (its side from ``side``, else from the
    clicked points ``pts``), and sampled into the map's texels, its glints left out."""
    if flat is not None and flat.shape != y.shape:
        raise InputError(f"flat field is {flat.shape[1]}×{flat.shape[0]}, the photo "
                         f"{y.shape[1]}×{y.shape[0]}", path=path, field="--flat")
    out = find_blade(y, flat=flat, path=path)
    reg = register_photo(surface, out, y.shape, focal_px=focal_px,
                         side=side or (pts["side"] if pts else None),
                         points=_point_pairs(surface, pts, path) if pts else None, path=path)
    rel = _prefilter(y / out.light)
    value, weight, cos = sample_texels(surface, reg.camera, reg.side, rel, out.mask)
    if not (weight > 0).any():
        raise InputError("the registered blade covers no texel of the map", path=path)
    view = PhotoView(str(path), y.shape, out, reg, value, weight, cos)
    _drop_glints(view)
    return view


def _slide_unanchored(surface: BladeSurface, views: list[PhotoView], lums: list[np.ndarray]) -> None:
    """Sections that see neither end of the blade slide along u to match the blend of the others seen so far
    (:func:`_slide`); each slid camera is refined on its outline (focal length fixed) and its photo (luminance
    ``lums[k]``) sampled again."""
    anchored = [v for v in views if v.reg.ends_seen > 0]
    for v in views:
        if v.reg.ends_seen > 0 or not anchored:
            continue
        ref_v, ref_w = _blend([a for a in anchored if a is not v])
        s = _slide(v, ref_v, ref_w)
        if s:
            cam = _camera_slid(surface, v, s)
            H, W = v.shape
            cam = _icp(surface, cam, v.outline.edge, v.outline.normal, W, H, iterations=20, gate=10.0, focal_prior=cam.f,
                       fix_focal=True)
            v.reg.camera = cam
            v.reg.residual_px = outline_residual(surface, cam, v.outline.edge, W, H)
            rel = _prefilter(lums[views.index(v)] / v.outline.light)
            v.value, v.weight, v.cos = sample_texels(surface, cam, v.reg.side, rel, v.outline.mask)
            _drop_glints(v)
            v.slide_texels = s
        anchored.append(v)


def _summary(views: list[PhotoView], n: int, unseen: float) -> str:
    """One line: the registration residuals, the share of texels seen, glints left out."""
    residuals = [v.reg.residual_px for v in views]
    sides_seen = sorted({v.reg.side for v in views})
    return (f"registration residual {max(residuals):.2f} px RMS (worst of {n} photo{'s' if n > 1 else ''}: "
            + ", ".join(f"{Path(v.path).name} {v.reg.residual_px:.2f} px {v.reg.side}" for v in views)
            + f"); {100 - unseen:.1f} % of texels seen"
            + (f", {unseen:.1f} % from the built-in map" if unseen > 0 else "")
            + (" (omote and ura share UVs: blended)" if len(sides_seen) == 2 else "")
            + (f"; {sum(v.glints for v in views)} texels showing a glint of the light left out"
               if any(v.glints for v in views) else ""))


def _report(views: list[PhotoView], dark: float, bright: float, unseen: float) -> dict:
    """The map's report: each photo's registration, gain, slide and coverage; the levels; where omote and ura
    both are seen, how far they disagree."""
    report = {
        "photos": [{"path": v.path, "side": v.reg.side, "residual_px": v.reg.residual_px,
                    "outline_points": v.reg.outline_points, "ends_seen": v.reg.ends_seen,
                    "focal_px": v.reg.camera.f, "off_normal_deg": v.reg.camera.off_normal_deg(),
                    "camera_centre_m": v.reg.camera.centre.tolist(), "rotvec": v.reg.camera.rotvec.tolist(),
                    "t": v.reg.camera.t.tolist(), "gain": v.gain, "slide_texels": v.slide_texels,
                    "glint_texels": v.glints,
                    "texels_seen_percent": float(100 * (v.weight > 0).mean())} for v in views],
        "dark": float(dark), "bright": float(bright), "unseen_percent": float(unseen),
        "filled_from": "the built-in map (jkatana.maps.default_map)" if unseen > 0 else None,
    }
    if len({v.reg.side for v in views}) == 2:
        report["omote_ura_disagreement"] = _side_disagreement(views, dark, bright)
    return report


def _point_pairs(surface: BladeSurface, pts: dict, path):
    """User-clicked points ``{"side": ..., "points": [[x, y, u, v], ...]}`` → (pixels (K, 2), 3-D (K, 3))."""
    side = pts.get("side", "omote")
    if side not in ("omote", "ura"):
        raise InputError(f"side must be omote or ura, got {side!r}", path=path, field="side")
    arr = np.asarray(pts.get("points", []), float)
    if arr.ndim != 2 or arr.shape[1] != 4 or len(arr) < 3 or not np.all(np.isfinite(arr)):
        raise InputError("need at least 3 points [x, y, u, v]", path=path, field="points")
    if arr[:, 2:].min() < 0 or arr[:, 2:].max() > 1:
        raise InputError("u, v must lie in [0, 1]", path=path, field="points")
    H, W = surface.resolution
    P = surface.points[side]
    X = np.stack([_bilinear(P[..., k], arr[:, 2] * W - 0.5, arr[:, 3] * H - 0.5) for k in range(3)], -1)
    return arr[:, :2], X


def _blend(views) -> tuple[np.ndarray, np.ndarray]:
    num = sum(v.weight * v.value * v.gain for v in views)
    den = sum(v.weight for v in views)
    return np.where(den > 0, num / np.maximum(den, 1e-12), 0.0), den


def _gains(views) -> None:
    """One gain per photo (geometric mean 1) from the median log ratios in same-face overlaps."""
    n = len(views)
    rows, rhs = [], []
    for i in range(n):
        for j in range(i + 1, n):
            if views[i].reg.side != views[j].reg.side:
                continue
            m = (views[i].weight > 0.05) & (views[j].weight > 0.05)
            if m.sum() < 200:
                continue
            r = np.median(np.log(np.maximum(views[i].value[m], 1e-4)) - np.log(np.maximum(views[j].value[m], 1e-4)))
            row = np.zeros(n)
            row[i], row[j] = 1.0, -1.0
            rows.append(row)
            rhs.append(-r)
    if not rows:
        return
    rows.append(np.ones(n))
    rhs.append(0.0)
    g, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    for v, gi in zip(views, g):
        v.gain = float(np.exp(gi))


def _check_same_blade(views) -> None:
    """Refuse same-face photos whose overlaps show different hamon lines: per texel column both see over at
    least 80 % of its height, the fraction of it that is hamon (brighter than Otsu's threshold of the pair's
    brightness) in each photo; two photos of one blade trace the same wiggles of the line along u (their
    profiles correlate), another blade's hamon does not. Offsets between the two (the hamon's brightness and
    a lit mune roof depend on the view) cancel in the correlation."""
    from scipy.ndimage import median_filter

    from jkatana.maps.photo import otsu_threshold

    n = len(views)
    for i in range(n):
        for j in range(i + 1, n):
            a, b = views[i], views[j]
            if a.reg.side != b.reg.side:
                continue
            m = (a.weight > 0.05) & (b.weight > 0.05)
            cols = m.mean(0) >= 0.8
            if cols.sum() < 20:
                continue
            va = median_filter(a.value * a.gain, size=3)
            vb = median_filter(b.value * b.gain, size=3)
            t = otsu_threshold(np.concatenate([va[m], vb[m]]))  # linear, as the levels: a lit mune roof is hiraji
            fa = ((va > t) & m).sum(0)[cols] / m.sum(0)[cols]
            fb = ((vb > t) & m).sum(0)[cols] / m.sum(0)[cols]
            d = float(np.median(np.abs(fa - fb)))
            k = np.ones(3) / 3  # the profiles' texel noise averaged over 3 columns
            fa, fb = np.convolve(fa, k, "valid"), np.convolve(fb, k, "valid")
            c = _ncc(fa, fb, np.ones(fa.shape, bool))
            wavy = min(fa.std(), fb.std()) > 0.005  # a straight line has no shape to compare
            if (wavy and c < MIN_LINE_CORRELATION) or d > MAX_DISAGREEMENT:
                raise InputError(f"its hamon differs from {Path(a.path).name}'s where both see the blade (the line's "
                                 f"course correlates {c:.2f}, its share of the width differs by {100 * d:.1f} % in the "
                                 "median column): photos of different blades?", path=b.path)


def _side_disagreement(views, dark, bright) -> float:
    """Mean |w_omote − w_ura| over the texels both faces' photos see."""
    out = {}
    for side in ("omote", "ura"):
        vv = [v for v in views if v.reg.side == side]
        val, den = _blend(vv)
        out[side] = (np.clip((bright - val) / (bright - dark), 0, 1), den > 0)
    m = out["omote"][1] & out["ura"][1]
    return float(np.mean(np.abs(out["omote"][0] - out["ura"][0])[m])) if m.any() else float("nan")


def preview_png(result: MosaicResult, photos: list[tuple[str, np.ndarray]], surface: BladeSurface,
                path: str | Path, *, width: int = 1400) -> Path:
    """Each photo (display-scaled) with the mesh drawn over it by its recovered camera: the silhouette in red,
    lines of constant u every 0.1 and of constant v at 0.25/0.5/0.75 in green; photos stacked, captioned
    with their residual."""
    from PIL import Image, ImageDraw

    from jkatana.io.atomic import atomic_path
    from jkatana.maps.register import _sample_silhouette

    panels = []
    Hm, Wm = surface.resolution
    for view, (_, y) in zip(result.views, photos):
        H, W = y.shape
        k = min(1.0, width / W)
        hi = float(np.percentile(y, 99.5)) or 1.0
        img = (np.clip(y / hi, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)
        im = Image.fromarray(img).convert("RGB").resize((max(1, int(W * k)), max(1, int(H * k))), Image.BILINEAR)
        d = ImageDraw.Draw(im)
        cam = view.reg.camera
        P = surface.points[view.reg.side]
        ok = surface.valid[view.reg.side]
        for j in np.linspace(0, Wm - 1, 11).astype(int):
            pts = cam.project(P[ok[:, j], j])[0] * k
            if len(pts) > 1:
                d.line([tuple(p) for p in pts], fill=(60, 220, 60), width=1)
        for fr in (0.25, 0.5, 0.75):
            i = int(fr * (Hm - 1))
            pts = cam.project(P[i, ok[i]])[0] * k
            if len(pts) > 1:
                d.line([tuple(p) for p in pts], fill=(60, 220, 60), width=1)
        _, xs = _sample_silhouette(surface, cam, W, H, spacing=2.0)
        for p in xs * k:
            d.point(tuple(p), fill=(255, 40, 40))
        d.text((8, 6), f"{Path(view.path).name}: {view.reg.side}, outline residual {view.reg.residual_px:.2f} px, "
                       f"{cam.off_normal_deg():.1f} deg off the normal, f {cam.f:.0f} px", fill=(255, 255, 0))
        panels.append(im)
    Wp = max(p.width for p in panels)
    out = Image.new("RGB", (Wp, sum(p.height for p in panels)), (0, 0, 0))
    yy = 0
    for p in panels:
        out.paste(p, (0, yy))
        yy += p.height
    with atomic_path(path) as tmp:
        out.save(tmp, format="PNG")
    return Path(path)


def write_confidence(result: MosaicResult, path: str | Path) -> Path:
    """The per-texel confidence (channel ``confidence``: 1 − Π(1 − cos θᵢ · featherᵢ) over the photos that
    see the texel, 0 where none does) as an EXR in the map's layout."""
    from jkatana.io.exr import write_exr

    return write_exr(path, {"confidence": result.confidence}, header={"jkatana_kind": "jkatana.map_confidence"})
