"""A lobe's identity (:class:`jkatana.models.lobe_id.LobeId`): the one value a region's lobe travels as from a
parameter file to the shader, the prefilter and the interactive tables."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.models.lobe_id import LobeId
from jkatana.models.lobes import GGX, GTR, Beckmann, Gaussian, GaussianVCavity, Mixture, lobe_from_params

LOBES = {
    "gaussian": Gaussian(jnp.float64(0.05), jnp.float64(2.0), normalised=False),
    "v-cavity": GaussianVCavity(jnp.float64(0.1), normalised=True),
    "beckmann": Beckmann(jnp.float64(0.2)),
    "ggx": GGX(jnp.float64(0.08)),
    "gtr": GTR(jnp.float64(0.1), jnp.float64(1.5)),
    "two-lobe": Mixture(GGX(jnp.float64(0.05)), GGX(jnp.float64(0.4)), jnp.float64(0.8)),
}


def _plain(params: dict) -> dict:
    return {k: _plain(v) if isinstance(v, dict) else (v if isinstance(v, (bool, str)) or v is None else float(v))
            for k, v in params.items()}


def _flat(params: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in _plain(params).items():
        out.update(_flat(v, prefix + k + ".") if isinstance(v, dict) else {prefix + k: v})
    return out


@pytest.mark.parametrize("name", LOBES)
def test_identity_round_trips_and_rebuilds_the_lobe_at_its_width(name):
    params = LOBES[name].to_params()
    ident = LobeId.of(params)
    assert _plain(ident.params()) == _plain(params)
    assert ident == LobeId.of(params) and hash(ident) == hash(LobeId.of(params))  # a static compile-key part
    width, shape = LobeId.shape_of(params)
    assert shape.family == params["lobe"]
    rebuilt, want = _flat(shape.at_width(jnp.float64(width), jnp.float64).to_params()), _flat(params)
    assert rebuilt.keys() == want.keys()
    for k, v in want.items():
        assert rebuilt[k] == (v if isinstance(v, (bool, str)) or v is None else pytest.approx(v, rel=1e-12)), k
    V = jnp.asarray([0.3, 0.0, np.sqrt(1 - 0.09)])
    L = jnp.asarray([-0.25, 0.05, np.sqrt(1 - 0.065)])
    want = lobe_from_params(params, jnp.float64).f_cos(L, V)
    assert float(shape.at_width(jnp.float64(width), jnp.float64).f_cos(L, V)) == pytest.approx(float(want), rel=1e-12)
    assert float(shape(jnp.float64(width)).f_cos(L, V)) == pytest.approx(float(want), rel=1e-12)


def test_per_pixel_widths_give_per_pixel_lobes():
    _, shape = LobeId.shape_of(GTR(jnp.float64(0.1), jnp.float64(1.5)).to_params())
    lobe = shape.at_width(jnp.asarray([0.05, 0.1, 0.2]), jnp.float64)
    assert lobe.alpha.shape == (3,) and lobe.gamma.shape == (3,)
    np.testing.assert_allclose(np.asarray(lobe.gamma), 1.5)


def test_normalised_form_and_the_rendered_lobe():
    calibrated = LobeId.of(Gaussian(jnp.float64(0.05), jnp.float64(2.0), normalised=False).to_params())
    normal = calibrated.normalised()
    assert dict(normal.fields)["normalised"] is True and "scale" not in dict(normal.fields)
    assert calibrated.rendered(None) == normal and calibrated.rendered(1e5) == calibrated


def test_name_is_the_nested_tuple_form_cache_keys_were_made_of():
    assert LobeId.of({"lobe": "ggx", "alpha": 1.0}).name == "('ggx', (('alpha', 1.0),))"


def test_a_lobe_without_width_or_with_a_bad_width_is_refused():
    with pytest.raises(ValueError, match="width must be > 0"):
        LobeId.shape_of({"lobe": "ggx", "alpha": 0.0})
    with pytest.raises(ValueError, match="scalar"):
        LobeId.of({"lobe": "ggx", "alpha": [0.1, 0.2]})
