"""Independent references for the measured-BRDF file formats: files built from the published layouts
(not by jkatana's writers) and the published readers' lookups, re-written here in a few lines of NumPy.

- **RGL ``.bsdf``** (Dupuy & Jakob 2018, "An adaptive parameterization for efficient material acquisition
  and rendering", ACM TOG 37(6); the tensor-file container of Mitsuba 3's ``TensorFile`` and the field
  list that Mitsuba 3's ``measured`` plugin checks): :func:`write_tensor_file_by_hand` lays out the
  container byte by byte, :func:`smooth_rgl_fields` fills every field with smooth positive tables of the
  shapes the plugin requires, and :func:`mitsuba_measured_eval` evaluates a file with Mitsuba's own
  ``measured`` BSDF. Mitsuba's ``eval`` returns f·cos θo (its BSDF contract), so f = eval / cos θo.
- **MERL ``.binary``** (Matusik, Pfister, Brand & McMillan 2003, "A data-driven reflectance model",
  ACM TOG 22(3); the reference reader ``BRDFRead.cpp`` distributed with the database):
  :func:`merl_reference_lookup` is that reader's ``lookup_brdf_val`` (half/difference angles by its two
  rotations, indices rounded down, channel blocks and scales), :func:`write_merl_by_hand` writes the
  header and three float64 blocks of a BRDF given as a function of the Rusinkiewicz angles at the
  reader's index nodes.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

# ----------------------------------------------------------------------------------------------- RGL

_DTYPE_CODES = {"u1": 1, "f4": 10}


def write_tensor_file_by_hand(fields: dict[str, np.ndarray], path) -> Path:
    """Write Mitsuba 3's tensor-file container: ``"tensor_file\\0"``, version 1.0, field count, then per
    field name length (u16), name, rank (u16), dtype code (u8), data offset (u64) and extents (u64 each);
    the data follows the table. Only uint8 and float32 fields (all that ``measured`` reads)."""
    names = list(fields)
    arrays = [np.ascontiguousarray(fields[k]) for k in names]
    header = b"tensor_file\0" + bytes([1, 0]) + struct.pack("<I", len(names))
    table_len = sum(2 + len(k) + 2 + 1 + 8 + 8 * a.ndim for k, a in zip(names, arrays))
    offset = len(header) + table_len
    table, data = b"", b""
    for k, a in zip(names, arrays):
        code = _DTYPE_CODES[a.dtype.str[1:]]
        table += struct.pack("<H", len(k)) + k.encode() + struct.pack("<HBQ", a.ndim, code, offset + len(data))
        table += b"".join(struct.pack("<Q", n) for n in a.shape)
        data += a.astype(a.dtype.newbyteorder("<")).tobytes()
    path = Path(path)
    path.write_bytes(header + table + data)
    return path


def smooth_rgl_fields(*, n_theta: int = 7, res: int = 24, spectral: bool = False, seed: int = 0) -> dict:
    """The fields of an isotropic ``.bsdf`` (``phi_i`` = (−π, π), Mitsuba's isotropic layout) with smooth,
    strictly positive random tables: a Beckmann-like ``ndf``, ``sigma``, ``vndf`` and ``luminance``, and
    reflectance ``rgb`` (3 channels) or ``spectra`` (5 wavelengths, 400–700 nm). The two φi slices hold the
    same tables, as an isotropic material's do."""
    rng = np.random.default_rng(seed)
    u = np.linspace(0.0, 1.0, res)
    ux, uy = np.meshgrid(u, u, indexing="xy")

    def smooth(*lead):
        """``(2, *lead, res, res)``: one smooth positive table per entry of ``lead``, the same in both φi slices."""
        a = rng.uniform(0.2, 1.0, lead + (1, 1))
        fx, fy, ph = (rng.uniform(0.5, 2.0, lead + (1, 1)), rng.uniform(0.5, 2.0, lead + (1, 1)),
                      rng.uniform(0, 2 * np.pi, lead + (1, 1)))
        one = (1.0 + a * np.sin(2 * np.pi * fx * ux + ph) * np.cos(np.pi * fy * uy)).astype(np.float32)
        return np.repeat(one[None], 2, axis=0)

    theta_m = ux ** 2 * (np.pi / 2)
    ndf = (np.exp(-np.tan(theta_m) ** 2 / 0.3 ** 2) / np.cos(np.minimum(theta_m, 1.5)) ** 4 + 0.05)
    channels = 5 if spectral else 3
    fields = {
        "description": np.frombuffer(b"independent test file", np.uint8),
        "jacobian": np.array([1], np.uint8),
        "theta_i": np.deg2rad(np.linspace(0.0, 85.0, n_theta)).astype(np.float32),
        "phi_i": np.array([-np.pi, np.pi], np.float32),
        "ndf": ndf.astype(np.float32),
        "sigma": (0.8 + 0.2 * ux).astype(np.float32),
        "vndf": smooth(n_theta) * ndf.astype(np.float32),
        "luminance": smooth(n_theta),
        ("spectra" if spectral else "rgb"): smooth(n_theta, channels) * 0.1,
    }
    if spectral:
        fields["wavelengths"] = np.linspace(400.0, 700.0, channels).astype(np.float32)
    return fields


def mitsuba_measured_eval(path, wi: np.ndarray, wo: np.ndarray, variant: str, wavelengths=None) -> np.ndarray:
    """Mitsuba 3's ``measured`` BSDF evaluated at direction pairs ``(N, 3)`` (``si.wi`` = ``wi``): f·cos θo,
    ``(N, C)`` (RGB variants: 3 channels; spectral: one column per wavelength of ``wavelengths``)."""
    import mitsuba as mi

    mi.set_variant(variant)
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*[np.ascontiguousarray(wi[:, k], np.float32) for k in range(3)])
    n = wi.shape[0]
    cols = []
    if wavelengths is None:
        v = bsdf.eval(ctx, si, mi.Vector3f(*[np.ascontiguousarray(wo[:, k], np.float32) for k in range(3)]))
        return np.stack([np.asarray(v[c], np.float64).reshape(-1) * np.ones(n) for c in range(3)], -1)
    for lam in wavelengths:
        si.wavelengths = mi.Spectrum(*([mi.Float(np.full(n, lam, np.float32))] * 4))
        v = bsdf.eval(ctx, si, mi.Vector3f(*[np.ascontiguousarray(wo[:, k], np.float32) for k in range(3)]))
        cols.append(np.asarray(v[0], np.float64).reshape(-1) * np.ones(n))
    return np.stack(cols, -1)


# ---------------------------------------------------------------------------------------------- MERL

RES_TH, RES_TD, RES_PD = 90, 90, 360  # BRDFRead.cpp's constants (φd stored over half its range)
SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)


def _rotate(v, axis, angle):
    """BRDFRead.cpp's ``rotate_vector``: Rodrigues' rotation of ``v`` about the unit ``axis``."""
    axis = np.broadcast_to(axis, v.shape)
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    dot = np.sum(axis * v, -1, keepdims=True)
    return v * c + axis * dot * (1 - c) + np.cross(axis, v) * s


def half_diff_reference(wi, wo):
    """BRDFRead.cpp's ``std_coords_to_half_diff_coords``: (θh, φh, θd, φd)."""
    h = (wi + wo) / 2
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    th, ph = np.arccos(np.clip(h[..., 2], -1, 1)), np.arctan2(h[..., 1], h[..., 0])
    tmp = _rotate(wi, np.array([0.0, 0.0, 1.0]), -ph)
    diff = _rotate(tmp, np.array([0.0, 1.0, 0.0]), -th)
    return th, ph, np.arccos(np.clip(diff[..., 2], -1, 1)), np.arctan2(diff[..., 1], diff[..., 0])


def _indices(th, td, pd):
    """BRDFRead.cpp's ``theta_half_index``, ``theta_diff_index``, ``phi_diff_index`` (rounded down, clamped)."""
    ih = np.where(th <= 0, 0, np.sqrt(np.maximum(th, 0) / (np.pi / 2) * RES_TH * RES_TH).astype(np.int64))
    idd = (td / (np.pi / 2) * RES_TD).astype(np.int64)
    pd = np.where(pd < 0, pd + np.pi, pd)
    ip = (pd / np.pi * RES_PD / 2).astype(np.int64)
    return np.clip(ih, 0, RES_TH - 1), np.clip(idd, 0, RES_TD - 1), np.clip(ip, 0, RES_PD // 2 - 1)


def merl_reference_lookup(raw: bytes, wi, wo) -> np.ndarray:
    """BRDFRead.cpp's ``lookup_brdf_val`` on a file's bytes: ``(N, 3)`` red, green, blue in 1/sr."""
    brdf = np.frombuffer(raw, "<f8", offset=12)
    th, _, td, pd = half_diff_reference(wi, wo)
    ih, idd, ip = _indices(th, td, pd)
    ind = ip + idd * (RES_PD // 2) + ih * (RES_PD // 2) * RES_TD
    block = RES_TH * RES_TD * RES_PD // 2
    return np.stack([brdf[ind + c * block] * SCALES[c] for c in range(3)], -1)


def write_merl_by_hand(f_of_angles, path) -> Path:
    """A MERL file of ``f_of_angles(θh, θd, φd) → (..., 3)`` (1/sr) sampled at the reader's index nodes
    (θh = (i/90)²·π/2, θd = j/90·π/2, φd = k/180·π), stored as value / scale in three float64 blocks."""
    th = (np.arange(RES_TH) / RES_TH) ** 2 * (np.pi / 2)
    td = np.arange(RES_TD) / RES_TD * (np.pi / 2)
    pd = np.arange(RES_PD // 2) / (RES_PD // 2) * np.pi
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    vals = np.asarray(f_of_angles(TH, TD, PD), np.float64)
    blocks = [(vals[..., c] / SCALES[c]).astype("<f8").tobytes() for c in range(3)]
    path = Path(path)
    path.write_bytes(struct.pack("<3i", RES_TH, RES_TD, RES_PD // 2) + b"".join(blocks))
    return path
