"""Every trace-time choice of the shader is a field of Plan, hence of the compile cache key: no stale programs."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.models.lobe_id import LobeId
from jkatana.render import dispatch, shading
from jkatana.render.environment import build_environment
from jkatana.render.fresnel_fold import Material, fresnel_table
from jkatana.render.plan import Pixels, Plan
from jkatana.render.shading import shade
from jkatana.spectral import DEFAULT_GRID

GGX_KEY = LobeId.of({"lobe": "ggx", "alpha": 1.0})
BECKMANN_KEY = LobeId.of({"lobe": "beckmann", "alpha": 1.0})
# a two-lobe mixture (sharp GGX + haze 8× wider, weight 0.9), at unit primary width as LobeId.shape_of gives it
TWO_LOBE_KEY = LobeId.of({"lobe": "mixture", "first": {"lobe": "ggx", "alpha": 1.0},
                          "second": {"lobe": "ggx", "alpha": 8.0}, "weight": 0.9})
# a value different from the default for every field of Plan
ALTERNATIVES = {"mode": "paper", "samples": 8, "hiraji": False, "hamon": False, "mirror": True,
                "env_sampling": False, "env_samples": 2, "env_window": 2.0, "factored": True, "fresnel_rank": 3, "lights": 1, "hiraji_lobe": GGX_KEY,
                "hamon_lobe": BECKMANN_KEY,
                "calibration": 1e5, "spectral": True, "visibility": True, "subpixels": 4,
                "cap_rule": "stroud"}


def test_every_plan_field_has_an_alternative():
    assert set(ALTERNATIVES) == {f.name for f in dataclasses.fields(Plan)}


def test_no_module_level_switch_changes_the_shader():
    """The trace-time switches the shader used to read from module globals are gone (Plan fields or arguments)."""
    for name in ("SEQUENCE", "SUBPIXEL_ORDER", "ENV_DENSITY"):
        assert not hasattr(shading, name), name
    # what is left at module level are constants of the numerics, not switches
    upper = {k for k, v in vars(shading).items() if k.isupper() and not callable(v)}
    assert upper <= {"MIRROR_MU", "FRESNEL_TABLE", "MODES", "LOBE_MODES", "FRESNEL_RANK_TOL", "_RANK_CACHE"}, upper


@pytest.mark.parametrize("field", sorted(ALTERNATIVES))
def test_changing_a_plan_field_gives_another_compiled_program(field):
    base = Plan(mode="reference", samples=4, fresnel_rank=0)
    other = dataclasses.replace(base, **{field: ALTERNATIVES[field]})
    assert other != base
    assert dispatch._compiled(other, 1, 1024)[0] is not dispatch._compiled(base, 1, 1024)[0]
    assert dispatch._compiled(base, 1, 1024)[0] is dispatch._compiled(base, 1, 1024)[0]  # and the same plan hits


def _inputs():
    grid = DEFAULT_GRID
    radiance = np.random.default_rng(0).uniform(0.5, 1.5, (4, 8, grid.size))  # not grey: full spectra
    env, factored, _ = build_environment(radiance, dtype=jnp.float32)
    assert not factored
    n = jnp.full((grid.size,), 2.9, jnp.float32)
    mat = Material(fresnel_table(n, n), jnp.float32(79000.0), jnp.float32(43000.0))
    P = 4
    nrm = jnp.tile(jnp.asarray([[0.0, 0.0, 1.0]], jnp.float32), (P, 1))
    view = jnp.tile(jnp.asarray([[0.3, 0.0, 0.954]], jnp.float32), (P, 1))
    px = Pixels(jnp.zeros((P, 3), jnp.float32), nrm, view, jnp.full((P,), 0.5, jnp.float32),
                jnp.full((P,), 0.05, jnp.float32), jnp.full((P,), 0.1, jnp.float32))
    cmf = jnp.ones((grid.size, 3), jnp.float32) / grid.size
    return mat, env, px, cmf


@pytest.mark.parametrize("field,value", [("mode", "paper"), ("samples", 8), ("hiraji", False), ("hamon", False),
                                         ("mirror", True), ("env_sampling", False), ("hamon_lobe", BECKMANN_KEY),
                                         ("hiraji_lobe", GGX_KEY), ("hiraji_lobe", TWO_LOBE_KEY),
                                         ("calibration", 1e5), ("spectral", True)])
def test_changing_a_plan_field_changes_the_traced_program(field, value):
    """Not only the cache key: the program the shader traces differs (so the field is really a trace-time choice)."""
    mat, env, px, cmf = _inputs()
    key = jax.random.PRNGKey(0)
    base = Plan(mode="reference", samples=4, fresnel_rank=0)
    other = dataclasses.replace(base, **{field: value})

    def program(plan):
        return str(jax.make_jaxpr(lambda m, e, p, c, k: shade(plan, m, e, None, p, c, k))(mat, env, px, cmf, key))

    assert program(other) != program(base)


@pytest.mark.parametrize("a,b", [(LobeId.of({"lobe": "gtr", "alpha": 1.0, "gamma": 1.5}),
                                  LobeId.of({"lobe": "gtr", "alpha": 1.0, "gamma": 1.6})),
                                 (TWO_LOBE_KEY, LobeId.of({"lobe": "mixture", "first": {"lobe": "ggx", "alpha": 1.0},
                                                           "second": {"lobe": "ggx", "alpha": 8.0}, "weight": 0.8}))])
def test_a_lobe_static_parameter_is_part_of_the_compile_key(a, b):
    """A lobe's static parameters (GTR's γ, a two-lobe's weight) select the compiled program like any Plan field."""
    pa, pb = (Plan(mode="reference", samples=4, fresnel_rank=0, hiraji_lobe=k) for k in (a, b))
    assert pa != pb and hash(pa) != hash(pb)
    assert dispatch._compiled(pa, 1, 1024)[0] is not dispatch._compiled(pb, 1, 1024)[0]
    mat, env, px, cmf = _inputs()
    key = jax.random.PRNGKey(0)

    def program(plan):  # the lowered program, constants included
        return jax.jit(lambda m, e, p, c, k: shade(plan, m, e, None, p, c, k)).lower(mat, env, px, cmf, key).as_text()

    assert program(pa) != program(pb)
