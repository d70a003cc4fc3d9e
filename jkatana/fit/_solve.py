"""Weighted least squares for eqs. (3)–(4): closed-form start, optimistix solve, honest convergence.

Residuals are r_j = (m_j − y_j) / σ_j in linear units, σ_j from a camera
noise model (:class:`NoiseModel`: relative + absolute floor), so points in the
tail (where y underflows or is 0) carry the information they really have —
almost none — instead of the absurd weight they get in log space, where the
far tail of a narrow lobe would pin μ.

**Start.** With F̄ divided out, log y = log s − ln2 (φ + t)²/μ² is *linear* in
(log s, 1/μ²) without a tilt and a quadratic in φ with one: a
weighted linear least-squares fit over points well above the noise floor gives
the start (:func:`closed_form_start`). Other lobes start from the same fit's
peak width mapped to the lobe's width through its reflected width, refined on
a few widths around it (:func:`moment_start`).

**Solve.** optimistix (Kidger et al., 2024) Levenberg–Marquardt (default),
Dogleg or Gauss–Newton, or jaxopt's LevenbergMarquardt with the Madsen–Nielsen
stopping rule (Madsen, Nielsen, Tingleff 2004) as a cross-check. The
solver stops when an accepted step changes every log-parameter by less than
1e-4·(1 + |value|) and every weighted residual by less than 1e-4·(1 + |r_j|)
(optimistix's Cauchy criterion, ``rtol = atol = 1e-4``). A move of one
standard error changes the residual vector by about 1 in Euclidean norm; such
a step changes it by less than 1e-4·√N·(1 + max|r_j|), about 0.01 for a
region's 10³ points at χ²/dof ≈ 1, so it is far below the statistical error,
and near the optimum LM's steps shrink faster than linearly, so the point it
returns is closer still. Tighter tolerances only add steps near the optimum
that the rounding of the cost rejects. The optimum itself is certified by the
decrement below, not by the step size.

**Convergence is checked, not assumed.** A solver's ``result`` is not enough
(optimistix LM in float32 from a far start can return the start with
success). At the returned point we compute the Gauss–Newton decrement
gᵀ(JᵀJ)⁻¹g (g = Jᵀr), i.e. how much cost one more Gauss–Newton step would
still remove. The fit is *converged* only if the solver reported success, the
values are finite, the decrement is below ``tol · max(1, cost)`` and the cost
did not increase from the start. Reasons are reported.

**Laplace.** cov(log-params) = s² (JᵀJ)⁻¹ at the optimum with
s² = max(1, χ²/dof) (Birge ratio: a noise model that is too optimistic for
real data widens the interval instead of lying), natural-unit standard errors
by the delta method and 95 % intervals from the normal in log space (so the
intervals of χ, β, μ stay positive).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jkatana.fit._model import ModelSpec, Terms, default_shape, evaluation_point, green, to_natural
from jkatana.measure.noise import NoiseModel
from jkatana.models.microfacet import LN2

SOLVERS = ("lm", "dogleg", "gn", "jaxopt")
Z95 = 1.959963984540054


def estimate_noise(value, sigma=None, *, floor_fraction: float = 1e-4) -> NoiseModel:
    """Estimate a :class:`NoiseModel` from a table.

    With the table's per-point ``sigma`` (e.g. pixel scatter over the region),
    σ² = r² ρ² + s|ρ| + a² is fitted by non-negative least squares (weights 1/σ⁴, so
    every point counts relatively). Without it, the relative part defaults to
    2 % and the floor to the robust scatter (MAD) of the lowest tenth of the
    values. In both cases the floor is at least ``floor_fraction`` × peak
    (1e-4: roughly the quantisation step of a 14-bit RAW at the peak's
    exposure), so no point is ever believed beyond what a camera can deliver.
    """
    y = np.asarray(value, np.float64)
    finite = np.isfinite(y)
    peak = float(np.max(np.abs(y[finite]))) if finite.any() else 1.0
    peak = peak if peak > 0 else 1.0
    floor = floor_fraction * peak
    if sigma is not None:
        s = np.asarray(sigma, np.float64)
        ok = finite & np.isfinite(s) & (s > 0)
        if ok.sum() >= 3:
            A = np.stack([y[ok] ** 2, np.abs(y[ok]), np.ones(ok.sum())], axis=1) / s[ok, None] ** 2
            b = np.ones(ok.sum())
            from scipy.optimize import nnls

            (r2, shot, a2), _ = nnls(A, b)
            return NoiseModel(relative=float(math.sqrt(r2)), shot=float(shot),
                              absolute=float(max(math.sqrt(a2), floor)))
    low = np.sort(y[finite])[: max(3, finite.sum() // 10)]
    mad = float(1.4826 * np.median(np.abs(low - np.median(low)))) if low.size else 0.0
    return NoiseModel(relative=0.02, absolute=max(mad, floor))


# --------------------------------------------------------------------------- residuals


def residuals(p, args):
    """r = (m − y)·w, w = 1/σ (0 for padded or excluded points).

    ``args`` = ``(terms, y, w, spec)`` or ``(terms, y, w, spec, at)`` with ``at`` the model's
    :func:`~jkatana.fit._model.evaluation_point` computed once outside a solver's loop (None: computed here).
    """
    terms, y, w, spec, *at = args
    return (green(p, terms, spec, at[0] if at else None) - y) * w


@functools.partial(jax.jit, static_argnames=("spec",))
def weighted_residuals(p, terms: Terms, y, w, spec: ModelSpec):
    """:func:`residuals` as one compiled program per spec and table shape, for callers outside a solver."""
    return residuals(p, (terms, y, w, spec))


@functools.partial(jax.jit, static_argnames=("spec",))
def model_values(p, terms: Terms, spec: ModelSpec):
    """:func:`~jkatana.fit._model.green` as one compiled program per spec and table shape."""
    return green(p, terms, spec)


def _jac(p, args):
    return jax.jacfwd(residuals)(p, args)


def _jac_and_residuals(p, args):
    """(J, r) at ``p`` from one forward-mode pass (the residuals are its primal output)."""
    def both(q):
        r = residuals(q, args)
        return r, r

    return jax.jacfwd(both, has_aux=True)(p)


# --------------------------------------------------------------------------- closed form


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


def _start_in_solve(terms: Terms, y, w, spec: ModelSpec, fallback):
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
    """Linear least-squares start in log space (module docstring), jit/vmap-able.

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


# --------------------------------------------------------------------------- solve


def _solver(name: str, rtol: float, atol: float):
    if name == "lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol)
    if name == "gn":
        return optx.GaussNewton(rtol=rtol, atol=atol)
    raise ValueError(f"solver must be one of {SOLVERS}, got {name!r}")


@functools.partial(jax.jit, static_argnames=("spec", "solver", "max_steps", "rtol", "atol"))
def solve(terms: Terms, y, w, p0, *, spec: ModelSpec, solver: str = "lm", max_steps: int = 200,
          rtol: float | None = None, atol: float | None = None, fallback=None):
    """One weighted least-squares solve from ``p0``; returns a dict of arrays (jit-compiled).

    With ``fallback`` (a parameter vector, finite or not) the start is part of the program: ``p0`` where it is
    finite, else :func:`_start_in_solve`'s (:func:`start_vector`'s, or ``fallback`` where that has no peak to
    measure). A region's fits (the first, the IRLS and robust refits from the previous optimum, the refits of
    each incidence from the region's optimum: :func:`fit_program`) are then calls of one compiled program per
    spec and table shape, each one dispatch, instead of a start program, a solve program and a batched program
    of refits. Without ``fallback``, ``p0`` is the start as given.

    Keys: ``p`` (final parameters), ``p0``, ``cost0``/``cost`` (½Σr²),
    ``decrement`` (Gauss–Newton decrement at ``p``), ``grad_norm``,
    ``steps``, ``solver_ok`` (the solver's own verdict), ``jtj`` (JᵀJ at ``p``).
    ``rtol``/``atol`` default to 1e-4 for optimistix's Cauchy criterion (module
    docstring) and 1e-10 for jaxopt's Madsen–Nielsen rule (whose ``gtol`` is an
    absolute gradient norm).

    The model's evaluation point (:func:`~jkatana.fit._model.evaluation_point`:
    geometry and Fresnel factors) is computed once here, outside the solver's
    loop. The residuals and Jacobian at ``p`` are those of optimistix's last
    linearisation, which is at the point it returns (its ``f_info`` follows every
    accepted step), so the check costs no further forward pass.
    """
    if fallback is not None:
        p0 = jnp.asarray(p0, y.dtype)
        fallback = jnp.asarray(fallback, y.dtype)
        p0 = jax.lax.cond(jnp.all(jnp.isfinite(p0)), lambda: p0,
                          lambda: _start_in_solve(terms, y, w, spec, fallback))
    args = (terms, y, w, spec, None if spec.tilt else evaluation_point(terms, spec))
    if solver == "jaxopt":
        rtol = 1e-10 if rtol is None else rtol
        atol = 1e-10 if atol is None else atol
        import jaxopt

        lm = jaxopt.LevenbergMarquardt(lambda p: residuals(p, args), maxiter=max_steps,
                                       stop_criterion="madsen-nielsen", xtol=rtol, gtol=atol,
                                       tol=atol, jit=True, implicit_diff=False)
        with jax.numpy_dtype_promotion("standard"):  # jaxopt's LM multiplies bool by float internally
            p, state = lm.run(p0)
        steps = state.iter_num
        solver_ok = steps < max_steps
    else:
        rtol = 1e-4 if rtol is None else rtol
        atol = 1e-4 if atol is None else atol
        sol = optx.least_squares(residuals, _solver(solver, rtol, atol), p0, args=args,
                                 max_steps=max_steps, throw=False)
        p = sol.value
        steps = sol.stats["num_steps"]
        solver_ok = sol.result == optx.RESULTS.successful
    r0 = residuals(p0, args)
    if solver == "jaxopt":
        J, r = _jac_and_residuals(p, args)
    else:  # the solver's last linearisation is at its returned point: r and J there without another pass
        info = sol.state.f_info
        r, J = info.residual, info.jac.as_matrix()
    g = J.T @ r
    jtj = J.T @ J
    dec = _decrement(jtj, g)
    return dict(p=p, p0=p0, cost0=0.5 * jnp.sum(r0 * r0), cost=0.5 * jnp.sum(r * r), decrement=dec,
                grad_norm=jnp.max(jnp.abs(g)), steps=steps, solver_ok=solver_ok, jtj=jtj)


def fit_program(terms: Terms, y, w, spec: ModelSpec, *, start=None, fallback=None, solver: str = "lm",
                max_steps: int = 200) -> dict:
    """:func:`solve` with its start in the same compiled program: from ``start`` (a parameter vector) or, when
    None, from :func:`start_vector`'s start (``fallback``: the vector where that has no peak to measure, e.g.
    a whole table's optimum for a refit of part of it). Every call of a spec and table shape (any start,
    fallback or weights) runs one compiled program."""
    nan = np.full(spec.size, np.nan, y.dtype)  # numpy: no eager program
    p0 = nan if start is None else start
    fb = nan if fallback is None else fallback
    return solve(terms, y, w, p0, spec=spec, solver=solver, max_steps=max_steps, fallback=fb)


def _decrement(jtj, g):
    """gᵀ(JᵀJ)⁻¹g, with JᵀJ scaled to unit diagonal and eigenvalues floored (never NaN)."""
    d = jnp.sqrt(jnp.maximum(jnp.diag(jtj), jnp.finfo(jtj.dtype).tiny))
    A = jtj / d[:, None] / d[None, :]
    gs = g / d
    lam, V = jnp.linalg.eigh(A)
    lam = jnp.maximum(lam, jnp.finfo(jtj.dtype).eps * jnp.max(lam))
    proj = V.T @ gs
    return jnp.sum(proj * proj / lam)


def verdict(out: dict, dtype=np.float64, *, tol: float | None = None) -> tuple[bool, list[str]]:
    """Converged or not, with the reasons (module docstring)."""
    eps = float(np.finfo(dtype).eps)
    tol = tol if tol is not None else max(1e-8, 1e3 * eps)
    p = np.asarray(out["p"])
    cost, cost0 = float(out["cost"]), float(out["cost0"])
    dec = float(out["decrement"])
    reasons = []
    if not np.all(np.isfinite(p)) or not math.isfinite(cost):
        reasons.append("non-finite parameters or cost")
    if not bool(out["solver_ok"]):
        reasons.append("solver did not report success (max steps or failure)")
    if not (dec <= tol * max(1.0, cost)):
        reasons.append(f"gradient not small: a Gauss-Newton step would still lower the cost by "
                       f"{dec:.3g} (cost {cost:.6g})")
    if cost > cost0 * (1 + 10 * eps) + 10 * eps:
        reasons.append(f"cost increased from the start ({cost0:.6g} -> {cost:.6g})")
    if int(out["steps"]) == 0 or np.array_equal(p, np.asarray(out["p0"])):
        if reasons:
            reasons.append("no step taken")
    return (not reasons), reasons


# --------------------------------------------------------------------------- Laplace


def natural_intervals(p, cov, spec: ModelSpec, z: float = Z95) -> tuple[dict, dict, bool]:
    """Natural-unit standard errors and intervals from a covariance of the fit vector.

    Each natural parameter v is a monotone function of one scalar u(p) that is
    close to normal: log v for positive parameters (scale, widths, the haze
    width), the logit for γ and the mixture weight, v itself for tilt and
    floor. The interval is v(u ± z·sd(u)) (so it stays inside the parameter's
    domain), sd(u)² = ∇uᵀ Σ ∇u (delta method), and the standard error is
    |dv/du|·sd(u). Returns ``(se, ci, ok)``.
    """
    p = np.asarray(p, np.float64)
    cov = np.asarray(cov, np.float64)
    ok = bool(np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0))
    fm = spec.fit_model
    from scipy.special import expit as sig
    exp = lambda t: math.exp(min(t, 700.0))  # noqa: E731
    items = [(fm.scale_name, np.eye(spec.size)[0], p[0], exp)]
    items.append((fm.names[0], np.eye(spec.size)[1], p[1], exp))
    if spec.model == "gtr":
        items.append(("gamma", np.eye(spec.size)[2], p[2], lambda t: 1.0 + 3.0 * sig(t)))
    if spec.model == "two-lobe":
        g = np.eye(spec.size)[1] + np.eye(spec.size)[2] * sig(p[2])
        items.append(("alpha_haze", g, p[1] + float(np.logaddexp(0.0, p[2])), exp))
        items.append(("weight", np.eye(spec.size)[3], p[3], sig))
    if spec.tilt:
        items.append(("tilt_deg", np.eye(spec.size)[spec.tilt_index], p[spec.tilt_index], math.degrees))
    if spec.floor:
        items.append(("floor", np.eye(spec.size)[spec.floor_index], p[spec.floor_index], lambda t: t))
    se, ci = {}, {}
    for name, g, u, f in items:
        sd = math.sqrt(abs(float(g @ cov @ g))) if ok else float("nan")
        lo, hi = (f(u - z * sd), f(u + z * sd)) if math.isfinite(sd) else (float("nan"), float("nan"))
        h = 1e-6 * max(1.0, abs(u))
        se[name] = float(abs(f(u + h) - f(u - h)) / (2 * h) * sd)
        ci[name] = [float(lo), float(hi)]
    return se, ci, ok


def laplace(jtj, cost: float, n_eff: int, p, spec: ModelSpec, *, birge: bool = True) -> dict:
    """Gauss–Newton covariance at the optimum, natural-unit errors and 95 % intervals (:func:`natural_intervals`)."""
    jtj = np.asarray(jtj, np.float64)
    p = np.asarray(p, np.float64)
    dof = max(1, n_eff - spec.size)
    chi2_dof = 2.0 * cost / dof
    scale = max(1.0, chi2_dof) if birge else 1.0
    try:
        cov = np.linalg.inv(jtj) * scale
    except np.linalg.LinAlgError:
        cov = np.full_like(jtj, np.nan)
    se, ci, ok = natural_intervals(p, cov, spec)
    return dict(ok=ok, names=list(spec.names), params=spec.log_names, cov_log=cov.tolist(), se=se, ci95=ci,
                chi2_dof=chi2_dof, covariance_scale=scale)


__all__ = ["NoiseModel", "estimate_noise", "residuals", "weighted_residuals", "model_values", "closed_form_start",
           "grid_start", "two_level_start", "moment_start", "pair_start", "start_vector", "solve", "fit_program",
           "verdict", "laplace", "natural_intervals", "SOLVERS", "to_natural"]
