"""The blade in a photo (:mod:`jkatana.maps.register`, steps 1–2): the light it was lit by, its mask, outline and
ends.

The background's brightness is a smooth fit (a bivariate polynomial in log brightness, refitted without
outliers; :func:`background_fit`), or a flat-field photo when given; the blade is the pixels that differ from it
by more than six robust sigmas of its noise (at least 15 %), the largest connected region, holes filled
(:func:`find_blade`). Its outline is the midpoints between in/out pixel pairs, except along the image's border.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jkatana.errors import InputError


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
    """Segment the blade against the background (module docstring); :class:`InputError` when no
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


__all__ = ["PhotoOutline", "background_fit", "find_blade"]
