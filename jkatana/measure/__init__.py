"""Measurements: goniometer protocol, RAW ingestion (rawpy), measurement tables, synthetic goniometer.

Modules:

- :mod:`~jkatana.measure.protocol`: the paper's capture protocol and user protocols;
- :mod:`~jkatana.measure.manifest`: the capture manifest (CSV/TOML) format;
- :mod:`~jkatana.measure.decode`: RAW (rawpy/LibRaw), TIFF and EXR decoding, ROI statistics;
- :mod:`~jkatana.measure.ingest`: manifest → :class:`MeasurementTable`;
- :mod:`~jkatana.measure.table`: the measurement table and its CSV/Parquet files;
- :mod:`~jkatana.measure.camera`: camera green sensitivity and band weights (ρ = (C/E) @ w);
- :mod:`~jkatana.measure.synthetic`: in-memory synthetic campaigns;
- :mod:`~jkatana.measure.goniometer`: synthetic campaigns written as DNG files + manifest.

Workflow::

    jkatana simulate -o camp --full-well 20000 --read-noise 2 --bits 14   # paper protocol, 1188 DNGs
    jkatana measure camp/manifest.csv -o camp/table.csv --plot camp/table.png --overlay camp/truth.csv
    jkatana fit camp/table.csv --region hiraji -o hiraji.json

For real captures write the manifest by hand or by script
(:mod:`~jkatana.measure.manifest` documents it) and start at ``measure``.

Conventions: angles in degrees in files; θr is measured from the normal on
the side opposite the light, θr = θi is specular; φ = (θr − θi)/2,
θH = (θi + θr)/2; values are exposure-normalised camera units
(:mod:`~jkatana.measure.table`), and a model's green value is
ρ = (C/E) @ w with the band weights of :mod:`~jkatana.measure.camera`.

Names are imported lazily, so that decoding worker processes do not pay for
colour-science and JAX.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "band_weights": "camera", "green_sensitivity": "camera",
    "Protocol": "protocol", "paper_protocol": "protocol", "reduced_protocol": "protocol",
    "NoiseModel": "synthetic", "simulate_table": "synthetic",
    "MeasurementTable": "table", "read_table": "table", "write_table": "table",
    "read_manifest": "manifest", "measure": "ingest", "measure_to_file": "ingest",
    "Sensor": "goniometer", "simulate_campaign": "goniometer", "write_dng": "goniometer",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"jkatana.measure.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'jkatana.measure' has no attribute {name!r}")


def __dir__():
    return __all__
