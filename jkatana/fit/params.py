"""The parameter file (``jkatana-params/1``, JSON): what ``jkatana fit`` writes and the renderer reads.

Shape::

    {"format": "jkatana-params/1", "region": str, "model": one of jkatana.fit._model.MODELS,
     "lobe": {"lobe": name, ...} (the fitted lobe's ``to_params()``, jkatana.models.lobes),
     "values": {scale name: float, shape parameters..., ["tilt_deg": float], ["floor": float]},
     "laplace": {"names": [...], "params": [...], "cov_log": [[...]], "ci95": {name: [lo, hi]}, "se": {...}, ...},
     "robust": {...} | null, "bootstrap": {...} | null, "emcee": {"median", "ci95", "diagnostics"} | null,
     "misfit": {"flag": bool, "chi2_dof": float, "note": str},
     "optical_constants": "Fe-Johnson", "grid": {"start", "stop", "step", "size"},
     "camera": str, "light": str, "camera_sensitivity": [...], "light_spectrum": [...],
     "converged": bool, "diagnostics": {...}, "options": {...},
     "per_incidence": [{"incidence_deg", "n", "chi2_dof", "rms_rel", "refit": {...}}, ...],
     "data": {"table": path or null, "region": str}}

The scale is ``chi`` (hiraji), ``beta`` (hamon) or ``scale`` (other lobes),
in camera units. ``cov_log`` is the covariance of the fit vector named by
``laplace.params`` (:class:`jkatana.fit._model.ModelSpec`). Only ``format``,
``region``, ``model``, ``values``, ``optical_constants`` and ``converged``
are required; files written by the API without ``diagnostics`` or camera
arrays are read too. Written atomically (:func:`jkatana.io.atomic.write_text`).
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
    from jkatana.fit._model import build_lobe

    setup = fit.setup.describe()
    spec = fit.spec
    lobe = build_lobe(spec.fit_model, fit.p[1:1 + spec.n_shape]).to_params()
    return _clean(dict(
        format=FORMAT, region=fit.region, model=spec.model, lobe=lobe, values=fit.values,
        robust=getattr(fit, "robust", None), bootstrap=getattr(fit, "bootstrap", None),
        misfit=getattr(fit, "misfit", None),
        laplace={k: v for k, v in fit.laplace.items() if k != "ok"} | {"ok": fit.laplace["ok"]},
        emcee=fit.emcee, optical_constants=setup["optical_constants"], grid=setup["grid"],
        camera=setup["camera"], light=setup["light"], camera_sensitivity=setup["camera_sensitivity"],
        light_spectrum=setup["light_spectrum"], converged=bool(fit.converged),
        diagnostics=fit.diagnostics, per_incidence=fit.per_incidence,
        options=dict(tilt=spec.tilt, floor=spec.floor, loss=getattr(fit, "loss", "squared"),
                     instrument=None if spec.instrument is None else dict(
                         source_radius_deg=math.degrees(spec.instrument[0]),
                         aperture_radius_deg=math.degrees(spec.instrument[1]), points=spec.instrument[2])),
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

    ``scale`` is χ (hiraji), β (hamon) or the lobe's scale, in camera units;
    ``mu`` the lobe's width (μ in radians for the paper's lobes, α for the
    microfacet lobes); ``lobe`` the fitted lobe's ``to_params()`` dict
    (:func:`jkatana.models.lobes.lobe_from_params` rebuilds it); ``ci95`` maps
    names to (lo, hi) from the Laplace approximation; ``raw`` is the whole file.
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
    lobe: dict | None = None
    raw: dict = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def values(self) -> dict:
        return dict(self.raw["values"])


def read_params(path) -> Params:
    """Read and validate a parameter file; errors name the file and the field."""
    from jkatana.io.jsonfile import read_json

    path = Path(path)
    return params_from_dict(read_json(path, "a parameter file"), path)


def params_from_dict(d, path=None) -> Params:
    """:class:`Params` of a parameter file's content; every field a reader uses checked (widths and scales by
    :mod:`jkatana.models.bounds`), errors naming the file and the field."""
    from jkatana.io.jsonfile import expect
    from jkatana.measure.table import REGIONS
    from jkatana.models import bounds

    if not isinstance(d, dict):
        raise InputError("top level must be an object", path=path)
    if d.get("format") != FORMAT:
        raise InputError(f"expected format {FORMAT!r}, got {d.get('format')!r}", path=path, field="format")
    from jkatana.fit._model import MODELS, SCALE_NAME, SHAPE_NAMES

    model = d.get("model")
    if model not in MODELS:
        raise InputError(f"must be one of {list(MODELS)}, got {model!r}", path=path, field="model")
    region = d.get("region")
    if not isinstance(region, str) or not region:
        raise InputError("missing or not a string", path=path, field="region")
    if region not in REGIONS:
        raise InputError(f"unknown region {region!r}; known: {', '.join(REGIONS)}", path=path, field="region")
    values = d.get("values")
    if not isinstance(values, dict):
        raise InputError("missing or not an object", path=path, field="values")
    scale_name = SCALE_NAME[model]

    def num(name, positive=False, default=None):
        v = values.get(name, default)
        if v is None or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"must be a finite number, got {v!r}", path=path, field=f"values.{name}")
        if positive and not v > 0:
            raise InputError(f"must be > 0, got {v!r}", path=path, field=f"values.{name}")
        return float(v)

    scale = bounds.scale(values.get(scale_name), f"values.{scale_name}", path)
    width_name = SHAPE_NAMES[model][0]
    mu = bounds.width(values.get(width_name), f"values.{width_name}", path,
                      hi=bounds.WIDTH_MAX if model in bounds.REGIONS else None)
    for extra in SHAPE_NAMES[model][1:]:
        num(extra)
    tilt = num("tilt_deg", default=0.0)
    floor = num("floor", default=0.0)
    oc = d.get("optical_constants")
    if not isinstance(oc, str):
        raise InputError("missing or not a string", path=path, field="optical_constants")
    conv = d.get("converged")
    if not isinstance(conv, bool):
        raise InputError("missing or not a boolean", path=path, field="converged")
    lap = expect(d.get("laplace"), dict, "laplace", path, optional=True) or {}
    ci95 = expect(lap.get("ci95"), dict, "laplace.ci95", path, optional=True) or {}
    for k, v in ci95.items():  # [lo, hi], a bound null where the fit could not give it
        if not (isinstance(v, list) and len(v) == 2 and all(
                b is None or (isinstance(b, (int, float)) and not isinstance(b, bool)) for b in v)):
            raise InputError(f"must be [lo, hi] (numbers or null), got {v!r}", path=path, field=f"laplace.ci95.{k}")
    ci = {k: tuple(v) for k, v in ci95.items()}
    for key in ("diagnostics", "options", "data", "misfit", "robust", "bootstrap", "emcee"):
        expect(d.get(key), dict, key, path, optional=True)
    expect(d.get("per_incidence"), list, "per_incidence", path, optional=True)
    lobe = d.get("lobe")
    if lobe is not None and not (isinstance(lobe, dict) and isinstance(lobe.get("lobe"), str)):
        raise InputError("must be an object naming its lobe", path=path, field="lobe")
    return Params(region=region, model=model, scale=scale, mu=mu, tilt_deg=tilt, floor=floor,
                  optical_constants=oc, converged=conv, ci95=ci, lobe=lobe, raw=d)


__all__ = ["FORMAT", "Params", "read_params", "write_params", "to_dict", "params_from_dict"]
