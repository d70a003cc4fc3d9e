"""Hard cases of the reflection models, property-based (hypothesis).

Every model (Hiraji, Hamon; ``camera`` and ``brdf_cos``) and Beckmann/Smith is
evaluated on directions drawn over the whole hemisphere including exactly
0° and 90°, L = V, L = −V (H of zero length), μ from 1e-6 to 1, n in
[0.1, 5], k in [0, 10] (k = 0 exactly too), at the paper's scales
χ = 79000, β = 43000, in float32:

- every value is finite and ≥ 0;
- every gradient (w.r.t. χ/β, μ, n, k, L and V) is finite;
- float32 agrees with float64 evaluated on the *same* inputs (the float32
  directions and parameters, upcast exactly), to the tolerance stated in
  :func:`_f32_tolerance`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from jkatana.models import Conductor, Hamon, Hiraji, beckmann, beckmann_phi, half_vector_cos, half_vector_terms, smith_beckmann

F32, F64 = jnp.float32, jnp.float64
EPS32 = float(np.finfo(np.float32).eps)

angles = st.one_of(st.sampled_from([0.0, math.pi / 2, math.pi / 4, 1e-4]),
                   st.floats(0.0, math.pi / 2, allow_nan=False))
azimuths = st.one_of(st.sampled_from([0.0, math.pi]), st.floats(0.0, 2 * math.pi, allow_nan=False))
mus = st.one_of(st.sampled_from([1e-6, 1e-3, 0.05, 1.0]),
                st.floats(math.log(1e-6), 0.0).map(math.exp))
ns = st.one_of(st.sampled_from([0.1, 1.0, 5.0]), st.floats(0.1, 5.0))
ks = st.one_of(st.sampled_from([0.0, 10.0]), st.floats(0.0, 10.0))
modes = st.sampled_from(["free", "free", "free", "L=V", "L=-V", "mirror", "near-mirror", "offplane-mirror"])


def _direction(theta: float, az: float) -> np.ndarray:
    """Unit vector at polar angle θ, azimuth az; z exactly 0 at θ = 90°, exactly 1 at 0°."""
    z = 0.0 if theta == math.pi / 2 else math.cos(theta)
    s = 1.0 if theta == math.pi / 2 else math.sin(theta)
    return np.array([s * math.cos(az), s * math.sin(az), z])


def _geometry(mode, ti, tr, ai, ar):
    L = _direction(ti, ai)
    if mode == "L=V":
        V = L.copy()
    elif mode == "L=-V":
        V = -L
    elif mode == "mirror":
        V = np.array([-L[0], -L[1], L[2]])
    elif mode == "offplane-mirror":  # the mirror direction, L moved 1e-16 out of the plane of incidence
        V = np.array([-L[0], -L[1], L[2]])
        L = L + np.array([0.0, 1e-16, 0.0])
    elif mode == "near-mirror":  # within a few μ of the specular direction
        V = np.array([-L[0], -L[1], L[2]])
        V = _direction(min(math.acos(np.clip(V[2], -1, 1)) + 1e-3 * (tr - 0.7), math.pi / 2),
                       math.atan2(V[1], V[0]))
    else:
        V = _direction(tr, ar)
    return L, V


def _f32_tolerance(v64, s64, phi64, mu, dF=0.0):
    """Allowed |float32 − float64| for a model value.

    ``s64`` is the same model with a perfect conductor (F = 1, float64): the
    geometric part. Two error sources in float32:

    - the Fresnel term: absolute error ≤ 2e-6 in F (it loses relative accuracy
      where F → 0, e.g. n → 1, k = 0), plus ``dF`` (:func:`_fresnel_condition`: what
      float32 rounding of the cosine does to F where F is ill-conditioned), hence
      ``(2e-6 + dF) · s64``;
    - the facet term exp(−ln2 φ²/μ²): relative error ≈ 2 ln2 (φ/μ)² · δφ/φ with
      δφ/φ a few float32 ulps, hence ``1e-5 · (1 + 2 ln2 (φ/μ)²) · v64``.
    """
    cond = 1.0 + 2.0 * math.log(2.0) * (phi64 / mu) ** 2
    return (2e-6 + dF) * s64 + 1e-5 * cond * v64 + 1e-30


def _fresnel_condition(cosines, n, k):
    """Largest float64 change of F, per wavelength, when a cosine the models evaluate F at (cos θi for the
    hiraji, cos θd for the hamon) moves by 4 float32 ulps — its rounding in a float32 evaluation. Below
    2e-6 almost everywhere; large only where F is ill-conditioned: k = 0 with n < 1, where F has an
    infinite slope at the critical angle cos θc = √(1 − n²) (hypothesis found n = 0.1, θi = 0.1 rad,
    0.2 mrad from θc: float32 off by 6e-5 relative, the conditioning, not the arithmetic)."""
    cond = Conductor(jnp.asarray([n, 2.945], F64), jnp.asarray([k, 2.929], F64))
    d = 4 * EPS32
    out = np.zeros(2)
    for c in cosines:
        lo, hi = np.clip([c - d, c + d], 0.0, 1.0)
        out = np.maximum(out, np.abs(np.asarray(cond.fresnel(jnp.asarray(hi, F64)))
                                     - np.asarray(cond.fresnel(jnp.asarray(lo, F64)))) / 2)
    return out


@jax.jit
def _eval_jit(L, V, mu, n, k):
    dtype = L.dtype
    cond = Conductor(jnp.stack([n, jnp.asarray(2.945, dtype)]), jnp.stack([k, jnp.asarray(2.929, dtype)]))
    out = []
    for m in (Hiraji(jnp.asarray(79000.0, dtype), mu), Hamon(jnp.asarray(43000.0, dtype), mu)):
        out.append(m.camera(L, V, cond))
        out.append(m.brdf_cos(L, V, cond))
    return out


def _eval_all(dtype, L, V, mu, n, k):
    args = (jnp.asarray(L, dtype), jnp.asarray(V, dtype)) + tuple(jnp.asarray(x, dtype) for x in (mu, n, k))
    return [np.asarray(v) for v in _eval_jit(*args)]


def _loss(which, method, params, L, V):
    scale, mu_, n_, k_ = params
    dtype = L.dtype
    model = (Hiraji if which == 0 else Hamon)(scale, mu_)
    cond = Conductor(jnp.stack([n_, jnp.asarray(2.945, dtype)]), jnp.stack([k_, jnp.asarray(2.929, dtype)]))
    return jnp.sum(getattr(model, method)(L, V, cond))


@jax.jit
def _grads_jit(L, V, mu, n, k):
    grads = []
    for which in range(2):
        for method in ("camera", "brdf_cos"):
            params = (jnp.asarray((79000.0, 43000.0)[which], L.dtype), mu, n, k)
            grads.append(jax.grad(lambda p, L, V: _loss(which, method, p, L, V), argnums=(0, 1, 2))(params, L, V))
    return grads


def _grads(dtype, L, V, mu, n, k):
    """Gradients of every model output (summed over λ) w.r.t. χ/β, μ, n, k, L, V."""
    args = (jnp.asarray(L, dtype), jnp.asarray(V, dtype)) + tuple(jnp.asarray(x, dtype) for x in (mu, n, k))
    return _grads_jit(*args)


@given(mode=modes, ti=angles, tr=angles, ai=azimuths, ar=azimuths, mu=mus, n=ns, k=ks)
@example(mode="L=-V", ti=math.pi / 2, tr=0.0, ai=0.0, ar=0.0, mu=0.05, n=2.9, k=2.9)  # H = 0/0 on the horizon
@example(mode="mirror", ti=math.pi / 2, tr=0.0, ai=0.0, ar=0.0, mu=1e-6, n=2.9, k=2.9)  # double grazing
@example(mode="free", ti=0.3, tr=math.pi / 2, ai=math.pi, ar=0.0, mu=0.05, n=2.9, k=2.9)  # grazing V
@example(mode="mirror", ti=0.0, tr=0.0, ai=0.0, ar=0.0, mu=1e-6, n=1.0, k=0.0)  # L = V = N, F = 0
@example(mode="L=V", ti=math.pi / 2, tr=0.0, ai=0.0, ar=0.0, mu=1.0, n=0.1, k=10.0)
@example(mode="free", ti=0.1, tr=0.0, ai=0.0, ar=0.0, mu=0.05, n=0.1, k=0.0)  # F(θi) 0.2 mrad from its critical angle
@example(mode="offplane-mirror", ti=math.pi / 2 - 1e-3, tr=0.0, ai=0.0, ar=0.0, mu=1e-8, n=2.9, k=2.9)  # |N×(L+V)| = 1e-16
@example(mode="offplane-mirror", ti=math.pi / 2 - 1e-5, tr=0.0, ai=0.0, ar=0.0, mu=1e-8, n=2.9, k=2.9)
@example(mode="mirror", ti=0.0, tr=0.0, ai=0.0, ar=0.0, mu=1e-19, n=2.9, k=2.9)  # d/dμ at φ = 0: μ² underflows
@example(mode="mirror", ti=0.6, tr=0.0, ai=0.0, ar=0.0, mu=1e-20, n=2.9, k=2.9)
@example(mode="mirror", ti=0.0, tr=0.0, ai=0.0, ar=0.0, mu=0.05, n=1e-8, k=0.0)  # Fresnel's 1/den² overflowed
def test_models_float32_hard_cases(mode, ti, tr, ai, ar, mu, n, k):
    L64, V64 = _geometry(mode, ti, tr, ai, ar)
    L32, V32 = jnp.asarray(L64, F32), jnp.asarray(V64, F32)
    # float32 inputs, and the same numbers exactly in float64
    mu32, n32, k32 = (float(np.float32(v)) for v in (mu, n, k))
    Lr, Vr = jnp.asarray(np.asarray(L32), F64), jnp.asarray(np.asarray(V32), F64)

    vals32 = _eval_all(F32, L32, V32, mu32, n32, k32)
    vals64 = _eval_all(F64, Lr, Vr, mu32, n32, k32)
    geom64 = _eval_all(F64, Lr, Vr, mu32, 1.0, 1e8)  # F ≈ 1 − 4e-16: the geometric part
    for v in vals32:
        assert v.dtype == np.float32
        assert np.all(np.isfinite(v)), (mode, v)
        assert np.all(v >= 0), (mode, v)

    # float32 vs float64 where float64's value is a normal float32 number, |L+V| is above float32's
    # half-vector cut (below it float32 returns 0 by design) and μ above float32's floor of the lobe
    # normalisation, tiny^(1/4) = 3.3e-10 (below it the normalised lobes take that width, by design)
    s = np.asarray(Lr) + np.asarray(Vr)
    phi64 = math.atan2(math.hypot(s[0], s[1]), s[2])
    if np.linalg.norm(s) > 4 * EPS32 and mu32 > float(np.finfo(np.float32).tiny) ** 0.25:
        dF = _fresnel_condition((float(np.asarray(Lr)[2]), float(np.linalg.norm(s)) / 2), n32, k32)
        for v32, v64, g64 in zip(vals32, vals64, geom64):
            representable = (v64 < np.finfo(np.float32).max) & ((v64 == 0) | (v64 > np.finfo(np.float32).tiny))
            tol = _f32_tolerance(v64, g64[..., 1:2], phi64, mu32, dF)
            err = np.abs(v32.astype(np.float64) - v64)
            assert np.all(err[representable] <= tol[representable]), (mode, v32, v64, tol)

    for g in _grads(F32, L32, V32, mu32, n32, k32):
        for leaf in jax.tree_util.tree_leaves(g):
            assert np.all(np.isfinite(np.asarray(leaf))), (mode, g)


@jax.jit
def _beckmann_smith(alpha, L, V):
    phi, _, _, valid = half_vector_terms(L, V)
    d = beckmann_phi(phi, alpha)
    g = smith_beckmann(jnp.maximum(V[2], 0.0), jnp.maximum(L[2], 0.0), alpha)
    return jnp.where(valid, d * g, 0.0)


_beckmann_smith_grad = jax.jit(jax.grad(_beckmann_smith, argnums=(0, 1, 2)))


@given(ti=angles, tr=angles, ai=azimuths, ar=azimuths, mode=modes,
       alpha=st.one_of(st.sampled_from([1e-6, 1e-3, 1.0]), st.floats(math.log(1e-6), 0.0).map(math.exp)))
def test_beckmann_smith_float32_hard_cases(ti, tr, ai, ar, mode, alpha):
    L64, V64 = _geometry(mode, ti, tr, ai, ar)

    f = _beckmann_smith
    for dtype in (F32, F64):
        L, V = jnp.asarray(L64, dtype), jnp.asarray(V64, dtype)
        a = jnp.asarray(alpha, dtype)
        v = f(a, L, V)
        assert v.dtype == dtype and bool(jnp.isfinite(v)) and float(v) >= 0
        for leaf in _beckmann_smith_grad(a, L, V):
            assert bool(jnp.all(jnp.isfinite(leaf))), (mode, leaf)
    # float32 vs float64 on the same inputs
    L32, V32 = jnp.asarray(L64, F32), jnp.asarray(V64, F32)
    a32 = jnp.asarray(alpha, F32)
    v32 = float(f(a32, L32, V32))
    v64 = float(f(jnp.asarray(float(a32), F64), jnp.asarray(np.asarray(L32), F64), jnp.asarray(np.asarray(V32), F64)))
    if v64 < 1e30 and np.linalg.norm(np.asarray(L32) + np.asarray(V32)) > 4 * EPS32:
        # Beckmann's exponent tan²φ/α² amplifies the relative error of tan²φ the same way
        s = np.asarray(L32, np.float64) + np.asarray(V32, np.float64)
        phi = math.atan2(math.hypot(s[0], s[1]), s[2])
        t2 = min(math.tan(phi) ** 2 / float(a32) ** 2, 1e300)
        tol = (1e-5 * (1 + 2 * t2) * v64 + 1e-6) if v64 > 0 else 1e-30
        assert abs(v32 - v64) <= tol, (mode, v32, v64)


def test_beckmann_from_cos_loses_small_angles_in_float32():
    """The measured trap: ``beckmann(cos φ)`` in float32 returns the peak at φ = 3e-5, α = 1e-6."""
    phi = np.float32(3e-5)
    alpha = np.float32(1e-6)
    exact = 0.0  # exp(−900) underflows in float64 too
    assert float(beckmann(jnp.cos(jnp.asarray(phi)), jnp.asarray(alpha))) > 1e11  # the trap
    assert float(beckmann_phi(jnp.asarray(phi), jnp.asarray(alpha))) == exact
    # and they agree where cos φ carries the information
    for p in (0.01, 0.3, 1.2):
        a = beckmann(jnp.cos(jnp.asarray(p, F64)), 0.3)
        b = beckmann_phi(jnp.asarray(p, F64), 0.3)
        assert float(b) == pytest.approx(float(a), rel=1e-12)


@pytest.mark.parametrize("dtype", [F32, F64])
@pytest.mark.parametrize("alpha", [1e-8, 1e-6, 0.3])
def test_beckmann_at_the_peak_has_finite_gradients(dtype, alpha):
    """beckmann(cos = 1, α): value 1/(π α²) and finite derivatives (α⁴ is never formed)."""
    c, a = jnp.asarray(1.0, dtype), jnp.asarray(alpha, dtype)
    assert float(beckmann(c, a)) == pytest.approx(1 / (np.pi * float(a) ** 2), rel=1e-6)
    for g in jax.grad(beckmann, argnums=(0, 1))(c, a):
        assert bool(jnp.isfinite(g))
    assert float(jax.grad(beckmann, argnums=1)(c, a)) == pytest.approx(-2 / (np.pi * float(a) ** 3), rel=1e-5)


@pytest.mark.parametrize("dtype", [F32, F64])
@pytest.mark.parametrize("nk", [(1e20, 1e20), (1e20, 0.0), (1e30, 3.0)])
def test_fresnel_of_a_huge_index_is_one(dtype, nk):
    from jkatana.models import fresnel_conductor

    cos = jnp.asarray([0.0, 0.3, 1.0], dtype)
    n, k = (jnp.asarray(x, dtype) for x in nk)
    f = np.asarray(fresnel_conductor(cos, n, k))
    assert np.isfinite(f).all()
    np.testing.assert_allclose(f, 1.0, atol=1e-7)
    for g in jax.grad(lambda n, k: jnp.sum(fresnel_conductor(cos, n, k)), argnums=(0, 1))(n, k):
        assert bool(jnp.isfinite(g))


def test_beckmann_normalised_and_smith_limits():
    """∫ D cosφ dω_h = 1 (Walter et al. 2007, eq. 4); G1 = 1 at normal, 0 at grazing."""
    for alpha in (0.05, 0.3):
        phi = np.linspace(0.0, np.pi / 2, 20001)
        d = np.asarray(beckmann_phi(jnp.asarray(phi), alpha))
        integral = 2 * np.pi * np.trapezoid(d * np.cos(phi) * np.sin(phi), phi)
        assert integral == pytest.approx(1.0, rel=1e-4)
    assert float(smith_beckmann(1.0, 1.0, 0.3)) == 1.0
    assert float(smith_beckmann(0.0, 1.0, 0.3)) == 0.0
