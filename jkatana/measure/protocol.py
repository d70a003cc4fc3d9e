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
"""

from __future__ import annotations

import dataclasses

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
    """

    incidences_deg: tuple[float, ...] = (15.0, 25.0, 35.0, 45.0, 55.0, 65.0)
    receive_min_deg: float = 10.0
    receive_max_deg: float = 80.0
    dense_step_deg: float = 0.2
    dense_halfwidth_deg: float = 20.0
    sparse_step_deg: float = 2.0

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


__all__ = ["Protocol", "PAPER_PROTOCOL", "paper_protocol", "reduced_protocol", "as_pairs"]
