"""Slice a measured BRDF into the rows a goniometer protocol would have measured.

A measured BRDF (:class:`~jkatana.brdf.merl.MerlBRDF`, an RGL ``.bsdf``, or
any object with ``eval(wi, wo, channel)``) is evaluated at a protocol's
(θi, θr) pairs (:class:`jkatana.measure.protocol.Protocol`, the paper's by
default) and at receiver azimuths out of the plane of incidence. The
quantity a goniometer sees is the reflected radiance for a fixed irradiance,
i.e. ``value = f_r · cos θi`` (in units of the BRDF, 1/sr); σ follows a
:class:`~jkatana.measure.noise.NoiseModel` of that value, optionally drawn as
noise. In-plane slices become a measurement table
(:mod:`jkatana.measure.table`) that ``jkatana fit`` reads like a capture
campaign; out-of-plane slices keep their azimuth in a BRDF table
(:mod:`jkatana.brdf.table`), which ``jkatana fit`` reads as well.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jkatana.brdf.geometry import goniometer_vectors
from jkatana.brdf.table import BRDFTable
from jkatana.errors import InputError


def load_brdf(path):
    """A measured BRDF by file type: MERL ``.binary``, RGL ``.bsdf`` or a BRDF table ``.csv``."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".binary":
        from jkatana.brdf.merl import read_merl

        return read_merl(p)
    if suffix == ".bsdf":
        from jkatana.brdf.rgl import read_rgl

        return read_rgl(p)
    if suffix == ".csv":
        from jkatana.brdf.table import read_brdf_table

        return read_brdf_table(p)
    raise InputError("unknown measured-BRDF type (expected .binary, .bsdf or .csv)", path=p)


def slice_brdf(brdf, protocol=None, *, channel: str = "green", azimuths_deg=(0.0,), noise=None,
               seed: int | None = None, **eval_kwargs) -> BRDFTable:
    """Evaluate ``brdf`` at a protocol's geometry (module docstring).

    **Arguments:**

    - `brdf`: an object with ``eval(wi, wo, channel, **eval_kwargs)`` (1/sr).
    - `protocol`: a :class:`~jkatana.measure.protocol.Protocol` or a list of
      (θi, θr) pairs in degrees (default: the paper's protocol).
    - `channel`: the channel to slice.
    - `azimuths_deg`: receiver azimuths from the plane of incidence (0 = in plane).
    - `noise`: a :class:`~jkatana.measure.noise.NoiseModel` of ``f_r cos θi``,
      or ``(relative, floor_fraction)``: σ = relative·value ⊕ floor_fraction·peak
      (the peak of the slice). None: σ unknown (NaN), no noise.
    - `seed`: draw Gaussian noise of that σ with this seed (None: σ only).

    **Returns:** a :class:`~jkatana.brdf.table.BRDFTable` (``value`` = f_r).
    """
    from jkatana.measure.noise import NoiseModel
    from jkatana.measure.protocol import as_pairs

    pairs = np.asarray(as_pairs(protocol), np.float64)
    az = np.asarray(azimuths_deg, np.float64).ravel()
    if not np.all(np.isfinite(az)):
        raise InputError("azimuths must be finite", field="azimuth")
    ti = np.repeat(pairs[:, 0][None, :], az.size, 0).ravel()
    to = np.repeat(pairs[:, 1][None, :], az.size, 0).ravel()
    ps = np.repeat(az[:, None], pairs.shape[0], 1).ravel()
    wi, wo = goniometer_vectors(ti, to, ps)
    fr = np.asarray(brdf.eval(wi, wo, channel, **eval_kwargs), np.float64)
    cos_i = np.cos(np.deg2rad(ti))
    seen = fr * cos_i
    ok = np.isfinite(seen)
    if not ok.any():
        raise InputError(f"the BRDF has no finite value at the protocol's geometry (channel {channel!r})",
                         field="channel")
    ti, to, ps, fr, seen, cos_i = ti[ok], to[ok], ps[ok], fr[ok], seen[ok], cos_i[ok]
    if noise is None:
        sigma = np.full(fr.shape, np.nan)
    else:
        if not isinstance(noise, NoiseModel):
            rel, frac = noise
            noise = NoiseModel(relative=float(rel), absolute=float(frac) * float(np.max(np.abs(seen))))
        sig_seen = noise.sigma(seen)
        if seed is not None:
            seen = seen + np.random.default_rng(seed).standard_normal(seen.shape) * sig_seen
            fr = seen / cos_i
        sigma = sig_seen / cos_i
    return BRDFTable(ti, to, ps, np.full(ti.shape, channel, dtype=object), fr, sigma,
                     source=getattr(brdf, "source", None))


def to_measurement_table(table: BRDFTable, *, region: str = "hiraji", channel: str | None = None):
    """The in-plane rows (azimuth 0) of a BRDF table as a measurement table (value = f_r cos θi)."""
    from jkatana.measure.table import MeasurementTable

    if channel is not None:
        table = table.select(channel)
    elif len(table.channels) != 1:
        raise InputError(f"table has channels {table.channels}: choose one", path=table.source, field="channel")
    m = np.isclose(table.azimuth_deg, 0.0)
    if not m.any():
        raise InputError("no in-plane rows (azimuth 0)", path=table.source, field="azimuth_deg")
    cos_i = np.cos(np.deg2rad(table.theta_i_deg[m]))
    sigma = np.where(np.isfinite(table.sigma[m]), table.sigma[m] * cos_i, 0.0)
    caps = [f"i{a:.1f}_r{b:.1f}" for a, b in zip(table.theta_i_deg[m], table.theta_o_deg[m])]
    return MeasurementTable.from_columns(capture=caps, region=[region] * int(m.sum()),
                                         theta_i_deg=table.theta_i_deg[m], theta_r_deg=table.theta_o_deg[m],
                                         value=table.value[m] * cos_i, sigma=sigma)


__all__ = ["load_brdf", "slice_brdf", "to_measurement_table"]
