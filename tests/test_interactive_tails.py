"""The tail taps of long-tailed lobes (:func:`jkatana.interactive.taps.tail_fit`): three fitted taps hold GGX's
core but not the light in its tails; the tail taps, up to two further reads at wider levels, put the lobe's energy
back where the lobe has it, and not below the horizon. And the shader's ``JK_TAIL`` path: off (the same program as
before) for the paper's lobes, live reads that keep a constant environment constant where a bake has tails."""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.fit._model import FIT_MODELS
from jkatana.interactive import bake as B
from jkatana.interactive import taps as TP
from jkatana.interactive.lobe_tables import PAPER_LOBES, moment_taps, region_lobes
from jkatana.models import Conductor
from jkatana.models.lobe_id import LobeId
from jkatana.spectral import DEFAULT_GRID

MUS = np.array([0.05, 0.2])                 # the widest level bounds the tail tap's width: 4 μ at μ = 0.05
N_COS = 5                                   # cos θv 0, 0.25, 0.5, 0.75, 1


@pytest.fixture(scope="module")
def iron():
    return Conductor.from_table("Fe-Johnson", DEFAULT_GRID, dtype=jnp.float64)


def _shape_key(model: str, values: dict):
    fm = FIT_MODELS[model]
    return LobeId.shape_of(fm.build(jnp.asarray(fm.shape_from_natural(values))).to_params())[1]


@functools.lru_cache(maxsize=None)
def _fit():
    """GGX (α = μ) in hiraji, the paper's hamon lobe: the three fitted taps (tap_fit) and the tail tap.

    Shared by the three checks of the fit below; the two fits are long, so those checks run with the slow tests."""
    iron = Conductor.from_table("Fe-Johnson", DEFAULT_GRID, dtype=jnp.float64)
    lobes = (region_lobes({"hiraji": _shape_key("ggx", {"scale": 2000.0, "alpha": 0.05})})[0], PAPER_LOBES[1])
    _, start, _, _ = TP.tap_fit(iron, MUS, n_cos=N_COS, lobes=lobes)
    taps, tail, l1 = TP.tail_fit(iron, start, MUS, N_COS, lobes)
    return iron, lobes, start, taps, tail, l1


def _energy_beyond(F, dw, psi, r):
    return float(np.sum((F * dw)[psi > r]))


def _below_horizon(F, dw, ap, aq, cv):
    _, R, t, y = TP.view_frame(np.asarray(cv), xp=np)
    Lz = np.cos(aq) * (np.cos(ap) * R[2] + np.sin(ap) * t[2]) + np.sin(aq) * y[2]
    return float(np.sum((F * dw)[Lz <= 0]))


@pytest.mark.slow
def test_tail_taps_put_ggx_tail_energy_where_the_lobe_has_it():
    """GGX keeps 1/(1 + k²) of its facet mass beyond a half-angle k α: ≥ 10 % of the reflected light lies beyond
    4 μ from R. With the tail taps (at μ = 0.05, where the widest level leaves them room) the fitted kernel holds
    that energy within 0.03 (of 1) at cos θv ≥ 0.5; the same three taps without them miss it by more than 0.05,
    and the 4–6 % beyond 8 μ by more than 0.03, which the tail taps (here with one wider level to choose, 4 μ)
    bring within 60 % of that miss. What the mix reads from below the horizon (where the lobe has nothing) stays
    under 1 % of the light."""
    iron, lobes, _, taps, tail, _ = _fit()
    for k, mu in enumerate(MUS[:1]):
        for c in (2, 3, 4):
            cv = c / (N_COS - 1)
            K, ap, aq, dw, psi = (np.asarray(x) for x in
                                  TP.polar_lobe_kernel(lobes[0](jnp.asarray(mu)), iron, cv, 64, 48, width=mu))
            t = taps[0, k, c]
            F = np.asarray(TP.tail_kernel(jnp.asarray(t), jnp.asarray(tail[0, k, c]), mu, ap, aq, MUS.min(), MUS.max()))
            F0 = np.asarray(TP.tail_kernel(jnp.asarray(t), jnp.zeros((TP.N_TAIL, 3)), mu, ap, aq, MUS.min(),
                                           MUS.max()))
            lobe4 = _energy_beyond(K, dw, psi, 4 * mu)
            assert lobe4 > 0.1, lobe4
            assert abs(_energy_beyond(F, dw, psi, 4 * mu) - lobe4) < 0.03, (mu, cv)
            lobe8 = _energy_beyond(K, dw, psi, 8 * mu)
            assert lobe4 - _energy_beyond(F0, dw, psi, 4 * mu) > 0.05, (mu, cv)
            assert lobe8 - _energy_beyond(F0, dw, psi, 8 * mu) > 0.03, (mu, cv)
            assert abs(_energy_beyond(F, dw, psi, 8 * mu) - lobe8) < 0.6 * (lobe8 - _energy_beyond(F0, dw, psi, 8 * mu))
            assert _below_horizon(K, dw, ap, aq, cv) == 0.0 and _below_horizon(F, dw, ap, aq, cv) < 0.01, (mu, cv)


@pytest.mark.slow          # the tail fit of GTR (γ 1.5) at one μ: one JAX compilation
def test_tail_fit_keeps_a_heavy_tail_above_the_horizon(iron):
    """GTR (γ 1.5, Burley 2012) at μ = 0.05 and the 11 shipped levels: about 8 % of its light lies beyond 12 μ,
    which one tail tap cannot hold with the rest; the fit reads two levels (the wider ≥ 0.28 rad), puts back the
    light beyond 4 μ and brings that beyond 12 μ within 0.02 of the lobe's. The lobe is zero below the horizon;
    the widest level alone, weighted to put back the same light, would read 2–4 % of it from there, the fit less
    than half of that."""
    from jkatana.interactive import tables as T
    from jkatana.interactive.levels import MU_LEVELS
    from jkatana.interactive.lobe_tables import family_core

    family = region_lobes({"hiraji": _shape_key("gtr", {"scale": 2000.0, "alpha": 0.05, "gamma": 1.5})})[0]
    base, c = family_core(family)
    core, _ = TP.core_taps(T.family_tables(iron, MU_LEVELS, 64, base)["taps"], MU_LEVELS, c)
    k = int(np.argmin(np.abs(MU_LEVELS - 0.05)))
    rows = np.asarray(TP._tail_rows(family, jnp.asarray(0.05), iron, jnp.asarray([0.6, 0.8]),
                                    jnp.asarray(core[k, [38, 50]]), jnp.asarray(MU_LEVELS),
                                    jnp.asarray(TP.horizon_clearance(MU_LEVELS)), jnp.asarray(MU_LEVELS[0]),
                                    48, 32))
    for cv, row, t in zip((0.6, 0.8), rows, core[k, [38, 50]]):
        tail = row[:-1].reshape(TP.N_TAIL, 3)
        assert np.all(tail[:, 2] > 0) and 0.05 * np.exp(tail[1, 0]) >= 0.28, tail
        K, ap, aq, dw, psi = (np.asarray(x) for x in TP.polar_lobe_kernel(family(jnp.asarray(0.05)), iron, cv, 64, 48,
                                                                           width=0.05))
        F = np.asarray(TP.tail_kernel(jnp.asarray(t), jnp.asarray(tail), 0.05, ap, aq, MU_LEVELS[0], MU_LEVELS[-1]))
        F1 = np.asarray(TP.tail_kernel(jnp.asarray(t), jnp.zeros((TP.N_TAIL, 3)), 0.05, ap, aq, MU_LEVELS[0],
                                       MU_LEVELS[-1]))
        lobe12 = _energy_beyond(K, dw, psi, 12 * 0.05)
        assert lobe12 > 0.05, lobe12
        assert abs(_energy_beyond(F, dw, psi, 4 * 0.05) - _energy_beyond(K, dw, psi, 4 * 0.05)) < 0.01, cv
        assert abs(_energy_beyond(F, dw, psi, 12 * 0.05) - lobe12) < 0.02, (cv, lobe12)
        assert lobe12 - _energy_beyond(F1, dw, psi, 12 * 0.05) > 0.04
        widest = np.zeros((TP.N_TAIL, 3))
        widest[0] = np.log(MU_LEVELS[-1] / 0.05), tail[0, 1], 1.0
        Fw = np.asarray(TP.tail_kernel(jnp.asarray(t), jnp.asarray(widest), 0.05, ap, aq, MU_LEVELS[0], MU_LEVELS[-1]))
        e3, ew = _energy_beyond(F1, dw, psi, 0.2), _energy_beyond(Fw, dw, psi, 0.2)
        w = (_energy_beyond(K, dw, psi, 0.2) - e3) / (ew - e3)
        assert _below_horizon(K, dw, ap, aq, cv) == 0.0
        assert _below_horizon(F, dw, ap, aq, cv) < 0.5 * w * _below_horizon(Fw, dw, ap, aq, cv), cv
        # each read is turned towards N as far as its width needs: at most TAIL_BELOW of it beneath the horizon
        # (at cos θv 0.6 the widest level read at the far light's mean angle took 12 % of its light from there)
        for s_t, o_t, _ in tail:
            mu_t = 0.05 * np.exp(s_t)
            height = 0.5 * np.pi - np.arccos(cv) + o_t
            got = float(TP.below_fraction(mu_t, height))
            assert got <= TP.TAIL_BELOW + 2e-3, (cv, mu_t, got)
        assert tail[1, 1] > tail[0, 1] or cv > 0.7, tail                 # the wider read turned further


@pytest.mark.parametrize("mu_e", [0.05, 0.2, 0.4])
def test_below_fraction_is_the_kernels_light_from_beneath_a_horizon(mu_e):
    """below_fraction's ring formula against the prefilter kernel summed over a 512 × 1024 sphere grid, its centre at
    elevations 0 (half of it beneath), 0.3 and 0.9 rad above the plane z = 0; horizon_clearance is the elevation
    where that fraction reaches TAIL_BELOW, higher for a wider level."""
    from jkatana.light.envmap import texel_directions_np, texel_solid_angles_np

    D, dw = texel_directions_np(512, 1024), texel_solid_angles_np(512, 1024)
    for h in (0.0, 0.3, 0.9):
        c = np.array([np.cos(h), 0.0, np.sin(h)])
        k = np.asarray(TP.prefilter_kernel(jnp.asarray((1.0 - D @ c) / 2.0), jnp.asarray(mu_e)), np.float64) * dw
        want = k[D[..., 2] < 0].sum() / k.sum()
        got = float(TP.below_fraction(mu_e, h))
        assert abs(got - want) < 2e-3, (mu_e, h, got, want)
    clear = float(TP.horizon_clearance(mu_e))
    assert abs(float(TP.below_fraction(mu_e, clear)) - TP.TAIL_BELOW) < 2e-3
    assert clear > 2.0 * mu_e and float(TP.horizon_clearance(1.4 * mu_e)) > clear


@pytest.mark.parametrize("mu_e", [0.0125, 0.05, 0.4])
def test_kernel_profiles_read_back_the_prefilter_kernel(mu_e):
    """The tail fit reads the levels and the three taps from the prefilter kernel's radial profiles (normalised on
    their own nodes): at 4000 random directions (half of them within 5 μ of the centre, some a hair from the
    horizon, where the kernel drops to zero) they give prefilter_kernel (normalised by its own quadrature) within
    1e-5 of its peak, and zero beyond the horizon."""
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(0.0, 1.0, 2000) ** 4, rng.uniform(0.0, np.sin(5 * mu_e) ** 2, 1990),
                        0.5 - rng.uniform(0.0, 1e-4, 5), 0.5 + rng.uniform(0.0, 1e-4, 5)])
    prof = TP.kernel_profiles(mu_e)
    got = TP.profile_read(prof, x)
    want = np.asarray(TP.prefilter_kernel(jnp.asarray(x), jnp.asarray(mu_e)), np.float64)
    assert np.max(np.abs(got - want)) < 1e-5 * want.max(), mu_e
    assert np.all(got[x > 0.5] == 0.0)


@pytest.mark.slow
def test_tail_fit_weights_and_the_paper_region():
    """The three taps are kept; the tail taps' total weight lies in (0, 0.9] for GGX off grazing where a wider level
    exists and is 0 at the widest level (nothing wider to read); a region holding the paper's lobe has no tail
    (w_t = 0); with the paper's lobes in both regions nothing is fitted."""
    iron, _, start, taps, tail, l1 = _fit()
    np.testing.assert_array_equal(taps, start)
    assert tail.shape == taps.shape[:3] + (TP.N_TAIL, 3)
    total = tail[0, 0, 1:, :, 2].sum(-1)
    assert np.all((total > 0.01) & (total <= 0.9 + 1e-12)) and np.all(tail[..., 2] >= 0), tail[0, 0, :, :, 2]
    np.testing.assert_array_equal(tail[0, 1, :, :, ::2], 0.0)               # w_t = 0 and s_t = 0 there
    assert np.all(np.isfinite(tail)) and np.all(l1[0] > 0)
    np.testing.assert_array_equal(tail[1], 0.0)
    same, none, _ = TP.tail_fit(iron, start, MUS, N_COS, PAPER_LOBES)
    np.testing.assert_array_equal(same, start)
    np.testing.assert_array_equal(none, 0.0)


def _patterns(seed: int = 0):
    """Random tap tables ``(2, n_mu, n_cos, 1 + 2T)`` (offsets, positive weights summing to 1), lobe moments
    ``(…, 3)`` and a tail table whose region 0 holds a tail (w_t > 0 somewhere) and region 1 none."""
    rng = np.random.default_rng(seed)
    T = TP.N_TAPS
    shape = (2, len(MUS), N_COS)
    w = rng.uniform(0.1, 1.0, shape + (T,))
    taps = np.concatenate([rng.normal(0, 0.3, shape + (1,)), rng.normal(0, 0.05, shape + (T,)),
                           w / w.sum(-1, keepdims=True)], -1)
    spread = np.stack([rng.normal(0, 0.3, shape), rng.uniform(0, 0.05, shape), rng.normal(0, 0.02, shape)], -1)
    tail = np.zeros(shape + (TP.N_TAIL, 3))
    tail[0, ..., 0, 0], tail[0, ..., 0, 1], tail[0, ..., 0, 2] = 1.0, 0.1, rng.uniform(0.0, 0.5, shape[1:])
    tail[0, ..., 1, 0], tail[0, ..., 1, 1], tail[0, ..., 1, 2] = 2.0, 0.15, rng.uniform(0.0, 0.3, shape[1:])
    return taps, spread, tail


def test_fitted_moments_keep_a_patterns_first_and_second_moments():
    """moment_taps(fitted_moments(taps)): the binomial pattern with the taps' filter width, weighted mean offset
    and offset variance."""
    taps, _, _ = _patterns(1)
    T = TP.N_TAPS
    m = moment_taps(TP.fitted_moments(taps))
    for p in (taps, m):
        assert np.allclose(p[..., 1 + T:].sum(-1), 1.0)
    mean = lambda p: np.sum(p[..., 1:1 + T] * p[..., 1 + T:], -1)                      # noqa: E731
    var = lambda p: np.sum((p[..., 1:1 + T] - mean(p)[..., None]) ** 2 * p[..., 1 + T:], -1)   # noqa: E731
    np.testing.assert_allclose(mean(m), mean(taps), atol=1e-15)
    np.testing.assert_allclose(var(m), var(taps), rtol=1e-12)
    np.testing.assert_array_equal(m[..., 0], taps[..., 0])


def test_resolved_taps_fall_back_to_the_cores_moments_where_a_tail_is_read():
    """Where the map does not resolve the fitted taps: a region without a tail (the paper's lobe) reads the lobe's
    moment pattern; a region with one (a long-tailed lobe) the moment pattern of its own three taps and keeps its
    tail tap, since the lobe's moments count the tails that the tail tap reads. Where the map resolves them, the
    fitted taps and the tail unchanged."""
    taps, spread, tail = _patterns(2)
    coarse, tail_c = TP.resolved_taps(taps, spread, MUS, 8, tail)            # 8 rows: nothing resolved
    np.testing.assert_array_equal(coarse[1], moment_taps(spread)[1])
    np.testing.assert_array_equal(tail_c[1], 0.0)
    np.testing.assert_array_equal(coarse[0], moment_taps(TP.fitted_moments(taps))[0])
    np.testing.assert_array_equal(tail_c[0], tail[0])
    fine, tail_f = TP.resolved_taps(taps, spread, MUS, 100000, tail)
    np.testing.assert_array_equal(fine, taps)
    np.testing.assert_array_equal(tail_f, tail)
    np.testing.assert_array_equal(TP.resolved_taps(taps, spread, MUS, 8), moment_taps(spread))


@pytest.mark.gl
def test_tail_tap_in_the_shader(glr):
    """The paper's lobes: no tail, the shader's ``JK_TAIL`` 0 and the 8-layer table. One tail tap in the bake: 10
    layers (8, 9: s_t, o_t, w_t), ``JK_TAIL`` 1; two: 12 layers (10, 11: the second), ``JK_TAIL`` 2. Under a
    constant environment each frame is the tail-less one (every read is the same constant and the weights sum to
    1), under the studio it changes (the reads are live), and the second tap changes it again."""
    from jkatana.interactive import scene as S
    from jkatana.interactive.glstate import lut_layers

    sc = S.default_scene("studio", 160, 120)
    rad = np.full((16, 32, DEFAULT_GRID.size), 0.7)
    frames = {}
    for name, env in (("constant", rad), ("studio", S.environment("studio", height=32))):
        paper = B.cached_bake(env, split_sun=False)
        one = np.zeros(paper.taps.shape[:3] + (TP.N_TAIL, 3))
        one[..., 0, :] = 1.0, 0.15, 0.3
        two = one.copy()
        two[..., 1, :] = 2.0, 0.3, 0.2
        states = [glr.ShadingState(b, sc.refl_map) for b in
                  (paper, dataclasses.replace(paper, tail=one), dataclasses.replace(paper, tail=two))]
        assert [st.defines()["JK_TAIL"] for st in states] == [0, 1, 2]
        assert lut_layers(paper, 2).shape[0] == 8
        for b, n in ((states[1].baked, 10), (states[2].baked, 12)):
            layers = lut_layers(b, 2)
            assert layers.shape[0] == n
            for t in range(n // 2 - 4):
                np.testing.assert_array_equal(layers[8 + 2 * t:10 + 2 * t, ..., :3], b.tail[..., t, :])
            np.testing.assert_array_equal(layers[:8], lut_layers(paper, 2))
        frames[name] = [A_frame(glr, st, sc) for st in states]
    a, b, c = frames["constant"]
    assert np.any(a != a[0, 0])
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1 and np.abs(a.astype(int) - c.astype(int)).max() <= 1
    a, b, c = frames["studio"]
    assert np.abs(a.astype(int) - b.astype(int)).max() > 3
    assert np.abs(b.astype(int) - c.astype(int)).max() > 3


def A_frame(glr, st, sc):
    r = glr.BakedOffscreenRenderer(st, sc.view.width, sc.view.height)
    try:
        return r.render(glr.build_scene(sc.mesh, sc.view))
    finally:
        r.delete()


def test_table_keys_read_the_source_of_functions_only():
    """The tap, tail and lobe tables are keyed by the source text of the code that builds them, read on the bake's
    threads. inspect.getsource of a class parses its whole module, which CPython 3.11 cannot do on two threads at
    once (SystemError: AST constructor recursion depth mismatch): the keys name functions only."""
    import inspect

    from jkatana.interactive.lobe_tables import LUT_SOURCES

    for f in (*TP.FIT_SOURCES, *TP.TAIL_SOURCES, *LUT_SOURCES):
        assert inspect.isfunction(inspect.unwrap(f)), f
