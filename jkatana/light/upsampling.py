"""RGB → spectrum upsampling of emission (HDR environment maps), by colour-science's methods.

An RGB environment map holds linear RGB radiance in arbitrary units. jkatana
turns every texel into a spectrum ``S(λ) = R(λ; rgb) · I(λ)``, where ``R`` is
a reflectance-like spectrum recovered from the RGB triplet and ``I`` the
colourspace's white (D65 for sRGB / Rec. 709), normalised so that

    Y_E(S) = Σ S ȳ Δλ / Σ ȳ Δλ

equals the luminance of the RGB triplet (``Y`` of a grey ``(c, c, c)`` is
``c``). A grey RGB value ``c`` therefore becomes the D65 spectrum with an
equal-energy-normalised luminance of ``c``. Round trip:
:func:`spectrum_to_rgb` inverts this convention, and
:func:`round_trip_error` reports ``|RGB → S → RGB − RGB|``.

Methods (registered in :data:`UPSAMPLING_METHODS`, chosen by name):

- ``"Jakob 2019"`` — Jakob & Hanika (2019), "A Low-Dimensional Function Space
  for Efficient Spectral Upsampling", CGF 38(2): a sigmoid of a quadratic
  polynomial per texel, coefficients from colour-science's
  ``LUT3D_Jakob2019`` (trilinear in the LUT). HDR values use pbrt-v4's
  ``RGBIlluminantSpectrum`` scaling (Pharr, Jakob & Humphreys 2023, §4.6.6):
  ``m = max(r, g, b)``, the LUT is queried at ``rgb / (2m)`` and the spectrum
  multiplied by ``2m``. The LUT is built once by colour-science (its optimiser,
  minutes) and cached; a resolution-8 sRGB LUT ships with jkatana. The LUT's
  trilinear coefficients are then refined per texel by a few Newton steps
  (vectorised, in normalised wavelength) so that the spectrum reproduces the
  RGB on the target grid — the per-colour optimisation of the paper, started
  from the LUT. ``"Jakob 2019 LUT"`` skips the refinement (LUT only).
- ``"Mallett 2019"`` — Mallett & Yuksel (2019), "Spectral Primary
  Decomposition for Rendering with sRGB Reflectance", EGSR: ``R = r b_r + g b_g
  + b b_b`` with colour-science's ``MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019``
  (linear, so exact for any HDR value; sRGB only).
- ``"Smits 1999"`` — Smits (1999), "An RGB-to-Spectrum Conversion for
  Reflectances", JGT 4(4), with colour-science's ``SDS_SMITS1999`` basis
  (10 samples 380–720 nm, linearly interpolated; vectorised here).
- ``"Flat"`` — no spectral detail: ``R(λ) = Y`` (a grey map stays grey; for
  the renderer's one-band mode).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from jkatana.errors import InputError
from jkatana.spectral.colorimetry import (colourspace as _colourspace, equal_energy_xyz_weights, illuminant,
                                         xyz_to_rgb_matrix)
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid

_DATA = Path(__file__).resolve().parents[1] / "data" / "upsampling"
SHIPPED_JAKOB_LUT = _DATA / "jakob2019_sRGB_8.coeff"


def _white(grid: WavelengthGrid, colourspace: str) -> np.ndarray:
    """The colourspace's white spectrum on ``grid``, scaled to Y_E = 1."""
    cs = _colourspace(colourspace)
    name = getattr(cs, "whitepoint_name", "D65") or "D65"
    try:
        w = illuminant(name, grid)
    except Exception:
        w = illuminant("D65", grid)
    return w / (w @ equal_energy_xyz_weights(grid)[:, 1])


def _rgb_to_xyz(colourspace: str) -> np.ndarray:
    return np.linalg.inv(xyz_to_rgb_matrix(colourspace))


def spectrum_to_rgb(spectrum, grid: WavelengthGrid = DEFAULT_GRID, colourspace: str = "sRGB") -> np.ndarray:
    """Inverse of the module's convention: spectra ``(..., wl)`` → linear RGB ``(..., 3)``.

    ``XYZ = Σ S x̄ȳz̄ / Σ ȳ`` (equal-energy normalisation), then the
    colourspace's XYZ → RGB matrix.
    """
    xyz = np.asarray(spectrum, np.float64) @ equal_energy_xyz_weights(grid)
    return xyz @ xyz_to_rgb_matrix(colourspace).T


def _mallett(rgb, grid, colourspace):
    import colour

    if colourspace not in ("sRGB", "ITU-R BT.709"):
        raise InputError(f"Mallett 2019 is defined for sRGB primaries only, not {colourspace!r}",
                         field="upsampling")
    basis = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    wl = grid.wavelengths
    B = np.stack([np.interp(wl, basis.wavelengths, basis.values[:, i]) for i in range(3)])  # (3, wl)
    return rgb @ B


def _smits(rgb, grid, colourspace):
    import colour

    sds = colour.recovery.SDS_SMITS1999
    wl = grid.wavelengths

    def b(name):
        sd = sds[name]
        return np.interp(wl, sd.wavelengths, sd.values)

    white, cyan, magenta, yellow = b("white"), b("cyan"), b("magenta"), b("yellow")
    red, green, blue = b("red"), b("green"), b("blue")
    r, g, bl = rgb[..., 0:1], rgb[..., 1:2], rgb[..., 2:3]
    out = np.zeros(rgb.shape[:-1] + (wl.size,))
    # Smits (1999), fig. 2: subtract the smallest component as white, then the
    # middle one as the complementary secondary, the rest as a primary.
    rmin = (r <= g) & (r <= bl)
    gmin = ~rmin & (g <= bl)
    bmin = ~rmin & ~gmin
    # red smallest → white + cyan (g, b) + green or blue
    o_r = r * white + np.where(g <= bl, (g - r) * cyan + (bl - g) * blue, (bl - r) * cyan + (g - bl) * green)
    o_g = g * white + np.where(r <= bl, (r - g) * magenta + (bl - r) * blue, (bl - g) * magenta + (r - bl) * red)
    o_b = bl * white + np.where(r <= g, (r - bl) * yellow + (g - r) * green, (g - bl) * yellow + (r - g) * red)
    out = np.where(rmin, o_r, np.where(gmin, o_g, o_b))
    del bmin
    return out


@functools.lru_cache(maxsize=4)
def jakob2019_lut(colourspace: str = "sRGB", size: int = 8, path: str | None = None):
    """colour-science's ``LUT3D_Jakob2019`` for ``colourspace``, built once and cached on disk.

    Looks in ``path``, then the shipped LUT (sRGB, size 8), then
    ``~/.cache/jkatana/jakob2019_<colourspace>_<size>.coeff``; otherwise runs
    colour-science's optimiser (minutes of CPU even at size 8, hence the
    shipped LUT and the cache) and writes the cache file.
    """
    import colour

    lut = colour.recovery.LUT3D_Jakob2019()
    candidates = [Path(path)] if path else []
    if colourspace == "sRGB" and size == 8:
        candidates.append(SHIPPED_JAKOB_LUT)
    cache = Path.home() / ".cache" / "jkatana" / f"jakob2019_{colourspace.replace(' ', '_')}_{size}.coeff"
    candidates.append(cache)
    for c in candidates:
        if c.is_file():
            lut.read(str(c))
            return lut
    cs = colour.RGB_COLOURSPACES[colourspace]
    lut.generate(cs, size=size, print_callable=lambda *a, **k: None)
    cache.parent.mkdir(parents=True, exist_ok=True)
    lut.write(str(cache))
    return lut


def _solve3(J, b):
    """``x`` with ``J x = b`` for stacks of 3×3 systems ``J (N, 3, 3)``, ``b (N, 3)``, by Cramer's rule (one
    vectorised pass; a batched LAPACK call pays its per-matrix overhead N times); singular rows give
    non-finite steps, which :func:`_jakob_refine` rejects."""
    c0, c1, c2 = J[:, :, 0], J[:, :, 1], J[:, :, 2]
    x12 = np.cross(c1, c2)
    det = np.sum(c0 * x12, -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([np.sum(b * x12, -1), np.sum(c0 * np.cross(b, c2), -1),
                         np.sum(c0 * np.cross(c1, b), -1)], -1) / det[:, None]


def _jakob_refine(coeffs, q, grid, colourspace, iters: int = 4):
    """Newton steps on the sigmoid-polynomial coefficients so that the spectrum reproduces ``q``
    exactly on ``grid`` (trilinear interpolation of the LUT's coefficients only approximates it).

    Works in normalised wavelength ``t = (λ − 550)/150``; a step is kept per texel only where it
    lowers the residual, so colours no sigmoid spectrum can reach keep their best (LUT or refined)
    approximation.
    """
    wl = grid.wavelengths
    t = (wl - 550.0) / 150.0
    c0, c1, c2 = coeffs[:, 0], coeffs[:, 1], coeffs[:, 2]
    s, l0 = 150.0, 550.0
    p = np.stack([c0 * s * s, s * (2 * c0 * l0 + c1), c0 * l0 * l0 + c1 * l0 + c2], axis=1)  # (N, 3)
    white = _white(grid, colourspace)
    A = (white[:, None] * equal_energy_xyz_weights(grid)) @ xyz_to_rgb_matrix(colourspace).T  # (wl, 3): R → rgb
    T = np.stack([t * t, t, np.ones_like(t)], axis=1)  # (wl, 3)
    AT = (A[:, :, None] * T[:, None, :]).reshape(len(wl), 9)  # J = dR @ AT: one matmul, not N small ones

    def model(p):
        U = p @ T.T
        root = np.sqrt(1.0 + U * U)
        return 0.5 + U / (2 * root), 1.0 / (2 * root**3)

    R, dR = model(p)
    res = R @ A - q
    err = np.max(np.abs(res), axis=1)
    for _ in range(iters):
        if not np.any(err > 1e-9):
            break
        J = (dR @ AT).reshape(-1, 3, 3) + 1e-12 * np.eye(3)  # (N, 3, 3): d rgb_c / d p_k
        step = _solve3(J, res)
        p_new = p - step
        R_new, dR_new = model(p_new)
        res_new = R_new @ A - q
        err_new = np.max(np.abs(res_new), axis=1)
        ok = np.isfinite(err_new) & (err_new < err)
        p = np.where(ok[:, None], p_new, p)
        R = np.where(ok[:, None], R_new, R)
        dR = np.where(ok[:, None], dR_new, dR)
        res = np.where(ok[:, None], res_new, res)
        err = np.where(ok, err_new, err)
    return R


def _jakob(rgb, grid, colourspace, lut_size: int = 8, refine: bool = True):
    lut = jakob2019_lut(colourspace, lut_size)
    m = np.max(rgb, axis=-1, keepdims=True)
    scale = 2.0 * m
    safe = np.where(scale > 0, scale, 1.0)
    q = np.clip(np.where(scale > 0, rgb / safe, 0.0), 0.0, 1.0)
    if refine:
        # the refined spectrum depends on the chromaticity q alone: solved once per distinct q (an RGBE map
        # holds a few distinct mantissa triples per texel), in blocks of 2¹⁵
        flat_q, inv = np.unique(q.reshape(-1, 3), axis=0, return_inverse=True)
        flat_c = np.reshape(lut.RGB_to_coefficients(flat_q), (-1, 3))
        flat_o = np.empty((flat_q.shape[0], grid.size))
        for s0 in range(0, flat_c.shape[0], 1 << 15):
            flat_o[s0:s0 + (1 << 15)] = _jakob_refine(flat_c[s0:s0 + (1 << 15)], flat_q[s0:s0 + (1 << 15)],
                                                      grid, colourspace)
        R = flat_o[inv.reshape(-1)].reshape(rgb.shape[:-1] + (grid.size,))
    else:
        coeffs = lut.RGB_to_coefficients(q.reshape(-1, 3)).reshape(rgb.shape[:-1] + (3,))
        wl = grid.wavelengths
        U = coeffs[..., 0:1] * wl**2 + coeffs[..., 1:2] * wl + coeffs[..., 2:3]
        R = 0.5 + U / (2.0 * np.sqrt(1.0 + U * U))
    return np.where(scale > 0, R * scale, 0.0)


def _jakob_lut_only(rgb, grid, colourspace):
    return _jakob(rgb, grid, colourspace, refine=False)


def _flat(rgb, grid, colourspace):
    Y = rgb @ _rgb_to_xyz(colourspace)[1]
    return np.repeat(Y[..., None], grid.size, axis=-1)


UPSAMPLING_METHODS = {
    "Jakob 2019": _jakob,
    "Jakob 2019 LUT": _jakob_lut_only,
    "Mallett 2019": _mallett,
    "Smits 1999": _smits,
    "Flat": _flat,
}


def rgb_to_spectrum(rgb, method: str = "Jakob 2019", grid: WavelengthGrid = DEFAULT_GRID, *,
                    colourspace: str = "sRGB", chunk: int = 1 << 18) -> np.ndarray:
    """Upsample linear RGB ``(..., 3)`` to spectral radiance ``(..., len(grid))`` (float32).

    **Arguments:**

    - `rgb`: linear RGB in `colourspace` (negative and non-finite values become 0).
    - `method`: a key of :data:`UPSAMPLING_METHODS`.
    - `grid`: target wavelength grid.
    - `chunk`: texels per batch (bounds the float64 temporaries).

    **Returns:** float32 spectra in the module's convention (``Y_E(S) = Y(rgb)``;
    the ``"Flat"`` method returns ``S = Y``, no illuminant).
    """
    if method not in UPSAMPLING_METHODS:
        raise InputError(f"unknown upsampling method {method!r}; choose one of {sorted(UPSAMPLING_METHODS)}",
                         field="upsampling")
    rgb = np.maximum(np.nan_to_num(np.asarray(rgb, np.float64), nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    if rgb.shape[-1] != 3:
        raise InputError(f"RGB input must have a last axis of 3, got {rgb.shape}", field="rgb")
    flat = rgb.reshape(-1, 3)
    out = np.empty((flat.shape[0], grid.size), np.float32)
    fn = UPSAMPLING_METHODS[method]
    white = None if method == "Flat" else _white(grid, colourspace)
    for s in range(0, flat.shape[0], chunk):
        part = fn(flat[s:s + chunk], grid, colourspace)
        out[s:s + chunk] = part if white is None else part * white
    return out.reshape(rgb.shape[:-1] + (grid.size,))


def round_trip_error(rgb, method: str = "Jakob 2019", grid: WavelengthGrid = DEFAULT_GRID, *,
                     colourspace: str = "sRGB") -> dict[str, float]:
    """RGB → spectrum → RGB error, relative to each texel's max channel.

    **Returns:** ``{"max": ..., "mean": ..., "p99": ...}`` of
    ``|rgb' − rgb|_∞ / max(rgb)`` over texels with ``max(rgb) > 0``.
    """
    rgb = np.maximum(np.asarray(rgb, np.float64).reshape(-1, 3), 0.0)
    rgb = rgb[rgb.max(axis=1) > 0]
    back = spectrum_to_rgb(rgb_to_spectrum(rgb, method, grid, colourspace=colourspace), grid, colourspace)
    err = np.max(np.abs(back - rgb), axis=1) / rgb.max(axis=1)
    return {"max": float(err.max()), "mean": float(err.mean()), "p99": float(np.quantile(err, 0.99))}


#: Nodes per side of :func:`chromaticity_table`: its bilinear interpolation of Jakob 2019 spectra is within
#: ~6e-5 (relative, Frobenius) of the per-texel upsampling on a natural HDR, ~1e-3 at worst per texel.
TABLE_NODES = 65


def chromaticity_table(project, method: str = "Jakob 2019", grid: WavelengthGrid = DEFAULT_GRID, *,
                       colourspace: str = "sRGB", nodes: int = TABLE_NODES) -> np.ndarray:
    """``project`` of the upsampled spectra of the RGB values of unit maximum, on a ``nodes × nodes`` grid per
    face of the RGB cube: ``(3, nodes, nodes, C)`` for a ``project: (N, wl) → (N, C)``.

    Every method here is homogeneous of degree one, ``S(c·rgb) = c·S(rgb)`` (Jakob 2019 through pbrt-v4's
    ``2m`` scaling, Mallett 2019 and the flat method by linearity, Smits 1999 by construction), so a spectrum
    is ``m = max(r, g, b)`` times the spectrum of ``rgb / m``, a point of one of the three faces ``{c_k = 1}``
    of the unit cube: a function of two coordinates in [0, 1]. Face ``k``'s table is indexed by the other two
    channels in increasing order (:func:`table_lookup`). A linear ``project`` (onto a spectral basis, a
    luminance) commutes with the scaling, so projected values interpolate as the spectra do.
    """
    a = np.linspace(0.0, 1.0, nodes)
    A, B = np.meshgrid(a, a, indexing="ij")
    faces = []
    for k in range(3):
        o1, o2 = (c for c in range(3) if c != k)
        rgb = np.zeros((nodes, nodes, 3))
        rgb[..., k], rgb[..., o1], rgb[..., o2] = 1.0, A, B
        faces.append(rgb)
    spectra = rgb_to_spectrum(np.stack(faces).reshape(-1, 3), method, grid, colourspace=colourspace)
    return np.asarray(project(spectra.astype(np.float64)), np.float64).reshape(3, nodes, nodes, -1)


def table_lookup(table: np.ndarray, rgb: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """``project(S(rgb))`` for RGB ``(N, 3)`` (non-negative) from a :func:`chromaticity_table` ``(3, n, n, C)``:
    bilinear on the face of the largest channel, times that channel. ``(N, C)`` float32, in chunks of
    ``chunk`` texels (each cell's four corners stored together: one gather per texel)."""
    n, C = table.shape[1], table.shape[-1]
    T = np.asarray(table, np.float32)
    cells = np.stack([T[:, :-1, :-1], T[:, :-1, 1:], T[:, 1:, :-1], T[:, 1:, 1:]], axis=3).reshape(-1, 4, C)
    rgb = np.asarray(rgb, np.float32).reshape(-1, 3)
    out = np.empty((rgb.shape[0], C), np.float32)
    for s in range(0, rgb.shape[0], chunk):
        r, g, b = rgb[s:s + chunk, 0], rgb[s:s + chunk, 1], rgb[s:s + chunk, 2]
        m = np.maximum(np.maximum(r, g), b)
        k = np.where(r >= np.maximum(g, b), 0, np.where(g >= b, 1, 2))
        inv = np.float32(n - 1) / np.where(m > 0, m, np.float32(1))
        x, y = np.where(k == 0, g, r) * inv, np.where(k == 2, g, b) * inv
        i0, j0 = np.minimum(x.astype(np.int32), n - 2), np.minimum(y.astype(np.int32), n - 2)
        fx, fy = x - i0, y - j0
        w = np.stack([(1 - fx) * (1 - fy), (1 - fx) * fy, fx * (1 - fy), fx * fy], axis=1) * m[:, None]
        out[s:s + chunk] = np.einsum("nk,nkc->nc", w, cells[(k * (n - 1) + i0) * (n - 1) + j0])
    return out
