"""The MERL isotropic BRDF binary format: reader, writer and evaluation.

W. Matusik, H. Pfister, M. Brand, L. McMillan (2003), "A data-driven
reflectance model", ACM Trans. Graph. 22(3) 759–769; the layout and the
constants below are those of the reference reader ``BRDFRead.cpp`` that MERL
distributed with the database.

Layout (little-endian): three ``int32`` dimensions (90, 90, 180) — θh, θd,
φd — then 3 × 90·90·180 ``float64`` values, the red block, then the green,
then the blue, each ordered with φd fastest and θh slowest. The stored number
times the channel's scale is the BRDF in 1/sr: red 1/1500, green 1.15/1500,
blue 1.66/1500. Negative stored values mark samples that were not measured
(below the horizon); they evaluate to NaN here.

Indices (Rusinkiewicz angles, :mod:`jkatana.brdf.geometry`):

- θh ∈ [0, π/2): index 90·sqrt(θh / (π/2)) — dense near the mirror direction
  (the second sample is at 0.011°), which is what a polished metal needs;
- θd ∈ [0, π/2): index θd / (π/2) · 90;
- φd ∈ [0, π): index φd / π · 180 (reciprocity: φd and φd + π are the same).

The reference reader takes the sample at the index rounded down
(``method="nearest"``); ``method="linear"`` interpolates trilinearly in
index space (φd periodic) — geometrically, i.e. linearly in log f, where all
eight neighbours are positive, so that the exponential fall-off of a sharp
lobe between the samples is followed rather than overestimated, and
linearly elsewhere.
The writer samples a BRDF at the index nodes.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Callable

import numpy as np

from jkatana.brdf.geometry import from_half_diff, half_diff
from jkatana.errors import InputError

RES_THETA_H, RES_THETA_D, RES_PHI_D = 90, 90, 180
#: Channel scale factors of the reference reader (stored value × scale = BRDF in 1/sr).
SCALE = {"red": 1.0 / 1500.0, "green": 1.15 / 1500.0, "blue": 1.66 / 1500.0}
CHANNELS = ("red", "green", "blue")
_N = RES_THETA_H * RES_THETA_D * RES_PHI_D


class MerlBRDF:
    """An isotropic measured BRDF on the MERL grid.

    ``data`` is ``(3, 90, 90, 180)`` float64, the BRDF in 1/sr per channel
    (scales applied; NaN where not measured). :meth:`eval` evaluates it at
    direction pairs.
    """

    channels = CHANNELS

    def __init__(self, data: np.ndarray, source: str | None = None):
        data = np.asarray(data, np.float64)
        if data.shape != (3, RES_THETA_H, RES_THETA_D, RES_PHI_D):
            raise InputError(f"MERL data must have shape (3, 90, 90, 180), got {data.shape}", path=source)
        self.data = data
        self.source = source

    def _index(self, wi, wo):
        th, _, td, pd = half_diff(wi, wo)
        xh = RES_THETA_H * np.sqrt(np.clip(th, 0.0, None) / (np.pi / 2))
        xd = td / (np.pi / 2) * RES_THETA_D
        pd = np.where(pd < 0, pd + np.pi, pd)
        xp = pd / np.pi * RES_PHI_D
        return xh, xd, xp

    def eval(self, wi, wo, channel: str = "green", *, method: str = "linear") -> np.ndarray:
        """BRDF (1/sr) of ``channel`` at direction pairs ``(..., 3)``; 0 below the horizon.

        `method`: ``"nearest"`` (the reference reader: index rounded down) or
        ``"linear"`` (trilinear in index space, in log f where positive).
        """
        if channel not in CHANNELS:
            raise InputError(f"MERL channels are {CHANNELS}, got {channel!r}", path=self.source, field="channel")
        wi = np.asarray(wi, np.float64)
        wo = np.asarray(wo, np.float64)
        vol = self.data[CHANNELS.index(channel)]
        xh, xd, xp = self._index(wi, wo)
        if method == "nearest":
            ih = np.clip(np.floor(xh).astype(np.int64), 0, RES_THETA_H - 1)
            idd = np.clip(np.floor(xd).astype(np.int64), 0, RES_THETA_D - 1)
            ip = np.clip(np.floor(xp).astype(np.int64), 0, RES_PHI_D - 1)
            out = vol[ih, idd, ip]
        elif method == "linear":
            xh = np.clip(xh, 0.0, RES_THETA_H - 1)
            xd = np.clip(xd, 0.0, RES_THETA_D - 1)
            h0 = np.minimum(np.floor(xh).astype(np.int64), RES_THETA_H - 2)
            d0 = np.minimum(np.floor(xd).astype(np.int64), RES_THETA_D - 2)
            p0 = np.floor(xp).astype(np.int64) % RES_PHI_D
            th_, td_, tp_ = xh - h0, xd - d0, xp - np.floor(xp)
            lin = np.zeros(np.shape(xh))
            logs = np.zeros(np.shape(xh))
            positive = np.ones(np.shape(xh), bool)
            for a, wa in ((0, 1 - th_), (1, th_)):
                for b, wb in ((0, 1 - td_), (1, td_)):
                    for c, wc in ((0, 1 - tp_), (1, tp_)):
                        v = vol[h0 + a, d0 + b, (p0 + c) % RES_PHI_D]
                        lin = lin + wa * wb * wc * v
                        positive &= v > 0
                        logs = logs + wa * wb * wc * np.log(np.where(v > 0, v, 1.0))
            out = np.where(positive, np.exp(logs), lin)
        else:
            raise InputError(f"method must be 'nearest' or 'linear', got {method!r}", field="method")
        visible = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return np.where(visible, out, 0.0)


def read_merl(path) -> MerlBRDF:
    """Read a MERL ``.binary`` file (module docstring); errors name the file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path) from None
    if len(raw) < 12:
        raise InputError("too short for a MERL header", path=path)
    dims = struct.unpack("<3i", raw[:12])
    if dims != (RES_THETA_H, RES_THETA_D, RES_PHI_D):
        raise InputError(f"MERL dimensions must be (90, 90, 180), got {dims}", path=path, field="header")
    want = 12 + 3 * _N * 8
    if len(raw) != want:
        raise InputError(f"MERL file must be {want} bytes, got {len(raw)}", path=path)
    v = np.frombuffer(raw, "<f8", offset=12).reshape(3, RES_THETA_H, RES_THETA_D, RES_PHI_D)
    if not np.all(np.isfinite(v)):
        raise InputError("non-finite values", path=path)
    scale = np.array([SCALE[c] for c in CHANNELS])[:, None, None, None]
    data = np.where(v < 0, np.nan, v * scale)
    return MerlBRDF(data, source=str(path))


def node_directions() -> tuple[np.ndarray, np.ndarray]:
    """(ωi, ωo) ``(90, 90, 180, 3)`` at the MERL index nodes (θh = (i/90)²·π/2, θd = j/90·π/2, φd = k/180·π)."""
    th = (np.arange(RES_THETA_H) / RES_THETA_H) ** 2 * (np.pi / 2)
    td = np.arange(RES_THETA_D) / RES_THETA_D * (np.pi / 2)
    pd = np.arange(RES_PHI_D) / RES_PHI_D * np.pi
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    return from_half_diff(TH, np.zeros_like(TH), TD, PD)


def merl_from_function(brdf: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> MerlBRDF:
    """Sample ``brdf(wi, wo) → (..., 3)`` (1/sr, red/green/blue) at the index nodes; NaN below the horizon."""
    wi, wo = node_directions()
    v = np.asarray(brdf(wi, wo), np.float64)
    if v.shape != wi.shape[:-1] + (3,):
        raise ValueError(f"brdf must return (..., 3) channels, got {v.shape}")
    visible = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    v = np.where(visible[..., None], v, np.nan)
    return MerlBRDF(np.moveaxis(v, -1, 0))


def write_merl(brdf: MerlBRDF, path) -> Path:
    """Write a MERL ``.binary`` file atomically (NaN → −1, the format's 'not measured')."""
    from jkatana.io.atomic import atomic_path

    scale = np.array([SCALE[c] for c in CHANNELS])[:, None, None, None]
    stored = np.where(np.isfinite(brdf.data), brdf.data / scale, -1.0).astype("<f8")
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(struct.pack("<3i", RES_THETA_H, RES_THETA_D, RES_PHI_D))
            f.write(stored.tobytes(order="C"))
    return path


__all__ = ["MerlBRDF", "read_merl", "write_merl", "merl_from_function", "node_directions", "SCALE", "CHANNELS"]
