"""The cap × lobe quadrature (:mod:`jkatana.light.capquad`) against dense quadratures."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.light import sky as S
from jkatana.light.capquad import (
    cap_coverage,
    cap_disc_nodes,
    cap_integral,
    cap_point_integral,
    reflected_cap_radiance,
)
from jkatana.light.sampling import frame_from_normal, to_world
from jkatana.light.sun import split_sky_sun
from jkatana.models import Conductor, Hiraji
from jkatana.models.lobes import Gaussian
from jkatana.spectral.grid import WavelengthGrid

GRID = WavelengthGrid(400.0, 700.0, 10.0)
SUN_R = S.SOLAR_RADIUS  # 0.00445 rad


def sigma(mu):
    """The cap rule's width of the paper's lobe of facet width ``mu``."""
    return Gaussian(jnp.asarray(mu), jnp.asarray(1.0), normalised=False).reflected_width()


COND = Conductor.from_table("Fe-Johnson", grid=WavelengthGrid(400.0, 700.0, 150.0))


def dense_cap(brdf, V, C, r, n_r=160, n_a=320):
    """Brute-force ∫_cap over polar coordinates about the cap centre (GL × midpoint)."""
    x, w = np.polynomial.legendre.leggauss(n_r)
    a = 0.5 * r * (x + 1)
    wa = 0.5 * r * w * np.sin(a)
    az = (np.arange(n_a) + 0.5) / n_a * 2 * np.pi
    loc = np.stack(np.broadcast_arrays(np.sin(a)[:, None] * np.cos(az)[None], np.sin(a)[:, None] * np.sin(az)[None],
                                       np.cos(a)[:, None]), -1)
    L = to_world(frame_from_normal(jnp.asarray(C)), jnp.asarray(loc))
    f = brdf(L, jnp.broadcast_to(jnp.asarray(V), L.shape))
    return np.einsum("r,rl->l", wa * 2 * np.pi / n_a, np.asarray(f).sum(1))


def rotate(v, axis, ang):
    axis = axis / np.linalg.norm(axis)
    return v * math.cos(ang) + np.cross(axis, v) * math.sin(ang) + axis * (axis @ v) * (1 - math.cos(ang))


def lobe(mu):
    h = Hiraji(chi=jnp.asarray(1.0), mu=jnp.asarray(mu))
    return lambda L, V: h.brdf_cos(L, V, COND)


@pytest.mark.parametrize("theta", [0.0, 0.6, 1.2])
@pytest.mark.parametrize("mu", [0.001, 0.003, 0.01, 0.03, 0.1, 0.3])
@pytest.mark.slow
def test_cap_rule_error_vs_dense(mu, theta):
    """Error of the default rule (4 × 16) against a dense quadrature, relative to the value with
    the cap centred on the mirror direction, for the sun's cap (0.255°): ≤ 2e-2 where the cap's
    edge crosses a lobe narrower than the cap (an antialiasing error along the glint's outline),
    ≤ 1e-3 everywhere else."""
    V = np.array([math.sin(theta), 0.0, math.cos(theta)])
    R = V * np.array([-1.0, -1.0, 1.0])
    f = lobe(mu)
    sig = float(sigma(mu))
    on = np.abs(dense_cap(f, V, R, SUN_R)).max()
    for dd in (0.0, 0.5, 0.97, 1.03, 1.5, 3.0):
        for axis in (np.array([0.0, 1.0, 0.0]), np.array([R[2], 0.0, -R[0]])):
            C = rotate(R, np.cross(R, axis), dd * SUN_R)
            ref = dense_cap(f, V, C, SUN_R)
            got = np.asarray(cap_integral(f, jnp.asarray(V), jnp.asarray(C), SUN_R, sig, n_radial=4, n_azimuth=16))
            edge = abs(dd - 1.0) < 0.1 and sig < SUN_R * 2
            assert np.abs(got - ref).max() / on <= (2e-2 if edge else 1e-3), (dd, axis)


@pytest.mark.slow
def test_mirror_limit():
    """μ → 0: the cap contributes F(θ)·[R inside the cap], ½ F on its edge."""
    mu = 1e-5
    f = lobe(mu)
    sig = float(sigma(mu))
    for theta in (0.0, 0.7):
        V = np.array([math.sin(theta), 0.0, math.cos(theta)])
        R = V * np.array([-1.0, -1.0, 1.0])
        F = np.asarray(COND.fresnel(jnp.asarray(math.cos(theta))))
        axis = np.cross(R, np.array([0.0, 1.0, 0.0]))
        val = lambda dd: np.asarray(cap_integral(f, jnp.asarray(V), jnp.asarray(rotate(R, axis, dd * SUN_R)),
                                                 SUN_R, sig))
        np.testing.assert_allclose(val(0.6), F, rtol=1e-3)
        np.testing.assert_allclose(val(1.0), 0.5 * F, rtol=2e-2)
        assert np.abs(val(1.4)).max() < 1e-6


def test_cap_coverage_antialiases_the_edge():
    R = jnp.asarray([0.0, 0.0, 1.0])
    width = 0.1 * SUN_R
    cov = lambda dd: float(cap_coverage(R, jnp.asarray(rotate(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0, 0]),
                                                                   dd * SUN_R)), SUN_R, width))
    assert cov(0.0) == pytest.approx(1.0, abs=1e-6)
    assert cov(0.5) == pytest.approx(1.0, abs=1e-6)
    assert cov(1.0) == pytest.approx(0.5, abs=0.03)
    # one footprint-σ inside/outside the edge: the Gaussian's mass beyond a straight edge (Φ(±1))
    assert cov(1.1) == pytest.approx(0.1587, abs=0.02)
    assert cov(0.9) == pytest.approx(0.8413, abs=0.02)
    assert cov(2.0) == pytest.approx(0.0, abs=1e-9)


def test_cap_rule_jit_float32_and_finite_gradients():
    mu = 0.02
    h = Hiraji(chi=jnp.asarray(1.0, jnp.float32), mu=jnp.asarray(mu, jnp.float32))
    cond32 = Conductor(COND.n.astype(jnp.float32), COND.k.astype(jnp.float32))
    V = np.array([math.sin(0.5), 0.0, math.cos(0.5)])
    R = V * np.array([-1.0, -1.0, 1.0])
    # (not exactly on the edge, where float32 and float64 may take different branches of the rule)
    Cs = np.stack([rotate(R, np.array([0.0, 1.0, 0.0]), dd * SUN_R) for dd in (0.0, 0.5, 0.98, 2.0)])
    f32 = jax.jit(lambda V, C, s: cap_integral(lambda L, V_: h.brdf_cos(L, V_, cond32), V, C, SUN_R, s))
    got = np.asarray(f32(jnp.asarray(np.broadcast_to(V, Cs.shape), jnp.float32), jnp.asarray(Cs, jnp.float32),
                         jnp.float32(sigma(mu))))
    assert got.dtype == np.float32 and got.shape == (4, COND.n.shape[-1])
    ref = np.stack([np.asarray(cap_integral(lobe(mu), jnp.asarray(V), jnp.asarray(C), SUN_R, sigma(mu)))
                    for C in Cs])
    np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6 * np.abs(ref).max())
    # gradients in the lobe width and the cap direction: finite, also at C = R and on the edge
    g = jax.jit(jax.grad(lambda s, C: jnp.sum(cap_integral(lobe(mu), jnp.asarray(V), C, SUN_R, s)), argnums=(0, 1)))
    for C in list(Cs) + [rotate(R, np.array([0.0, 1.0, 0.0]), SUN_R), R]:
        gs, gc = g(jnp.asarray(sigma(mu)), jnp.asarray(C))
        assert np.isfinite(float(gs)) and np.all(np.isfinite(np.asarray(gc)))


@pytest.mark.slow
def test_reflected_cap_radiance_matches_cap_integral_in_world_frame():
    mu = 0.01
    cap = split_sky_sun(40.0, 90.0, 3.0, 0.1, (32, 64), GRID)[1].cap
    n = np.array([0.3, 0.9, -0.2])
    n = n / np.linalg.norm(n)
    frame = frame_from_normal(jnp.asarray(n))
    s = np.asarray(cap.direction, np.float64)
    V_world = 2 * (s @ n) * n - s  # looking at the sun's mirror image
    V_local = np.asarray(frame) @ V_world
    cond = Conductor.from_table("Fe-Johnson", grid=GRID)
    h = Hiraji(chi=jnp.asarray(1.0), mu=jnp.asarray(mu))
    f = lambda L, V: h.brdf_cos(L, V, cond)
    got = np.asarray(reflected_cap_radiance(cap, f, jnp.asarray(V_local), frame, sigma(mu)))
    ref = np.asarray(cap.radiance) * dense_cap(f, V_local, np.asarray(frame) @ s, float(cap.radius))
    np.testing.assert_allclose(got, ref, rtol=1e-3, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("mu", [0.03, 0.1, 0.3])
def test_point_light_limit_for_wide_lobes(mu):
    """σ ≫ r: the cap as a point light is within ½ (r/σ)² of the rule (relative to the on-centre value)."""
    f = lobe(mu)
    sig = float(sigma(mu))
    V = np.array([math.sin(0.6), 0.0, math.cos(0.6)])
    R = V * np.array([-1.0, -1.0, 1.0])
    on = np.abs(np.asarray(cap_integral(f, jnp.asarray(V), jnp.asarray(R), SUN_R, sig))).max()
    for off in (0.0, 0.5, 1.0, 2.0):
        C = rotate(R, np.array([0.0, 1.0, 0.0]), off * sig)
        rule = np.asarray(cap_integral(f, jnp.asarray(V), jnp.asarray(C), SUN_R, sig))
        point = np.asarray(cap_point_integral(f, jnp.asarray(V), jnp.asarray(C), SUN_R))
        assert np.abs(point - rule).max() / on <= 0.5 * (SUN_R / sig) ** 2, off


@pytest.mark.parametrize("theta", [0.0, 0.6, 1.22])
@pytest.mark.parametrize("ratio", [8.0, 20.0])
def test_stroud_rule_for_lobes_wider_than_eight_cap_radii(ratio, theta):
    """The 4 fixed directions of ``cap_disc_nodes`` (Stroud 1971, degree 3) against the dense quadrature
    for a lobe ``ratio`` cap radii wide at incidence up to 70°: within 1e-3 of the on-centre value, for
    the cap anywhere from the lobe's centre to 3σ off it."""
    r = math.radians(1.0)
    sig = ratio * r
    mu = sig / float(sigma(1.0))
    f = lobe(mu)
    V = np.array([math.sin(theta), 0.0, math.cos(theta)])
    R = V * np.array([-1.0, -1.0, 1.0])
    on = np.abs(dense_cap(f, V, R, r, 48, 96)).max()
    for off in (0.0, 0.3, 1.0, 2.0, 3.0):
        for axis in (np.array([0.0, 1.0, 0.0]), np.array([R[2], 0.0, -R[0]])):
            C = rotate(R, axis, off * sig * (math.cos(theta) if axis[1] == 0 else 1.0))
            if C[2] < 0.05:
                continue
            ref = dense_cap(f, V, C, r, 48, 96)
            L, w = cap_disc_nodes(jnp.asarray(C), r)
            got = np.einsum("n,nl->l", np.asarray(w), np.asarray(f(L, jnp.broadcast_to(jnp.asarray(V), L.shape))))
            assert np.abs(got - ref).max() / on <= 1e-3, (off, axis)
    L, w = cap_disc_nodes(jnp.asarray(R), r)
    np.testing.assert_allclose(np.asarray(L) @ R, math.cos(r / math.sqrt(2.0)), rtol=1e-12)
    assert float(np.sum(w)) == pytest.approx(2 * math.pi * (1 - math.cos(r)), rel=1e-12)
