"""The render modes are the integrators of one registry: every list of modes and every per-mode property is read
from it, and each registered integrator implements the strategy's two functions."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from jkatana.render.integrators import INTEGRATORS, integrator_for


def test_every_list_of_modes_is_the_registry():
    from jkatana.render.commands import _common
    from jkatana.render.plan import LOBE_MODES, MODES, SAMPLED_MODES
    from jkatana.render.scene import RENDER_MODES

    assert MODES == RENDER_MODES == tuple(INTEGRATORS) == tuple(i.name for i in INTEGRATORS.values())
    assert set(LOBE_MODES) == {m for m, i in INTEGRATORS.items() if i.any_lobe}
    assert SAMPLED_MODES == {m for m, i in INTEGRATORS.items() if i.sampled}
    p = argparse.ArgumentParser()
    _common(p)
    mode = next(a for a in p._actions if a.dest == "mode")
    assert tuple(mode.choices) == MODES
    assert all(i.name in mode.help and i.summary in mode.help for i in INTEGRATORS.values())


def test_the_environments_split_default_agrees_with_the_registry():
    """``environment.SPLIT_MODES`` (the split default's other list) names the integrators that split the sun."""
    from jkatana.render.environment import SPLIT_MODES

    assert set(SPLIT_MODES) == {m for m, i in INTEGRATORS.items() if i.splits_sun}


@pytest.mark.parametrize("mode", list(INTEGRATORS))
def test_each_integrator_implements_the_strategy(mode):
    strategy = integrator_for(mode).strategy()
    assert callable(strategy.radiance) and callable(strategy.directions)
    i = INTEGRATORS[mode]
    assert not (i.deterministic and i.sampled)
    assert not i.deterministic or i.cap_rule  # a deterministic frame may shade its caps on a pass of their own
    assert not (i.whole_map and (i.splits_sun or i.cap_rule))


def test_an_unknown_mode_is_refused_by_name():
    with pytest.raises(ValueError, match="unknown render mode 'mirror'.*reference"):
        integrator_for("mirror")


def test_the_registry_imports_without_jax():
    """The command line lists the modes before JAX is imported (its device count is set first)."""
    code = "import sys, jkatana.render.integrators; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
