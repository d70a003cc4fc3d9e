"""Start strategies for a region's least-squares fit (:mod:`jkatana.fit.solve`): each a :class:`Start`, a name
and the function that proposes a parameter vector from a table ``(terms, y, w, spec)``.

**Closed form** (``log-quadratic``). With F̄ divided out, log y = log s − ln2 (φ + t)²/μ² is *linear* in
(log s, 1/μ²) without a tilt and a quadratic in φ with one: a weighted linear least-squares fit over points
well above the noise floor gives the start (:func:`closed_form_start`).

**Moment** (``moment``). Other lobes start from the same fit's peak width mapped to the lobe's width through
its reflected width, refined on a few widths around it (:func:`moment_start`; a two-lobe sum's parts from
:func:`pair_start`).

**Grid** (``grid``, ``two-level``). For each width on a log grid the best scale is linear and the lowest cost
wins (:func:`grid_start`); :func:`two_level_start` searches the same range in two levels.

**Default** (``default``): the closed form for the paper's Gaussian models, the moment start for other lobes
(:func:`start_vector`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Callable

import jax
import jax.numpy as jnp

from jkatana.fit._model import ModelSpec, Terms, default_shape, evaluation_point, green
from jkatana.models.microfacet import LN2


@dataclasses.dataclass(frozen=True)
class Start:
    """A start strategy: its ``name`` (what :func:`jkatana.fit.region.fit_region`'s ``start`` accepts) and
    ``propose(terms, y, w, spec, ...)``, the (jit-compiled) function that returns a parameter vector."""

    name: str
    propose: Callable

    def __call__(self, terms: Terms, y, w, spec: ModelSpec, *args, **kwargs):
        return self.propose(terms, y, w, spec, *args, **kwargs)


@functools.partial(jax.jit, static_argnames=("spec",))
def start_vector(terms: Terms, y, w, spec: ModelSpec, fallback=None):
    """The default start: closed form for the paper's Gaussian models, :func:`moment_start` for other lobes
    (`fallback`: see there)."""
    if spec.model in ("hiraji", "hamon"):
        return closed_form_start(terms, y, w, spec)
    return moment_start(terms, y, w, spec, fallback)


#: Widths tried by :func:`moment_start`, as factors of the closed-form width (log-spaced: ÷√3, 1, ×√3).
MOMENT_FACTORS = (3.0 ** -0.5, 3.0 ** 0.5, 3)


@functools.partial(jax.jit, static_argnames=("spec",))
def moment_start(terms: Terms, y, w, spec: ModelSpec, fallback=None):
    """Start for a non-paper lobe from the data's peak width: 5 model evaluations instead of 21 over the whole width range.

    The log-quadratic closed form (:func:`closed_form_start`, amplitude 1) measures the data's peak as
    the paper's Gaussian facet distribution of width μ; the lobe's width is the one whose
    :meth:`~jkatana.models.lobes.Lobe.reflected_width` equals that Gaussian's (for a two-lobe sum, its
    sharp first lobe's: the peak is what the closed form sees). Every lobe's reflected width is linear
    in its width, so one ratio maps it. The closed form sees the peak's curvature while a heavy-tailed
    lobe's reflected width is its core's scale, so :func:`grid_start` then picks the best of
    :data:`MOMENT_FACTORS` around it (other shape parameters at their defaults, the scale linear); a
    two-lobe sum's widths, haze ratio and weight come from :func:`pair_start` around it.
    Where the closed form has no peak to measure (too few points above the noise, or no downward
    curvature) the start is :func:`two_level_start`'s search over the whole width range, or `fallback`
    when one is given (a batch of refits passes the full fit's optimum: under ``vmap`` a ``lax.cond``
    becomes a select that compiles and runs both branches, so the batch keeps one branch).
    """
    good, near = _moment_near(terms, y, w, spec)
    if fallback is not None:
        return jnp.where(good, near(), jnp.asarray(fallback, y.dtype))
    return jax.lax.cond(good, near, lambda: two_level_start(terms, y, w, spec))


def _moment_near(terms: Terms, y, w, spec: ModelSpec):
    """:func:`moment_start`'s parts: whether the closed form measured a peak, and the start near it (a function,
    so that a ``lax.cond`` evaluates it only where it is taken)."""
    from jkatana.models.lobes import Gaussian, Mixture

    p_cf, good = _log_quadratic(terms, y, w, spec.tilt, spec.floor)
    mu = jnp.exp(p_cf[1])
    sigma = Gaussian(mu, jnp.ones_like(mu), normalised=False).reflected_width()
    lobe = spec.fit_model.build(default_shape(spec, p_cf[1], y.dtype))
    core = lobe.first if isinstance(lobe, Mixture) else lobe
    width = mu * sigma / core.reflected_width()
    lo, hi, n = MOMENT_FACTORS
    factors = jnp.geomspace(lo, hi, n).astype(y.dtype)
    good = good & jnp.isfinite(width) & (width > 0)
    width = jnp.where(good, width, 1.0)
    if isinstance(lobe, Mixture):
        return good, lambda: pair_start(terms, y, w, spec, width)
    return good, lambda: grid_start(terms, y, w, spec, mus=width * factors)


def start_in_solve(terms: Terms, y, w, spec: ModelSpec, fallback):
    """The start :func:`solve` computes itself (its ``p0`` not finite): :func:`start_vector`'s, with ``fallback``
    where that has no peak to measure or is not finite, when ``fallback`` is finite (a refit of part of a table
    from the whole table's optimum); else :func:`start_vector`'s own fallback, the two-level search.
    ``lax.cond`` throughout: outside ``vmap`` only the branch taken runs."""
    have = jnp.all(jnp.isfinite(fallback))
    if spec.model in ("hiraji", "hamon"):
        p = closed_form_start(terms, y, w, spec)
    else:
        good, near = _moment_near(terms, y, w, spec)
        p = jax.lax.cond(good, near, lambda: jax.lax.cond(have, lambda: fallback,
                                                          lambda: two_level_start(terms, y, w, spec)))
    return jnp.where(jnp.all(jnp.isfinite(p)) | ~have, p, fallback)


@functools.partial(jax.jit, static_argnames=("spec",))
def pair_start(terms: Terms, y, w, spec: ModelSpec, width):
    """Start for a sharp + haze sum (two-lobe model): the sharp width from :data:`MOMENT_FACTORS` around the
    moment width, the haze at the model's default ratio, and the weight fitted, not assumed.

    With both widths fixed the model s·(w f(α₁) + (1 − w) f(α₂)) is linear in the parts' amplitudes
    a₁ = s·w and a₂ = s·(1 − w): each candidate's best amplitudes come from a 2×2 weighted least-squares
    solve (one evaluation of each part: :func:`~jkatana.fit._model.mixture_parts`), and the lowest-cost
    candidate with both amplitudes positive (a sum, not a difference) wins. Where none has (no haze in the
    data) the start is :func:`grid_start`'s at these widths: the default weight, the scale linear.
    """
    from jkatana.fit._model import mixture_parts

    dtype = y.dtype
    haze, weight = spec.fit_model.defaults
    lo, hi, n = MOMENT_FACTORS
    sharp = jnp.log(width) + jnp.log(jnp.geomspace(lo, hi, n)).astype(dtype)
    at = evaluation_point(terms, dataclasses.replace(spec, tilt=False))
    parts = jax.vmap(lambda t: mixture_parts(t, terms, spec, at))
    A1, A2 = parts(sharp) * w, parts(sharp + math.log(haze)) * w  # (n, points)
    yw = y * w
    g11, g22, g12 = jnp.sum(A1 * A1, -1), jnp.sum(A2 * A2, -1), jnp.sum(A1 * A2, -1)
    b1, b2 = A1 @ yw, A2 @ yw
    det = g11 * g22 - g12**2
    ok = det > 1e-12 * g11 * g22
    det = jnp.where(ok, det, 1.0)
    a1 = (g22 * b1 - g12 * b2) / det
    a2 = (g11 * b2 - g12 * b1) / det
    gain = a1 * b1 + a2 * b2  # the cost removed: ½‖yw‖² − cost = ½ gain at the candidate's amplitudes
    ok = ok & (a1 > 0) & (a2 > 0) & jnp.isfinite(gain)
    # the default weight w₀ instead (grid_start's candidates, from the same part values): scale linear
    m = weight * A1 + (1.0 - weight) * A2
    mm = jnp.maximum(jnp.sum(m * m, -1), jnp.finfo(dtype).tiny)
    s0 = jnp.maximum(m @ yw / mm, jnp.finfo(dtype).tiny)
    gain0 = jnp.where(jnp.isfinite(s0), s0 * (m @ yw), -jnp.inf)
    fitted = jnp.any(ok)
    k = jnp.where(fitted, jnp.argmax(jnp.where(ok, gain, -jnp.inf)), jnp.argmax(gain0))
    a1 = jnp.where(fitted, jnp.where(ok, a1, 1.0)[k], weight * s0[k])
    a2 = jnp.where(fitted, jnp.where(ok, a2, 1.0)[k], (1.0 - weight) * s0[k])
    tail = jnp.zeros(int(spec.tilt) + int(spec.floor), dtype)
    shape = spec.fit_model.encode(sharp[k], (haze, a1 / (a1 + a2)))
    return jnp.concatenate([jnp.stack([jnp.log(a1 + a2), *(jnp.asarray(v, dtype) for v in shape)]), tail])


#: Width grid of :func:`grid_start` (radians for the paper's μ, the microfacet α otherwise).
GRID_WIDTHS = (1e-3, 0.5, 48)


@functools.partial(jax.jit, static_argnames=("spec",))
def two_level_start(terms: Terms, y, w, spec: ModelSpec):
    """:func:`grid_start` in two levels: 12 widths over the :data:`GRID_WIDTHS` range, then 9 widths spanning
    one coarse step either side of the best; the same range and a finer final spacing than the single
    48-width grid, at 21 model evaluations instead of 48 (jit/vmap-able).

    The refinement relies on the cost at the best scale having one minimum in log width over the grid's
    range, as it has for a single-peaked lobe on a table with one peak per incidence; the full grid
    (``start="grid"`` or ``multistart`` of :func:`jkatana.fit.region.fit_region`) searches every width.
    """
    lo, hi, _ = GRID_WIDTHS
    coarse = jnp.geomspace(lo, hi, 12).astype(y.dtype)
    step = (hi / lo) ** (1.0 / 11)
    best = jnp.exp(grid_start(terms, y, w, spec, mus=coarse)[1])
    return grid_start(terms, y, w, spec, mus=best * jnp.geomspace(1.0 / step, step, 9).astype(y.dtype))


@functools.partial(jax.jit, static_argnames=("spec",))
def grid_start(terms: Terms, y, w, spec: ModelSpec, mus=None):
    """Coarse-grid start: for each width on a log grid (other shape parameters at their defaults) the
    best scale is linear; the lowest cost wins (jit/vmap-able)."""
    mus = jnp.geomspace(*GRID_WIDTHS[:2], GRID_WIDTHS[2]).astype(y.dtype) if mus is None else jnp.asarray(mus, y.dtype)
    tail = jnp.zeros(int(spec.tilt) + int(spec.floor), y.dtype)

    def vec(log_s, log_mu):
        return jnp.concatenate([jnp.reshape(log_s, (1,)), default_shape(spec, log_mu, y.dtype), tail])

    def cost_at(mu):
        m1 = green(vec(jnp.zeros((), y.dtype), jnp.log(mu)), terms, spec)  # scale 1
        a = jnp.sum(m1 * y * w * w) / jnp.maximum(jnp.sum((m1 * w) ** 2), jnp.finfo(y.dtype).tiny)
        a = jnp.maximum(a, jnp.finfo(y.dtype).tiny)
        r = (a * m1 - y) * w
        return jnp.sum(r * r), jnp.log(a)

    costs, logs = jax.vmap(cost_at)(mus)
    i = jnp.argmin(jnp.where(jnp.isfinite(costs), costs, jnp.inf))
    return vec(logs[i], jnp.log(mus[i]))


@functools.partial(jax.jit, static_argnames=("spec", "snr_min", "rel_min", "mu_fallback"))
def closed_form_start(terms: Terms, y, w, spec: ModelSpec, *, snr_min: float = 3.0,
                      rel_min: float = 1e-3, mu_fallback: float = 0.05):
    """Linear least-squares start in log space (the module's closed form), jit/vmap-able.

    Uses points with y > ``snr_min``·σ, y > ``rel_min``·max y and a > 0;
    weights (y/σ)² (the variance of log y is (σ/y)²). Falls back to
    μ = ``mu_fallback`` and the peak's scale where the quadratic term has the
    wrong sign or too few points qualify. Returns the parameter vector.
    """
    return _log_quadratic(terms, y, w, spec.tilt, spec.floor, snr_min=snr_min, rel_min=rel_min,
                          mu_fallback=mu_fallback)[0]


def _log_quadratic(terms: Terms, y, w, tilt: bool, floor: bool, *, snr_min: float = 3.0, rel_min: float = 1e-3,
                   mu_fallback: float = 0.05):
    """:func:`closed_form_start`'s vector and whether the fit itself was usable (else the fallback)."""
    dtype = y.dtype
    amp = terms.amp
    ymax = jnp.max(jnp.where(w > 0, y, -jnp.inf))
    ok = (w > 0) & (y * w > snr_min) & (y > rel_min * ymax) & (amp > 0)
    z = jnp.log(jnp.where(ok, y, 1.0) / jnp.where(ok, amp, 1.0))
    om = jnp.where(ok, (y * w) ** 2, 0.0)
    om = om / jnp.maximum(jnp.max(om), jnp.finfo(dtype).tiny)
    phi = terms.phi
    scale_phi = 0.05
    u = phi / scale_phi
    X = jnp.stack([jnp.ones_like(u), u, u * u], axis=-1) if tilt else None
    n_coef = 3 if tilt else 2
    if tilt:
        A = (X * om[:, None]).T @ X
        b = (X * om[:, None]).T @ z
        ridge = 1e-9 * jnp.trace(A) * jnp.eye(A.shape[0], dtype=dtype)
        c = jnp.linalg.solve(A + ridge, b)
    else:  # 2×2 normal equations by hand: much cheaper than a batched LU under vmap
        u2 = u * u
        s0, s1, s2 = jnp.sum(om), jnp.sum(om * u2), jnp.sum(om * u2 * u2)
        b0, b1 = jnp.sum(om * z), jnp.sum(om * u2 * z)
        det = s0 * s2 - s1 * s1
        det = jnp.where(det > 0, det, jnp.finfo(dtype).tiny)
        c = jnp.stack([(s2 * b0 - s1 * b1) / det, (s0 * b1 - s1 * b0) / det])
    q = c[-1] / scale_phi**2  # = −ln2/μ²
    good = (jnp.sum(ok) >= n_coef + 1) & (q < 0) & jnp.all(jnp.isfinite(c))
    q_safe = jnp.where(good, q, -LN2 / mu_fallback**2)
    mu = jnp.sqrt(-LN2 / q_safe)
    if tilt:
        delta = jnp.where(good, (c[1] / scale_phi) / (2 * q_safe), 0.0)
        delta = jnp.clip(delta, -0.2, 0.2)
        log_s = c[0] - q_safe * delta**2
    else:
        delta = None
        log_s = c[0]
    # fallback scale: peak value over the amplitude at the peak
    i = jnp.argmax(jnp.where(w > 0, y, -jnp.inf))
    log_s_fb = jnp.log(jnp.maximum(y[i], jnp.finfo(dtype).tiny) / jnp.maximum(amp[i], jnp.finfo(dtype).tiny))
    log_s = jnp.where(good & jnp.isfinite(log_s), log_s, log_s_fb)
    parts = [log_s, jnp.log(mu)]
    if tilt:
        parts.append(delta)
    if floor:
        parts.append(jnp.zeros((), dtype))
    return jnp.stack(parts).astype(dtype), good


#: The start strategies by name.
STARTS: dict[str, Start] = {s.name: s for s in (
    Start("default", start_vector), Start("log-quadratic", closed_form_start), Start("moment", moment_start),
    Start("grid", grid_start), Start("two-level", two_level_start))}


__all__ = ["Start", "STARTS", "closed_form_start", "grid_start", "two_level_start", "moment_start", "pair_start",
           "start_vector", "start_in_solve", "MOMENT_FACTORS", "GRID_WIDTHS"]
