"""The measurement table: one row per capture and region (DESIGN.md, measure → fit).

Columns (all the same length; angles in degrees, at the file edges only):

| column | type | meaning |
| --- | --- | --- |
| ``capture`` | str | capture id (the manifest's ``capture`` or the file's stem) |
| ``region`` | str | ``hiraji``, ``hamon`` or ``other`` |
| ``theta_i_deg`` | float | incidence θi, from the normal, light side |
| ``theta_r_deg`` | float | receiving angle θr, from the normal, opposite side (θr = θi: specular) |
| ``phi_deg`` | float | in-plane facet angle φ = (θr − θi)/2 (signed) |
| ``theta_h_deg`` | float | θH = (θi + θr)/2 |
| ``value`` | float | green value, camera units, exposure-normalised (below) |
| ``sigma`` | float | standard error of ``value`` (0 = noiseless synthetic data) |
| ``n_pixels`` | int | photosites averaged (saturated ones excluded) |
| ``n_saturated`` | int | saturated photosites found in the ROI (excluded, flagged) |
| ``exposure_s`` | float | exposure time (s) |

**Camera units.** ``value`` is the mean over the region of interest of the
green photosites' (DN − black) / (white − black) / exposure_s: a fraction of
the sensor's full scale per second of exposure (times an optional per-capture
``gain`` from the manifest). The paper's χ, β are in the same kind of unit
(its camera's green values); the synthetic goniometer
(:mod:`jkatana.measure.synthetic`) writes its RAW files in exactly this
unit, so a fit of its output recovers the χ, β it was given.

Files: CSV (always; header row, one row per record), Parquet when the file
name ends in ``.parquet`` and ``pyarrow`` is installed. Reading validates
every row and raises :class:`~jkatana.errors.InputError` naming the file,
the row (1-based data row, header excluded) and the column. Writing is atomic.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from jkatana.errors import InputError
from jkatana.io.atomic import atomic_path

REGIONS = ("hiraji", "hamon", "other")

#: column name -> numpy dtype
COLUMNS: dict[str, type] = {
    "capture": str,
    "region": str,
    "theta_i_deg": np.float64,
    "theta_r_deg": np.float64,
    "phi_deg": np.float64,
    "theta_h_deg": np.float64,
    "value": np.float64,
    "sigma": np.float64,
    "n_pixels": np.int64,
    "n_saturated": np.int64,
    "exposure_s": np.float64,
}


def check_angles(theta_i, theta_r, *, path=None, row=None) -> tuple[float, float]:
    """Validate one (θi, θr) pair in degrees: finite, 0 ≤ θi < 90, 0 ≤ θr < 90."""
    for name, v in (("theta_i_deg", theta_i), ("theta_r_deg", theta_r)):
        if isinstance(v, bool):
            raise InputError(f"not a number: {v!r}", path=path, row=row, field=name)
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise InputError(f"not a number: {v!r}", path=path, row=row, field=name) from None
        if not math.isfinite(v):
            raise InputError(f"angle must be finite, got {v}", path=path, row=row, field=name)
        if v < 0:
            raise InputError(f"angle must be non-negative (degrees from the normal), got {v}",
                             path=path, row=row, field=name)
        if v >= 90:
            raise InputError(f"angle must be below 90 degrees (grazing or beyond), got {v}",
                             path=path, row=row, field=name)
    return float(theta_i), float(theta_r)


@dataclasses.dataclass
class MeasurementTable:
    """Equal-length numpy columns (module docstring). Build with :meth:`from_rows` or directly: any
    array-like column is converted to a 1-D numpy array of its column's dtype."""

    capture: npt.ArrayLike
    region: npt.ArrayLike
    theta_i_deg: npt.ArrayLike
    theta_r_deg: npt.ArrayLike
    phi_deg: npt.ArrayLike
    theta_h_deg: npt.ArrayLike
    value: npt.ArrayLike
    sigma: npt.ArrayLike
    n_pixels: npt.ArrayLike
    n_saturated: npt.ArrayLike
    exposure_s: npt.ArrayLike

    def __post_init__(self):
        n = None
        for name, dtype in COLUMNS.items():
            col = np.asarray(getattr(self, name), dtype=object if dtype is str else dtype)
            if dtype is str:
                col = np.array([str(x) for x in col.ravel()], dtype=object)
            if col.ndim != 1:
                raise InputError(f"column must be 1-D, got shape {col.shape}", field=name)
            n = len(col) if n is None else n
            if len(col) != n:
                raise InputError(f"column has {len(col)} rows, expected {n}", field=name)
            setattr(self, name, col)

    @classmethod
    def from_columns(cls, *, capture, region, theta_i_deg, theta_r_deg, value, sigma,
                     n_pixels=None, n_saturated=None, exposure_s=None) -> "MeasurementTable":
        """Build a table, deriving φ and θH from θi, θr (and zero/one defaults)."""
        ti = np.asarray(theta_i_deg, np.float64)
        tr = np.asarray(theta_r_deg, np.float64)
        m = len(ti)
        return cls(capture=capture, region=region, theta_i_deg=ti, theta_r_deg=tr,
                   phi_deg=0.5 * (tr - ti), theta_h_deg=0.5 * (ti + tr), value=value, sigma=sigma,
                   n_pixels=np.zeros(m, np.int64) if n_pixels is None else n_pixels,
                   n_saturated=np.zeros(m, np.int64) if n_saturated is None else n_saturated,
                   exposure_s=np.ones(m) if exposure_s is None else exposure_s)

    @classmethod
    def concatenate(cls, tables) -> "MeasurementTable":
        tables = list(tables)
        if not tables:
            return cls(**{k: np.zeros(0, dtype=object if t is str else t) for k, t in COLUMNS.items()})
        return cls(**{k: np.concatenate([getattr(t, k) for t in tables]) for k in COLUMNS})

    def __len__(self) -> int:
        return len(self.value)

    def columns(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in COLUMNS}

    def take(self, index) -> "MeasurementTable":
        """Rows selected by a boolean mask or an index array."""
        return MeasurementTable(**{k: v[index] for k, v in self.columns().items()})

    def select(self, region: str | None = None, incidence_deg: float | None = None,
               *, atol: float = 1e-6) -> "MeasurementTable":
        """Rows of one region and/or one incidence setting (θi within ``atol`` degrees)."""
        mask = np.ones(len(self), bool)
        if region is not None:
            mask &= self.region == region
        if incidence_deg is not None:
            mask &= np.abs(self.theta_i_deg - float(incidence_deg)) <= atol
        return self.take(mask)

    def regions(self) -> list[str]:
        """Regions present, in first-appearance order."""
        return list(dict.fromkeys(self.region.tolist()))

    def incidences(self) -> list[float]:
        """Distinct incidence settings θi (degrees), sorted."""
        return sorted(set(np.round(self.theta_i_deg, 6).tolist()))

    def validate(self, path=None) -> "MeasurementTable":
        """Check every row (angles, region, finite value, sigma ≥ 0, no duplicates)."""
        seen: dict[tuple[str, str], int] = {}
        for i in range(len(self)):
            row = i + 1
            check_angles(self.theta_i_deg[i], self.theta_r_deg[i], path=path, row=row)
            if self.region[i] not in REGIONS:
                raise InputError(f"region must be one of {REGIONS}, got {self.region[i]!r}",
                                 path=path, row=row, field="region")
            if not math.isfinite(self.value[i]):
                raise InputError(f"value must be finite, got {self.value[i]}", path=path, row=row,
                                 field="value")
            if not (math.isfinite(self.sigma[i]) and self.sigma[i] >= 0):
                raise InputError(f"sigma must be finite and >= 0, got {self.sigma[i]}", path=path,
                                 row=row, field="sigma")
            if not (math.isfinite(self.exposure_s[i]) and self.exposure_s[i] > 0):
                raise InputError(f"exposure must be > 0 s, got {self.exposure_s[i]}", path=path,
                                 row=row, field="exposure_s")
            for name in ("phi_deg", "theta_h_deg"):
                want = (0.5 * (self.theta_r_deg[i] - self.theta_i_deg[i]) if name == "phi_deg"
                        else 0.5 * (self.theta_r_deg[i] + self.theta_i_deg[i]))
                if not abs(getattr(self, name)[i] - want) <= 1e-6 * max(1.0, abs(want)):
                    raise InputError(f"{getattr(self, name)[i]} disagrees with θi, θr (expected {want})",
                                     path=path, row=row, field=name)
            key = (self.capture[i], self.region[i])
            if key in seen:
                raise InputError(f"duplicate row: capture {key[0]!r}, region {key[1]!r} already in row "
                                 f"{seen[key]}", path=path, row=row, field="capture")
            seen[key] = row
        return self


def _table_to_csv(table: MeasurementTable) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    cols = table.columns()
    for i in range(len(table)):
        writer.writerow([cols[k][i] if COLUMNS[k] is str else
                         (int(cols[k][i]) if COLUMNS[k] is np.int64 else repr(float(cols[k][i])))
                         for k in COLUMNS])
    return buf.getvalue()


def write_table(table: MeasurementTable, path: str | Path) -> Path:
    """Write ``table`` atomically: CSV, or Parquet if ``path`` ends in ``.parquet``."""
    path = Path(path)
    if path.suffix.lower() == ".parquet":
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise InputError("writing Parquet needs pyarrow (pip install pyarrow); use .csv",
                             path=path) from None
        arrays = {k: (pa.array(v.tolist(), pa.string()) if COLUMNS[k] is str else pa.array(v))
                  for k, v in table.columns().items()}
        with atomic_path(path) as tmp:
            pq.write_table(pa.table(arrays), tmp)
        return path
    with atomic_path(path) as tmp:
        tmp.write_text(_table_to_csv(table), encoding="utf-8")
    return path


def _parse_column(raw: list, name: str, path) -> np.ndarray:
    dtype = COLUMNS[name]
    if dtype is str:
        return np.array([str(x).strip() for x in raw], dtype=object)
    out = np.empty(len(raw), dtype)
    for i, x in enumerate(raw):
        try:
            v = float(x)
            if dtype is np.int64:
                if not (math.isfinite(v) and v == int(v) and v >= 0):
                    raise ValueError
                v = int(v)
        except (TypeError, ValueError):
            kind = "a non-negative integer" if dtype is np.int64 else "a number"
            raise InputError(f"expected {kind}, got {x!r}", path=path, row=i + 1, field=name) from None
        out[i] = v
    return out


def read_table(path: str | Path) -> MeasurementTable:
    """Read and validate a table (CSV, or Parquet by extension). ``phi_deg``/``theta_h_deg``
    may be omitted (they are derived); ``n_pixels``, ``n_saturated`` default to 0,
    ``exposure_s`` to 1."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path=path)
    if path.suffix.lower() == ".parquet":
        try:
            import pyarrow.parquet as pq
        except ImportError:
            raise InputError("reading Parquet needs pyarrow (pip install pyarrow)", path=path) from None
        try:
            data = {k: list(v) for k, v in pq.read_table(path).to_pydict().items()}
        except Exception as err:  # noqa: BLE001  (pyarrow raises many kinds)
            raise InputError(f"not a readable Parquet file ({err})", path=path) from None
    else:
        try:
            text = path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError:
            raise InputError("not a UTF-8 text (CSV) file", path=path) from None
        reader = csv.reader(io.StringIO(text))
        rows = [r for r in reader if r and not (len(r) == 1 and not r[0].strip())]
        if not rows:
            raise InputError("empty table (no header)", path=path)
        header = [h.strip() for h in rows[0]]
        dup = sorted({h for h in header if header.count(h) > 1})
        if dup:
            raise InputError(f"the header names column(s) {dup} more than once", path=path, row=0, field=dup[0])
        for i, r in enumerate(rows[1:]):
            if len(r) != len(header):
                raise InputError(f"has {len(r)} fields, the header has {len(header)}", path=path, row=i + 1)
        data = {h: [r[j] for r in rows[1:]] for j, h in enumerate(header)}
    required = ("capture", "region", "theta_i_deg", "theta_r_deg", "value", "sigma")
    for name in required:
        if name not in data:
            raise InputError(f"missing column (needs {', '.join(required)})", path=path, field=name)
    cols = {k: _parse_column(data[k], k, path) for k in COLUMNS if k in data}
    m = len(cols["value"])
    cols.setdefault("phi_deg", 0.5 * (cols["theta_r_deg"] - cols["theta_i_deg"]))
    cols.setdefault("theta_h_deg", 0.5 * (cols["theta_r_deg"] + cols["theta_i_deg"]))
    cols.setdefault("n_pixels", np.zeros(m, np.int64))
    cols.setdefault("n_saturated", np.zeros(m, np.int64))
    cols.setdefault("exposure_s", np.ones(m))
    return MeasurementTable(**cols).validate(path)


__all__ = ["MeasurementTable", "COLUMNS", "REGIONS", "read_table", "write_table", "check_angles"]
