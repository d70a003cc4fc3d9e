"""Weighted least squares for eqs. (3)–(4): optimistix solve from a start (:mod:`jkatana.fit.starts`), honest
convergence.

Residuals are r_j = (m_j − y_j) / σ_j in linear units, σ_j from a camera
noise model (:class:`~jkatana.measure.noise.NoiseModel`: relative + absolute floor), so points in the
tail (where y underflows or is 0) carry the information they really have —
almost none — instead of the absurd weight they get in log space, where the
far tail of a narrow lobe would pin μ.

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
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jkatana.fit._model import ModelSpec, Terms, evaluation_point, green
from jkatana.fit.starts import start_in_solve

SOLVERS = ("lm", "dogleg", "gn", "jaxopt")


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


def _jac_and_residuals(p, args):
    """(J, r) at ``p`` from one forward-mode pass (the residuals are its primal output)."""
    def both(q):
        r = residuals(q, args)
        return r, r

    return jax.jacfwd(both, has_aux=True)(p)


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
    finite, else :func:`~jkatana.fit.starts.start_in_solve`'s (:func:`~jkatana.fit.starts.start_vector`'s, or
    ``fallback`` where that has no peak to measure). A region's fits (the first, the IRLS and robust refits from the previous optimum, the refits of
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
                          lambda: start_in_solve(terms, y, w, spec, fallback))
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
    None, from :func:`~jkatana.fit.starts.start_vector`'s start (``fallback``: the vector where that has no
    peak to measure, e.g. a whole table's optimum for a refit of part of it). Every call of a spec and table shape (any start,
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


__all__ = ["SOLVERS", "residuals", "weighted_residuals", "model_values", "solve", "fit_program", "verdict"]
