"""A plain isotropic BRDF table (CSV): one row per direction pair and channel.

Columns (header row required; angles in degrees, goniometer convention of
:mod:`jkatana.brdf.geometry`):

| column | meaning |
| --- | --- |
| ``theta_i_deg`` | incidence θi, 0 ≤ θi < 90 |
| ``theta_o_deg`` | receiver polar angle θo, 0 ≤ θo < 90 |
| ``azimuth_deg`` | receiver azimuth from the plane of incidence, forward side (0 = in plane) |
| ``channel`` | a channel or band name (``green``, ``red``, ``550nm``, …) |
| ``value`` | BRDF f_r in 1/sr |
| ``sigma`` | standard error of ``value`` (optional column; empty or 0 = unknown) |

The form every measured source can be written in without loss of the
sampled points, and the form out-of-plane slices take (the measurement table
of :mod:`jkatana.measure.table` is in-plane only). Reading validates every
row and names the file, the row (1-based, header excluded) and the column.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from jkatana.errors import InputError

HEADER = ("theta_i_deg", "theta_o_deg", "azimuth_deg", "channel", "value", "sigma")


@dataclasses.dataclass
class BRDFTable:
    """Rows of an isotropic BRDF table (module docstring); ``sigma`` NaN where unknown.

    Columns are given array-like and stored as 1-D NumPy arrays (``azimuth_deg``, ``channel`` and
    ``sigma`` broadcast to the row count)."""

    theta_i_deg: ArrayLike
    theta_o_deg: ArrayLike
    azimuth_deg: ArrayLike
    channel: ArrayLike
    value: ArrayLike
    sigma: ArrayLike
    source: str | None = None

    def __post_init__(self):
        self.theta_i_deg = np.asarray(self.theta_i_deg, np.float64).ravel()
        n = self.theta_i_deg.size
        self.theta_o_deg = np.asarray(self.theta_o_deg, np.float64).ravel()
        self.azimuth_deg = np.broadcast_to(np.asarray(self.azimuth_deg, np.float64), (n,)).copy()
        self.channel = np.broadcast_to(np.asarray(self.channel, dtype=object), (n,)).copy()
        self.value = np.asarray(self.value, np.float64).ravel()
        self.sigma = np.broadcast_to(np.asarray(self.sigma, np.float64), (n,)).copy()
        for name in ("theta_o_deg", "value"):
            if getattr(self, name).size != n:
                raise InputError(f"column has {getattr(self, name).size} rows, expected {n}", path=self.source,
                                 field=name)

    def __len__(self) -> int:
        return self.value.size

    @property
    def channels(self) -> list[str]:
        return sorted({str(c) for c in self.channel})

    def select(self, channel: str) -> "BRDFTable":
        m = self.channel == channel
        if not m.any():
            raise InputError(f"no rows for channel {channel!r} (has {self.channels})", path=self.source,
                             field="channel")
        return BRDFTable(self.theta_i_deg[m], self.theta_o_deg[m], self.azimuth_deg[m], self.channel[m],
                         self.value[m], self.sigma[m], source=self.source)


def write_brdf_table(table: BRDFTable, path) -> Path:
    """Write the CSV atomically (``repr`` floats: a round trip is exact)."""
    from jkatana.io.atomic import write_text

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(HEADER)
    for row in zip(table.theta_i_deg, table.theta_o_deg, table.azimuth_deg, table.channel, table.value,
                   table.sigma):
        ti, to, az, ch, v, s = row
        w.writerow([repr(float(ti)), repr(float(to)), repr(float(az)), str(ch), repr(float(v)),
                    "" if not math.isfinite(s) else repr(float(s))])
    return write_text(path, buf.getvalue())


def read_brdf_table(path) -> BRDFTable:
    """Read and validate a BRDF table CSV (module docstring)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path) from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise InputError("empty file", path=path)
    header = [h.strip() for h in rows[0]]
    missing = [h for h in HEADER[:5] if h not in header]
    if missing:
        raise InputError(f"missing columns {missing} (header {header})", path=path, field=missing[0])
    col = {h: header.index(h) for h in header}
    out = {h: [] for h in HEADER}
    for r, row in enumerate(rows[1:], start=1):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise InputError(f"{len(row)} fields, header has {len(header)}", path=path, row=r)
        for h in ("theta_i_deg", "theta_o_deg", "azimuth_deg", "value", "sigma"):
            if h not in col:
                out[h].append(math.nan if h == "sigma" else 0.0)
                continue
            raw = row[col[h]].strip()
            if h == "sigma" and raw == "":
                out[h].append(math.nan)
                continue
            try:
                v = float(raw)
            except ValueError:
                raise InputError(f"not a number: {raw!r}", path=path, row=r, field=h) from None
            if not math.isfinite(v):
                raise InputError(f"must be finite, got {raw!r}", path=path, row=r, field=h)
            if h in ("theta_i_deg", "theta_o_deg") and not 0 <= v < 90:
                raise InputError(f"angle must be in [0, 90) degrees, got {v}", path=path, row=r, field=h)
            if h == "sigma" and v < 0:
                raise InputError(f"must be >= 0, got {v}", path=path, row=r, field=h)
            out[h].append(math.nan if (h == "sigma" and v == 0) else v)
        ch = row[col["channel"]].strip()
        if not ch:
            raise InputError("empty channel", path=path, row=r, field="channel")
        out["channel"].append(ch)
    if not out["value"]:
        raise InputError("no data rows", path=path)
    return BRDFTable(**{h: np.asarray(out[h], dtype=object if h == "channel" else np.float64) for h in HEADER},
                     source=str(path))


def is_brdf_table(path) -> bool:
    """True when the file's header is a BRDF table's (so ``fit`` can tell it from a measurement table)."""
    try:
        with open(path, encoding="utf-8") as f:
            first = f.readline()
    except OSError:
        return False
    names = [h.strip() for h in first.split(",")]
    return "theta_o_deg" in names and "channel" in names


__all__ = ["BRDFTable", "read_brdf_table", "write_brdf_table", "is_brdf_table", "HEADER"]
