"""Bounds of the reflection models' parameters: one home for what the physics needs of them.

Every reader of model parameters (a parameter file, a scene's material, a
region fit handed to ``jkatana map``, ``jkatana simulate --params``) checks
them here, so a width of zero or a scale of 1e308 is refused the same way
everywhere, naming the field:

- a lobe width (μ of the paper's facet distribution D(φ, μ) = exp(−ln 2 · φ²/μ²),
  the half-width at half-maximum of the facet angle φ, in radians; α of the
  microfacet lobes) must be finite and > 0: D is undefined at μ = 0 and a
  negative width is no width. For the paper's two regions it is also at
  most π/2: φ lies in [0, π/2], so a wider half-maximum is no longer a lobe
  (Mochizuki et al. fit 0.05 rad).
- a scale (χ of the hiraji, β of the hamon, a lobe's scale; camera units)
  must be finite, > 0 (a region that reflects nothing has no lobe to fit or
  render) and at most :data:`SCALE_MAX`, the bound of a measured value
  (:func:`jkatana.fit.commands`: squares of values stay finite in float64).
- the regions are the paper's two, :data:`REGIONS`; their parameter names are
  those of :data:`jkatana.models.PAPER_HIRAJI` / ``PAPER_HAMON``.
"""

from __future__ import annotations

import math

from jkatana.errors import InputError
from jkatana.io.limits import number

#: The regions whose models jkatana simulates, maps and renders (Mochizuki et al. §2).
REGIONS = ("hiraji", "hamon")
#: Largest scale accepted: 1e150, so that its square (χ² sums) stays finite in float64 (max 1.8e308).
SCALE_MAX = 1e150
#: Largest width of the paper's facet distributions: π/2 rad, the range of the facet angle.
WIDTH_MAX = math.pi / 2


def scale(value, field: str, path=None) -> float:
    """A model scale (χ, β, a lobe's scale): finite, > 0, at most :data:`SCALE_MAX`."""
    return float(number(_required(value, field, path), field, lo=0.0, lo_open=True, hi=SCALE_MAX, path=path))


def width(value, field: str, path=None, *, hi: float | None = None) -> float:
    """A lobe width (μ, α; radians or dimensionless): finite, > 0, at most ``hi`` when given."""
    return float(number(_required(value, field, path), field, lo=0.0, lo_open=True, hi=hi, path=path))


def _required(value, field, path):
    if value is None:
        raise InputError("missing", field=field, path=path)
    return value


def region(name, field: str = "region", path=None) -> str:
    """``name`` if it is one of :data:`REGIONS`."""
    if name not in REGIONS:
        raise InputError(f"unknown region {name!r}; known: {', '.join(REGIONS)}", field=field, path=path)
    return name


def region_params(name, params: dict, *, field: str = "params", path=None) -> dict[str, float]:
    """The paper's parameters of region ``name`` (a subset of its names), each checked; floats.

    ``chi``/``beta`` are scales, ``mu`` (also ``mu0``/``mu1``, the reflectance map's names) a width
    of at most :data:`WIDTH_MAX`.
    """
    from jkatana.models.reflectance import PAPER_HAMON, PAPER_HIRAJI

    region(name, field=field, path=path)
    known = PAPER_HIRAJI if name == "hiraji" else PAPER_HAMON
    if not isinstance(params, dict):
        raise InputError(f"must be an object of {name} parameters, got {type(params).__name__}", field=field,
                         path=path)
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise InputError(f"unknown parameters {unknown} for {name} (expects {sorted(known)})", field=field,
                         path=path)
    out = {}
    for k, v in params.items():
        f = f"{field}.{name}.{k}" if field == "params" else f"{field}.{k}"
        out[k] = width(v, f, path, hi=WIDTH_MAX) if k.startswith("mu") else scale(v, f, path)
    return out


__all__ = ["REGIONS", "SCALE_MAX", "WIDTH_MAX", "scale", "width", "region", "region_params"]
