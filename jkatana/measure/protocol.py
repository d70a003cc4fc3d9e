"""Goniometer protocols: which (incidence, receiving angle) pairs to capture.

Geometry (SPEC §2, §4; :func:`jkatana.models.in_plane`): everything happens in
the plane of incidence. The light is at incidence θi from the sample normal on
one side; the receiver (camera) is at θr from the normal on the *opposite*
side, so θr = θi is the specular direction (the peak of the highlight). From
the pair, the in-plane facet angle is φ = (θr − θi)/2 (signed) and the
half-angle θH = (θi + θr)/2.

The paper's protocol (Mochizuki et al., §6.1): incidence 15°–65° every 10°
(six settings); for each, the receiver sweeps θr = 10°–80° on the specular
side, every 0.2° within ±20° of the peak (θr = θi) and every 2° elsewhere.
Angles are generated on an integer grid of 0.1° (the goniometer's automated
step) so that no floating-point drift creeps in, and rounded to 0.1°.

For that protocol this gives 1188 captures (149–217 per incidence; the
dense window is clipped at 10° for θi = 15°, 25° and at 80° for θi = 65°).

The instrument (:class:`Instrument`): the angular radius of the source and
of the detector's aperture seen from the sample. A protocol carries it, a
manifest may give it (columns ``source_radius_deg``, ``aperture_radius_deg``),
and it travels with the measurement table in a sidecar file
``<table stem>.instrument.json`` (:func:`write_instrument`), which ``jkatana
fit`` reads so that the fit's forward model includes the instrument's
response (:mod:`jkatana.fit._model`) without any flag.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from jkatana.errors import InputError


@dataclasses.dataclass(frozen=True)
class Protocol:
    """A user protocol. Defaults are the paper's.

    **Arguments:**

    - `incidences_deg`: the light's incidence settings θi (degrees).
    - `receive_min_deg`, `receive_max_deg`: range of the receiving angle θr.
    - `dense_step_deg`: θr step near the specular peak.
    - `dense_halfwidth_deg`: the dense window is θi ± this.
    - `sparse_step_deg`: θr step elsewhere (on a grid from `receive_min_deg`).
    - `source_radius_deg`, `aperture_radius_deg`: the instrument (:class:`Instrument`).
    """

    incidences_deg: tuple[float, ...] = (15.0, 25.0, 35.0, 45.0, 55.0, 65.0)
    receive_min_deg: float = 10.0
    receive_max_deg: float = 80.0
    dense_step_deg: float = 0.2
    dense_halfwidth_deg: float = 20.0
    sparse_step_deg: float = 2.0
    source_radius_deg: float = 0.0
    aperture_radius_deg: float = 0.0

    @property
    def instrument(self) -> "Instrument | None":
        """The protocol's instrument, or ``None`` for point source and point detector."""
        inst = Instrument(self.source_radius_deg, self.aperture_radius_deg)
        return inst if inst else None

    def __post_init__(self):
        object.__setattr__(self, "incidences_deg", tuple(float(a) for a in self.incidences_deg))
        for name in ("receive_min_deg", "receive_max_deg", "dense_step_deg",
                     "dense_halfwidth_deg", "sparse_step_deg"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise InputError(f"must be a finite non-negative angle, got {v}", field=name)
        if not self.incidences_deg:
            raise InputError("needs at least one incidence", field="incidences_deg")
        for a in self.incidences_deg:
            if not (np.isfinite(a) and 0 <= a < 90):
                raise InputError(f"incidence must be in [0, 90) degrees, got {a}", field="incidences_deg")
        tenths = [round(a * 10) for a in self.incidences_deg]
        if len(set(tenths)) != len(tenths):
            raise InputError(f"duplicate incidence settings (to 0.1°) in {self.incidences_deg}",
                             field="incidences_deg")
        if not self.receive_max_deg < 90:
            raise InputError("receiving angle must be below 90 degrees", field="receive_max_deg")
        if self.receive_max_deg < self.receive_min_deg:
            raise InputError("receive_max_deg < receive_min_deg", field="receive_max_deg")
        if self.dense_step_deg <= 0 or self.sparse_step_deg <= 0:
            raise InputError("steps must be positive", field="dense_step_deg")
        Instrument(self.source_radius_deg, self.aperture_radius_deg)  # validates both angles

    def pairs(self) -> list[tuple[float, float]]:
        """``[(θi, θr), ...]`` in degrees, sorted by θi then θr."""
        tenth = lambda x: int(round(float(x) * 10))  # noqa: E731  (0.1° integer grid)
        lo, hi = tenth(self.receive_min_deg), tenth(self.receive_max_deg)
        dstep, sstep, half = tenth(self.dense_step_deg), tenth(self.sparse_step_deg), tenth(self.dense_halfwidth_deg)
        if dstep <= 0 or sstep <= 0:
            raise InputError("steps must be at least 0.1 degree", field="dense_step_deg")
        out = []
        for ti in self.incidences_deg:
            c = tenth(ti)
            dense = {r for r in range(c - half, c + half + 1, dstep) if lo <= r <= hi}
            sparse = {r for r in range(lo, hi + 1, sstep) if not (c - half <= r <= c + half)}
            out.extend((ti, r / 10.0) for r in sorted(dense | sparse))
        return out

    def __len__(self) -> int:
        return len(self.pairs())



#: Largest instrument angle accepted (degrees): beyond it the disk quadrature of the response is not a
#: small-angle average any more.
INSTRUMENT_MAX_DEG = 10.0


def instrument_angle(value, field: str, *, path=None, row=None) -> float:
    """A validated instrument angle (degrees, in [0, :data:`INSTRUMENT_MAX_DEG`)); errors name path/row/field."""
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise InputError(f"must be a number (degrees), got {value!r}", path=path, row=row, field=field) from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and 0 <= value < INSTRUMENT_MAX_DEG):
        raise InputError(f"must be an angle in [0, {INSTRUMENT_MAX_DEG:g}) degrees, got {value!r}", path=path,
                         row=row, field=field)
    return float(value)


@dataclasses.dataclass(frozen=True)
class Instrument:
    """The goniometer's angular response: source and detector aperture as uniform disks of directions.

    **Arguments:**

    - `source_radius_deg`: angular radius of the source seen from the sample (degrees).
    - `aperture_radius_deg`: angular radius of the detector aperture seen from the sample (degrees).
    - `points`: quadrature points per disk (:func:`jkatana.fit._model.disk_offsets`).

    Falsy when both radii are 0 (a point source and a point detector: no response to model).
    """

    source_radius_deg: float = 0.0
    aperture_radius_deg: float = 0.0
    points: int = 12

    def __post_init__(self):
        for name in ("source_radius_deg", "aperture_radius_deg"):
            object.__setattr__(self, name, instrument_angle(getattr(self, name), name))
        if isinstance(self.points, bool) or not isinstance(self.points, int) or not 1 <= self.points <= 256:
            raise InputError(f"must be an integer in [1, 256], got {self.points!r}", field="points")

    def __bool__(self) -> bool:
        return self.source_radius_deg > 0 or self.aperture_radius_deg > 0

    def radians(self) -> tuple[float, float, int] | None:
        """``(source radius, aperture radius, points)`` in radians, the fit's ``instrument`` argument."""
        if not self:
            return None
        return (math.radians(self.source_radius_deg), math.radians(self.aperture_radius_deg), self.points)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def instrument_path(table) -> Path:
    """The instrument sidecar of a measurement table: ``<table stem>.instrument.json`` beside it."""
    table = Path(table)
    return table.with_name(table.stem + ".instrument.json")


def write_instrument(table, instrument: Instrument | None) -> Path | None:
    """Write (atomically) the sidecar of ``table``; with no instrument remove a stale one. Returns its path."""
    from jkatana.io.atomic import write_text

    path = instrument_path(table)
    if not instrument:
        path.unlink(missing_ok=True)
        return None
    return write_text(path, json.dumps({"format": "jkatana-instrument/1", **instrument.to_dict()}, indent=2) + "\n")


def read_instrument(table) -> Instrument | None:
    """The instrument stored beside ``table`` (:func:`instrument_path`), or ``None`` when there is none."""
    path = instrument_path(table)
    if not path.is_file():
        return None
    from jkatana.io.jsonfile import read_json

    d = read_json(path, "an instrument file")
    if not isinstance(d, dict) or d.get("format") != "jkatana-instrument/1":
        raise InputError("expected format 'jkatana-instrument/1'", path=path, field="format")
    src, ap = (instrument_angle(d.get(f, 0.0), f, path=path) for f in ("source_radius_deg", "aperture_radius_deg"))
    points = d.get("points", 12)
    if isinstance(points, bool) or not isinstance(points, int) or not 1 <= points <= 256:
        raise InputError(f"must be an integer in [1, 256], got {points!r}", path=path, field="points")
    return Instrument(src, ap, points)


PAPER_PROTOCOL = Protocol()


def paper_protocol() -> list[tuple[float, float]]:
    """The paper's protocol as ``[(theta_i_deg, theta_r_deg), ...]`` (module docstring)."""
    return PAPER_PROTOCOL.pairs()


def reduced_protocol(incidences_deg=(15.0, 45.0), dense_step_deg=1.0, sparse_step_deg=5.0) -> Protocol:
    """A cheaper protocol of the same shape (for tests and quick looks)."""
    return Protocol(incidences_deg=tuple(incidences_deg), dense_step_deg=dense_step_deg,
                    sparse_step_deg=sparse_step_deg)


def as_pairs(protocol) -> list[tuple[float, float]]:
    """Accept a :class:`Protocol`, or an iterable of ``(θi, θr)`` pairs (degrees)."""
    if protocol is None:
        return paper_protocol()
    if isinstance(protocol, Protocol):
        return protocol.pairs()
    pairs = [(float(a), float(b)) for a, b in protocol]
    return pairs


__all__ = ["Protocol", "PAPER_PROTOCOL", "Instrument", "INSTRUMENT_MAX_DEG", "paper_protocol", "reduced_protocol",
           "as_pairs", "instrument_angle", "instrument_path", "read_instrument", "write_instrument"]
