"""Guards for singular points that keep values *and gradients* finite.

The "double where" pattern (JAX FAQ, "Gradients contain NaN where using
where"): the unsafe branch is evaluated on a substituted, harmless input, so
its (unused) derivative is finite too and cannot poison the gradient with
0 · inf = NaN.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def tiny(dtype) -> float:
    """Smallest positive normal of ``dtype`` (float32: 1.2e-38)."""
    return float(jnp.finfo(dtype).tiny)


def safe_sqrt(x):
    """√max(x, 0) with derivative 0 (not inf) at x ≤ 0."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def safe_div(num, den, *, fallback=0.0):
    """``num / den`` where ``den != 0``, ``fallback`` elsewhere; finite gradient (differentiated as
    :func:`ratio`, without forming 1/den², which overflows float32 for den ~ 1e-16)."""
    ok = den != 0
    return jnp.where(ok, ratio(num, jnp.where(ok, den, 1.0)), fallback)


@jax.custom_jvp
def _norm_last(v):
    return safe_sqrt(jnp.sum(v * v, axis=-1))


@_norm_last.defjvp
def _norm_last_jvp(primals, tangents):
    # d|v| = (v/|v|)·dv with the unit vector formed first: no 1/(2|v|) factor that overflows
    # float32 when |v| ~ 1e-16 meets a large cotangent
    (v,), (dv,) = primals, tangents
    n = _norm_last(v)
    ok = n > 0
    unit = jnp.where(ok[..., None], v / jnp.where(ok, n, 1.0)[..., None], 0.0)
    return n, jnp.sum(unit * dv, axis=-1)


def norm(v, axis=-1, keepdims=False):
    """Euclidean norm with derivative 0 at the zero vector and derivative v/|v| formed as a unit vector
    (bounded), so that gradients through tiny vectors stay finite in float32."""
    out = _norm_last(jnp.moveaxis(jnp.asarray(v), axis, -1))
    return jnp.expand_dims(out, axis) if keepdims else out


@jax.custom_jvp
def ratio(a, b):
    """``a / b`` whose derivative is ``(da − (a/b) db) / b`` — never ``a/b²``, which underflows (NaN at
    ``a = 0``) or overflows in float32 for ``b`` below ~1e-19. The caller guarantees ``b != 0``."""
    return a / b


@ratio.defjvp
def _ratio_jvp(primals, tangents):
    (a, b), (da, db) = primals, tangents
    q = a / b
    return q, (da - q * db) / b


def normalize(v, axis=-1):
    """``v / |v|``; the zero vector maps to zero (finite gradient)."""
    n2 = jnp.sum(v * v, axis=axis, keepdims=True)
    ok = n2 > 0
    return jnp.where(ok, v * jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, n2, 1.0)), 0.0), 0.0)


def safe_atan2(y, x):
    """atan2 with derivative 0 at (0, 0) instead of NaN (value 0 there, as jnp.arctan2)."""
    ok = (x != 0) | (y != 0)
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0.0), jnp.where(ok, x, 1.0)), 0.0)
