"""Blade shape: parametric katana, range scans, registration and merging, Bezier smoothing.

See :mod:`jkatana.shape.katana` for the world frame and UV convention.
"""

from jkatana.shape.katana import (
    MUNE_SHAPES as MUNE_SHAPES,
    KatanaSpec as KatanaSpec,
    build_blade as build_blade,
    default_blade as default_blade,
    export_blade as export_blade,
    welded as welded,
)
