"""The fitted models' parameterisation: for each model a fitter can fit (:data:`FIT_MODELS`), its lobe of
:mod:`jkatana.models.lobes`, the names of its natural parameters and the map between them and the fit vector
(logs of scale and width, logits of bounded shape parameters; the table in :mod:`jkatana.fit._model`).

The fitter (:mod:`jkatana.fit`), the parameter files' readers, the BRDF exporters (:mod:`jkatana.brdf`) and the
renderer all name models and rebuild lobes from natural values through this registry.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np


def _sigmoid(t):
    return jax.nn.sigmoid(t)


@dataclasses.dataclass(frozen=True)
class FitModel:
    """How one lobe is fitted: its natural parameter names and the maps to/from the fit vector."""

    name: str
    lobe: str
    scale_name: str
    names: tuple[str, ...]  # natural shape parameters after the scale (width first)
    defaults: tuple[float, ...]  # natural defaults of the shape parameters after the width

    def build(self, q):
        """The lobe for shape vector ``q`` (fit space: ``q[0]`` = log width)."""
        from jkatana.models import lobes as L

        width = jnp.exp(q[0])
        if self.name == "hiraji":
            return L.Gaussian(width, jnp.ones_like(width), normalised=False)
        if self.name == "hamon":
            return L.GaussianVCavity(width, jnp.ones_like(width), normalised=False)
        if self.name == "beckmann":
            return L.Beckmann(width)
        if self.name == "ggx":
            return L.GGX(width)
        if self.name == "gtr":
            return L.GTR(width, 1.0 + 3.0 * _sigmoid(q[1]))
        if self.name == "two-lobe":
            return L.Mixture(L.GGX(width), L.GGX(width * (1.0 + jnp.exp(q[1]))), _sigmoid(q[2]))
        raise ValueError(self.name)

    def shape_to_natural(self, q) -> dict:
        q = np.asarray(q, np.float64)
        out = {self.names[0]: float(np.exp(q[0]))}
        from scipy.special import expit

        if self.name == "gtr":
            out["gamma"] = float(1.0 + 3.0 * expit(q[1]))
        if self.name == "two-lobe":
            out["alpha_haze"] = float(np.exp(q[0] + np.logaddexp(0.0, q[1])))
            out["weight"] = float(expit(q[2]))
        return out

    def encode(self, log_width, extra=(), xp=jnp):
        """The fit-space shape vector (:meth:`build`'s argument, the inverse of its map) at width
        ``exp(log_width)`` and the extra shape parameters ``extra`` in natural units, missing ones at
        :attr:`defaults`: γ for ``gtr`` (→ logit((γ − 1)/3)); the haze ratio α_haze/α and the weight w for
        ``two-lobe`` (→ log(ratio − 1), logit w). ``xp``: :mod:`jax.numpy` (traceable, the default) or
        :mod:`math` (floats for parameter files, no compiled program)."""
        extra = tuple(extra) + tuple(self.defaults[len(tuple(extra)):])
        out = [log_width]
        if self.name == "gtr":
            x = (extra[0] - 1.0) / 3.0
            out.append(xp.log(x / (1.0 - x)))
        if self.name == "two-lobe":
            ratio, w = extra
            out.append(xp.log((max if xp is math else xp.maximum)(ratio - 1.0, 1e-12)))
            out.append(xp.log(w / (1.0 - w)))
        return out

    def shape_from_natural(self, values: dict) -> list[float]:
        """:meth:`encode` of natural values by name (the two-lobe haze as the width ``alpha_haze``)."""
        width = float(values[self.names[0]])
        extra = []
        if self.name == "gtr":
            extra = [float(values.get("gamma", self.defaults[0]))]
        if self.name == "two-lobe":
            extra = [float(values.get("alpha_haze", width * self.defaults[0])) / width,
                     float(values.get("weight", self.defaults[1]))]
        return self.encode(math.log(width), extra, xp=math)


@functools.partial(jax.jit, static_argnums=0)
def build_lobe(fit_model: FitModel, q):
    """:meth:`FitModel.build` as one compiled program per model (for callers outside a compiled fit)."""
    return fit_model.build(q)


FIT_MODELS: dict[str, FitModel] = {m.name: m for m in (
    FitModel("hiraji", "gaussian", "chi", ("mu",), ()),
    FitModel("hamon", "gaussian-vcavity", "beta", ("mu",), ()),
    FitModel("beckmann", "beckmann", "scale", ("alpha",), ()),
    FitModel("ggx", "ggx", "scale", ("alpha",), ()),
    FitModel("gtr", "gtr", "scale", ("alpha", "gamma"), (1.5,)),
    FitModel("two-lobe", "mixture", "scale", ("alpha", "alpha_haze", "weight"), (10.0, 0.9)),
)}
MODELS = tuple(FIT_MODELS)
SCALE_NAME = {k: m.scale_name for k, m in FIT_MODELS.items()}
#: Natural shape parameters each model reports (width first), for readers of parameter files.
SHAPE_NAMES = {k: m.names for k, m in FIT_MODELS.items()}


@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """Which model and which optional parameters (static, hashable: one compiled program per spec)."""

    model: str = "hiraji"
    tilt: bool = False
    floor: bool = False
    instrument: tuple[float, float, int] | None = None

    def __post_init__(self):
        if self.model not in FIT_MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")
        if self.instrument is not None:
            src, ap, n = self.instrument
            if not (src >= 0 and ap >= 0 and int(n) >= 1):
                raise ValueError(f"instrument radii must be >= 0 and n >= 1, got {self.instrument}")
            object.__setattr__(self, "instrument", (float(src), float(ap), int(n)))

    @property
    def fit_model(self) -> FitModel:
        return FIT_MODELS[self.model]

    @property
    def n_shape(self) -> int:
        return len(self.fit_model.names)

    @property
    def names(self) -> tuple[str, ...]:
        """Natural-unit names of the parameters, in vector order."""
        out = [self.fit_model.scale_name, *self.fit_model.names]
        if self.tilt:
            out.append("tilt_deg")
        if self.floor:
            out.append("floor")
        return tuple(out)

    @property
    def size(self) -> int:
        return 1 + self.n_shape + int(self.tilt) + int(self.floor)

    @property
    def tilt_index(self) -> int | None:
        return 1 + self.n_shape if self.tilt else None

    @property
    def floor_index(self) -> int | None:
        return 1 + self.n_shape + int(self.tilt) if self.floor else None

    @property
    def log_names(self) -> list[str]:
        """Names of the fit-vector entries (what ``cov_log`` is the covariance of)."""
        m = self.fit_model
        shape = {"gtr": ["log_alpha", "logit_gamma"],
                 "two-lobe": ["log_alpha", "log_haze_ratio_m1", "logit_weight"]}.get(
            m.name, ["log_" + m.names[0]])
        return ["log_" + m.scale_name] + shape + (["tilt_rad"] if self.tilt else []) + (
            ["floor"] if self.floor else [])


def to_natural(p, spec: ModelSpec) -> dict[str, float]:
    """Parameter vector → natural units (``tilt_deg`` in degrees)."""
    p = np.asarray(p, np.float64)
    out = {spec.fit_model.scale_name: float(np.exp(p[0]))}
    out |= spec.fit_model.shape_to_natural(p[1:1 + spec.n_shape])
    if spec.tilt:
        out["tilt_deg"] = float(np.rad2deg(p[spec.tilt_index]))
    if spec.floor:
        out["floor"] = float(p[spec.floor_index])
    return out


def from_natural(values: dict, spec: ModelSpec) -> np.ndarray:
    """Natural units → parameter vector (inverse of :func:`to_natural`; missing shape values → defaults)."""
    out = [math.log(values[spec.fit_model.scale_name])] + spec.fit_model.shape_from_natural(values)
    if spec.tilt:
        out.append(math.radians(values.get("tilt_deg", 0.0)))
    if spec.floor:
        out.append(float(values.get("floor", 0.0)))
    return np.asarray(out, np.float64)


def default_shape(spec: ModelSpec, log_width, dtype):
    """Fit-space shape vector at width ``exp(log_width)`` with the model's default extra parameters."""
    fm = spec.fit_model
    width = 1.0
    extra = fm.shape_from_natural({fm.names[0]: width} | dict(zip(fm.names[1:], fm.defaults)))[1:]
    return jnp.concatenate([jnp.reshape(log_width, (1,)).astype(dtype), jnp.asarray(extra, dtype)])


__all__ = ["FIT_MODELS", "MODELS", "SCALE_NAME", "SHAPE_NAMES", "FitModel", "ModelSpec", "build_lobe",
           "default_shape", "from_natural", "to_natural"]
