"""Measured BRDFs in, measurement tables out: MERL binary, RGL ``.bsdf`` and a plain isotropic table.

- :mod:`jkatana.brdf.merl` — MERL binary reader/writer (Matusik et al. 2003).
- :mod:`jkatana.brdf.rgl` — RGL ``.bsdf`` tensor files (Dupuy & Jakob 2018).
- :mod:`jkatana.brdf.table` — a plain isotropic BRDF table (angles, channel, value, σ).
- :mod:`jkatana.brdf.slicing` — a measured BRDF sliced in a goniometer protocol
  (in-plane and out-of-plane) into the table ``jkatana fit`` reads.
"""

from jkatana.brdf.merl import MerlBRDF as MerlBRDF, read_merl as read_merl, write_merl as write_merl
from jkatana.brdf.slicing import load_brdf as load_brdf, slice_brdf as slice_brdf
from jkatana.brdf.slicing import to_measurement_table as to_measurement_table
from jkatana.brdf.table import BRDFTable as BRDFTable, read_brdf_table as read_brdf_table
from jkatana.brdf.table import write_brdf_table as write_brdf_table
