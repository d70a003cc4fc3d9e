"""Reflection lobes: value, sampling and pdf agree with each other for every lobe.

- the pdf integrates to 1 over facet normals at normal view (the Gaussian
  lobes: to their stated facet mass 1 − exp(−ln2 (π/2)²/μ²)) and, at oblique
  view, the L-space pdf with the reflection Jacobian equals the facet density
  over the facets that face V (quadrature, float64); for the lobes sampled by
  their visible normals (Beckmann, GGX) it integrates to 1 over the sphere of
  L at every view, grazing ones included;
- a chi-square test of the sampled facet angles against the pdf, and for the
  visible-normal samplers one of the facet angle and azimuth together;
- the mean of f·cos/pdf over samples is the quadrature albedo (unbiased);
- float32 properties (hypothesis) with μ from 1e-6 to 1 and grazing views:
  samples finite and unit, pdf(sample) > 0 and finite where the sample is
  valid, f·cos/pdf bounded, gradients finite;
- the registry and the params round trip; the paper's Hiraji/Hamon are these lobes;
- each lobe's reflected width against the second moment of its own f·cos at normal view.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import stats

from jkatana.models import Conductor, Hamon, Hiraji
from jkatana.models.lobes import (GGX, GTR, LOBES, Beckmann, Gaussian, GaussianVCavity, Mixture, lobe_from_params,
                                  reflect)
from jkatana.models.microfacet import LN2


def make(kind: str, width, dtype=jnp.float64):
    """A lobe of ``kind`` whose narrowest part has width ``width`` (μ or α)."""
    w = jnp.asarray(width, dtype)
    if kind == "gaussian":
        return Gaussian(w)
    if kind == "gaussian-vcavity":
        return GaussianVCavity(w)
    if kind == "beckmann":
        return Beckmann(w)
    if kind == "ggx":
        return GGX(w)
    if kind == "gtr":
        return GTR(w, jnp.asarray(1.5, dtype))
    if kind == "gtr1":
        return GTR(w, jnp.asarray(1.0, dtype))
    if kind == "mixture":
        return Mixture(GGX(w), GTR(jnp.minimum(4 * w, 1.0), jnp.asarray(1.5, dtype)), jnp.asarray(0.6, dtype))
    if kind == "paper":
        return Mixture(Gaussian(w), GaussianVCavity(jnp.minimum(2 * w, 1.0)), jnp.asarray(0.4, dtype))
    raise KeyError(kind)


KINDS = ("gaussian", "gaussian-vcavity", "beckmann", "ggx", "gtr", "gtr1", "mixture", "paper")
N = np.array([0.0, 0.0, 1.0])


def view(theta):
    return np.array([np.sin(theta), 0.0, np.cos(theta)])


def expected_mass(lobe) -> float:
    """Probability that a sampled facet normal is in the upper hemisphere (stated truncation)."""
    if isinstance(lobe, (Gaussian, GaussianVCavity)):
        return float(lobe.facet_mass())
    if isinstance(lobe, Mixture):
        w = float(lobe.weight)
        return w * expected_mass(lobe.first) + (1 - w) * expected_mass(lobe.second)
    return 1.0


def facet_grid(width, n_x=3000, n_psi=48):
    """Facet normals on a grid in (x = ln tan φ, ψ) fine enough for lobes from width·1e-6 to 90°."""
    x = np.linspace(np.log(width) - 14.0, np.log(1e8), n_x)
    phi = np.arctan(np.exp(x))
    psi = (np.arange(n_psi) + 0.5) / n_psi * 2 * np.pi
    P, S = np.meshgrid(phi, psi, indexing="ij")
    h = np.stack([np.sin(P) * np.cos(S), np.sin(P) * np.sin(S), np.cos(P)], -1)
    # dω_h = sin φ dφ dψ and dφ = sin φ cos φ dx
    w = np.sin(P) ** 2 * np.cos(P) * (2 * np.pi / n_psi)
    return x, phi, h, w


# The quadrature grids' lobe evaluations, each one compiled program per lobe class and grid shape (the
# lobe's parameters are traced arrays, so every width reuses it) rather than dispatched operation by operation.
@eqx.filter_jit
def _pdf_at_reflection(lobe, V, h):
    """pdf_L(reflect(V, h), V), V broadcast to h's shape."""
    Vb = jnp.broadcast_to(V, h.shape)
    return lobe.pdf(reflect(Vb, h), Vb)


@eqx.filter_jit
def _f_cos_at_reflection(lobe, V, h):
    """f·cos at (reflect(V, h), V), V broadcast to h's shape."""
    Vb = jnp.broadcast_to(V, h.shape)
    return lobe.f_cos(reflect(Vb, h), Vb)


def facet_density(lobe, h):
    """Density per steradian of facet normals, from the lobe's pdf at normal view (pdf_L · 4 cos φ)."""
    return np.asarray(_pdf_at_reflection(lobe, jnp.asarray(N), jnp.asarray(h))) * 4 * h[..., 2]


def visible_mass(lobe, V, h, w, x) -> float:
    """∫ pdf_L dω_L at view V: 1 for the visible-normal samplers, else the facet density over facets facing V."""
    if isinstance(lobe, Mixture):
        wt = float(lobe.weight)
        return wt * visible_mass(lobe.first, V, h, w, x) + (1 - wt) * visible_mass(lobe.second, V, h, w, x)
    if isinstance(lobe, (Beckmann, GGX)):
        return 1.0
    faces = (np.sum(np.broadcast_to(V, h.shape) * h, -1) > 0)
    return np.trapezoid((facet_density(lobe, h) * faces * w).sum(1), x)


def l_space(lobe, V, h):
    """(pdf_L, Jacobian 4 max(V·h, 0)) at L = reflect(V, h)."""
    vh = np.sum(np.broadcast_to(V, h.shape) * h, -1)
    return np.asarray(_pdf_at_reflection(lobe, jnp.asarray(V), jnp.asarray(h))), 4 * np.maximum(vh, 0.0)


def l_space_f_cos(lobe, V, h):
    """f·cos at L = reflect(V, h)."""
    return np.asarray(_f_cos_at_reflection(lobe, jnp.asarray(V), jnp.asarray(h)))


WIDTHS = (1e-3, 0.05, 0.3, 1.0)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("width", WIDTHS)
def test_pdf_integrates_to_its_stated_mass(kind, width):
    lobe = make(kind, width)
    x, phi, h, w = facet_grid(width)
    p_h = facet_density(lobe, h)
    mass = np.trapezoid((p_h * w).sum(1), x)
    assert mass == pytest.approx(expected_mass(lobe), abs=2e-5)
    # oblique view: the L-space pdf with the Jacobian integrates to the mass of the facets the sampler draws
    V = view(1.2)
    p, jac = l_space(lobe, V, h)
    lhs = np.trapezoid((p * jac * w).sum(1), x)
    assert lhs == pytest.approx(visible_mass(lobe, V, h, w, x), abs=2e-5)


@pytest.mark.parametrize("kind", ("beckmann", "ggx"))
@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("cos_v", (1e-6, 0.01, 0.2))
def test_visible_normal_pdf_integrates_to_one_at_grazing_view(kind, width, cos_v):
    lobe = make(kind, width)
    x, phi, h, w = facet_grid(width, n_psi=720)  # fine in azimuth: the visible facets end at V·h = 0
    p, jac = l_space(lobe, view(np.arccos(cos_v)), h)
    assert np.isfinite(p).all()
    assert np.trapezoid((p * jac * w).sum(1), x) == pytest.approx(1.0, abs=2e-4)


@pytest.mark.parametrize("kind", ("beckmann", "ggx"))
@pytest.mark.parametrize("width,theta", [(0.05, 0.7), (0.2, 1.3), (0.2, 1.55), (1.0, 1.0)])
def test_visible_normals_follow_the_pdf_in_angle_and_azimuth(kind, width, theta):
    """Chi-square of the sampled facet normals binned in facet angle (equal expected mass) × 8 azimuths."""
    lobe = make(kind, width)
    V = view(theta)
    n = 40000
    Vb = jnp.broadcast_to(jnp.asarray(V), (n, 3))
    L, pdf = lobe.sample(Vb, jax.random.uniform(jax.random.PRNGKey(11), (n, 2), jnp.float64))
    L, pdf = np.asarray(L), np.asarray(pdf)
    assert (pdf > 0).all()  # a visible normal always reflects V into a direction the pdf covers
    hs = L + V
    phi_s = np.arctan2(np.linalg.norm(hs[:, :2], axis=1), hs[:, 2])
    psi_s = np.mod(np.arctan2(hs[:, 1], hs[:, 0]), 2 * np.pi)
    x, phi, h, w = facet_grid(width, n_psi=480)
    p, jac = l_space(lobe, V, h)
    dx = np.gradient(x)
    mass = p * jac * w * dx[:, None]  # (x, ψ) cells; 60 ψ cells per azimuth bin
    row = np.cumsum(mass.sum(1))
    k = 12
    cut = np.searchsorted(row, np.linspace(0, row[-1], k + 1)[1:-1])
    edges = np.concatenate([[0.0], 0.5 * (phi[cut] + phi[cut + 1]), [np.pi]])
    expect = np.add.reduceat(np.add.reduceat(mass, np.concatenate([[0], cut + 1]), 0), np.arange(0, 480, 60), 1)
    counts = np.histogram2d(phi_s, psi_s, [edges, np.linspace(0, 2 * np.pi, 9)])[0]
    expect = expect * n / expect.sum()
    keep = expect > 5
    obs_k = np.append(counts[keep], counts[~keep].sum())  # the bins expecting ≤ 5 pooled into one
    exp_k = np.append(expect[keep], expect[~keep].sum())
    chi2 = np.sum((obs_k - exp_k) ** 2 / np.maximum(exp_k, 1e-3))
    assert stats.chi2.sf(chi2, len(obs_k) - 1) > 1e-4, (chi2, counts, expect)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("width,theta", [(1e-3, 0.0), (0.05, 0.7), (0.3, 1.3), (1.0, 0.4)])
def test_sampled_facet_angles_follow_the_pdf_chi_square(kind, width, theta):
    lobe = make(kind, width)
    V = view(theta)
    n = 20000
    ku, kc = jax.random.split(jax.random.PRNGKey(7))
    Vb = jnp.broadcast_to(jnp.asarray(V), (n, 3))
    L, pdf = lobe.sample(Vb, jax.random.uniform(ku, (n, 2), jnp.float64), jax.random.uniform(kc, (n,), jnp.float64))
    L, pdf = np.asarray(L), np.asarray(pdf)
    valid = pdf > 0
    hs = L[valid] + V
    phi_s = np.arctan2(np.linalg.norm(hs[:, :2], axis=1), hs[:, 2])
    # expected: facet density over facets facing V, binned in φ at equal expected mass
    x, phi, h, w = facet_grid(width)
    p, jac = l_space(lobe, V, h)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * ((p * jac * w).sum(1)[1:] + (p * jac * w).sum(1)[:-1])
                                           * np.diff(x))])
    total = cdf[-1]
    k = 24
    edges = np.interp(np.linspace(0, total, k + 1), cdf, phi)
    edges[0], edges[-1] = 0.0, np.pi
    counts = np.histogram(phi_s, edges)[0]
    expect = np.full(k, n * total / k)
    obs = np.append(counts, n - valid.sum())
    exp = np.append(expect, n * (1 - total))
    keep = exp > 5
    obs_k, exp_k = obs[keep], exp[keep]
    chi2 = np.sum((obs_k - exp_k) ** 2 / exp_k)
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-4, (chi2, counts, expect)
    # unbiased: mean f·cos/pdf over the samples is the albedo (quadrature), within 5 standard errors
    f = np.asarray(lobe.f_cos(jnp.asarray(L), Vb))
    ratio = np.where(valid, f / np.where(valid, pdf, 1.0), 0.0)
    albedo = np.trapezoid((l_space_f_cos(lobe, V, h) * jac * w).sum(1), x)
    assert ratio.mean() == pytest.approx(albedo, abs=5 * ratio.std() / np.sqrt(n) + 1e-6)
    if not kind.startswith("gtr") and kind != "mixture":  # GTR borrows GGX's shadowing (see its docstring)
        assert albedo <= 1.0 + 2e-3  # energy conserving (F = 1)
    # the pdf sample() returns is pdf(L, V)
    np.testing.assert_array_equal(pdf[valid], np.asarray(lobe.pdf(jnp.asarray(L), Vb))[valid])


# compiled once per lobe class (the lobe's parameters are traced arrays), not once per drawn example
_sample_jit = eqx.filter_jit(lambda lobe, Vb, u, uc: lobe.sample(Vb, u, uc))
_f_cos_jit = eqx.filter_jit(lambda lobe, L, V: lobe.f_cos(L, V))
_value_grads_jit = eqx.filter_jit(lambda lobe, Ls, Vs: jax.grad(
    lambda lb, Ls, Vs: jnp.sum(lb.f_cos(Ls, Vs)) + jnp.sum(jnp.log1p(lb.pdf(Ls, Vs))), argnums=(0, 1, 2))(lobe, Ls, Vs))
_sample_grads_jit = eqx.filter_jit(lambda lobe, V, u, uc: jax.grad(
    lambda lb: jnp.sum(lb.sample(V, u, uc)[0]))(lobe))


def _check_f32(kind, log_w, cos_v, seed):
    lobe = make(kind, 10.0**log_w, jnp.float32)
    sin_v = np.sqrt(max(1.0 - cos_v * cos_v, 0.0))
    V = jnp.asarray([sin_v, 0.0, cos_v], jnp.float32)
    n = 256
    ku, kc = jax.random.split(jax.random.PRNGKey(seed))
    Vb = jnp.broadcast_to(V, (n, 3))
    u = jax.random.uniform(ku, (n, 2), jnp.float32)
    uc = jax.random.uniform(kc, (n,), jnp.float32)
    L, pdf = _sample_jit(lobe, Vb, u, uc)
    L, pdf = np.asarray(L), np.asarray(pdf)
    assert L.dtype == np.float32 and pdf.dtype == np.float32
    assert np.isfinite(L).all() and np.isfinite(pdf).all() and (pdf >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(L, axis=1), 1.0, atol=1e-5)
    # pdf(sample) > 0: at normal view every facet normal faces V, so the samples with pdf 0 are those
    # beyond the stated truncation only
    resolved = 10.0**log_w * cos_v >= 0.99e-6  # a float32 L resolves the lobe (angular error ~eps/cos θr)
    if cos_v == 1.0 and resolved:
        m = expected_mass(lobe)
        assert (pdf > 0).mean() >= m - 5 * np.sqrt(m * (1 - m) / n) - 1e-9
    s = L + np.asarray(V)
    h = s / np.maximum(np.linalg.norm(s, axis=1, keepdims=True), 1e-30)
    # f·cos/pdf bounded: the Gaussian lobes by N(μ)·2πσ² (the sampler's normalisation), microfacets
    # with Smith shadowing by cos θH/(cos θr cos φ)
    f = np.asarray(_f_cos_jit(lobe, jnp.asarray(L), Vb))
    assert np.isfinite(f).all() and (f >= 0).all()
    ok = pdf > 0
    ratio = f[ok] / pdf[ok]
    assert np.isfinite(ratio).all()
    if not resolved:
        pass
    elif kind in ("gaussian", "gaussian-vcavity"):
        mu = max(10.0**log_w, 1e-7)
        bound = float(lobe.scale) * 2 * np.pi * mu * mu / (2 * LN2) * (2.0 if kind == "gaussian-vcavity" else 1.0)
        assert (ratio <= bound * 1.01 + 1e-6).all()
    elif kind in ("beckmann", "ggx"):  # G1(L) G1(V)/G1_exact(V): Walter et al.'s G1 within 0.35 %
        assert (ratio <= 1.0035 * 1.001 + 1e-5).all()
    elif kind in ("gtr", "gtr1") and cos_v > 0.05:
        cos_th, cos_h = np.abs(h[ok] @ np.asarray(V)), h[ok, 2]
        assert (ratio <= 1.01 * cos_th / (cos_v * np.maximum(cos_h, 1e-6)) + 1e-5).all()
    # gradients w.r.t. the lobe's parameters and the directions are finite
    idx = np.resize(np.nonzero(ok)[0], 16) if ok.any() else np.arange(16)  # 16 rows: one compiled program
    Ls, Vs = jnp.asarray(L[idx]), Vb[idx]
    grads = _value_grads_jit(lobe, Ls, Vs)
    for g in jax.tree.leaves(grads):
        assert np.isfinite(np.asarray(g)).all(), (kind, grads)
    gs = _sample_grads_jit(lobe, Vb[:8], u[:8], uc[:8])
    for g in jax.tree.leaves(gs):
        assert np.isfinite(np.asarray(g)).all(), (kind, gs)


@settings(deadline=None)
@given(kind=st.sampled_from(KINDS), log_w=st.floats(-6.0, 0.0),
       cos_v=st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.0, 1e-7, 1e-4, 1.0])),
       seed=st.integers(0, 2**16))
@pytest.mark.slow
def test_float32_samples_pdf_and_gradients_are_finite(kind, log_w, cos_v, seed):
    _check_f32(kind, log_w, cos_v, seed)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("log_w,cos_v", [(-6.0, 1.0), (-6.0, 1e-4), (0.0, 1e-7), (0.0, 1.0), (-3.0, 0.0)])
def test_float32_extremes(kind, log_w, cos_v):
    _check_f32(kind, log_w, cos_v, 3)


@pytest.mark.parametrize("kind", KINDS)
def test_params_round_trip_and_registry(kind):
    lobe = make(kind, 0.07)
    p = lobe.to_params()
    assert p["lobe"] in LOBES and LOBES[p["lobe"]] is type(lobe)
    import json

    back = lobe_from_params(json.loads(json.dumps(p)), jnp.float64)
    L = jnp.asarray([[0.1, 0.05, 0.99]]) / jnp.linalg.norm(jnp.asarray([0.1, 0.05, 0.99]))
    V = jnp.asarray([[-0.08, -0.02, 0.99]]) / jnp.linalg.norm(jnp.asarray([-0.08, -0.02, 0.99]))
    np.testing.assert_allclose(back.f_cos(L, V), lobe.f_cos(L, V), rtol=1e-12)
    np.testing.assert_allclose(back.pdf(L, V), lobe.pdf(L, V), rtol=1e-12)
    with pytest.raises(ValueError):
        lobe_from_params({"lobe": "no-such-lobe"})


def test_lobes_vmap_and_batch_parameters():
    mus = jnp.asarray([0.01, 0.05, 0.2])
    V = jnp.asarray([[0.3, 0.0, 0.954]] * 3)
    V = V / jnp.linalg.norm(V, axis=-1, keepdims=True)
    u = jnp.full((3, 2), 0.3)
    L1, p1 = GGX(mus).sample(V, u)
    L2, p2 = jax.vmap(lambda m, v, uu: GGX(m).sample(v, uu))(mus, V, u)
    np.testing.assert_allclose(L1, L2, rtol=1e-12)
    np.testing.assert_allclose(p1, p2, rtol=1e-12)


def test_paper_models_are_the_gaussian_lobes():
    cond = Conductor.from_table()
    rng = np.random.default_rng(1)
    V = rng.normal(size=(64, 3))
    V[:, 2] = np.abs(V[:, 2])
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    L = np.stack([-V[:, 0], -V[:, 1], V[:, 2]], -1) + 0.05 * rng.normal(size=(64, 3))
    L /= np.linalg.norm(L, axis=1, keepdims=True)
    L, V = jnp.asarray(L), jnp.asarray(V)
    for model, lobe_cls in ((Hiraji(79000.0, 0.04), Gaussian), (Hamon(43000.0, 0.06), GaussianVCavity)):
        lobe = lobe_cls(model.mu)
        np.testing.assert_array_equal(model.brdf_cos(L, V, cond), lobe.brdf_cos(L, V, cond))
        assert float(model.lobe().mu) == float(lobe.mu) and float(model.lobe().scale) == float(lobe.scale)
        scale = getattr(model, "chi", None) or model.beta
        np.testing.assert_array_equal(model.camera(L, V, cond),
                                      lobe_cls(model.mu, scale, normalised=False).brdf_cos(L, V, cond))


# ---------------------------------------------------------------- the reflected width (cap-rule node scale)


def _normal_incidence_moments(lobe, scale):
    """``(σ_m, σ_c)`` of a lobe's f·cos at normal view (V = N), ψ the angle of L from the mirror direction N,
    by Gauss–Legendre quadrature (24 nodes on each of 120 geometrically growing intervals from 1e-3·scale to
    π/2, float64): the moment width ``σ_m = √(E[ψ²]/2)`` (a 2-D Gaussian exp(−ψ²/2σ²) has E[ψ²] = 2σ²) and the
    peak-curvature width ``σ_c = ψ₀ / √(2 ln(f(0)/f(ψ₀)))`` at ψ₀ = 1e-2·scale."""
    x, w = np.polynomial.legendre.leggauss(24)
    edges = np.concatenate([[0.0], np.geomspace(1e-3 * scale, np.pi / 2, 120)])
    a, b = edges[:-1, None], edges[1:, None]
    th = (0.5 * (b - a) * (x + 1) + a).ravel()
    wt = (0.5 * (b - a) * w).ravel()
    V = jnp.asarray([0.0, 0.0, 1.0])

    def fcos(t):
        t = np.asarray(t, np.float64)
        return np.asarray(lobe.f_cos(jnp.asarray(np.stack([np.sin(t), 0.0 * t, np.cos(t)], -1)), V))

    f = fcos(th) * np.sin(th) * wt
    sigma_m = np.sqrt(0.5 * np.sum(f * th**2) / np.sum(f))
    psi0 = 1e-2 * scale
    f0, f1 = fcos(np.array([0.0, psi0]))
    return sigma_m, psi0 / np.sqrt(2.0 * np.log(f0 / f1))


def _x64(x):
    return jnp.asarray(x, jnp.float64)


MOMENT_MATCHED = [
    *[(f"gaussian-{m}", lambda m=m: Gaussian(_x64(m))) for m in (1e-3, 1e-2, 0.1)],
    *[(f"gaussian-vcavity-{m}", lambda m=m: GaussianVCavity(_x64(m))) for m in (1e-3, 1e-2, 0.1)],
    *[(f"beckmann-{a}", lambda a=a: Beckmann(_x64(a))) for a in (1e-3, 1e-2, 0.1)],
    *[(f"gtr3-{a}", lambda a=a: GTR(_x64(a), _x64(3.0))) for a in (1e-2, 0.05)],
    ("gaussian+beckmann", lambda: Mixture(Gaussian(_x64(0.01)), Beckmann(_x64(0.05)), _x64(0.3))),
    ("vcavity+gtr3", lambda: Mixture(GaussianVCavity(_x64(0.003)), GTR(_x64(0.1), _x64(3.0)), _x64(0.8))),
]


@pytest.mark.parametrize("name, build", MOMENT_MATCHED, ids=[n for n, _ in MOMENT_MATCHED])
def test_reflected_width_is_the_second_moment_at_normal_incidence(name, build):
    """``reflected_width()`` against the numerical second moment of the lobe's own f·cos at V = N.

    Tolerance |σ_m/σ − 1| ≤ σ_max² + 1e-6 (σ_max: the widest part). The match is exact only as the lobe
    narrows: sin ψ ≠ ψ and the 1/cos θH of the hiraji lobe shift σ by −σ²/24, the V-cavity's shadowing
    by −σ²/6, Beckmann's φ ≠ tan φ by −σ²/3, GTR γ = 3's slope tail (a fourth moment that diverges
    logarithmically) by ~σ² ln(1/σ)/2; the 1e-6 covers the quadrature. A width off by any constant factor
    (√2 for the Beckmann/GGX scales, √ln2 for μ as a half-width) fails by orders of magnitude."""
    lobe = build()
    sigma = float(lobe.reflected_width())
    widest = max(float(p.reflected_width()) for p in ([lobe.first, lobe.second] if isinstance(lobe, Mixture)
                                                       else [lobe]))
    narrowest = min(float(p.reflected_width()) for p in ([lobe.first, lobe.second] if isinstance(lobe, Mixture)
                                                          else [lobe]))
    sigma_m, _ = _normal_incidence_moments(lobe, narrowest)
    assert abs(sigma_m / sigma - 1.0) <= widest**2 + 1e-6, (sigma_m, sigma)


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0])
def test_heavy_tailed_lobes_have_no_moment_width_and_sigma_is_their_core(gamma):
    """GTR with γ ≤ 2 (GGX at γ = 2): the second moment of f·cos grows without bound as α → 0 (the slope
    density's t⁻⁴ tail), so ``reflected_width`` is the core's scale instead: √γ times the peak-curvature
    width α√(2/γ), which the numerical curvature reproduces to 1e-3 (its O(ψ₀²) error is 1e-4·σ²/α²)."""
    ratios = []
    for alpha in (1e-3, 1e-2):
        lobe = GGX(_x64(alpha)) if gamma == 2.0 else GTR(_x64(alpha), _x64(gamma))
        sigma = float(lobe.reflected_width())
        sigma_m, sigma_c = _normal_incidence_moments(lobe, sigma)
        ratios.append(sigma_m / sigma)
        assert sigma_c == pytest.approx(alpha * np.sqrt(2.0 / gamma), rel=1e-3)
        assert sigma == pytest.approx(np.sqrt(gamma) * sigma_c, rel=1e-3)
    assert ratios[0] > ratios[1] > 1.5, ratios  # no finite moment to match: wider the narrower the core


@pytest.mark.parametrize("kind", ["beckmann", "ggx", "gtr"])
def test_microfacet_value_from_tan_equals_value_from_facet_angle(kind):
    """The microfacet lobes take tan φ from L + V (no atan2): the same D as the facet-angle form
    (float64, to rounding), narrow lobes included in float32 (tan φ ≈ φ where 1 − cos φ rounds to 0),
    and 0 for facet normals at or beyond 90°."""
    from jkatana.models.geometry import half_vector_tan_terms, half_vector_terms

    rng = np.random.default_rng(3)
    for width, dtype, rtol in ((0.2, jnp.float64, 1e-12), (0.3, jnp.float32, 2e-5), (1e-4, jnp.float32, 2e-5)):
        lobe = make(kind, width, dtype)
        V = jnp.asarray([np.sin(0.5), 0.0, np.cos(0.5)], dtype)
        # facet normals within a few widths of N (φ ≤ 3 widths), reflected about them
        phi = np.abs(rng.normal(size=256)) * width
        az = rng.uniform(0, 2 * np.pi, 256)
        h = np.stack([np.sin(phi) * np.cos(az), np.sin(phi) * np.sin(az), np.cos(phi)], -1)
        L = reflect(V, jnp.asarray(h, dtype))
        t, c, _, ok_t = half_vector_tan_terms(L, V)
        p, c2, _, ok_p = half_vector_terms(L, V)
        np.testing.assert_array_equal(np.asarray(ok_t), np.asarray(ok_p))
        np.testing.assert_allclose(np.asarray(c), np.asarray(c2), rtol=0, atol=0)
        got, want = np.asarray(lobe.D_tan(t, c)), np.asarray(lobe.D(p, c2))
        assert np.all(want > 0)
        np.testing.assert_allclose(got, want, rtol=rtol)
        np.testing.assert_allclose(np.asarray(t), np.tan(np.asarray(p, np.float64)), rtol=rtol)
    # φ ≥ 90°: L + V points below the surface
    L = jnp.asarray([[0.0, 0.0, -1.0]])
    V = jnp.asarray([[0.6, 0.0, 0.8]])
    t, c, _, ok = half_vector_tan_terms(L, V)
    assert bool(ok[0]) and float(c[0]) < 0 and float(t[0]) == 0.0
    assert float(make(kind, 0.2).D_tan(t, c)[0]) == 0.0


# ---------------------------------------------------------------- evaluation from precomputed geometry


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_terms_at_precomputed_geometry_equal_terms_for_every_parameter(kind, dtype):
    """One Geometry, computed once outside a jitted map over widths, gives each width's terms(L, V) exactly:
    the fitter's path (geometry hoisted out of the solver loop) and the ordinary path are one formula.
    Directions include grazing light and view, L = −V and the back-scatter side."""
    from jkatana.models.lobes import Geometry

    rng = np.random.default_rng(3)
    theta_i = np.concatenate([rng.uniform(0, 1.5, 60), [np.pi / 2, 1.5707, 0.3, 1.0]])
    theta_r = np.concatenate([rng.uniform(-1.5, 1.5, 60), [0.2, np.pi / 2, -0.3, 1.0]])
    L = jnp.asarray(np.stack([-np.sin(theta_i), 0 * theta_i, np.cos(theta_i)], -1), dtype)
    V = jnp.asarray(np.stack([np.sin(theta_r), 0 * theta_r, np.cos(theta_r)], -1), dtype)
    g = Geometry.of(L, V)
    widths = jnp.asarray([1e-6, 1e-3, 0.05, 0.4, 1.0], dtype)
    via_geo = jax.jit(jax.vmap(lambda w, g: [a for a, _ in make(kind, w, dtype).terms_at(g)], (0, None)))(widths, g)
    for i, w in enumerate(widths):
        direct = make(kind, w, dtype).terms(L, V)
        assert len(direct) == len(via_geo)
        for (a, c), a_geo in zip(direct, via_geo):
            # jitted against eager: rounding only, amplified up to |ln D| ≈ 30 by GTR's log-space evaluation
            np.testing.assert_allclose(np.asarray(a_geo[i]), np.asarray(a), rtol=32 * float(jnp.finfo(dtype).eps),
                                       atol=0)
            assert c.shape == a.shape


@pytest.mark.parametrize("kind", KINDS)
def test_terms_at_gradients_are_finite_at_grazing_angles_and_vanishing_width(kind):
    """d(f·cos)/d(log width) through terms_at stays finite at grazing light and view and at width 1e-7, float32."""
    from jkatana.models.lobes import Geometry

    dtype = jnp.float32
    ti = np.array([np.pi / 2, 1.5706, 0.7, 1e-4, 1.2])
    tr = np.array([np.pi / 2, 1.5706, 0.7, 1e-4, -1.2])
    L = jnp.asarray(np.stack([-np.sin(ti), 0 * ti, np.cos(ti)], -1), dtype)
    V = jnp.asarray(np.stack([np.sin(tr), 0 * tr, np.cos(tr)], -1), dtype)
    g = Geometry.of(L, V)
    for log_w in (-16.0, -7.0, -3.0, 0.0):
        grad = jax.grad(lambda t: sum(jnp.sum(a) for a, _ in make(kind, jnp.exp(t), dtype).terms_at(g)))(
            jnp.asarray(log_w, dtype))
        assert np.isfinite(float(grad)), (kind, log_w)


def test_geometry_broadcasts_direction_batches():
    """Geometry.of(L[:, None], V[None, :]) has every field on the pair grid (the instrument's disks of directions)."""
    from jkatana.models.lobes import Geometry

    L = jnp.asarray([[0.0, 0.0, 1.0], [-0.6, 0.0, 0.8]])
    V = jnp.asarray([[0.6, 0.0, 0.8], [0.0, 0.0, 1.0], [0.0, 0.6, 0.8]])
    g = Geometry.of(L[:, None], V[None, :])
    for f in ("cos_i", "cos_r", "phi", "cos_phi", "cos_th", "valid", "tan_phi"):
        assert getattr(g, f).shape == (2, 3), f
    np.testing.assert_array_equal(np.asarray(g.cos_i), [[1.0] * 3, [0.8] * 3])
    lobe = GGX(jnp.asarray(0.3))
    np.testing.assert_array_equal(np.asarray(lobe.terms_at(g)[0][0]), np.asarray(lobe.terms(L[:, None], V[None, :])[0][0]))


def _visible_slope_cdf_error(cot, u, dtype, steps=None):
    """|P(x̃) − u| of :func:`_beckmann_visible_slope` on the grid ``cot × u`` (float64 reference CDF), and x̃."""
    from scipy.special import erf

    from jkatana.models.lobes import BECKMANN_HALLEY_STEPS, _beckmann_visible_slope

    shape = (cot.size, u.size)
    x = np.asarray(_beckmann_visible_slope(jnp.asarray(np.broadcast_to(cot, shape), dtype),
                                           jnp.asarray(np.broadcast_to(u, shape), dtype),
                                           BECKMANN_HALLEY_STEPS if steps is None else steps), np.float64)
    c = np.minimum(cot, 1e4)
    cdf = (c * (1 + erf(x)) + np.exp(-x * x) / np.sqrt(np.pi)) / (c * (1 + erf(c)) + np.exp(-c * c) / np.sqrt(np.pi))
    # float32: the tails beyond |x| ≈ 3.9 are drawn at that slope (u within 3e-7 of 0 or 1)
    inner = (u > 3e-7) & (u < 1 - 3e-7) if dtype == jnp.float32 else np.ones_like(u, bool)
    return np.abs(cdf - u)[np.broadcast_to(inner, shape)], x


@pytest.mark.parametrize("dtype,tol", [(jnp.float64, 5e-9), (jnp.float32, 5e-7)])
def test_beckmann_visible_slope_inverts_its_cdf(dtype, tol):
    """The Halley inversion of the visible-slope CDF (Heitz & d'Eon 2014) to the stated accuracy, grazing to normal view."""
    cot = np.concatenate([[0.0, 1e-6, 1e-3], np.geomspace(1e-2, 1e4, 200)])[:, None]
    u = np.linspace(0.0, 1.0 - 1e-7, 1001)[None]
    err, x = _visible_slope_cdf_error(cot, u, dtype)
    assert np.isfinite(x).all() and (x <= cot + 1e-6).all()
    assert np.max(err) <= tol


@pytest.mark.parametrize("dtype,tol", [(jnp.float64, 5e-9), (jnp.float32, 5e-7)])
@pytest.mark.parametrize("steps", [0, 1, 2])
def test_beckmann_visible_slope_needs_its_halley_steps(dtype, tol, steps):
    """Over a grid of view angles θ (normal to 1e-7 rad above the horizon, and beyond cot θ's clamp, as
    α → 0 gives) × u (from 0 and 1e-12 to 1 − 1e-7, denser at both ends) the two Halley steps meet the
    stated accuracy and fewer do not: Jakob's start alone is off by ~5e-2, one step by ~1e-4."""
    theta = np.concatenate([[0.0, 1e-6], np.linspace(0.01, np.pi / 2 - 0.01, 120),
                            np.pi / 2 - np.geomspace(1e-2, 1e-7, 30), [np.pi / 2]])
    with np.errstate(divide="ignore"):
        cot = (np.cos(theta) / np.sin(theta))[:, None]  # inf at θ = 0, clamped by the sampler
    cot = np.concatenate([np.maximum(cot, 0.0), [[1e6]]])
    u = np.concatenate([[0.0], np.geomspace(1e-12, 1e-2, 40), np.linspace(0.01, 0.99, 197),
                        1.0 - np.geomspace(1e-2, 1e-7, 40)])[None]
    err, x = _visible_slope_cdf_error(cot, u, dtype, steps)
    assert np.isfinite(x).all() and (x <= np.minimum(cot, 1e4) + 1e-6).all()
    if steps == 2:
        assert np.max(err) <= tol
    else:
        assert np.max(err) > 100 * tol
