"""Guards for singular points that keep values *and gradients* finite.

The "double where" pattern (JAX FAQ, "Gradients contain NaN where using
where"): the unsafe branch is evaluated on a substituted, harmless input, so
its (unused) derivative is finite too and cannot poison the gradient with
0 · inf = NaN.
"""

from __future__ import annotations

import jax.numpy as jnp


def tiny(dtype) -> float:
    """Smallest positive normal of ``dtype`` (float32: 1.2e-38)."""
    return float(jnp.finfo(dtype).tiny)


def safe_sqrt(x):
    """√max(x, 0) with derivative 0 (not inf) at x ≤ 0."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def safe_div(num, den, *, fallback=0.0):
    """``num / den`` where ``den != 0``, ``fallback`` elsewhere; finite gradient."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), fallback)


def norm(v, axis=-1, keepdims=False):
    """Euclidean norm with derivative 0 at the zero vector."""
    return safe_sqrt(jnp.sum(v * v, axis=axis, keepdims=keepdims))


def normalize(v, axis=-1):
    """``v / |v|``; the zero vector maps to zero (finite gradient)."""
    n2 = jnp.sum(v * v, axis=axis, keepdims=True)
    ok = n2 > 0
    return jnp.where(ok, v * jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, n2, 1.0)), 0.0), 0.0)


def safe_atan2(y, x):
    """atan2 with derivative 0 at (0, 0) instead of NaN (value 0 there, as jnp.arctan2)."""
    ok = (x != 0) | (y != 0)
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0.0), jnp.where(ok, x, 1.0)), 0.0)
