"""The MIS modes' lobe sampling in the shader: unbiased with visible-normal sampling.

A rough Beckmann hamon region (the Mitsuba comparison's lobe, sampled by its visible normals) under a sky
with a sun, seen from normal to 1° above the horizon: over many seeds each pixel's mean matches a
converged estimate (z-scores); and the lobe samples alone (no environment sampling) converge to the same
frame, so the pdf the MIS weights use is the density the sampler draws.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.models import Conductor
from jkatana.models.lobe_id import LobeId
from jkatana.render.film import film_weights
from jkatana.render.environment import build_environment
from jkatana.render.fresnel_fold import Material, fresnel_table
from jkatana.render.plan import Pixels, Plan
from jkatana.render.shading import shade
from jkatana.spectral import DEFAULT_GRID

GRID = DEFAULT_GRID
CMF = film_weights(GRID)
BECKMANN = LobeId.of({"lobe": "beckmann", "alpha": 1.0})


def _scene(n_pix: int, alpha: float):
    c = Conductor.from_table("Fe-Johnson", GRID, dtype=jnp.float64)
    mat = Material(fresnel_table(c.n, c.k), jnp.asarray(1.0), jnp.asarray(1.0))
    from jkatana.light.sky import hosek_wilkie_sky

    sky = np.asarray(hosek_wilkie_sky(35.0, 160.0, 3.0, 0.1, (32, 64), GRID, sun_supersampling=4).radiance)
    env, _, _ = build_environment(sky, dtype=jnp.float64)
    # normals up; views from normal to 1° above the horizon, at several azimuths
    theta = np.linspace(0.0, np.radians(89.0), n_pix)
    az = np.linspace(0.0, 2 * np.pi, n_pix, endpoint=False)
    view = np.stack([np.sin(theta) * np.cos(az), np.sin(theta) * np.sin(az), np.cos(theta)], -1)
    P = n_pix
    px = Pixels(jnp.zeros((P, 3)), jnp.tile(jnp.array([[0.0, 0.0, 1.0]]), (P, 1)), jnp.asarray(view),
                jnp.zeros((P,)), jnp.full((P,), 0.05), jnp.full((P,), alpha))
    return mat, env, px


def _shader(plan, mat, env, px):
    return jax.jit(jax.vmap(lambda k: shade(plan, mat, env, None, px, jnp.asarray(CMF), k)[0]))


def _plan(samples, env_sampling=True):
    return Plan(samples=samples, hiraji=False, hamon=True, hamon_lobe=BECKMANN, fresnel_rank=0,
                env_sampling=env_sampling)


@pytest.mark.slow
@pytest.mark.parametrize("alpha", [0.05, 0.2])
def test_beckmann_visible_normals_estimate_is_unbiased(alpha):
    mat, env, px = _scene(8, alpha)
    seeds = 192
    keys = jax.random.split(jax.random.PRNGKey(5), seeds)
    est = np.asarray(_shader(_plan(4), mat, env, px)(keys))[..., 1]
    ref = np.asarray(_shader(_plan(4096), mat, env, px)(keys[:2])).mean(0)[..., 1]
    assert np.all(ref > 0)
    zz = (est.mean(0) - ref) / (est.std(0, ddof=1) / np.sqrt(seeds) + 1e-3 * ref)
    assert np.all(np.abs(zz) < 5.0), zz
    assert np.mean(zz**2) < 3.0, zz
    # lobe sampling alone: f·cos/pdf = F G1(L) G1(V)/G1_exact(V) ≤ 1.0035 F, converged with few samples
    lobe = np.asarray(_shader(_plan(1024, env_sampling=False), mat, env, px)(keys[:2])).mean(0)[..., 1]
    np.testing.assert_allclose(lobe, ref, rtol=0.02)


@pytest.mark.parametrize("n", [1, 5, 8, 11, 17])
@pytest.mark.parametrize("with_x", [False, True])
def test_sample_passes_accumulates_each_sample_once(n, with_x):
    """The two-pass sample loop (draw a block, then load and accumulate) visits k = 0 … n − 1 once each, in
    blocks that do not divide n as well (the padding's samples are dropped, even where they are not finite)."""
    from jkatana.render.integrators.mis import sample_passes as _sample_passes

    P = 3
    xs = jnp.asarray(np.random.default_rng(n).uniform(size=(n, P))) if with_x else None

    def rays(k):  # beyond n it would add infinities, which must not reach the sum
        return jnp.where(k < n, 1.0 + k.astype(jnp.float64), jnp.inf) * jnp.arange(1.0, P + 1.0)

    def body(acc, k, r, x):
        return acc + (r if x is None else r * x)

    got = _sample_passes(n, rays, body, jnp.zeros(P), xs, block=4)
    k = np.arange(n, dtype=float)[:, None]
    want = ((1.0 + k) * np.arange(1.0, P + 1.0) * (1.0 if xs is None else np.asarray(xs))).sum(0)
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-12)
