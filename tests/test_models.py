"""Reflection models: Fresnel, geometry traps, facet distributions, the paper's eqs. (1), (2), (5).

Every reference here is computed independently of jkatana: complex Fresnel
amplitudes in NumPy complex128, quadrature with SciPy, the paper's equations
written out in NumPy.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import integrate

from jkatana.models import (
    Conductor,
    Hamon,
    Hiraji,
    blend,
    facet_angle,
    fresnel_conductor,
    fresnel_dielectric,
    fresnel_schlick,
    gaussian_facet,
    gaussian_normalisation,
    half_vector_cos,
    in_plane,
    in_plane_angles,
    normal_incidence,
    paper_models,
    vcavity,
    vcavity_over_cos,
)

F32, F64 = jnp.float32, jnp.float64
LN2 = math.log(2.0)


@eqx.filter_jit
def _camera(model, L, V, cond, E=None):
    """``model.camera`` jitted once per shape/dtype, shared by the tests (eager JAX is slow)."""
    return model.camera(L, V, cond, E)


@eqx.filter_jit
def _brdf_cos(model, L, V, cond, calibration=None):
    return model.brdf_cos(L, V, cond, calibration)


# ------------------------------------------------------------- Fresnel ---


def fresnel_reference(cos_i, n, k):
    """Born & Wolf amplitudes with Snell's law and a complex cos θt (NumPy complex128)."""
    cos_i = np.asarray(cos_i, np.float64)
    eta = np.asarray(n, np.float64) + 1j * np.asarray(k, np.float64)
    sin2_i = 1.0 - cos_i**2
    cos_t = np.sqrt(1.0 - sin2_i / eta**2 + 0j)  # sin θt = sin θi / η
    with np.errstate(all="ignore"):
        rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
        rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def _grid_cos():
    theta = np.linspace(0.0, 90.0, 181)
    c = np.cos(np.deg2rad(theta))
    c[-1] = 0.0  # exactly 90°
    return c


def test_fresnel_matches_complex_amplitudes_on_grid():
    c = _grid_cos()
    n = np.linspace(0.1, 5.0, 50)
    k = np.linspace(0.0, 10.0, 41)
    C, N, K = np.meshgrid(c, n, k, indexing="ij")
    ref = fresnel_reference(C, N, K)
    ours = np.asarray(fresnel_conductor(jnp.asarray(C), jnp.asarray(N), jnp.asarray(K)))
    # n = 1, k = 0 at exactly 90° is 0/0 in the amplitudes (no interface); ours returns the limit 1
    undefined = (N == 1.0) & (K == 0.0) & (C == 0.0)
    assert np.isnan(ref[undefined]).all() and np.all(ours[undefined] == 1.0)
    np.testing.assert_allclose(ours[~undefined], ref[~undefined], rtol=0, atol=1e-12)


@given(theta=st.one_of(st.just(90.0), st.just(0.0), st.floats(0.0, 90.0)),
       n=st.floats(0.1, 5.0), k=st.one_of(st.just(0.0), st.floats(0.0, 10.0)))
def test_fresnel_matches_complex_amplitudes_hypothesis(theta, n, k):
    c = 0.0 if theta == 90.0 else math.cos(math.radians(theta))
    ref = float(fresnel_reference(c, n, k))
    ours = float(fresnel_conductor(jnp.asarray(c, F64), jnp.asarray(n, F64), jnp.asarray(k, F64)))
    if math.isnan(ref):  # only n = 1, k = 0, θ = 90°
        assert n == 1.0 and k == 0.0 and c == 0.0
        return
    assert abs(ours - ref) <= 1e-12
    assert 0.0 <= ours <= 1.0


def test_fresnel_normal_incidence_formula():
    n = np.linspace(0.1, 5.0, 30)[:, None]
    k = np.linspace(0.0, 10.0, 31)[None, :]
    ours = np.asarray(fresnel_conductor(jnp.ones((30, 31)), jnp.asarray(n), jnp.asarray(k)))
    np.testing.assert_allclose(ours, ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(np.asarray(normal_incidence(n, k)), ours, rtol=1e-13, atol=1e-15)


def dielectric_reference(cos_i, eta):
    """Textbook real Fresnel (Hecht, *Optics*), with total internal reflection for η < 1."""
    sin_t = np.sqrt(1 - cos_i**2) / eta
    if sin_t >= 1.0:
        return 1.0
    cos_t = math.sqrt(1 - sin_t**2)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


@pytest.mark.parametrize("eta", [0.1, 0.5, 0.9, 1.0 + 1e-9, 1.5, 2.4, 5.0])
def test_k_zero_is_dielectric_fresnel(eta):
    for theta in np.linspace(0.0, 89.9, 300):
        c = math.cos(math.radians(theta))
        ref = dielectric_reference(c, eta)
        ours = float(fresnel_dielectric(jnp.asarray(c, F64), jnp.asarray(eta, F64)))
        assert ours == pytest.approx(ref, abs=1e-12), theta
    if eta < 1:  # beyond the critical angle everything is reflected
        crit = math.asin(eta)
        c = jnp.asarray(np.cos(np.linspace(crit + 1e-6, math.pi / 2, 50)))
        np.testing.assert_allclose(np.asarray(fresnel_dielectric(c, jnp.full_like(c, eta))), 1.0, atol=1e-12)


def test_grazing_is_one_and_gradients_finite():
    n = np.linspace(0.1, 5.0, 25)[:, None]
    k = np.array([0.0, 1e-8, 3.0, 10.0])[None, :]
    grad = jax.jit(jax.grad(lambda c, n, k: jnp.sum(fresnel_conductor(c, n, k)), argnums=(0, 1, 2)))
    for dtype in (F32, F64):
        F = jax.jit(fresnel_conductor)(jnp.zeros((), dtype), jnp.asarray(n, dtype), jnp.asarray(k, dtype))
        np.testing.assert_allclose(np.asarray(F), 1.0, atol=1e-6 if dtype == F32 else 1e-14)
        c = jnp.asarray([0.0, 1e-7, 0.3, 1.0], dtype)[:, None, None]
        nn = jnp.asarray([0.1, 0.999, 1.0, 1.001, 5.0], dtype)[None, :, None]
        kk = jnp.asarray([0.0, 1e-6, 10.0], dtype)[None, None, :]
        g = grad(c, nn, kk)
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in g)


def test_schlick_is_exact_at_normal_and_grazing_only():
    iron = Conductor.from_table("Fe-Johnson")
    f0 = normal_incidence(iron.n, iron.k)
    for c in (1.0, 0.0):
        np.testing.assert_allclose(np.asarray(fresnel_schlick(c, f0)), np.asarray(iron.fresnel(jnp.asarray(c))), atol=1e-12)
    c = jnp.asarray(np.cos(np.deg2rad(np.linspace(0, 90, 91))))
    err = jax.jit(lambda c: jnp.abs(fresnel_schlick(c[:, None], f0) - iron.fresnel(c)))(c)
    err = np.asarray(err)
    assert 1e-3 < err.max() < 0.2  # an approximation: measurably off in between


# ---------------------------------------------------- geometry (traps) ---


def _pair_at_facet_angle(phi, theta=0.6, dtype=F32):
    """Float32 L, V in plane with facet angle ≈ φ, and the exact φ of those float32 vectors."""
    L, V = in_plane(np.float64(theta - phi), np.float64(theta + phi))
    L32, V32 = np.asarray(L, np.float32), np.asarray(V, np.float32)
    s = L32.astype(np.float64) + V32.astype(np.float64)
    # float64 reference: asin of |N × s|/|s| (well conditioned for small φ, unlike acos)
    exact = math.asin(math.hypot(s[0], s[1]) / np.linalg.norm(s))
    return jnp.asarray(L32, dtype), jnp.asarray(V32, dtype), exact


def _acos_facet(L, V):
    """The naive form the design forbids: φ = acos(N·normalize(L+V))."""
    h = (L + V) / jnp.linalg.norm(L + V, axis=-1, keepdims=True)
    return jnp.arccos(h[..., 2])


def test_acos_trap_and_atan2_is_exact():
    """acos(N·H) in float32 vs the atan2 form, on the same float32 vectors.

    Measured over θ ∈ [0.05, 1.2] rad: at φ = 1e-4 the naive form is anywhere
    from exactly 0 to 3.5× the true angle; at φ = 1e-3 it is up to ~9 % off
    (quantised by the 6e-8 ulp of N·H below 1). atan2 is within 1.4e-7
    relative everywhere.
    """
    L, V, exact = _pair_at_facet_angle(1e-4)
    assert float(_acos_facet(L, V)) == 0.0  # the trap: exactly 0 in float32
    assert abs(float(facet_angle(L, V)) - exact) <= 1e-6 * exact
    for phi, naive_off in ((1e-4, 1.0), (1e-3, 0.05)):
        worst_naive = worst_atan2 = 0.0
        for theta in np.linspace(0.05, 1.2, 40):
            L, V, exact = _pair_at_facet_angle(phi, theta)
            worst_naive = max(worst_naive, abs(float(_acos_facet(L, V)) / exact - 1.0))
            worst_atan2 = max(worst_atan2, abs(float(facet_angle(L, V)) / exact - 1.0))
        assert worst_naive > naive_off, (phi, worst_naive)
        assert worst_atan2 <= 1e-6, (phi, worst_atan2)
    for phi in (1e-6, 1e-5, 0.01, 0.05, 0.3):
        L, V, exact = _pair_at_facet_angle(phi)
        assert abs(float(facet_angle(L, V)) - exact) <= 1e-6 * exact, phi


def test_facet_angle_derivative_at_specular_is_finite():
    L, V = in_plane(jnp.asarray(0.4, F32), jnp.asarray(0.4, F32))
    # acos has an infinite derivative at 1: the naive form's gradient is not finite
    g_naive = jax.grad(lambda V: _acos_facet(L, V))(V)
    assert not bool(jnp.all(jnp.isfinite(g_naive)))
    cond = Conductor.from_table(dtype=F32)
    for model in paper_models(F32):
        g = jax.jit(jax.grad(lambda V: jnp.sum(model.camera(L, V, cond))))(V)
        assert bool(jnp.all(jnp.isfinite(g)))
    gphi = jax.jit(jax.grad(lambda V: facet_angle(L, V)))(V)
    assert bool(jnp.all(jnp.isfinite(gphi)))


@pytest.mark.parametrize("dtype", [F32, pytest.param(F64, marks=pytest.mark.slow)])
def test_opposite_directions_give_zero_with_finite_gradients(dtype):
    V = jnp.asarray([[0.6, 0.0, 0.8], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8]], dtype)
    L = -V
    L = L.at[0].set(jnp.asarray([-1.0, 0.0, 0.0], dtype))  # first row: both on the horizon, H = 0/0
    V = V.at[0].set(jnp.asarray([1.0, 0.0, 0.0], dtype))
    # an ε in the norm does not cure it: H = 0/ε = 0, cos φ = 0 but φ = atan2(0, 0) is ambiguous
    cos_nh, cos_th, valid = half_vector_cos(L, V)
    assert not bool(jnp.any(valid)) and float(jnp.max(jnp.abs(cos_th))) == 0.0
    cond = Conductor.from_table(dtype=dtype)

    @jax.jit
    def values_and_grads(models, L, V):
        out = []
        for model in models:
            for method in ("camera", "brdf_cos"):
                f = lambda m, L, V: jnp.sum(getattr(m, method)(L, V, cond))  # noqa: E731
                out.append((f(model, L, V), jax.grad(f, argnums=(0, 1, 2))(model, L, V)))
        return out

    for value, grads in values_and_grads(paper_models(dtype), L, V):
        assert float(value) == 0.0
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(grads))


@pytest.mark.parametrize("dtype", [F32, F64])
def test_grazing_view_limit_of_eq2(dtype):
    """N·V = 0 exactly: G/cosθr is finite and equals its limit 2 N·H / V·H."""
    theta_i = 0.7
    L = jnp.asarray([-math.sin(theta_i), 0.0, math.cos(theta_i)], dtype)
    V = jnp.asarray([1.0, 0.0, 0.0], dtype)  # grazing view
    s = np.asarray(L, np.float64) + np.asarray(V, np.float64)
    cos_nh = s[2] / np.linalg.norm(s)
    cos_vh = np.linalg.norm(s) / 2
    limit = 2 * cos_nh / cos_vh
    rtol = 1e-6 if dtype == F32 else 1e-13
    got = float(vcavity_over_cos(jnp.asarray(cos_nh, dtype), jnp.asarray(0.0, dtype),
                                 jnp.asarray(math.cos(theta_i), dtype), jnp.asarray(cos_vh, dtype)))
    assert got == pytest.approx(limit, rel=rtol)
    # continuity: approaching the horizon converges to the limit (1/N·V branch never wins)
    for nv in (1e-3, 1e-5, 1e-7):
        g = float(vcavity(cos_nh, nv, math.cos(theta_i), cos_vh)) / nv
        assert g == pytest.approx(limit, rel=1e-9)
    # naive eq. (2): G / N·V = 0 / 0 → NaN without a guard
    with np.errstate(all="ignore"):
        naive = min(1.0, 2 * cos_nh * 0.0 / cos_vh, 2 * cos_nh * math.cos(theta_i) / cos_vh) / np.float64(0.0)
    assert math.isnan(naive)
    # the model at grazing view: β F(θH) D(φ) · 2 N·H / V·H, with finite gradients
    cond = Conductor.from_table(dtype=dtype)
    hamon = Hamon(jnp.asarray(43000.0, dtype), jnp.asarray(1.0, dtype))
    phi = math.atan2(math.hypot(s[0], s[1]), s[2])
    F = Conductor.from_table(dtype=F64).fresnel(jnp.asarray(cos_vh, F64))  # float64 reference
    expected = 43000.0 * math.exp(-LN2 * phi**2) * limit * np.asarray(F, np.float64)
    np.testing.assert_allclose(np.asarray(_camera(hamon, L, V, cond)), expected, rtol=10 * rtol)
    g = jax.jit(jax.grad(lambda m, L, V: jnp.sum(m.camera(L, V, cond)), argnums=(0, 1, 2)))(hamon, L, V)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(g))


def test_in_plane_geometry():
    L, V = in_plane(jnp.asarray(0.3), jnp.asarray(0.3))
    assert float(facet_angle(L, V)) == pytest.approx(0.0, abs=1e-15)
    L, V = in_plane(jnp.asarray(0.3), jnp.asarray(0.5))
    phi, th = in_plane_angles(0.3, 0.5)
    assert float(facet_angle(L, V)) == pytest.approx(phi, rel=1e-12)
    assert float(half_vector_cos(L, V)[1]) == pytest.approx(math.cos(th), rel=1e-12)


# ------------------------------------------------- facet distributions ---


def test_gaussian_facet_peak_and_half_width():
    for mu in (1e-6, 0.05, 1.0):
        assert float(gaussian_facet(0.0, mu)) == 1.0
        assert float(gaussian_facet(mu, mu)) == pytest.approx(0.5, rel=1e-14)
        assert float(gaussian_facet(-mu, mu)) == pytest.approx(0.5, rel=1e-14)
    assert float(gaussian_facet(1.0, 1e-6)) == 0.0  # underflow handled, no inf/NaN
    g = jax.grad(lambda p, m: gaussian_facet(p, m), argnums=(0, 1))(jnp.asarray(1.0), jnp.asarray(1e-9))
    assert all(math.isfinite(float(x)) for x in g)


@pytest.mark.parametrize("mu", [0.005, 0.01, 0.05, 0.1, 0.3, 0.5])
def test_gaussian_normalisation_matches_quadrature(mu):
    integrand = lambda p: math.exp(-LN2 * (p / mu) ** 2) * math.cos(p) * math.sin(p)  # noqa: E731
    val, abserr = integrate.quad(integrand, 0.0, math.pi / 2, points=[mu, 3 * mu], limit=200, epsabs=0, epsrel=1e-13)
    expected = 1.0 / (2 * math.pi * val)
    assert float(gaussian_normalisation(mu)) == pytest.approx(expected, rel=1e-10)
    # float32 path
    assert float(gaussian_normalisation(jnp.asarray(mu, F32))) == pytest.approx(expected, rel=1e-5)


def test_gaussian_normalisation_small_mu_limit_and_gradient():
    for mu in (1e-3, 1e-5):
        assert float(gaussian_normalisation(mu)) == pytest.approx(LN2 / (math.pi * mu**2), rel=1e-5)
    g = jax.grad(gaussian_normalisation)(jnp.asarray(1e-6, F32))
    assert math.isfinite(float(g))


# ------------------------------------------------------ rendering lobe ---


def _hemisphere_integral_around_mirror(f, V, width, n_alpha=96, n_beta=128):
    """∫ f(ω_i) dω_i in polar coordinates (α, β) centred on the mirror direction of V.

    Gauss–Legendre in α ∈ [0, width] and the trapezoid (spectral for a periodic
    integrand) in β. Directions below the horizon are evaluated too (the models
    return 0 there). Independent of the half-vector Jacobian used by the model.
    """
    R = np.array([-V[0], -V[1], V[2]])
    t1 = np.cross(R, [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(R, t1)
    x, w = np.polynomial.legendre.leggauss(n_alpha)
    alpha = 0.5 * width * (x + 1.0)
    wa = 0.5 * width * w
    beta = np.linspace(0.0, 2 * np.pi, n_beta, endpoint=False)
    A, B = np.meshgrid(alpha, beta, indexing="ij")
    dirs = (np.cos(A)[..., None] * R + np.sin(A)[..., None] * (np.cos(B)[..., None] * t1 + np.sin(B)[..., None] * t2))
    vals = np.asarray(f(jnp.asarray(dirs), jnp.broadcast_to(jnp.asarray(V), dirs.shape)))
    weights = np.broadcast_to((wa * np.sin(alpha))[:, None] * (2 * np.pi / n_beta), A.shape)
    return np.tensordot(weights, vals, axes=([0, 1], [0, 1]))


@pytest.mark.parametrize("model_cls", [Hiraji, Hamon])
@pytest.mark.parametrize("theta_r", [0.0, 0.5, 1.0])
def test_normalised_lobe_tends_to_mirror_of_reflectance_F(model_cls, theta_r):
    cond = Conductor.from_table()
    V = np.array([math.sin(theta_r), 0.0, math.cos(theta_r)])
    F = np.asarray(cond.fresnel(jnp.asarray(math.cos(theta_r))))
    for mu, tol in ((0.01, 0.01), (0.002, 0.002)):
        model = model_cls(jnp.asarray(1.0), jnp.asarray(mu))
        total = _hemisphere_integral_around_mirror(lambda L, V: _brdf_cos(model, L, V, cond), V, width=16 * mu)
        np.testing.assert_allclose(total, F, rtol=tol)


def test_calibrated_brdf_is_camera_over_K_E():
    cond = Conductor.from_table()
    E = jnp.asarray(np.linspace(50.0, 150.0, 61))
    L, V = in_plane(jnp.asarray([0.3, 0.5]), jnp.asarray([0.32, 0.55]))
    for model in paper_models():
        K = 2.5e5
        np.testing.assert_allclose(np.asarray(_brdf_cos(model, L, V, cond, K)),
                                   np.asarray(_camera(model, L, V, cond, E) / (K * E)), rtol=1e-13)


# --------------------------------------------- the paper's equations ---


def _iron_np():
    c = Conductor.from_table()
    return np.asarray(c.n), np.asarray(c.k)


def test_hiraji_and_hamon_equal_the_printed_equations():
    """Eqs. (1) and (2) written out in NumPy from angles, against the models from vectors."""
    n, k = _iron_np()
    cond = Conductor.from_table()
    E = np.linspace(80.0, 120.0, 61)
    ti = np.deg2rad(np.array([15.0, 35.0, 35.0, 65.0, 45.0]))
    tr = np.deg2rad(np.array([15.0, 37.0, 30.0, 70.0, 80.0]))
    L, V = in_plane(jnp.asarray(ti), jnp.asarray(tr))
    phi = (tr - ti) / 2
    th = (ti + tr) / 2
    chi, mu0, beta, mu1 = 79000.0, 0.05, 43000.0, 0.07
    D0 = np.exp(-LN2 * phi**2 / mu0**2)
    D1 = np.exp(-LN2 * phi**2 / mu1**2)
    eq1 = chi * D0[:, None] * fresnel_reference(np.cos(ti)[:, None], n, k) * E
    nh, nv, nl, vh = np.cos(phi), np.cos(tr), np.cos(ti), np.cos(th)
    G = np.minimum(1.0, np.minimum(2 * nh * nv / vh, 2 * nh * nl / vh))
    eq2 = beta * fresnel_reference(np.cos(th)[:, None], n, k) * (D1 * G / np.cos(tr))[:, None] * E
    np.testing.assert_allclose(np.asarray(_camera(Hiraji(chi, mu0), L, V, cond, jnp.asarray(E))), eq1, rtol=1e-11)
    np.testing.assert_allclose(np.asarray(_camera(Hamon(beta, mu1), L, V, cond, jnp.asarray(E))), eq2, rtol=1e-11)
    np.testing.assert_allclose(np.asarray(vcavity(nh, nv, nl, vh)), G, rtol=1e-13)


def test_blend_eq5():
    cf = jnp.asarray(np.random.default_rng(0).uniform(size=(4, 61)))
    ct = jnp.asarray(np.random.default_rng(1).uniform(size=(4, 61)))
    w = jnp.asarray([1.0, 0.0, 0.25, 0.5])
    out = np.asarray(blend(w, cf, ct))
    np.testing.assert_array_equal(out[0], np.asarray(cf[0]))
    np.testing.assert_array_equal(out[1], np.asarray(ct[1]))
    np.testing.assert_allclose(out[2], 0.25 * np.asarray(cf[2]) + 0.75 * np.asarray(ct[2]), rtol=1e-15)


def test_models_vectorise_over_batch_and_params():
    cond = Conductor.from_table()
    L, V = in_plane(jnp.zeros((3, 1)) + 0.5, jnp.linspace(0.4, 0.6, 5)[None, :])
    out = _camera(Hiraji(jnp.full((3, 5), 79000.0), jnp.full((3, 5), 0.05)), L, V, cond)
    assert out.shape == (3, 5, 61)
    out32 = _camera(paper_models(F32)[1], L.astype(F32), V.astype(F32), Conductor.from_table(dtype=F32))
    assert out32.dtype == F32


# ----------------------------------------------------- Fig. 9 shape ---


@pytest.mark.parametrize("theta_i_deg", [15, 25, 35, 45, 55, 65])
def test_fig9_shape(theta_i_deg):
    """Paper's parameters, iron (Johnson & Christy), 550 nm: peak and half width of the lobe.

    Hiraji (eq. 1): F(θi) is constant along the scan, so the peak is exactly at
    the specular angle and the half maximum exactly where the in-plane facet
    angle is ±μ0. Hamon (eq. 2): the 1/cos θr factor tilts the lobe, moving
    the peak to φ ≈ μ² tan θr / ln 2 (first order; 0.06° at 15°, 0.45° at
    65° in θr) and widening the half width by ≤ 3 % up to 65°.
    """
    mu = 0.05
    cond = Conductor.from_table()
    ti = math.radians(theta_i_deg)
    phi = np.linspace(-6 * mu, 6 * mu, 24001)  # step 2.5e-5 rad in φ
    L, V = in_plane(jnp.full(phi.shape, ti), jnp.asarray(ti + 2 * phi))
    step = phi[1] - phi[0]
    for model in paper_models():
        c = np.asarray(_camera(model, L, V, cond))[:, 30]  # 550 nm
        i = int(np.argmax(c))
        half = c[i] / 2
        lo = np.where(c >= half)[0][0]
        hi = np.where(c >= half)[0][-1]
        phi_lo = np.interp(half, [c[lo - 1], c[lo]], [phi[lo - 1], phi[lo]])
        phi_hi = np.interp(half, [c[hi + 1], c[hi]], [phi[hi + 1], phi[hi]])
        hwhm = 0.5 * (phi_hi - phi_lo)
        if isinstance(model, Hiraji):
            assert abs(phi[i]) <= step / 2
            assert phi_lo == pytest.approx(-mu, rel=1e-4) and phi_hi == pytest.approx(mu, rel=1e-4)
            assert c[i] == pytest.approx(79000.0 * float(cond.fresnel(jnp.asarray(math.cos(ti)))[30]), rel=1e-6)
        else:
            tilt = mu**2 * math.tan(ti + 2 * phi[i]) / LN2
            assert abs(phi[i] - tilt) <= 0.05 * tilt + step
            assert hwhm == pytest.approx(mu, rel=0.03)


def test_fig9_script_writes_png(tmp_path):
    """experiments/fig9_paper_curves.py runs end to end into a temporary folder (coarse angles)."""
    import importlib.util
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "experiments" / "fig9_paper_curves.py"
    spec = importlib.util.spec_from_file_location("fig9_paper_curves", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    path = module.main(["--out", str(tmp_path), "--angles", "181"])
    assert path == tmp_path / "fig9_paper_curves.png"
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    theta_r, result = module.curves(n_angles=181)  # peaks at the specular angle (0.5° grid)
    for ti in module.INCIDENCES_DEG:
        assert theta_r[np.argmax(result[ti]["hiraji"]["green"])] == pytest.approx(ti, abs=0.25)
