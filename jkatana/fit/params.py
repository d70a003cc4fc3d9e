"""The parameter file (``jkatana-params/1``, JSON): what ``jkatana fit`` writes and the renderer reads.

Shape::

    {"format": "jkatana-params/1", "region": "hiraji"|"hamon", "model": "hiraji"|"hamon",
     "values": {"chi"|"beta": float, "mu": float, ["tilt_deg": float], ["floor": float]},
     "laplace": {"names": [...], "cov_log": [[...]], "ci95": {name: [lo, hi]}, "se": {...}, ...},
     "emcee": {"median": ..., "ci95": ..., "diagnostics": {...}} | null,
     "optical_constants": "Fe-Johnson", "grid": {"start", "stop", "step", "size"},
     "camera": str, "light": str, "converged": bool, "diagnostics": {...},
     "per_incidence": [{"incidence_deg", "n", "chi2_dof", "rms_rel", "refit": {...}}, ...],
     "data": {"table": path or null, "region": str}}

``cov_log`` is the covariance of (log scale, log μ[, tilt rad][, floor]).
Written atomically (:func:`jkatana.io.atomic.write_text`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from jkatana.errors import InputError

FORMAT = "jkatana-params/1"


def _clean(x):
    """JSON-safe: NaN/inf → None, numpy → Python."""
    import numpy as np

    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def to_dict(fit, table_path: str | None = None) -> dict:
    """The parameter-file dict of a :class:`~jkatana.fit.region.RegionFit`."""
    setup = fit.setup.describe()
    return _clean(dict(
        format=FORMAT, region=fit.region, model=fit.spec.model, values=fit.values,
        laplace={k: v for k, v in fit.laplace.items() if k != "ok"} | {"ok": fit.laplace["ok"]},
        emcee=fit.emcee, optical_constants=setup["optical_constants"], grid=setup["grid"],
        camera=setup["camera"], light=setup["light"], camera_sensitivity=setup["camera_sensitivity"],
        light_spectrum=setup["light_spectrum"], converged=bool(fit.converged),
        diagnostics=fit.diagnostics, per_incidence=fit.per_incidence,
        options=dict(tilt=fit.spec.tilt, floor=fit.spec.floor),
        data=dict(table=table_path, region=fit.data.region),
    ))


def write_params(fit_or_dict, path, table_path: str | None = None) -> Path:
    """Write the parameter file atomically; returns the path."""
    from jkatana.io.atomic import write_text

    d = fit_or_dict if isinstance(fit_or_dict, dict) else to_dict(fit_or_dict, table_path)
    return write_text(path, json.dumps(d, indent=2, allow_nan=False) + "\n")


@dataclasses.dataclass(frozen=True)
class Params:
    """What a renderer needs from a parameter file (validated by :func:`read_params`).

    ``scale`` is χ (hiraji) or β (hamon) in camera units; ``mu`` in radians;
    ``ci95`` maps names to (lo, hi) from the Laplace approximation; ``raw``
    is the whole file.
    """

    region: str
    model: str
    scale: float
    mu: float
    tilt_deg: float
    floor: float
    optical_constants: str
    converged: bool
    ci95: dict
    raw: dict = dataclasses.field(repr=False, compare=False)

    @property
    def values(self) -> dict:
        return dict(self.raw["values"])


def read_params(path) -> Params:
    """Read and validate a parameter file; errors name the file and the field."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path) from None
    except json.JSONDecodeError as err:
        raise InputError(f"not JSON ({err.msg} at line {err.lineno})", path=path) from None
    return params_from_dict(d, path)


def params_from_dict(d, path=None) -> Params:
    if not isinstance(d, dict):
        raise InputError("top level must be an object", path=path)
    if d.get("format") != FORMAT:
        raise InputError(f"expected format {FORMAT!r}, got {d.get('format')!r}", path=path, field="format")
    model = d.get("model")
    if model not in ("hiraji", "hamon"):
        raise InputError(f"must be 'hiraji' or 'hamon', got {model!r}", path=path, field="model")
    region = d.get("region")
    if not isinstance(region, str) or not region:
        raise InputError("missing or not a string", path=path, field="region")
    values = d.get("values")
    if not isinstance(values, dict):
        raise InputError("missing or not an object", path=path, field="values")
    scale_name = "chi" if model == "hiraji" else "beta"

    def num(name, positive=False, default=None):
        v = values.get(name, default)
        if v is None or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"must be a finite number, got {v!r}", path=path, field=f"values.{name}")
        if positive and not v > 0:
            raise InputError(f"must be > 0, got {v!r}", path=path, field=f"values.{name}")
        return float(v)

    scale = num(scale_name, positive=True)
    mu = num("mu", positive=True)
    tilt = num("tilt_deg", default=0.0)
    floor = num("floor", default=0.0)
    oc = d.get("optical_constants")
    if not isinstance(oc, str):
        raise InputError("missing or not a string", path=path, field="optical_constants")
    conv = d.get("converged")
    if not isinstance(conv, bool):
        raise InputError("missing or not a boolean", path=path, field="converged")
    lap = d.get("laplace") or {}
    if not isinstance(lap, dict):
        raise InputError("not an object", path=path, field="laplace")
    ci = {k: tuple(v) for k, v in (lap.get("ci95") or {}).items() if isinstance(v, list) and len(v) == 2}
    return Params(region=region, model=model, scale=scale, mu=mu, tilt_deg=tilt, floor=floor,
                  optical_constants=oc, converged=conv, ci95=ci, raw=d)


__all__ = ["FORMAT", "Params", "read_params", "write_params", "to_dict", "params_from_dict"]
