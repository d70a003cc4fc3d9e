"""Per-pixel quasi-Monte Carlo points of the MIS modes: a 3D Sobol sequence under random digital shifts.

Dimensions 0 and 1 of the Sobol sequence (Joe & Kuo 2008 direction numbers,
``scipy.stats.qmc``) form a (0, 2)-sequence; each pixel XORs its points with
random bits (a random digital shift, which keeps the net property; Owen 2003,
"Quasi-Monte Carlo sampling", SIGGRAPH course notes), independently for the
lobe and the environment strategies. With subpixels (``Plan.subpixels``),
one sequence per output pixel is shared: subpixel ``q`` takes points
``q·N … q·N + N − 1``, so the union over the pixel is one (0, m, 2)-net.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from jkatana.render.plan import Plan


@functools.lru_cache(maxsize=64)
def sobol_table(n: int) -> np.ndarray:
    """First ``n`` points of the 3D Sobol sequence (Joe & Kuo 2008 directions, scipy.stats.qmc) as uint32.

    Dimensions 0 and 1 form a (0, 2)-sequence: every power-of-two prefix is a
    (0, m, 2)-net, i.e. one point in every elementary interval of the unit
    square. The renderer XORs each pixel's points with random bits (a random
    digital shift, which keeps the net property; Owen 2003, "Quasi-Monte Carlo
    sampling", SIGGRAPH course notes) — independently for the lobe and the
    environment strategies, so each gets its own well-stratified 2D set.
    """
    from scipy.stats import qmc

    m = 1 << max(n - 1, 0).bit_length()  # a power-of-two prefix (scipy warns otherwise), then the first n
    pts = qmc.Sobol(d=3, scramble=False).random(m)[:n]
    return np.asarray(np.round(pts * 2.0**32), np.uint64).astype(np.uint32)


class PixelIds(NamedTuple):
    """Which output pixel and which of its subpixels each G-buffer sample is (see ``Plan.subpixels``).

    ``pixel (P,)`` uint32: a frame-wide pixel index (the scramble of the pixel's
    point set is ``jax.random.bits(fold_in(key, pixel))``, so it does not depend on
    the chunk or device that shades it); ``subpixel (P,)`` int32 in ``[0, S)``.
    """

    pixel: Array
    subpixel: Array


def per_pixel(plan: Plan, ids: PixelIds | None) -> bool:
    return ids is not None and plan.subpixels > 1


def mis_offset(key, P, dtype, plan: Plan | None = None, ids: PixelIds | None = None):
    """Per-pixel randomisation of the Sobol sample sequence: random digital shifts ``(P, 5)`` (uint32).

    With :class:`PixelIds` (and ``plan.subpixels > 1``) the randomisation is drawn per output
    pixel from ``fold_in(key, pixel)``, so all subpixels of a pixel share it wherever they are shaded."""
    if plan is not None and per_pixel(plan, ids):
        def one(p):
            kp = jax.random.fold_in(key, p)
            return jax.random.bits(kp, (5,), jnp.uint32)

        return jax.vmap(one)(ids.pixel)
    return jax.random.bits(key, (P, 5), jnp.uint32)


def sample_index(plan: Plan, ids: PixelIds | None, k, n: int | None = None):
    """Index of the k-th sample of each G-buffer sample in its pixel's sequence: ``k`` (scalar), or
    ``(P,)`` per subpixel (subpixel ``s`` takes indices ``s·N … s·N + N − 1``: for ``N`` a power of two each
    block is a (0, m, 2)-net and their union the full prefix). ``n``: the strategy's samples per G-buffer
    sample ``N`` (default ``plan.samples``)."""
    k = jnp.asarray(k, jnp.int32)
    if not per_pixel(plan, ids):
        return k
    sub = ids.subpixel.astype(jnp.int32)
    return sub * (plan.samples if n is None else n) + k


def uniforms(plan: Plan, offset, k, dtype, ids: PixelIds | None = None, n: int | None = None):
    """The k-th point per pixel: ``(mix, lobe u1, lobe u2, env (P, 2))``, for a strategy of ``n`` samples
    per G-buffer sample (default ``plan.samples``; the environment's is ``plan.n_env``)."""
    n = plan.samples if n is None else n
    idx = sample_index(plan, ids, k, n)
    n = n * (plan.subpixels if per_pixel(plan, ids) else 1)
    t = jnp.asarray(sobol_table(n))[idx]  # (3,) the same point for every pixel, or (P, 3) per subpixel
    t = jnp.broadcast_to(t, offset.shape[:1] + (3,))

    def unit(x):  # top 24 bits → [0, 1) exactly representable in float32
        return (x >> 8).astype(dtype) * jnp.asarray(2.0**-24, dtype)

    return (unit(t[:, 2] ^ offset[:, 4]), unit(t[:, 0] ^ offset[:, 0]), unit(t[:, 1] ^ offset[:, 1]),
            jnp.stack([unit(t[:, 0] ^ offset[:, 2]), unit(t[:, 1] ^ offset[:, 3])], -1))


def sample_points(plan: Plan, key, n: int, ids: PixelIds | None = None, dtype=jnp.float32):
    """The unit-cube points the MIS modes use: ``(n, plan.samples, 5)`` = (mixture choice, lobe u1, lobe u2,
    environment u1, u2) per G-buffer sample (Sobol), for inspection and tests.

    Same construction as :func:`shade` with the same ``key`` and ``ids``; the environment's columns are the
    environment's points when ``plan.n_env == plan.samples`` (the default).
    """
    offset = mis_offset(key, n, dtype, plan, ids)

    def one(k):
        r0, r1, r2, re = uniforms(plan, offset, k, dtype, ids)
        return jnp.concatenate([jnp.stack([r0, r1, r2], -1), re], -1)

    return jax.vmap(one, out_axes=1)(jnp.arange(plan.samples))
