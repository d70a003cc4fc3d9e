"""Reflectance maps (paper eq. 5): w and per-pixel model parameters over the blade's UVs."""

from jkatana.maps.reflectance_map import (
    PAPER_PARAMETERS as PAPER_PARAMETERS,
    REFLECTANCE_CHANNELS as REFLECTANCE_CHANNELS,
    ReflectanceMap as ReflectanceMap,
    default_map as default_map,
    hamon_line as hamon_line,
    read_map as read_map,
)
