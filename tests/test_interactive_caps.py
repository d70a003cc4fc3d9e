"""The interactive shader's cap rule (:mod:`validation.shader_cap_rule`, the NumPy transcription of ``shade.glsl``'s
``jk_caps_xyz``) against the library's cap quadrature :func:`jkatana.light.capquad.cap_integral` of the paper's
lobes (:meth:`Hiraji.brdf_cos`, :meth:`Hamon.brdf_cos`, iron, summed over λ); and the cap kernel table of
non-paper lobes (:mod:`jkatana.interactive.captable`) against the same quadrature of GGX and Beckmann."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.interactive import lobe_tables as LT
from jkatana.interactive import tables as T
from jkatana.interactive.levels import MU_LEVELS
from jkatana.light.capquad import cap_integral
from jkatana.models.lobes import Gaussian
from jkatana.models import Conductor, Hamon, Hiraji
from validation import shader_cap_rule as C

#: sunrise.exr's sun: a 0.31° cap
RADIUS = 0.0055
#: cos θv of the table's grid rows used below (64 rows on [0, 1]): 0°, 44°, 56°, 66° incidence
ROWS = {0: 63, 44: 45, 56: 35, 66: 25}
#: worst error relative to the lobe's value at its mean, per incidence (degrees), for the narrow lobes
#: (μ ≤ 0.071, the sun's glints) and a wide one (μ = 0.141); measured 0.4 / 1.8 / 3.9 / 8.6 % and
#: 1.4 / 5.1 / 13.5 / 49 % (the wide lobe at grazing incidence is skewed and cut by the horizon: two moments
#: do not describe it)
NARROW_TOL = {0: 0.01, 44: 0.03, 56: 0.06, 66: 0.10}
WIDE_TOL = {0: 0.02, 44: 0.07, 56: 0.15, 66: 0.55}


@functools.lru_cache(maxsize=None)
def _tables():
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    iron = Conductor.from_table("Fe-Johnson", dtype=dt)
    _, _, _, spread = T.cached_material_tables(iron, 3, MU_LEVELS)
    return iron, dt, spread


def _errors(cls, level: int, row: int, isotropic: bool = False) -> float:
    """Worst |rule − cap_integral| over caps on the lobe's mean and 0.5–2 widths away along and across the
    plane of incidence, relative to cap_integral on the mean."""
    iron, dt, spread = _tables()
    mu = float(MU_LEVELS[level])
    model = cls(jnp.asarray(1.0, dt), jnp.asarray(mu, dt))
    cv = np.linspace(0.0, 1.0, spread.shape[2])[row]
    V = np.array([np.sqrt(1 - cv * cv), 0.0, cv])
    R = np.array([-V[0], 0.0, cv])
    t = np.array([0.0, 0.0, 1.0]) - cv * R
    t = t / np.linalg.norm(t) if np.linalg.norm(t) > 1e-9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(R, t)
    sp = np.array(spread[int(cls is Hamon), level, row], np.float64)
    if isotropic:
        sp[1] = 0.0
    s0, s1, mean = sp
    mu_e = mu * np.exp(s0)
    w_perp = mu_e * np.sqrt(2 / np.log(2))
    w_par = np.hypot(w_perp, s1)
    offsets = [(0, 0), (0.5, 0), (-0.5, 0), (1, 0), (-1, 0), (0, 1), (1.4, 0), (-1.4, 0), (0, 1.4), (0.7, 0.7),
               (2, 0), (-2, 0)]
    caps = np.array([np.cos(b * w_perp) * (np.cos(mean + a * w_par) * R + np.sin(mean + a * w_par) * t)
                     + np.sin(b * w_perp) * y for a, b in offsets])
    caps = caps[caps[:, 2] > 0.02]                              # above the horizon
    truth = np.asarray(cap_integral(functools.partial(model.brdf_cos, conductor=iron),
                                    jnp.asarray(np.broadcast_to(V, caps.shape), dt), jnp.asarray(caps, dt),
                                    RADIUS, float(Gaussian(mu=jnp.asarray(mu, dt)).reflected_width()), n_radial=8, n_azimuth=32)).sum(-1)
    energy = float(np.sum(np.asarray(LT.lobe_integral(model, iron, jnp.asarray(V, dt)))))
    omega = 4 * np.pi * np.sin(RADIUS / 2) ** 2
    rule = energy * omega * C.cap_response(R, t, sp, mu_e, caps, RADIUS)
    return float(np.max(np.abs(rule - truth)) / truth[0])


@pytest.mark.slow          # ~50 s: 32 cap quadratures of the spectral models
@pytest.mark.parametrize("cls", [Hiraji, Hamon])
def test_cap_rule_against_the_cap_quadrature_of_the_models(cls):
    """Narrow lobes (μ 0.018–0.071, where a sun glints) within 10 % of the peak up to 66° incidence (the
    three-tap rule before: 31–39 % there); a wide lobe (μ 0.141) within 2 % at normal incidence, the
    stated worse bound at grazing incidence."""
    worst = {}
    for deg, row in ROWS.items():
        for level in (1, 3, 5):
            worst[deg, level] = _errors(cls, level, row)
            assert worst[deg, level] < NARROW_TOL[deg], (deg, float(MU_LEVELS[level]), worst)
        worst[deg, 7] = _errors(cls, 7, row)
        assert worst[deg, 7] < WIDE_TOL[deg], (deg, float(MU_LEVELS[7]), worst)


@pytest.mark.slow
def test_cap_rule_for_a_narrow_lobe_at_66_degrees():
    """The everyday check of the sweep above: the hiraji at μ 0.035 and 66° incidence, where the shader's
    earlier rule (three moment-matched taps, each a kernel of the across-plane width) was 34 % off."""
    assert _errors(Hiraji, 3, ROWS[66]) < NARROW_TOL[66]


@pytest.mark.slow
def test_cap_rule_needs_the_in_plane_spread():
    """It can fail: with the lobe's in-plane spread dropped (an isotropic kernel of the across-plane width)
    a narrow lobe at 66° misses the cap quadrature by far more than the bound."""
    assert _errors(Hiraji, 3, ROWS[66], isotropic=True) > 3 * NARROW_TOL[66]


def test_cap_kernel_is_normalised_and_skips_far_caps():
    """K integrates to 1 over the sphere (a point cap, an anisotropic kernel of widths 0.05 and 0.1 rad), and
    is exactly 0 where the cap lies beyond √30 kernel widths (the shader's early out)."""
    n_t, n_p = 2000, 400
    th = (np.arange(n_t) + 0.5) * np.pi / n_t
    ph = (np.arange(n_p) + 0.5) * 2 * np.pi / n_p
    T, P = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    M, tp, ty = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    c_perp = 2 / 0.05 ** 2
    c_par = 2 / 0.1 ** 2
    k = C.kernel(M, tp, ty, c_par, c_perp, d, 0.0)
    total = float(np.sum(k * np.sin(T)) * (np.pi / n_t) * (2 * np.pi / n_p))
    assert abs(total - 1.0) < 2e-3, total
    far = np.array([np.sin(0.9), 0.0, np.cos(0.9)])
    assert float(C.kernel(M, tp, ty, c_par, c_perp, far, 0.0)) == 0.0


@functools.lru_cache(maxsize=None)
def _ggx_beckmann_table():
    """The cap kernel table of GGX (α 0.05, on the first level) and Beckmann (α 0.12, between the last two)
    families at four μ levels, 0.05–0.141."""
    from jkatana.interactive import captable as CT
    from jkatana.models.lobes import lobe_from_params
    from jkatana.models.lobe_id import LobeId

    iron, dt, _ = _tables()
    lobes = tuple(lobe_from_params({"lobe": name, "alpha": a}, dt) for name, a in (("ggx", 0.05), ("beckmann", 0.12)))
    families = tuple(LobeId.shape_of(lobe.to_params())[1] for lobe in lobes)
    mus = MU_LEVELS[4:8]
    return lobes, mus, CT.cap_kernel_table(families, mus, RADIUS, iron)


def _table_errors(region: int, deg: float, moments: bool = False) -> float:
    """Worst |rule − cap_integral| of the lobe of ``region`` (0: GGX α 0.05, 1: Beckmann α 0.12) over caps from
    the mirror direction out to 8 α, along, across and between, relative to the peak of cap_integral: the
    table read as the shader reads it (``captable.table_kernel``), or (``moments``) the closed-form rule of
    the lobe's moments."""
    from jkatana.interactive import captable as CT
    from jkatana.models.lobes import lobe_from_params

    iron, dt, _ = _tables()
    model = lobe_from_params({"lobe": ("ggx", "beckmann")[region], "alpha": (0.05, 0.12)[region]}, dt)
    a = float(model.alpha)
    cv = float(np.cos(np.radians(deg)))
    V, R, t, y = (x[0] for x in CT.table_frame(np.array([cv])))
    offs = a * np.array([(0, 0), (0.5, 0), (-0.5, 0), (1, 0.3), (-1.3, 0.2), (0, 1), (2, 0), (-3, 1), (4, 0),
                         (0, 6), (-8, 0)])
    caps = CT.cap_directions(R, t, y, offs[:, 0], offs[:, 1])
    truth = np.asarray(cap_integral(functools.partial(model.brdf_cos, conductor=iron),
                                    jnp.asarray(np.broadcast_to(V, caps.shape), dt), jnp.asarray(caps, dt), RADIUS,
                                    float(model.reflected_width()), n_radial=8, n_azimuth=32)).sum(-1)
    _, (mean, var_par, var_perp) = LT.lobe_integral(model, iron, jnp.asarray(V[None], dt), moments=True, width=a,
                                                    tails=True)
    energy = float(np.sum(np.asarray(LT.lobe_integral(model, iron, jnp.asarray(V, dt), width=a, tails=True))))
    omega = 4 * np.pi * np.sin(RADIUS / 2) ** 2
    if moments:
        _, (_, g_par, g_perp) = LT.lobe_integral(Gaussian(mu=jnp.asarray(a, dt)), iron,
                                                 jnp.asarray([[0.0, 0.0, 1.0]], dt), moments=True)
        sp = np.array([0.5 * np.log(float(var_perp[0]) / (0.5 * float(g_par[0] + g_perp[0]))),
                       np.sqrt(max(float(var_par[0] - var_perp[0]), 0.0)), float(mean[0])])
        rule = energy * omega * C.cap_response(R, t, sp, a * np.exp(sp[0]), caps, RADIUS)
    else:
        _, mus, table = _ggx_beckmann_table()
        level = float(np.log(a / mus[0]) / np.log(mus[1] / mus[0]))
        rule = energy * omega * CT.table_kernel(table, mus, region, level, cv, offs[:, 0], offs[:, 1])
    return float(np.max(np.abs(rule - truth)) / np.max(truth))


#: worst error of the cap kernel table relative to the lobe's peak (measured 1.6 / 1.8 / 2.1 / 2.8 % for GGX
#: α 0.05 and 1.5 / 1.7 / 2.1 / 2.4 % for Beckmann α 0.12, between two μ levels, at 0 / 35 / 50 / 66°; the
#: moments' Gaussian on GGX at 50°: 85 %)
TABLE_TOL = 0.03


@pytest.mark.slow          # ~1 min on 2 loaded cores: the table of two lobe families at four levels
@pytest.mark.parametrize("deg", [0, 50, 66])
def test_cap_kernel_table_against_the_cap_quadrature_of_ggx_and_beckmann(deg):
    """The table of the cap integrated against a heavy-tailed GGX (at a μ level) and a Beckmann lobe (between
    two levels), read as the shader reads it, within 3 % of the peak out to 8 α."""
    for region in (0, 1):
        assert _table_errors(region, deg) < TABLE_TOL, (region, deg)


@pytest.mark.slow
def test_the_moments_gaussian_misses_ggx_under_a_cap():
    """It can fail: the closed-form rule (one Gaussian with the lobe's moments) on GGX α 0.05 misses the cap
    quadrature by far more than the table's bound (its variance is set by the tails: the peak several times
    too low)."""
    assert _table_errors(0, 50, moments=True) > 10 * TABLE_TOL


def test_cap_kernel_table_reading_and_when_it_is_baked():
    """The paper's lobes keep the closed-form rule (no table); a non-paper family needs one. A table of μ² K̄ = 1
    reads 1/μ² at the pixel's own μ (between levels too) inside the table's reach and 0 beyond it."""
    from jkatana.interactive import captable as CT
    from jkatana.models.lobes import lobe_from_params
    from jkatana.models.lobe_id import LobeId

    assert not CT.needs_table(LT.PAPER_LOBES)
    ggx = LobeId.shape_of(lobe_from_params({"lobe": "ggx", "alpha": 0.05}).to_params())[1]
    assert CT.needs_table((ggx, LT.PAPER_LOBES[1]))
    mus = MU_LEVELS[:3]
    table = np.zeros((2, 3, CT.N_COS, CT.N_V, CT.N_U))          # ln 1
    mu = float(mus[0] * np.sqrt(2.0) ** 1.5)
    inside = np.array([0.0, 3.0, -11.9]) * mu
    got = CT.table_kernel(table, mus, 1, 1.5, 0.7, inside, 0.5 * inside)
    np.testing.assert_allclose(got, 1.0 / mu ** 2, rtol=1e-9)
    far = CT.table_kernel(table, mus, 1, 1.5, 0.7, np.array([12.1 * mu, 0.0]), np.array([0.0, 12.1 * mu]))
    assert np.all(far == 0.0)
