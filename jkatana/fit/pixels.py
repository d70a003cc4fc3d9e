"""Per-pixel fits for spatially varying maps: closed-form start + a fixed number of damped Gauss–Newton steps.

Every pixel of a reflectance map is measured at the same geometry, so the
parameter-free terms (φ, F̄, G/cos θr) are shared and only the values differ.
A general-purpose solver under ``vmap`` runs the whole batch until its
slowest pixel converges (one pixel that never meets the tolerance makes the
batch run to ``max_steps``). Here instead:

1. the log-linear closed form (:func:`jkatana.fit.starts.closed_form_start`)
   gives each pixel a start that is already close;
2. a *fixed* number of Levenberg–Marquardt-damped Gauss–Newton steps
   (Levenberg 1944, Marquardt 1963) with the analytic 2×2 normal equations
   (∂m/∂log s = m, ∂m/∂log μ = m · 2 ln2 φ²/μ²) polish it — no while-loop,
   so every pixel costs the same;
3. pixels whose Gauss–Newton decrement is still not small are reported as
   *stragglers* (``converged`` False), never silently accepted.

Parameters: (scale, μ) per pixel (no tilt or floor; fit those per region).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.fit._model import ModelSpec, Terms
from jkatana.fit.starts import closed_form_start
from jkatana.measure.noise import NoiseModel
from jkatana.models.microfacet import LN2, gaussian_facet


def _cost_jac(p, terms, y, w):
    s, mu = jnp.exp(p[0]), jnp.exp(p[1])
    m = s * gaussian_facet(terms.phi, mu) * terms.amp
    r = (m - y) * w
    j0 = m * w
    j1 = j0 * (2 * LN2) * (terms.phi / mu) ** 2
    return r, j0, j1


def _one_pixel(y, w, terms, spec, steps):
    p = closed_form_start(terms, y, w, spec)
    r, j0, j1 = _cost_jac(p, terms, y, w)
    cost = 0.5 * jnp.sum(r * r)
    lam = jnp.asarray(1e-3, y.dtype)

    def body(_, carry):
        p, cost, lam, r, j0, j1 = carry
        a, b, c = jnp.sum(j0 * j0), jnp.sum(j0 * j1), jnp.sum(j1 * j1)
        g0, g1 = jnp.sum(j0 * r), jnp.sum(j1 * r)
        a_, c_ = a * (1 + lam), c * (1 + lam)
        det = a_ * c_ - b * b
        det = jnp.where(det > 0, det, jnp.finfo(y.dtype).tiny)
        d0 = -(c_ * g0 - b * g1) / det
        d1 = -(a_ * g1 - b * g0) / det
        # keep steps in log space bounded (a far start can't jump to overflow)
        d0, d1 = jnp.clip(d0, -5.0, 5.0), jnp.clip(d1, -2.0, 2.0)
        pn = p + jnp.stack([d0, d1])
        rn, j0n, j1n = _cost_jac(pn, terms, y, w)
        cn = 0.5 * jnp.sum(rn * rn)
        better = jnp.isfinite(cn) & (cn <= cost)
        p = jnp.where(better, pn, p)
        r, j0, j1 = (jnp.where(better, rn, r), jnp.where(better, j0n, j0), jnp.where(better, j1n, j1))
        cost = jnp.where(better, cn, cost)
        lam = jnp.where(better, lam * 0.1, lam * 10.0)
        lam = jnp.clip(lam, 1e-12, 1e12)
        return p, cost, lam, r, j0, j1

    p, cost, lam, r, j0, j1 = jax.lax.fori_loop(0, steps, body, (p, cost, lam, r, j0, j1))
    a, b, c = jnp.sum(j0 * j0), jnp.sum(j0 * j1), jnp.sum(j1 * j1)
    g0, g1 = jnp.sum(j0 * r), jnp.sum(j1 * r)
    det = a * c - b * b
    dec = jnp.where(det > 0, (c * g0 * g0 - 2 * b * g0 * g1 + a * g1 * g1) / jnp.where(det > 0, det, 1.0),
                    jnp.inf)
    return p, cost, dec


@functools.partial(jax.jit, static_argnames=("spec", "steps", "noise"))
def _batch(Y, S, terms, spec, steps, noise):
    finite = jnp.isfinite(Y)
    Y = jnp.where(finite, Y, 0.0)
    if noise is not None:
        S = noise.sigma(Y)
    W = jnp.where(finite & (S > 0), 1.0 / jnp.where(S > 0, S, 1.0), 0.0).astype(Y.dtype)
    return jax.vmap(lambda y, w: _one_pixel(y, w, terms, spec, steps))(Y, W)


def fit_pixels(values, terms: Terms, *, model: str = "hiraji", noise: NoiseModel | None = None, sigma=None,
               steps: int = 4, tol: float | None = None, chunk: int | None = None) -> dict:
    """Fit (scale, μ) for every pixel; every pixel is measured at the geometry of ``terms``.

    **Arguments:**

    - `values`: ``(P, N)`` green values, P pixels × N measurements (NaN = missing).
    - `terms`: :class:`~jkatana.fit._model.Terms` from :func:`~jkatana.fit._model.prepare`
      for the N geometries (shared by all pixels).
    - `model`: ``"hiraji"`` or ``"hamon"``.
    - `noise`: a :class:`NoiseModel` (σ evaluated at each value), or `sigma`: ``(P, N)``.
    - `steps`: damped Gauss–Newton steps after the closed-form start (fixed).
    - `tol`: straggler threshold on the Gauss–Newton decrement relative to
      max(1, cost) (default 1e-6 for float64, 1e-3 for float32).
    - `chunk`: pixels per compiled batch (None: all at once).

    **Returns:** dict of numpy arrays: ``scale``, ``mu`` (P,), ``cost``,
    ``decrement``, ``converged`` (bool, False for stragglers and
    non-finite results) and ``n_stragglers``.
    """
    spec = ModelSpec(model)
    dtype = terms.phi.dtype
    Y = jnp.asarray(values, dtype)
    if Y.ndim != 2 or Y.shape[1] != terms.phi.shape[0]:
        raise ValueError(f"values must be (pixels, {terms.phi.shape[0]}), got {Y.shape}")
    if sigma is not None:
        S, noise = jnp.asarray(sigma, dtype), None
    else:
        S, noise = jnp.zeros((), dtype), (noise or NoiseModel(relative=0.02, absolute=1.0))
    P = Y.shape[0]
    chunk = chunk or P
    outs = [_batch(Y[i:i + chunk], S if S.ndim == 0 else S[i:i + chunk], terms, spec, steps, noise)
            for i in range(0, P, chunk)]
    p = np.concatenate([np.asarray(o[0]) for o in outs])
    cost = np.concatenate([np.asarray(o[1]) for o in outs])
    dec = np.concatenate([np.asarray(o[2]) for o in outs])
    tol = tol if tol is not None else (1e-6 if dtype == jnp.float64 else 1e-3)
    ok = np.all(np.isfinite(p), axis=1) & np.isfinite(cost) & (dec <= tol * np.maximum(1.0, cost))
    return dict(scale=np.exp(p[:, 0]), mu=np.exp(p[:, 1]), cost=cost, decrement=dec, converged=ok,
                n_stragglers=int(np.sum(~ok)))


__all__ = ["fit_pixels"]
