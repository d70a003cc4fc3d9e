"""The capture manifest: which file shows what, at which angles.

A manifest lists, per capture and region, the image file, the goniometer
angles and the region(s) of interest. It is a CSV file (header row) or a TOML
file (an array of ``[[capture]]`` tables with the same keys).

| key | required | meaning |
| --- | --- | --- |
| ``file`` | yes | image path; relative paths resolve against the manifest's folder, and a path that leads outside that folder (``..``, absolute elsewhere, symlink) is refused |
| ``region`` | yes | ``hiraji``, ``hamon`` or ``other`` |
| ``theta_i_deg`` | yes | incidence θi from the normal, degrees, 0 ≤ θi < 90 |
| ``theta_r_deg`` | yes | receiving angle θr from the normal on the side opposite the light (θr = θi: specular), 0 ≤ θr < 90 |
| ``roi`` | yes | rectangle(s) ``x y w h`` in pixels of the visible raw frame (x: column, y: row of the top-left corner), several separated by ``;`` — e.g. ``8 8 20 48; 36 8 20 48``. In TOML: ``[[x, y, w, h], ...]`` |
| ``exposure_s`` | no | exposure time (s), at most 3600; if empty the RAW file's own shutter time is used |
| ``capture`` | no | capture id (default: the file name without extension); (capture, region) must be unique |
| ``dark`` | no | dark frame (same size and format, same exposure), subtracted per photosite instead of the black level |
| ``aperture``, ``iso`` | no | f-number and ISO: validated, kept with the manifest for the record (not used in the arithmetic, not copied to the table) |
| ``gain`` | no | multiplies the value (default 1): convert to the unit of another rig; finite, > 0 and at most 1e150 (:data:`jkatana.models.bounds.SCALE_MAX`: the values it makes must square finitely in the fit) |
| ``black_level``, ``white_level`` | no | for TIFF/EXR captures only (RAW files carry their own); TIFF defaults 0 and 65535, EXR 0 and no saturation |
| ``source_radius_deg``, ``aperture_radius_deg`` | no | the instrument: angular radius of the source and of the detector aperture seen from the sample (degrees, :class:`~jkatana.measure.protocol.Instrument`); the same in every row that gives them. ``jkatana measure`` writes it beside the table, and ``jkatana fit`` models the instrument's response from it |

Formats by extension: ``.tif``/``.tiff`` linear 16-bit TIFF (one channel, or
RGB(A) of which G is used), ``.exr`` OpenEXR (channel ``G``, else ``Y``, else
the only channel), anything else is opened by LibRaw through rawpy (DNG,
CR2, NEF, ARW, ...), which reads both green photosites of the Bayer pattern.

Example (CSV)::

    file,region,theta_i_deg,theta_r_deg,exposure_s,roi
    raw/i15_r10.0.dng,hiraji,15,10.0,0.004,8 8 20 48
    raw/i15_r10.0.dng,hamon,15,10.0,0.004,36 8 20 48

Row numbers in errors are 1-based data rows (the header is row 0), or the
index of the ``[[capture]]`` table in TOML, starting at 1.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import os
import tomllib
from pathlib import Path

from jkatana.errors import InputError
from jkatana.models.bounds import SCALE_MAX
from jkatana.measure.protocol import Instrument, instrument_angle
from jkatana.measure.table import REGIONS, check_angles

REQUIRED = ("file", "region", "theta_i_deg", "theta_r_deg", "roi")
OPTIONAL = ("exposure_s", "capture", "dark", "aperture", "iso", "gain", "black_level", "white_level",
            "source_radius_deg", "aperture_radius_deg")
INSTRUMENT_KEYS = ("source_radius_deg", "aperture_radius_deg")


@dataclasses.dataclass(frozen=True)
class Entry:
    """One manifest row, validated; paths absolute."""

    row: int
    file: Path
    region: str
    theta_i_deg: float
    theta_r_deg: float
    rois: tuple[tuple[int, int, int, int], ...]
    capture: str
    exposure_s: float | None = None
    dark: Path | None = None
    aperture: float | None = None
    iso: float | None = None
    gain: float = 1.0
    black_level: float | None = None
    white_level: float | None = None
    source_radius_deg: float | None = None
    aperture_radius_deg: float | None = None


@dataclasses.dataclass(frozen=True)
class Manifest:
    path: Path
    entries: tuple[Entry, ...]
    instrument: Instrument | None = None
    """The instrument its rows give (``None``: none given, a point source and detector)."""

    @property
    def folder(self) -> Path:
        return self.path.parent

    def __len__(self) -> int:
        return len(self.entries)


def resolve_inside(folder: Path, value: str, *, path, row, field) -> Path:
    """Resolve ``value`` against ``folder``; refuse anything that ends up outside it."""
    if not isinstance(value, str):
        raise InputError(f"must be a path (text), got {value!r}", path=path, row=row, field=field)
    value = value.strip()
    if not value:
        raise InputError("empty path", path=path, row=row, field=field)
    if "\x00" in value:
        raise InputError("a path may not contain a NUL byte", path=path, row=row, field=field)
    root = folder.resolve()
    target = (root / value).resolve()
    try:
        target.relative_to(root)
    except ValueError:
        raise InputError(f"path {value!r} leads outside the manifest's folder {root}", path=path, row=row,
                         field=field) from None
    return target


def parse_rois(value, *, path, row) -> tuple[tuple[int, int, int, int], ...]:
    """``"x y w h; x y w h"`` (or a list of 4-lists) → tuple of integer rectangles."""
    if isinstance(value, str):
        parts = [p for p in value.replace(",", " ").split(";") if p.strip()]
        rects = [p.split() for p in parts]
    elif isinstance(value, (list, tuple)):
        rects = list(value)
        if rects and not isinstance(rects[0], (list, tuple)):
            rects = [rects]
    else:
        rects = []
    if not rects:
        raise InputError("needs at least one rectangle 'x y w h'", path=path, row=row, field="roi")
    out = []
    for rect in rects:
        if len(rect) != 4:
            raise InputError(f"a rectangle is 4 integers 'x y w h', got {rect!r}", path=path, row=row,
                             field="roi")
        try:
            x, y, w, h = (int(str(v)) for v in rect)
        except ValueError:
            raise InputError(f"rectangle values must be integers, got {rect!r}", path=path, row=row,
                             field="roi") from None
        if x < 0 or y < 0 or w <= 0 or h <= 0:
            raise InputError(f"rectangle {x} {y} {w} {h}: x, y must be >= 0 and w, h > 0", path=path,
                             row=row, field="roi")
        out.append((x, y, w, h))
    return tuple(out)


def _number(value, *, path, row, field, positive=False, default=None, hi=None):
    if value is None or (isinstance(value, str) and not value.strip()):
        return default
    if isinstance(value, bool):  # TOML true/false: not a number
        raise InputError(f"not a number: {value!r}", path=path, row=row, field=field)
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"not a number: {value!r}", path=path, row=row, field=field) from None
    if not math.isfinite(v) or (positive and v <= 0) or v < 0:
        raise InputError(f"must be finite and {'> 0' if positive else '>= 0'}, got {value!r}", path=path,
                         row=row, field=field)
    if hi is not None and v > hi:
        raise InputError(f"must be at most {hi:g}, got {value!r}", path=path, row=row, field=field)
    return v


def _records(path: Path) -> list[dict]:
    if path.suffix.lower() == ".toml":
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
            raise InputError(f"not valid TOML ({err})", path=path) from None
        records = data.get("capture")
        if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
            raise InputError("expects an array of [[capture]] tables", path=path, field="capture")
        return records
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM from spreadsheet exports is fine
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 CSV file", path=path) from None
    rows = [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r)
            and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError("empty manifest (no header)", path=path)
    header = [h.strip() for h in rows[0]]
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise InputError(f"the header names column(s) {dup} more than once", path=path, row=0, field=dup[0])
    records = []
    for i, r in enumerate(rows[1:], start=1):
        if len(r) != len(header):
            raise InputError(f"has {len(r)} fields, the header has {len(header)}", path=path, row=i)
        records.append(dict(zip(header, (c.strip() for c in r))))
    return records


def read_manifest(path: str | Path) -> Manifest:
    """Read and validate a manifest (CSV or TOML; module docstring). Checks angles,
    regions, ROI syntax, duplicates and that every referenced file exists inside the
    manifest's folder — before any image is decoded."""
    path = Path(path)
    if not path.is_file():
        raise InputError("no such manifest file", path=path)
    records = _records(path)
    if not records:
        raise InputError("the manifest lists no captures", path=path)
    folder = path.parent
    known = set(REQUIRED) | set(OPTIONAL)
    entries, seen = [], {}
    for row, rec in enumerate(records, start=1):
        unknown = set(rec) - known
        if unknown:
            raise InputError(f"unknown key(s) {sorted(unknown)}; known: {sorted(known)}", path=path, row=row,
                             field=sorted(unknown)[0])
        for key in REQUIRED:
            if key not in rec or (isinstance(rec[key], str) and not rec[key].strip()):
                raise InputError("missing required value", path=path, row=row, field=key)
        file = resolve_inside(folder, rec["file"], path=path, row=row, field="file")
        if not file.is_file():
            raise InputError(f"capture file {str(rec['file'])!r} does not exist ({file})", path=path, row=row,
                             field="file")
        region = str(rec["region"]).strip().lower()
        if region not in REGIONS:
            raise InputError(f"region must be one of {REGIONS}, got {rec['region']!r}", path=path, row=row,
                             field="region")
        ti, tr = check_angles(rec["theta_i_deg"], rec["theta_r_deg"], path=path, row=row)
        dark = None
        if str(rec.get("dark", "") or "").strip():
            dark = resolve_inside(folder, rec["dark"], path=path, row=row, field="dark")
            if not dark.is_file():
                raise InputError(f"dark frame {rec['dark']!r} does not exist", path=path, row=row, field="dark")
        capture = str(rec.get("capture", "") or "").strip() or Path(str(rec["file"])).stem
        key = (capture, region)
        if key in seen:
            raise InputError(f"duplicate row: capture {capture!r} region {region!r} is already row {seen[key]}"
                             " (give distinct 'capture' ids)", path=path, row=row, field="capture")
        seen[key] = row
        num = lambda f, **kw: _number(rec.get(f), path=path, row=row, field=f, **kw)  # noqa: E731
        entries.append(Entry(
            row=row, file=file, region=region, theta_i_deg=ti, theta_r_deg=tr,
            rois=parse_rois(rec["roi"], path=path, row=row), capture=capture,
            exposure_s=num("exposure_s", positive=True, hi=3600.0), dark=dark, aperture=num("aperture", positive=True),
            iso=num("iso", positive=True), gain=num("gain", positive=True, default=1.0, hi=SCALE_MAX),
            black_level=num("black_level"), white_level=num("white_level", positive=True),
            **{k: (instrument_angle(rec[k], k, path=path, row=row) if str(rec.get(k, "") or "").strip() else None)
               for k in INSTRUMENT_KEYS}))
    return Manifest(path=path, entries=tuple(entries), instrument=_instrument(entries, path))


def _instrument(entries, path) -> Instrument | None:
    """The one instrument of a manifest: every row that gives an angle gives the same (or none at all)."""
    values = {}
    for k in INSTRUMENT_KEYS:
        given = [(e.row, getattr(e, k)) for e in entries if getattr(e, k) is not None]
        if given and len(given) != len(entries):
            row = next(e.row for e in entries if getattr(e, k) is None)
            raise InputError(f"missing: give the instrument in every row or in none (row {given[0][0]} gives "
                             f"{given[0][1]:g})", path=path, row=row, field=k)
        for row, v in given:
            if v != given[0][1]:
                raise InputError(f"{v:g} differs from row {given[0][0]}'s {given[0][1]:g}: one instrument per "
                                 "manifest", path=path, row=row, field=k)
        values[k] = given[0][1] if given else 0.0
    inst = Instrument(values["source_radius_deg"], values["aperture_radius_deg"])
    return inst if inst else None


def manifest_csv(rows: list[dict], folder: Path | None = None) -> str:
    """Render manifest rows (dicts with the keys above) as CSV text; ``roi`` may be a list of rects.
    Paths are written relative to ``folder`` when given."""
    keys = [k for k in (*REQUIRED, *OPTIONAL) if any(k in r for r in rows)]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(keys)
    for r in rows:
        out = []
        for k in keys:
            v = r.get(k, "")
            if k == "roi" and not isinstance(v, str):
                v = "; ".join(" ".join(str(int(c)) for c in rect) for rect in v)
            elif k in ("file", "dark") and folder is not None and v:
                v = os.path.relpath(v, folder)
            elif isinstance(v, float):
                v = repr(v)
            out.append(v)
        w.writerow(out)
    return buf.getvalue()


__all__ = ["Entry", "Manifest", "read_manifest", "manifest_csv", "parse_rois", "resolve_inside"]
