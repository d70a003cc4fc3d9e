"""Fit one region of a measurement table: values, convergence, Laplace intervals, quality per incidence.

The entry point is :func:`fit_region`; :class:`FitData` is the fitting view
of a measurement table (:class:`jkatana.measure.table.MeasurementTable` or
plain arrays), and :class:`RegionFit` the result that
:mod:`jkatana.fit.params` writes as the parameter file.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.errors import InputError
from jkatana.fit._model import MODELS, ModelSpec, Terms, from_natural, prepare, to_natural
from jkatana.fit.laplace import laplace
from jkatana.fit.solve import fit_program, model_values, residuals, verdict, weighted_residuals
from jkatana.fit.starts import STARTS
from jkatana.measure.noise import NoiseModel, estimate_noise
from jkatana.measure.setup import Setup


@dataclasses.dataclass
class FitData:
    """What a fit needs from a table: angles (degrees), values, per-point σ (optional), usable mask."""

    theta_i_deg: np.ndarray
    theta_r_deg: np.ndarray
    value: np.ndarray
    sigma: np.ndarray | None = None
    usable: np.ndarray | None = None
    region: str = "hiraji"
    source: str | None = None
    azimuth_deg: np.ndarray | None = None

    def __post_init__(self):
        self.theta_i_deg = np.asarray(self.theta_i_deg, np.float64).ravel()
        if self.azimuth_deg is not None:
            self.azimuth_deg = np.broadcast_to(np.asarray(self.azimuth_deg, np.float64),
                                               self.theta_i_deg.shape).copy()
        self.theta_r_deg = np.asarray(self.theta_r_deg, np.float64).ravel()
        self.value = np.asarray(self.value, np.float64).ravel()
        n = self.value.size
        if self.theta_i_deg.size != n or self.theta_r_deg.size != n:
            raise InputError(f"angles ({self.theta_i_deg.size}, {self.theta_r_deg.size}) and values ({n}) "
                             "differ in length", path=self.source, field="value")
        if n == 0:
            raise InputError(f"no rows for region {self.region!r}", path=self.source, field="region")
        if self.sigma is not None:
            self.sigma = np.asarray(self.sigma, np.float64).ravel()
        usable = np.isfinite(self.value) & np.isfinite(self.theta_i_deg) & np.isfinite(self.theta_r_deg)
        if self.usable is not None:
            usable &= np.asarray(self.usable, bool).ravel()
        self.usable = usable
        if not usable.any():
            raise InputError("no usable (finite, unsaturated) values", path=self.source, field="value")

    @classmethod
    def from_table(cls, table, region: str | None = None, source=None) -> "FitData":
        """From a :class:`~jkatana.measure.table.MeasurementTable` (saturated rows are excluded)."""
        regions = list(table.regions())
        if region is None:
            if len(regions) != 1:
                raise InputError(f"table has regions {regions}: choose one with --region",
                                 path=source, field="region")
            region = regions[0]
        if region not in regions:
            raise InputError(f"region {region!r} not in table (has {regions})", path=source, field="region")
        t = table.select(region=region)
        sigma = np.asarray(t.sigma, np.float64)
        usable = np.asarray(t.n_saturated) == 0
        return cls(t.theta_i_deg, t.theta_r_deg, t.value, sigma if np.any(sigma > 0) else None,
                   usable, region=region, source=None if source is None else str(source))

    @property
    def has_sigma(self) -> bool:
        """True when every usable row has a positive, finite σ (then fits use it as given)."""
        if self.sigma is None:
            return False
        s = self.sigma[self.usable]
        return bool(np.all(np.isfinite(s) & (s > 0)))

    @property
    def incidences(self) -> np.ndarray:
        """Incidence angles (degrees) that have usable rows."""
        return np.unique(np.round(self.theta_i_deg[self.usable], 6))

    def take(self, mask) -> "FitData":
        mask = np.asarray(mask, bool)
        return FitData(self.theta_i_deg[mask], self.theta_r_deg[mask], self.value[mask],
                       None if self.sigma is None else self.sigma[mask], self.usable[mask],
                       region=self.region, source=self.source,
                       azimuth_deg=None if self.azimuth_deg is None else self.azimuth_deg[mask])

    @classmethod
    def from_brdf_table(cls, table, channel: str | None = None, region: str = "hiraji", source=None) -> "FitData":
        """From a :class:`~jkatana.brdf.table.BRDFTable`: value = f_r cos θi (σ likewise), azimuth kept."""
        if channel is None:
            if len(table.channels) != 1:
                raise InputError(f"table has channels {table.channels}: choose one with --channel",
                                 path=source, field="channel")
            channel = table.channels[0]
        t = table.select(channel)
        c = np.cos(np.deg2rad(t.theta_i_deg))
        sigma = t.sigma * c
        return cls(t.theta_i_deg, t.theta_o_deg, t.value * c,
                   sigma if np.all(np.isfinite(sigma) & (sigma > 0)) else None, None, region=region,
                   source=None if source is None else str(source),
                   azimuth_deg=t.azimuth_deg if np.any(t.azimuth_deg != 0) else None)


def load_fit_data(path, region=None, channel=None):
    """FitData from a measurement table or a BRDF table (told apart by the header)."""
    from jkatana.brdf.table import is_brdf_table, read_brdf_table
    from jkatana.measure.table import read_table

    if str(path).lower().endswith(".csv") and is_brdf_table(path):
        return FitData.from_brdf_table(read_brdf_table(path), channel, region=region or "hiraji", source=path)
    return FitData.from_table(read_table(path), region, source=path)


@dataclasses.dataclass
class RegionFit:
    """Result of :func:`fit_region` (see :mod:`jkatana.fit.params` for the file form)."""

    region: str
    spec: ModelSpec
    p: np.ndarray
    values: dict
    converged: bool
    reasons: list
    laplace: dict
    noise: NoiseModel
    diagnostics: dict
    per_incidence: list
    setup: Setup
    data: FitData
    terms: Terms = dataclasses.field(repr=False)
    weight: np.ndarray = dataclasses.field(repr=False)
    emcee: dict | None = None
    robust: dict | None = None
    bootstrap: dict | None = None
    misfit: dict | None = None
    loss: str = "squared"

    def model(self, p=None) -> np.ndarray:
        """Model green values at the data's geometry (at ``p`` or the optimum)."""
        return np.asarray(model_values(np.asarray(self.p if p is None else p), self.terms, self.spec))


def default_model(region: str) -> str:
    return "hamon" if region == "hamon" else "hiraji"


def _start(start, terms, y, w, spec, dtype):
    """The start vector a fit is given, or None for the default start (computed in the solver's program).

    A name is a strategy of :data:`~jkatana.fit.starts.STARTS`; ``closed`` and ``default`` are the default start
    (the closed form for the paper's models, the moment start for other lobes)."""
    if start is None or (isinstance(start, str) and start in ("closed", "default")):
        return None
    if isinstance(start, str):
        if start not in STARTS:
            raise InputError(f"start must be one of {', '.join(sorted(STARTS))}, a dict of values or a vector, "
                             f"got {start!r}", field="start")
        return STARTS[start](terms, y, w, spec)
    p0 = np.asarray(from_natural(start, spec) if isinstance(start, dict) else start, dtype)
    if p0.shape != (spec.size,) or not np.all(np.isfinite(p0)):
        raise InputError(f"start must be {spec.size} finite values ({', '.join(spec.log_names)}), got {start!r}",
                         field="start")
    return p0


def fit_arrays(terms: Terms, y, w, spec: ModelSpec, *, start=None, solver: str = "lm",
               max_steps: int = 200, multistart: bool = False) -> dict:
    """Solve from a start (closed form by default) with an optional grid multi-start; numpy dict out.

    Every solve is :func:`~jkatana.fit.solve.fit_program` (the default start in the solver's program), so
    the fits of a region, whatever their start, run one compiled program per spec and table shape."""
    dtype = y.dtype
    starts = [_start(start, terms, y, w, spec, dtype)]
    if multistart:
        starts.append(STARTS["grid"](terms, y, w, spec))
    best = None
    for p0 in starts:
        out = fit_program(terms, y, w, spec, start=p0, solver=solver, max_steps=max_steps)
        out = {k: np.asarray(v) for k, v in out.items()}
        if best is None or (np.isfinite(out["cost"]) and not out["cost"] >= best["cost"]):
            best = out
    return best


def fit_region(data: FitData, *, model: str | None = None, setup: Setup = Setup(), tilt: bool = False,
               floor: bool = False, solver: str = "lm", noise: NoiseModel | str = "auto", start=None,
               multistart: bool = False, max_steps: int = 200, per_incidence: bool = True,
               birge: bool = True, dtype=jnp.float64, irls: bool = True, loss: str = "squared",
               instrument: tuple[float, float, int] | None = None, robust: bool = True,
               bootstrap: int = 0, seed: int = 0) -> RegionFit:
    """Fit a model (the paper's eq. 3 / eq. 4, or any lobe of :data:`jkatana.fit._model.FIT_MODELS`) to one region.

    **Arguments:**

    - `data`: :class:`FitData` (e.g. ``FitData.from_table(table, "hiraji")``).
    - `model`: a name of :data:`~jkatana.fit._model.FIT_MODELS` (``"hiraji"``,
      ``"hamon"``, ``"beckmann"``, ``"ggx"``, ``"gtr"``, ``"two-lobe"``;
      default: the region's own paper model).
    - `setup`: optical constants, grid, camera, light (:class:`Setup`).
    - `tilt`, `floor`: free sample tilt (degrees, towards the light) / constant floor.
    - `solver`: ``"lm"`` (optimistix Levenberg–Marquardt), ``"dogleg"``, ``"gn"``
      (Gauss–Newton) or ``"jaxopt"`` (jaxopt LM, Madsen–Nielsen stop).
    - `noise`: ``"auto"`` (default): the table's per-row σ as given when every
      usable row has a positive finite σ, else a :class:`NoiseModel` estimated
      from the table (:func:`~jkatana.measure.noise.estimate_noise`);
      ``"given"``: the per-row σ (an error without it); ``"model"``: always
      the estimated noise model; or a :class:`NoiseModel`.
    - `start`: None/"closed"/"default" (log-linear closed form; the moment start for other lobes), another
      strategy of :data:`~jkatana.fit.starts.STARTS` by name ("grid", …), a dict of natural values, or a
      parameter vector. `multistart`: also try the grid start.
    - `per_incidence`: compute per-incidence quality and refits.
    - `birge`: scale the covariance by max(1, χ²/dof).
    - `dtype`: float64 (default). float32 works only with ``jax_enable_x64`` off
      (lineax fails on mixed dtypes otherwise):
      run float32 fits in a separate process.
    - `irls`: with a noise model, re-evaluate σ at the fitted model and refit
      once (σ from the data biases the fit towards low-fluctuating points).

    - `loss`: ``"squared"`` (default), ``"huber"`` or ``"cauchy"``: robust
      losses by iteratively reweighted least squares
      (:func:`~jkatana.fit.uncertainty.irls_weights`).
    - `instrument`: ``(source_radius, aperture_radius, points)`` in radians:
      the model convolved with the instrument's angular response
      (:mod:`jkatana.fit._model`).
    - `robust`: also compute the sandwich covariance and intervals
      (:func:`~jkatana.fit.uncertainty.sandwich`).
    - `bootstrap`: number of cluster-bootstrap replicates over incidences
      (0: none; :func:`~jkatana.fit.uncertainty.bootstrap_incidences`), with `seed`.

    **Returns:** :class:`RegionFit`.
    """
    t0 = time.perf_counter()
    spec = _spec(data.region, model, tilt, floor, instrument, loss, dtype)
    n, k = setup.nk()
    terms = prepare(spec.model, data.theta_i_deg, data.theta_r_deg, n, k, setup.weights(), dtype,
                    azimuth_deg=data.azimuth_deg)
    noise, given = _noise(data, noise)
    y = jnp.asarray(np.where(data.usable, data.value, 0.0), dtype)
    w = _weights(y, data.usable, noise, given, dtype)
    out = fit_arrays(terms, y, w, spec, start=start, solver=solver, max_steps=max_steps, multistart=multistart)
    steps = int(out["steps"])
    if irls and given is None and np.all(np.isfinite(out["p"])):
        out, w = _irls_refit(out, terms, y, data.usable, noise, spec, dtype, solver, max_steps)
        steps += int(out["steps"])
    if loss != "squared" and np.all(np.isfinite(out["p"])):
        out, w, more = _robust_loss_refits(out, terms, y, w, spec, loss, dtype, solver, max_steps)
        steps += more
    ok, reasons, lap, diagnostics = _summary(out, data, spec, noise, given, steps, solver, birge, dtype)
    values = to_natural(out["p"], spec) if np.all(np.isfinite(out["p"])) else {n_: float("nan") for n_ in spec.names}
    fit = RegionFit(region=data.region, spec=spec, p=np.asarray(out["p"], np.float64), values=values,
                    converged=ok, reasons=reasons, laplace=lap, noise=noise, diagnostics=diagnostics,
                    per_incidence=[], setup=setup, data=data, terms=terms, weight=np.asarray(w), loss=loss)
    _uncertainty(fit, robust, bootstrap, seed, per_incidence, solver, max_steps)
    fit.diagnostics["time_s"] = time.perf_counter() - t0
    return fit


def _spec(region: str, model: str | None, tilt: bool, floor: bool, instrument, loss: str, dtype) -> ModelSpec:
    """The model a fit solves (the region's own paper model by default), its options checked."""
    from jkatana.fit.uncertainty import LOSSES

    model = model or default_model(region)
    if model not in MODELS:
        raise InputError(f"unknown model {model!r}; known: {list(MODELS)}", field="model")
    if loss not in LOSSES:
        raise InputError(f"loss must be one of {list(LOSSES)}, got {loss!r}", field="loss")
    spec = ModelSpec(model, tilt, floor, instrument)
    if dtype == jnp.float32 and jax.config.jax_enable_x64:
        raise ValueError("float32 fits need jax_enable_x64 off (lineax fails on mixed dtypes); "
                         "run them in a separate process")
    return spec


def _noise(data: FitData, noise: NoiseModel | str) -> tuple[NoiseModel, np.ndarray | None]:
    """The noise model of a fit (:func:`fit_region`'s `noise`), and the per-row σ where the table's is used as
    given (else None)."""
    given = None
    if isinstance(noise, str):
        if noise not in ("auto", "given", "model"):
            raise InputError(f"noise must be 'auto', 'given', 'model' or a NoiseModel, got {noise!r}",
                             field="noise")
        if noise in ("auto", "given") and data.has_sigma:
            given = np.where(data.usable, data.sigma, 1.0)
        elif noise == "given":
            raise InputError("noise='given' needs a positive finite σ on every usable row", path=data.source,
                             field="sigma")
        noise = estimate_noise(data.value[data.usable],
                               None if data.sigma is None else data.sigma[data.usable])
    return noise, given


def _weights(y, use, noise: NoiseModel, given, dtype):
    """1/σ at the usable points, 0 elsewhere: σ the given per-row σ, else the noise model's at the data."""
    if given is not None:
        return jnp.asarray(np.where(use, 1.0 / np.asarray(given, dtype), 0.0), dtype)
    return noise.weights(y, use, dtype)


def _with_first_start(out: dict, first: dict, terms: Terms, y, w, spec: ModelSpec, dtype) -> dict:
    """A refit's result with the very first start and its cost under the refit's weights, so that the
    verdict's cost check compares with where the fit began."""
    r0 = np.asarray(weighted_residuals(jnp.asarray(first["p0"], dtype), terms, y, w, spec))
    out["cost0"] = 0.5 * float(np.sum(r0 * r0))
    out["p0"] = first["p0"]
    return out


def _irls_refit(out: dict, terms: Terms, y, use, noise: NoiseModel, spec: ModelSpec, dtype, solver: str,
                max_steps: int) -> tuple[dict, jnp.ndarray]:
    """One refit with σ re-evaluated at the fitted model instead of the data (σ from the data biases a fit
    towards points that happen to fluctuate low): the refit and its weights."""
    w = noise.weights(model_values(jnp.asarray(out["p"], dtype), terms, spec), use, dtype)
    out2 = fit_arrays(terms, y, w, spec, start=out["p"], solver=solver, max_steps=max_steps)
    return _with_first_start(out2, out, terms, y, w, spec, dtype), w


def _robust_loss_refits(out: dict, terms: Terms, y, w_base, spec: ModelSpec, loss: str, dtype, solver: str,
                        max_steps: int) -> tuple[dict, jnp.ndarray, int]:
    """A robust loss by iteratively reweighted least squares (:func:`~jkatana.fit.uncertainty.irls_weights`),
    at most 5 refits, until the parameters stop moving: the last refit, its weights and the steps taken."""
    from jkatana.fit.uncertainty import irls_weights

    steps, w = 0, w_base
    for _ in range(5):
        r = weighted_residuals(jnp.asarray(out["p"], dtype), terms, y, w_base, spec)
        w = (w_base * jnp.sqrt(irls_weights(r, loss))).astype(dtype)
        nxt = fit_arrays(terms, y, w, spec, start=out["p"], solver=solver, max_steps=max_steps)
        steps += int(nxt["steps"])
        nxt = _with_first_start(nxt, out, terms, y, w, spec, dtype)
        done = np.allclose(nxt["p"], out["p"], rtol=1e-8, atol=1e-10)
        out = nxt
        if done:
            break
    return out, w, steps


def _summary(out: dict, data: FitData, spec: ModelSpec, noise: NoiseModel, given, steps: int, solver: str,
             birge: bool, dtype) -> tuple[bool, list, dict, dict]:
    """A solved fit's verdict, its reasons, its Laplace intervals and its diagnostics."""
    ok, reasons = verdict(out, np.dtype(dtype))
    n_used = int(np.sum(data.usable))
    lap = laplace(out["jtj"], float(out["cost"]), n_used, out["p"], spec, birge=birge)
    if not lap["ok"]:
        reasons = reasons + ["Laplace covariance is singular (parameters not identifiable from these data)"]
        ok = False
    diagnostics = dict(solver=solver, steps=steps, cost=float(out["cost"]), cost_start=float(out["cost0"]),
                       gn_decrement=float(out["decrement"]), grad_inf_norm=float(out["grad_norm"]),
                       chi2_dof=lap["chi2_dof"], n_points=n_used, n_excluded=int(data.value.size - n_used),
                       dof=max(1, n_used - spec.size),
                       noise=noise.as_dict() | dict(sigma="per-row (given)" if given is not None else "model"),
                       start=to_natural(out["p0"], spec) if np.all(np.isfinite(out["p0"])) else None,
                       dtype=str(np.dtype(dtype)), reasons=reasons)
    return ok, reasons, lap, diagnostics


def _uncertainty(fit: RegionFit, robust: bool, bootstrap: int, seed: int, per_incidence: bool, solver: str,
                 max_steps: int) -> None:
    """The fit's misfit flag, and where asked its sandwich and bootstrap intervals and per-incidence quality."""
    from jkatana.fit import uncertainty as U

    fit.misfit = U.misfit(fit.laplace["chi2_dof"], fit.diagnostics["dof"])
    if robust and np.all(np.isfinite(fit.p)):
        fit.robust = U.sandwich(fit)
    if bootstrap:
        fit.bootstrap = U.bootstrap_incidences(fit, bootstrap, seed=seed, solver=solver, max_steps=max_steps)
    if per_incidence:
        from jkatana.fit.quality import per_incidence as _pi

        fit.per_incidence = _pi(fit, solver=solver, max_steps=max_steps)


def fit_table(table, region: str | None = None, **kwargs) -> RegionFit:
    """Convenience: :func:`fit_region` on ``FitData.from_table(table, region)``."""
    return fit_region(FitData.from_table(table, region), **kwargs)


__all__ = ["FitData", "Setup", "RegionFit", "fit_region", "fit_table", "fit_arrays", "residuals"]
