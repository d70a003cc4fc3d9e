"""Measurements: goniometer protocol, RAW ingestion (rawpy), measurement tables, synthetic goniometer."""

from jkatana.measure.camera import band_weights as band_weights, green_sensitivity as green_sensitivity
from jkatana.measure.protocol import Protocol as Protocol, paper_protocol as paper_protocol
from jkatana.measure.synthetic import NoiseModel as NoiseModel, simulate_table as simulate_table
from jkatana.measure.table import (
    MeasurementTable as MeasurementTable,
    read_table as read_table,
    write_table as write_table,
)
