"""RGL ``.bsdf`` files: the tensor-file container, evaluation as pbrt-v4 and Mitsuba 3 read it, and a writer.

J. Dupuy and W. Jakob (2018), "An adaptive parameterization for efficient
material acquisition and rendering", ACM Trans. Graph. 37(6) 274 — the
format of the RGL material database. No maintained Python reader is
published (the authors' ``brdf-loader`` is a C++ header with an unpublished
extension), so the documented format is implemented here, following the
reference evaluation ``powitacq.inl`` of that repository step by step.

**Container** (little-endian): ``b"tensor_file\\0"``, version (1, 0), a
``uint32`` field count, then per field its name (``uint16`` length + bytes),
``uint16`` rank, ``uint8`` dtype (1–11: u8 i8 u16 i16 u32 i32 u64 i64 f16
f32 f64), ``uint64`` offset of its data and ``uint64`` extents.

**Fields**: ``theta_i`` (n_θ,), ``phi_i`` (n_φ,) radians, the incidences the
tables are given at; ``ndf`` (H, W) the microfacet distribution D and
``sigma`` (H, W) the projected area σ(ωi) = ∫ D(ωm) ⟨ωm·ωi⟩ dωm, both over
the unit square u = (sqrt(θ / (π/2)), (φ + π) / 2π); ``vndf`` (n_φ, n_θ, H, W)
the visible-normal density in u-coordinates; ``luminance`` (n_φ, n_θ, h, w)
the luminance in the warped domain (for sampling); ``spectra``
(n_φ, n_θ, n_λ, h, w) or ``rgb`` (n_φ, n_θ, 3, h, w) the reflectance in
the warped domain; ``wavelengths`` (n_λ,) nm; ``description`` (bytes);
``jacobian`` (1,) u8.

**Stored quantity.** The reflectance table times D(ωm) / (4 σ(ωi)) is
f(ωi, ωo) · cos θo, the BRDF *with the cosine of the outgoing direction*:
what Mitsuba 3's ``measured`` plugin returns from ``eval`` (its BSDF
contract includes the cosine; ``src/bsdfs/measured.cpp``) and what pbrt-v4's
``MeasuredBxDF::f`` divides by |cos θo| to return f. ``jacobian = 0`` means
the table already holds f · cos θo without the D / 4σ factor. ωi is the
table's incident direction: Mitsuba's camera-side direction ``si.wi``, the
light's in the database's goniophotometer; the two coincide for the
reciprocal materials the database holds.

**Evaluation** f(ωi, ωo): ωm = normalize(ωi + ωo); its u-coordinates
(φm − φi for an isotropic file, n_φ ≤ 2) are mapped by the *inverse* of the
vndf's marginal–conditional warp (bilinear density, parameters interpolated
linearly) to the warped point s; f = spectra(s) · D(ωm) / (4 σ(ωi)) / cos θo.
``tests/test_brdf_interop.py`` checks it against Mitsuba's plugin on files
this module did not write.

**Writer** (:func:`rgl_from_function`): from an analytic isotropic BRDF and
its NDF, tables are built at chosen incidences: vndf ∝ D(ωm) ⟨ωm·ωi⟩ ·
2π² u₁ sin θm (the Jacobian of u → ω), ``spectra`` at the warped grid
points s is f(ωi, ωo(s)) · cos θo · 4σ(ωi) / D(ωm(s)), with ωm(s) the
*forward* warp of s, so that evaluation returns f at the grid and
interpolates between.
"""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path
from typing import Callable

import numpy as np

from jkatana.errors import InputError

_DTYPES = {1: "<u1", 2: "<i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f2", 10: "<f4",
           11: "<f8"}
_CODES = {np.dtype(v).str: k for k, v in _DTYPES.items()}
_MAGIC = b"tensor_file\0"


# --------------------------------------------------------------------------- container


def read_tensor_file(path) -> dict[str, np.ndarray]:
    """All fields of a tensor file as numpy arrays (module docstring); errors name the file and field."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path) from None
    if len(raw) < 18 or raw[:12] != _MAGIC:
        raise InputError("not a tensor file (bad header)", path=path, field="header")
    if raw[12:14] != b"\x01\x00":
        raise InputError(f"unknown tensor-file version {tuple(raw[12:14])}", path=path, field="version")
    (n_fields,) = struct.unpack_from("<I", raw, 14)
    pos, out = 18, {}
    try:
        for _ in range(n_fields):
            (nlen,) = struct.unpack_from("<H", raw, pos)
            name = raw[pos + 2: pos + 2 + nlen].decode("utf-8")
            pos += 2 + nlen
            ndim, code, offset = struct.unpack_from("<HBQ", raw, pos)
            pos += 11
            shape = struct.unpack_from(f"<{ndim}Q", raw, pos)
            pos += 8 * ndim
            if code not in _DTYPES:
                raise InputError(f"unknown dtype code {code}", path=path, field=name)
            dt = np.dtype(_DTYPES[code])
            count = int(np.prod(shape, dtype=np.int64))
            if offset + count * dt.itemsize > len(raw):
                raise InputError("data runs past the end of the file (truncated?)", path=path, field=name)
            out[name] = np.frombuffer(raw, dt, count, offset).reshape(shape).copy()
    except struct.error:
        raise InputError("truncated field table", path=path, field="header") from None
    return out


def write_tensor_file(fields: dict[str, np.ndarray], path) -> Path:
    """Write a tensor file atomically (data 8-byte aligned after the field table)."""
    from jkatana.io.atomic import write_bytes

    arrays = {k: np.ascontiguousarray(v) for k, v in fields.items()}
    for k, a in arrays.items():
        if a.dtype.newbyteorder("<").str not in _CODES:
            raise ValueError(f"field {k!r}: dtype {a.dtype} not storable in a tensor file")
    head = len(_MAGIC) + 2 + 4 + sum(2 + len(k.encode()) + 11 + 8 * a.ndim for k, a in arrays.items())
    offset = (head + 7) // 8 * 8
    table, blobs = [], []
    for k, a in arrays.items():
        a = a.astype(a.dtype.newbyteorder("<"))
        name = k.encode()
        table.append(struct.pack("<H", len(name)) + name + struct.pack("<HBQ", a.ndim, _CODES[a.dtype.str], offset)
                     + struct.pack(f"<{a.ndim}Q", *a.shape))
        blob = a.tobytes()
        pad = (-len(blob)) % 8
        blobs.append(blob + b"\0" * pad)
        offset += len(blob) + pad
    data = _MAGIC + b"\x01\x00" + struct.pack("<I", len(arrays)) + b"".join(table)
    data += b"\0" * ((-len(data)) % 8) + b"".join(blobs)
    return write_bytes(path, data)


# --------------------------------------------------------------------------- warps


def _theta2u(theta):
    return np.sqrt(np.clip(theta, 0.0, None) * (2.0 / np.pi))


def _phi2u(phi):
    return (phi + np.pi) / (2.0 * np.pi)


def _u2theta(u):
    return u * u * (np.pi / 2)


def _u2phi(u):
    return (2.0 * u - 1.0) * np.pi


def _param_weights(values: np.ndarray, x: np.ndarray):
    """Lower index and weight of the upper node for linear interpolation in a parameter (clamped)."""
    values = np.asarray(values, np.float64)
    if values.size == 1:
        return np.zeros(np.shape(x), np.int64), np.zeros(np.shape(x))
    i = np.clip(np.searchsorted(values, x, side="right") - 1, 0, values.size - 2)
    w = np.clip((x - values[i]) / (values[i + 1] - values[i]), 0.0, 1.0)
    return i, w


def _bilerp(table, pos):
    """Bilinear lookup of ``table[..., H, W]`` at unit-square positions ``pos[..., (x, y)]`` (x along W)."""
    H, W = table.shape[-2:]
    x = pos[..., 0] * (W - 1)
    y = pos[..., 1] * (H - 1)
    ix = np.clip(np.floor(x).astype(np.int64), 0, W - 2)
    iy = np.clip(np.floor(y).astype(np.int64), 0, H - 2)
    tx, ty = x - ix, y - iy
    t = table
    return ((1 - ty) * ((1 - tx) * t[..., iy, ix] + tx * t[..., iy, ix + 1])
            + ty * ((1 - tx) * t[..., iy + 1, ix] + tx * t[..., iy + 1, ix + 1]))


def _cdfs(data):
    """Normalised density, conditional and marginal CDFs of ``data[..., H, W]`` (powitacq's Marginal2D)."""
    data = np.asarray(data, np.float64)
    cc = np.concatenate([np.zeros(data.shape[:-1] + (1,)),
                         np.cumsum(0.5 * (data[..., :-1] + data[..., 1:]), axis=-1)], axis=-1)
    rows = cc[..., -1]
    mc = np.concatenate([np.zeros(rows.shape[:-1] + (1,)), np.cumsum(0.5 * (rows[..., :-1] + rows[..., 1:]), -1)],
                        axis=-1)
    norm = 1.0 / mc[..., -1:]
    return data * norm[..., None], cc * norm[..., None], mc * norm


def _invert(dens, cc, mc, u):
    """Inverse warp of one slice set: u ``(N, 2)`` → (sample ``(N, 2)``, density); ``dens`` etc. ``(N, H, W)``."""
    N = u.shape[0]
    H, W = dens.shape[-2:]
    s = u * np.array([W - 1, H - 1])
    px = np.minimum(np.floor(s[:, 0]).astype(np.int64), W - 2)
    py = np.minimum(np.floor(s[:, 1]).astype(np.int64), H - 2)
    fx, fy = s[:, 0] - px, s[:, 1] - py
    n = np.arange(N)
    v00, v10 = dens[n, py, px], dens[n, py, px + 1]
    v01, v11 = dens[n, py + 1, px], dens[n, py + 1, px + 1]
    c0 = (1 - fy) * v00 + fy * v01
    c1 = (1 - fy) * v10 + fy * v11
    pdf = (1 - fx) * c0 + fx * c1
    sx = fx * (c0 + 0.5 * fx * (c1 - c0))
    sx = sx + (1 - fy) * cc[n, py, px] + fy * cc[n, py + 1, px]
    r0, r1 = cc[n, py, W - 1], cc[n, py + 1, W - 1]
    sx = sx / ((1 - fy) * r0 + fy * r1)
    sy = fy * (r0 + 0.5 * fy * (r1 - r0)) + mc[n, py]
    return np.stack([sx, sy], -1), pdf * (W - 1) * (H - 1)


def _sample(dens, cc, mc, s):
    """Forward warp of one slice ``(H, W)``: warped points s ``(N, 2)`` → u ``(N, 2)`` (powitacq's sample)."""
    H, W = dens.shape
    s = np.clip(s, 1.0 - 0.999999940395355225, 0.999999940395355225)
    sy = s[:, 1].copy()
    row = np.clip(np.searchsorted(mc, sy, side="left") - 1, 0, H - 2)
    sy = sy - mc[row]
    r0, r1 = cc[row, W - 1], cc[row + 1, W - 1]
    const = np.abs(r0 - r1) < 1e-4 * (r0 + r1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ty = np.where(const, 2 * sy / (r0 + r1), (r0 - np.sqrt(np.maximum(r0 * r0 - 2 * sy * (r0 - r1), 0.0)))
                      / np.where(const, 1.0, r0 - r1))
    sx = s[:, 0] * ((1 - ty) * r0 + ty * r1)
    cond = (1 - ty)[:, None] * cc[row] + ty[:, None] * cc[row + 1]
    col = np.clip(np.sum(cond < sx[:, None], axis=1) - 1, 0, W - 2)
    n = np.arange(s.shape[0])
    sx = sx - cond[n, col]
    v00, v10 = dens[row, col], dens[row, col + 1]
    v01, v11 = dens[row + 1, col], dens[row + 1, col + 1]
    c0 = (1 - ty) * v00 + ty * v01
    c1 = (1 - ty) * v10 + ty * v11
    const = np.abs(c0 - c1) < 1e-4 * (c0 + c1)
    with np.errstate(invalid="ignore", divide="ignore"):
        tx = np.where(const, 2 * sx / (c0 + c1), (c0 - np.sqrt(np.maximum(c0 * c0 - 2 * sx * (c0 - c1), 0.0)))
                      / np.where(const, 1.0, c0 - c1))
    return np.stack([(col + tx) / (W - 1), (row + ty) / (H - 1)], -1)


# --------------------------------------------------------------------------- BRDF


@dataclasses.dataclass
class RGLBRDF:
    """An RGL ``.bsdf`` material (module docstring); ``fields`` as read, ``source`` the file."""

    fields: dict
    source: str | None = None

    def __post_init__(self):
        f = self.fields
        need = ("theta_i", "phi_i", "ndf", "sigma", "vndf")
        missing = [k for k in need if k not in f]
        if missing or ("spectra" not in f and "rgb" not in f):
            raise InputError(f"missing fields {missing or ['spectra or rgb']}", path=self.source,
                             field=(missing or ["spectra"])[0])
        self.theta_i = np.asarray(f["theta_i"], np.float64)
        self.phi_i = np.asarray(f["phi_i"], np.float64)
        self.isotropic = self.phi_i.size <= 2
        nphi, nth = self.phi_i.size, self.theta_i.size
        self.refl = np.asarray(f["spectra"] if "spectra" in f else f["rgb"], np.float64)
        if f["vndf"].shape[:2] != (nphi, nth) or self.refl.shape[:2] != (nphi, nth):
            raise InputError(f"vndf {f['vndf'].shape} / reflectance {self.refl.shape} do not match "
                             f"(phi_i, theta_i) = ({nphi}, {nth})", path=self.source, field="vndf")
        self.dens, self.cc, self.mc = _cdfs(f["vndf"])
        self.jacobian = bool(np.asarray(f.get("jacobian", [1])).ravel()[0])
        if "spectra" in f:
            self.wavelengths = np.asarray(f["wavelengths"], np.float64)
            self.channels = tuple(f"{w:g}nm" for w in self.wavelengths)
        else:
            self.wavelengths = None
            self.channels = ("red", "green", "blue")

    def _channel_weights(self, channel):
        if self.wavelengths is None:
            if channel not in self.channels:
                raise InputError(f"RGB file: channel must be one of {self.channels}, got {channel!r}",
                                 path=self.source, field="channel")
            w = np.zeros(3)
            w[self.channels.index(channel)] = 1.0
            return w
        try:
            lam = float(str(channel).lower().removesuffix("nm"))
        except ValueError:
            raise InputError(f"spectral file: channel must be a wavelength like '550nm' "
                             f"({self.wavelengths[0]:g}–{self.wavelengths[-1]:g} nm), got {channel!r}",
                             path=self.source, field="channel") from None
        i, t = _param_weights(self.wavelengths, np.asarray(lam))
        w = np.zeros(self.wavelengths.size)
        w[i] += 1 - t
        w[i + 1] += t
        return w

    def eval(self, wi, wo, channel="green") -> np.ndarray:
        """BRDF (1/sr) at direction pairs ``(..., 3)`` (module docstring); 0 below the horizon."""
        wi = np.asarray(wi, np.float64)
        wo = np.asarray(wo, np.float64)
        shape = np.broadcast_shapes(wi.shape, wo.shape)[:-1]
        wi = np.broadcast_to(wi, shape + (3,)).reshape(-1, 3)
        wo = np.broadcast_to(wo, shape + (3,)).reshape(-1, 3)
        cw = self._channel_weights(channel)
        wm = wi + wo
        wm = wm / np.maximum(np.linalg.norm(wm, axis=-1, keepdims=True), 1e-300)
        th_i = np.arccos(np.clip(wi[:, 2], -1, 1))
        ph_i = np.arctan2(wi[:, 1], wi[:, 0])
        th_m = np.arccos(np.clip(wm[:, 2], -1, 1))
        ph_m = np.arctan2(wm[:, 1], wm[:, 0])
        u_wi = np.stack([_theta2u(th_i), _phi2u(ph_i)], -1)
        um_y = _phi2u(ph_m - ph_i if self.isotropic else ph_m)
        u_wm = np.stack([_theta2u(th_m), um_y - np.floor(um_y)], -1)
        ip, wp = _param_weights(self.phi_i, ph_i)
        it, wt = _param_weights(self.theta_i, th_i)
        np1 = np.minimum(ip + 1, self.phi_i.size - 1)
        nt1 = np.minimum(it + 1, self.theta_i.size - 1)

        def mix(a):
            return ((1 - wp)[:, None, None] * ((1 - wt)[:, None, None] * a[ip, it] + wt[:, None, None] * a[ip, nt1])
                    + wp[:, None, None] * ((1 - wt)[:, None, None] * a[np1, it] + wt[:, None, None] * a[np1, nt1]))

        s, _ = _invert(mix(self.dens), mix(self.cc), mix(self.mc[..., None])[..., 0], u_wm)
        R = np.tensordot(self.refl, cw, axes=([2], [0]))  # (nφ, nθ, h, w)
        vals = []
        for a, b, wgt in ((ip, it, (1 - wp) * (1 - wt)), (ip, nt1, (1 - wp) * wt), (np1, it, wp * (1 - wt)),
                          (np1, nt1, wp * wt)):
            vals.append(wgt * _bilerp_rows(R[a, b], s))
        fr = sum(vals)
        ndf = _bilerp(np.asarray(self.fields["ndf"], np.float64), u_wm)
        sig = _bilerp(np.asarray(self.fields["sigma"], np.float64), u_wi)
        if self.jacobian:
            fr = fr * ndf / (4.0 * sig)
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            fr = fr / wo[:, 2]  # the table holds f·cos θo (module docstring, "Stored quantity")
        return np.where(ok, fr, 0.0).reshape(shape)


def _bilerp_rows(tables, pos):
    """Bilinear lookup of per-point tables ``(N, h, w)`` at ``pos (N, 2)``."""
    N, H, W = tables.shape
    x = pos[:, 0] * (W - 1)
    y = pos[:, 1] * (H - 1)
    ix = np.clip(np.floor(x).astype(np.int64), 0, W - 2)
    iy = np.clip(np.floor(y).astype(np.int64), 0, H - 2)
    tx, ty = x - ix, y - iy
    n = np.arange(N)
    t = tables
    return ((1 - ty) * ((1 - tx) * t[n, iy, ix] + tx * t[n, iy, ix + 1])
            + ty * ((1 - tx) * t[n, iy + 1, ix] + tx * t[n, iy + 1, ix + 1]))


def read_rgl(path) -> RGLBRDF:
    """Read an RGL ``.bsdf`` file (module docstring)."""
    return RGLBRDF(read_tensor_file(path), source=str(path))


def write_rgl(brdf: RGLBRDF, path) -> Path:
    """Write an :class:`RGLBRDF`'s fields as a tensor file (atomic)."""
    return write_tensor_file(brdf.fields, path)


def rgl_from_function(brdf: Callable[[np.ndarray, np.ndarray], np.ndarray], ndf: Callable[[np.ndarray], np.ndarray],
                      *, theta_i_deg=None, channels=("red", "green", "blue"), ndf_res: int = 257,
                      vndf_res: int = 129, refl_res: int = 257, description: str = "jkatana analytic BRDF"
                      ) -> RGLBRDF:
    """Tabulate an isotropic analytic BRDF in the RGL layout (module docstring, "Writer").

    **Arguments:**

    - `brdf`: ``brdf(wi, wo) → (..., C)`` in 1/sr, one column per channel;
      ``wi`` is the table's incident direction (Mitsuba's camera side, so a
      non-reciprocal lobe meant for Mitsuba is passed as f(L = wo, V = wi)).
    - `ndf`: ``ndf(cos θm) → D`` (any positive normalisation; the reflectance
      table compensates, so it only sets where the table's samples fall).
    - `theta_i_deg`: incidences of the tables (default: 0–85° every 5°);
      evaluation interpolates linearly between them.
    - `channels`: names: ``red/green/blue`` (an RGB file, C = 3) or
      wavelengths in nm (a spectral file).
    - `ndf_res`, `vndf_res`, `refl_res`: table resolutions (square). The
      reflectance table sets the accuracy of lobes with Gaussian tails (the
      paper's, Beckmann): their tails hold little of the vndf's mass, so few
      warped samples fall there and the reflectance f·4σ/D — which still
      varies with 1/cos θo and masking towards grazing — is interpolated
      bilinearly over wide cells. The error falls as the square of the
      spacing; the ``ndf`` and ``vndf`` resolutions barely matter (on a
      three-incidence in-plane protocol at σ = 5 % ⊕ 1e-3 peak, Beckmann
      α = 0.07 reads back within 0.35σ RMS at ``refl_res`` 97, 0.094σ at
      193, 0.041σ at 257; GGX within 0.011σ at 257), hence the default of
      257, finer than the database's own tables.
    """
    th_nodes = np.deg2rad(np.arange(0.0, 86.0, 5.0) if theta_i_deg is None
                          else np.sort(np.asarray(theta_i_deg, np.float64)))
    phi_nodes = np.array([0.0, 2 * np.pi]) - np.pi  # isotropic: two equal slices over φ ∈ [−π, π]
    ux, uy = _u_grid(ndf_res)
    m, th = _u_dirs(ux, uy)
    D = np.asarray(ndf(np.cos(th)), np.float64)
    proj_area = _projected_area(ndf)
    # isotropic: σ depends on θ only, i.e. on the grid column
    sig_col = np.array([proj_area(v) for v in m[0]])
    sig = np.broadcast_to(sig_col[None, :], D.shape)

    vx, vy = _u_grid(vndf_res)
    vm, vth = _u_dirs(vx, vy, -np.pi)  # isotropic tables: φm relative to φi = −π
    vD = np.asarray(ndf(np.cos(vth)), np.float64) * 2 * np.pi**2 * vx * np.sin(vth)
    rx, ry = _u_grid(refl_res)
    s_grid = np.stack([rx.ravel(), ry.ravel()], -1)
    nth = th_nodes.size
    vndf = np.zeros((2, nth, vndf_res, vndf_res))
    refl = np.zeros((2, nth, len(channels), refl_res, refl_res))
    for j, t in enumerate(th_nodes):
        wi = np.array([np.sin(t) * np.cos(-np.pi), np.sin(t) * np.sin(-np.pi), np.cos(t)])
        v = vD * np.maximum(vm @ wi, 0.0)
        vndf[:, j] = v
        r = _reflectance(brdf, ndf, wi, _sample(*_cdfs(v), s_grid), proj_area(wi), refl_res)
        refl[:, j] = np.moveaxis(r, -1, 0)
    return RGLBRDF(_tabulated_fields(th_nodes, phi_nodes, D, sig, vndf, refl, channels, description))


def _u_grid(res: int):
    """The unit square's ``res``² nodes as (x, y) arrays of shape (H = y, W = x)."""
    u = np.linspace(0.0, 1.0, res)
    ux, uy = np.meshgrid(u, u, indexing="xy")  # (H=y, W=x)
    return ux, uy


def _u_dirs(ux, uy, phi0=0.0):
    """Directions at unit-square coordinates (the layout's θ and φ warps, φ offset by ``phi0``), and θ."""
    th, ph = _u2theta(ux), _u2phi(uy) + phi0
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1), th


def _projected_area(ndf: Callable[[np.ndarray], np.ndarray]) -> Callable[[np.ndarray], float]:
    """σ(ωi) = ∫ D(ωm) ⟨ωm·ωi⟩ dωm, the microfacets' projected area, by trapezoidal quadrature over a 257² grid
    of the unit square (the θ warp's Jacobian 2π²·x·sin θ included)."""
    qx, qy = _u_grid(257)
    qm, qth = _u_dirs(qx, qy)
    qD = np.asarray(ndf(np.cos(qth)), np.float64) * 2 * np.pi**2 * qx * np.sin(qth)
    du = 1.0 / 256
    wq = np.full(qx.shape, du * du)
    wq[0, :] *= 0.5
    wq[-1, :] *= 0.5
    wq[:, 0] *= 0.5
    wq[:, -1] *= 0.5

    def proj_area(wi):
        return np.sum(qD * np.maximum(qm @ wi, 0.0) * wq)

    return proj_area


def _reflectance(brdf, ndf, wi, u, sig_i: float, refl_res: int) -> np.ndarray:
    """The reflectance table f·cos θo·4σ/D (refl_res, refl_res, C) at one incidence ``wi``, at the microfacet
    normals that the vndf's warp puts at unit-square points ``u``.

    Cells whose ωo lies below the horizon border visible ones in the warped domain: they take the value of the
    nearest visible cell, so bilinear interpolation next to them is not dragged towards 0 (evaluation returns 0
    below the horizon regardless); a table with no visible cell is 0."""
    thm, phm = _u2theta(u[:, 0]), _u2phi(u[:, 1]) - np.pi  # isotropic: φm relative to φi = −π
    wm = np.stack([np.sin(thm) * np.cos(phm), np.sin(thm) * np.sin(phm), np.cos(thm)], -1)
    wo = 2 * (wm @ wi)[:, None] * wm - wi
    f = np.asarray(brdf(np.broadcast_to(wi, wo.shape), wo), np.float64)
    Dm = np.asarray(ndf(np.cos(thm)), np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (f * np.maximum(wo[:, 2], 0.0)[:, None] * 4 * sig_i / Dm[:, None]).reshape(refl_res, refl_res, -1)
    valid = ((wo[:, 2] > 0) & (Dm > 0) & np.all(np.isfinite(r.reshape(-1, r.shape[-1])), -1)).reshape(
        refl_res, refl_res)
    if valid.any() and not valid.all():
        from scipy.ndimage import distance_transform_edt

        _, (iy, ix) = distance_transform_edt(~valid, return_indices=True)
        r = r[iy, ix]
    return np.where(valid.any(), r, 0.0)


def _tabulated_fields(th_nodes, phi_nodes, D, sig, vndf, refl, channels, description: str) -> dict:
    """The tensor file's fields (float32 little-endian), RGB or spectral by the channels' names."""
    fields = dict(theta_i=th_nodes.astype("<f4"), phi_i=phi_nodes.astype("<f4"), ndf=D.astype("<f4"),
                  sigma=sig.astype("<f4"), vndf=vndf.astype("<f4"),
                  luminance=np.mean(refl, axis=2).astype("<f4"),
                  description=np.frombuffer(description.encode(), np.uint8).copy(),
                  jacobian=np.array([1], np.uint8))
    if tuple(channels) == ("red", "green", "blue"):
        fields["rgb"] = refl.astype("<f4")
    else:
        fields["spectra"] = refl.astype("<f4")
        fields["wavelengths"] = np.array([float(str(c).lower().removesuffix("nm")) for c in channels], "<f4")
    return fields


__all__ = ["RGLBRDF", "read_rgl", "write_rgl", "rgl_from_function", "read_tensor_file", "write_tensor_file"]
