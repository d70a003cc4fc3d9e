"""A compact sun split off the environment as a cap light, in every render mode.

Scenes: a sphere under a smooth synthetic sky with a uniform solar disc of
known radius pasted in (texel averages by supersampling), so the split finds
one cap of that size; the same sky without the disc for the "nothing to split"
cases.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.light.envmap import texel_directions_np, texel_solid_angles_np
from jkatana.models import Conductor
from jkatana.models.lobes import Gaussian
from jkatana.render.camera import Camera
from jkatana.render.environment import Caps
from jkatana.render.film import film_weights
from jkatana.render.frame import render_frame
from jkatana.render.gbuffer import gbuffer_sphere
from jkatana.render.environment import build_environment
from jkatana.render.fresnel_fold import Material, fresnel_table
from jkatana.render.plan import Pixels, Plan
from jkatana.render.shading import shade
from jkatana.spectral.grid import WavelengthGrid
from tests._scenes import paste_disc, sphere_scene

GRID = WavelengthGrid(400.0, 700.0, 20.0)
CMF = film_weights(GRID)
SPHERE = ("sphere", (0.0, 0.0, 0.0), 1.0)
CAM = Camera(position=(0.0, 0.0, 4.0), fov_deg=32.0, width=28, height=28)
SUN_DIR = np.array([0.35, 0.45, 0.82]) / np.linalg.norm([0.35, 0.45, 0.82])  # glints on the sphere's upper right
SUN_R = math.radians(1.0)


def _sky(H=128, W=256):
    d = texel_directions_np(H, W)
    shape = 1.0 + 0.5 * (700.0 - GRID.wavelengths) / 300.0
    return (0.2 + 0.6 * np.maximum(d[..., 1], 0.0) + 0.05 * d[..., 0])[..., None] * shape


def _with_sun(L, radiance=2.0e4, s=SUN_DIR, radius=SUN_R, sub=12):
    """``L`` plus a uniform disc of ``radiance`` (a warm spectrum) — texel coverage by ``sub²`` supersampling."""
    spectrum = radiance * (0.7 + 0.3 * (GRID.wavelengths - 400.0) / 300.0)
    return paste_disc(L, s, radius, spectrum, sub=sub)[0]


def _iron():
    c = Conductor.from_table("Fe-Johnson", GRID, dtype=jnp.float32)
    return Material(fresnel_table(c.n, c.k), jnp.asarray(79000.0, jnp.float32), jnp.asarray(43000.0, jnp.float32))


def _maps(w, mu0, mu1):
    return np.array([[[w, mu0, mu1]]], np.float32).repeat(2, 0).repeat(2, 1)


def _plan(mode, samples, fac, **kw):
    return Plan(mode=mode, samples=samples, hiraji=True, hamon=True, factored=fac, **kw)


@pytest.fixture(scope="module")
def sun_map():
    return _with_sun(_sky())


# ---------------------------------------------------------------- nothing to split


@pytest.mark.parametrize("mode", ["prefiltered", pytest.param("reference", marks=pytest.mark.slow), "paper"])
def test_no_compact_source_the_program_and_the_frame_are_unchanged(mode):
    """A map without a compact source: ``split_sun=True`` finds nothing, builds the same environment
    (caps None, every array equal), compiles the same program and renders a bit-identical frame."""
    sky = _sky(64, 128)
    mus = (0.03, 0.2) if mode == "prefiltered" else ()
    e0, fac, _ = build_environment(sky, grid=GRID, prefilter_mus=mus)
    e1, _, _ = build_environment(sky, grid=GRID, prefilter_mus=mus, split_sun=True)
    assert e1.caps is None
    for a, b in zip(jax.tree.leaves(e0), jax.tree.leaves(e1)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    plan = _plan(mode, 8, fac, fresnel_rank=0)
    mat = _iron()
    gb = gbuffer_sphere(CAM)
    sel = gb.mask.reshape(-1)
    px = Pixels(*(jnp.asarray(a.reshape(-1, 3)[sel], jnp.float32) for a in (gb.position, gb.normal, gb.view)),
                *(jnp.full((int(sel.sum()),), v, jnp.float32) for v in (0.5, 0.05, 0.2)))

    def lowered(env):
        return jax.jit(lambda e, p: shade(plan, mat, e, None, p, jnp.asarray(CMF, jnp.float32),
                                          jax.random.PRNGKey(0))).lower(env, px).as_text()

    assert lowered(e0) == lowered(e1)
    f0 = render_frame(plan, mat, e0, None, SPHERE, CAM, _maps(0.5, 0.05, 0.2), CMF)
    f1 = render_frame(plan, mat, e1, None, SPHERE, CAM, _maps(0.5, 0.05, 0.2), CMF)
    np.testing.assert_array_equal(f0.xyz, f1.xyz)


# ---------------------------------------------------------------- the split environment


def test_split_environment_carries_the_cap_and_conserves_power(sun_map):
    """One cap of the pasted disc's direction and size; remainder power + cap power = the map's, per band;
    the background shows the disc where camera rays fall inside it."""
    env, fac, _ = build_environment(sun_map, grid=GRID, split_sun=True)
    assert not fac and env.caps is not None and env.caps.count == 1
    c = np.asarray(env.caps.direction[0], np.float64)
    assert math.degrees(math.acos(min(1.0, c @ SUN_DIR))) < 0.5
    assert abs(float(env.caps.radius[0]) / SUN_R - 1.0) < 0.1
    omega = texel_solid_angles_np(*sun_map.shape[:2])
    total = np.einsum("hw,hwl->l", omega, sun_map)
    rem = np.einsum("hw,hwl->l", omega, np.asarray(env.channels, np.float64))
    cap = np.asarray(env.caps.channels[0], np.float64) * float(env.caps.solid_angle()[0])
    np.testing.assert_allclose(rem + cap, total, rtol=1e-5)
    from jkatana.render.environment import background

    d = jnp.asarray(np.stack([SUN_DIR, -SUN_DIR]), jnp.float32)
    _, E = background(env, d, jnp.asarray(CMF, jnp.float32), spectral=True)
    np.testing.assert_allclose(np.asarray(E[0]), np.asarray(env.caps.channels[0] + env.channels.max()), rtol=0.2)
    assert float(E[1].max()) < 10.0


# ---------------------------------------------------------------- agreement between modes


def _frames(sun_map, modes, maps, split=True, seed=0):
    mat = _iron()
    out = {}
    for mode, spp in modes:
        mus = (0.02, 0.05, 0.12, 0.3) if mode == "prefiltered" else ()
        env, fac, _ = build_environment(sun_map, grid=GRID, prefilter_mus=mus, split_sun=split)
        out[mode, spp] = render_frame(_plan(mode, spp, fac), mat, env, None, SPHERE, CAM, maps, CMF, seed=seed)
    return out


@pytest.mark.slow
def test_reference_mode_with_split_equals_without_in_expectation(sun_map):
    """The cap as a third MIS strategy keeps the reference mode unbiased: the split frame's mean luminance
    over the sphere equals the unsplit one's within 4 standard errors (estimated from two seeds of each)
    plus 0.3 % for the sun's shape (a disc against the map's bilinear texels, whose difference reaches a
    lobe of width σ only as ≈ 0.3 (r/σ)²: < 1e-3 here, σ ≥ 0.14 rad against r = 0.017 rad)."""
    maps = _maps(0.5, 0.08, 0.2)
    means, ses = {}, {}
    for split in (False, True):
        a = _frames(sun_map, [("reference", 64)], maps, split, seed=1)["reference", 64]
        b = _frames(sun_map, [("reference", 64)], maps, split, seed=2)["reference", 64]
        m = a.mask
        ya, yb = a.xyz[m][:, 1].astype(np.float64), b.xyz[m][:, 1].astype(np.float64)
        means[split] = 0.5 * (ya.mean() + yb.mean())
        ses[split] = np.std(ya - yb) / math.sqrt(2.0) / math.sqrt(2.0 * len(ya))
    se = math.hypot(ses[False], ses[True])
    assert abs(means[True] - means[False]) <= 4 * se + 3e-3 * means[False], (means, ses)


@pytest.mark.slow
def test_prefiltered_mode_with_a_synthetic_sun_matches_the_reference(sun_map):
    """A sun of known size (1°) on a dim sky: the prefiltered mode's cap rule against the reference mode
    (split, 1024 MIS samples) on the sphere's glint: relative error ≤ 3 % in every pixel brighter than 2 %
    of the glint's peak (the reference's own noise included), and the glint's total within 1 %."""
    dim = _with_sun(0.01 * _sky())
    maps = _maps(0.6, 0.04, 0.15)
    fr = _frames(dim, [("prefiltered", 1), ("reference", 1024)], maps)
    ref, pre = fr["reference", 1024], fr["prefiltered", 1]
    m = ref.mask
    y_ref, y_pre = ref.xyz[m][:, 1].astype(np.float64), pre.xyz[m][:, 1].astype(np.float64)
    bright = y_ref > 0.02 * y_ref.max()
    assert bright.sum() > 10
    rel = np.abs(y_pre[bright] / y_ref[bright] - 1.0)
    assert rel.max() < 0.03, (rel.max(), np.median(rel))
    assert abs(y_pre[bright].sum() / y_ref[bright].sum() - 1.0) < 0.01


@pytest.mark.slow
def test_paper_mode_keeps_the_glint_that_the_published_rays_miss(sun_map):
    """The paper's rays on the remainder + the cap rule keep the sun's glint; the published estimator
    on the whole map (``paper-published``, 30 rays) loses most of it on a narrow lobe."""
    dim = _with_sun(0.01 * _sky())
    maps = _maps(1.0, 0.06, 0.15)
    mat = _iron()
    env_s, fac, _ = build_environment(dim, grid=GRID, split_sun=True)
    env_w, _, _ = build_environment(dim, grid=GRID)
    plan = Plan(mode="paper", samples=30, hiraji=True, hamon=False, factored=fac)
    split = render_frame(plan, mat, env_s, None, SPHERE, CAM, maps, CMF)
    published = render_frame(dataclasses.replace(plan, mode="paper-published"), mat, env_w, None, SPHERE, CAM,
                             maps, CMF)
    with pytest.raises(ValueError, match="paper-published"):
        render_frame(dataclasses.replace(plan, mode="paper-published"), mat, env_s, None, SPHERE, CAM, maps, CMF)
    pref = render_frame(Plan(mode="prefiltered", samples=1, hiraji=True, hamon=False, factored=fac), mat,
                        build_environment(dim, grid=GRID, split_sun=True, prefilter_mus=(0.02, 0.1))[0],
                        None, SPHERE, CAM, maps, CMF)
    m = split.mask
    y_s, y_p, y_f = (f.xyz[m][:, 1].astype(np.float64) for f in (split, published, pref))
    # the paper's rays on the remainder + the same cap rule as the prefiltered mode: the glint is the cap's
    glint = y_f > 0.1 * y_f.max()
    assert glint.sum() > 4
    np.testing.assert_allclose(y_s[glint], y_f[glint], rtol=0.05)
    assert y_p[glint].sum() < 0.7 * y_s[glint].sum() or np.abs(y_p[glint] / y_s[glint] - 1).max() > 0.3


# ---------------------------------------------------------------- energy


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["nodes", "stroud"])
def test_cap_power_reflected_by_a_white_wide_lobe_equals_its_irradiance_times_the_albedo(rule):
    """White (F ≡ 1) wide lobe (μ = 0.3) lit by a 1° cap of unit radiance 40° off the normal, nothing
    else: the exitance ``M = ∫ L_o(V) cos θ_V dω_V`` of the prefiltered mode's cap rule equals the cap's
    irradiance ``E = L Ω cos θ_C`` times the lobe's directional albedo for light from the cap,
    ``ρ(C) = ∫ f_r(C, V) cos θ_V dω_V`` (``f_r = f_cos(C, V)/cos θ_C`` from the lobe object; the paper's
    lobe is not reciprocal, so not the albedo seen from C), both on one midpoint grid of V, to 0.2 %
    (the cap rules' error for a lobe 30× wider than the cap is < 1e-3)."""
    H, W = 48, 96
    th = (np.arange(H) + 0.5) * (0.5 * math.pi / H)
    ph = (np.arange(W) + 0.5) * (2 * math.pi / W)
    th, ph = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    dw = (np.sin(th) * (0.5 * math.pi / H) * (2 * math.pi / W)).reshape(-1)
    P = V.shape[0]
    t = math.radians(40.0)
    C = np.array([math.sin(t), 0.0, math.cos(t)])
    env, fac, _ = build_environment(np.ones((16, 32, GRID.size)), grid=GRID, prefilter_mus=(0.3,))
    caps = Caps(jnp.asarray(C[None], jnp.float32), jnp.asarray([math.radians(1.0)], jnp.float32),
                jnp.asarray(np.ones((1, GRID.size)) @ np.asarray(env.basis, np.float64).T, jnp.float32))
    env = dataclasses.replace(env, channels=jnp.zeros_like(env.channels),
                              prefiltered=tuple(jnp.zeros_like(x) for x in env.prefiltered), caps=caps)
    white = Material(jnp.ones((64, GRID.size), jnp.float32), jnp.asarray(1.0, jnp.float32),
                     jnp.asarray(1.0, jnp.float32))
    f32 = jnp.float32
    px = Pixels(jnp.zeros((P, 3), f32), jnp.tile(jnp.asarray([[0.0, 0.0, 1.0]], f32), (P, 1)), jnp.asarray(V, f32),
                jnp.ones((P,), f32), jnp.full((P,), 0.3, f32), jnp.full((P,), 0.3, f32))
    plan = Plan(mode="prefiltered", samples=1, hiraji=True, hamon=False, factored=fac, fresnel_rank=0, cap_rule=rule)
    xyz, _ = shade(plan, white, env, None, px, jnp.asarray(CMF, f32), jax.random.PRNGKey(0))
    M = float(np.sum(np.asarray(xyz[:, 1], np.float64) * V[:, 2] * dw))
    omega = float(caps.solid_angle()[0])
    lobe = Gaussian(jnp.asarray(0.3, jnp.float64))
    f_r = np.asarray(lobe.f_cos(jnp.asarray(np.broadcast_to(C, V.shape)), jnp.asarray(V))) / C[2]
    rho = float(np.sum(f_r * V[:, 2] * dw))
    E = omega * C[2]
    assert 0.5 < rho < 1.05
    assert abs(M / (E * rho) - 1.0) < 2e-3, (M, E * rho)


# ---------------------------------------------------------------- visibility, low rank


def _sphere_pixels(n=None):
    gb = gbuffer_sphere(CAM)
    sel = gb.mask.reshape(-1)
    f32 = jnp.float32
    px = Pixels(*(jnp.asarray(a.reshape(-1, 3)[sel], f32) for a in (gb.position, gb.normal, gb.view)),
                *(jnp.full((int(sel.sum()),), v, f32) for v in (0.6, 0.04, 0.15)))
    return px


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["prefiltered", "reference"])
def test_the_cap_centre_ray_carries_the_caps_visibility(mode, sun_map):
    """``ray_directions`` adds one ray per cap toward its centre after the lights; all visible: the frame
    is the one without visibility; the cap's ray blocked (everything else visible): the prefiltered mode
    loses exactly the cap rule's term and the reference mode the cap's own samples."""
    from jkatana.render.plan import Visibility
    from jkatana.render.shading import ray_directions

    mus = (0.03, 0.2) if mode == "prefiltered" else ()
    env, fac, _ = build_environment(sun_map, grid=GRID, prefilter_mus=mus, split_sun=True)
    px = _sphere_pixels()
    mat = _iron()
    cmf = jnp.asarray(CMF, jnp.float32)
    key = jax.random.PRNGKey(3)
    plan = _plan(mode, 4, fac, fresnel_rank=0, cap_rule="nodes")
    rays = ray_directions(dataclasses.replace(plan, visibility=True), env, None, px, key)
    P = px.normal.shape[0]
    assert rays.lights.shape == (P, 1, 3) and np.all(np.isinf(np.asarray(rays.light_dist)))
    np.testing.assert_allclose(np.asarray(rays.lights[0, 0]), np.asarray(env.caps.world(env.rotation)[0]), atol=1e-6)
    ones = Visibility(*(jnp.ones(a.shape[:2] if a.ndim == 3 else a.shape, jnp.float32)
                        for a in (rays.mirror[:, 0], rays.lobe, rays.env, rays.lights)))
    vplan = dataclasses.replace(plan, visibility=True)
    base, _ = shade(plan, mat, env, None, px, cmf, key)
    seen, _ = shade(vplan, mat, env, None, px, cmf, key, ones)
    np.testing.assert_allclose(np.asarray(seen), np.asarray(base), rtol=1e-6, atol=1e-7)
    blocked, _ = shade(vplan, mat, env, None, px, cmf, key, ones._replace(lights=jnp.zeros_like(ones.lights)))
    y_b, y_s = np.asarray(blocked[:, 1]), np.asarray(seen[:, 1])
    assert np.all(y_b <= y_s + 1e-6) and (y_s - y_b).max() > 0.1 * y_s.max()
    if mode == "prefiltered":  # no cap at all = the cap's term removed
        none = dataclasses.replace(env, caps=None)
        rem, _ = shade(plan, mat, none, None, px, cmf, key)
        np.testing.assert_allclose(y_b, np.asarray(rem[:, 1]), rtol=1e-5, atol=1e-7)


@pytest.mark.slow
def test_lowrank_mode_with_the_split_agrees_with_the_reference(sun_map):
    """Low rank (3 principal spectra of the whole map, the cap projected on them) with the cap's MIS
    strategy: mean luminance of the sphere within 2 % of the full-spectrum reference mode (both split,
    64 samples, 4 seeds pooled), and no pixel non-finite."""
    maps = _maps(0.5, 0.08, 0.2)
    mat = _iron()
    env_r, fac_r, _ = build_environment(sun_map, grid=GRID, split_sun=True, rank=3)
    env_f, fac_f, _ = build_environment(sun_map, grid=GRID, split_sun=True)
    assert fac_r and env_r.caps.channels.shape == (1, 3)
    y = {}
    for name, env, fac in (("lowrank", env_r, fac_r), ("reference", env_f, fac_f)):
        fr = [render_frame(_plan(name, 64, fac), mat, env, None, SPHERE, CAM, maps, CMF, seed=s) for s in range(4)]
        assert all(np.isfinite(f.xyz).all() for f in fr)
        y[name] = np.mean([f.xyz[f.mask][:, 1].mean() for f in fr])
    assert abs(y["lowrank"] / y["reference"] - 1.0) < 0.02, y


def test_tabulated_normalisation_matches_the_quadrature():
    """The prefiltered mode's N(μ) table (128 nodes uniform in μ² over the pixels' range) against
    :func:`gaussian_normalisation` per pixel: relative error < 1e-5 from μ = 1e-4 to 0.5."""
    from jkatana.models.microfacet import gaussian_normalisation
    from jkatana.render.caps import _tabulated_norms

    mu = np.geomspace(1e-4, 0.5, 997)
    P = mu.size
    f64 = jnp.float64
    px = Pixels(jnp.zeros((P, 3), f64), jnp.zeros((P, 3), f64), jnp.zeros((P, 3), f64), jnp.full((P,), 0.5, f64),
                jnp.asarray(mu, f64), jnp.asarray(mu[::-1].copy(), f64))
    n0, n1 = _tabulated_norms(Plan(mode="prefiltered"), _iron(), px)
    np.testing.assert_allclose(np.asarray(n0), np.asarray(gaussian_normalisation(jnp.asarray(mu, f64))), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(n1), np.asarray(gaussian_normalisation(jnp.asarray(mu[::-1].copy(), f64))),
                               rtol=1e-5)


@pytest.mark.slow
def test_cap_rule_per_lobe_keeps_each_lobes_rule():
    """A narrow hiraji lobe (under 8 cap radii) beside a wide hamon lobe: :func:`cap_rule_for` picks the nodes
    for the first and Stroud's 4 directions for the second, and the mixed rule's terms are, lobe by lobe,
    those of the rule named for it; a bad rule name is refused."""
    from jkatana.render.caps import _cap_rule_terms, cap_rule_for
    from jkatana.models.lobes import GaussianVCavity

    r = math.radians(1.0)
    env, _, _ = build_environment(np.ones((16, 32, GRID.size)), grid=GRID)
    caps = Caps(jnp.asarray(SUN_DIR[None], jnp.float32), jnp.asarray([r], jnp.float32),
                jnp.ones((1, env.channels.shape[-1]), jnp.float32))
    env = dataclasses.replace(env, caps=caps)
    P = 5
    f32 = jnp.float32
    px = Pixels(jnp.zeros((P, 3), f32), jnp.tile(jnp.asarray([0.0, 0.0, 1.0], f32), (P, 1)),
                jnp.tile(jnp.asarray([0.0, 0.0, 1.0], f32), (P, 1)), jnp.full((P,), 0.5, f32),
                jnp.full((P,), 0.02, f32), jnp.full((P,), 0.3, f32))  # widths 0.034 < 8 r = 0.14 < 0.51
    plan = Plan(mode="prefiltered", samples=1)
    assert cap_rule_for(plan, env, px) == "nodes,stroud"
    assert cap_rule_for(plan, env, px._replace(mu0=px.mu1)) == "stroud"
    assert cap_rule_for(plan, env, px._replace(mu1=px.mu0)) == "nodes"
    th = np.radians([0.0, 15.0, 30.0, 45.0, 60.0])
    Vl = jnp.asarray(np.stack([np.sin(th), 0 * th, np.cos(th)], -1), f32)
    fr = tuple(jnp.tile(jnp.asarray(e, f32), (P, 1)) for e in np.eye(3))
    C = jnp.asarray([-0.3, 0.0, 0.954], f32)
    C = C / jnp.linalg.norm(C)
    lobes = [(Gaussian(px.mu0), px.w, None), (GaussianVCavity(px.mu1), 1.0 - px.w, None)]
    mixed = _cap_rule_terms(lobes, Vl, fr, C, jnp.asarray(r, f32), "nodes,stroud")
    nodes = _cap_rule_terms(lobes, Vl, fr, C, jnp.asarray(r, f32), "nodes")
    stroud = _cap_rule_terms(lobes, Vl, fr, C, jnp.asarray(r, f32), "stroud")
    assert len(mixed) == len(nodes) == len(stroud) == 2
    np.testing.assert_array_equal(np.asarray(mixed[0][0]), np.asarray(nodes[0][0]))
    np.testing.assert_array_equal(np.asarray(mixed[1][0]), np.asarray(stroud[1][0]))
    assert not np.array_equal(np.asarray(nodes[0][0]), np.asarray(stroud[0][0]))  # the two rules differ there
    with pytest.raises(ValueError, match="lobe parts"):
        _cap_rule_terms(lobes, Vl, fr, C, jnp.asarray(r, f32), "nodes,stroud,nodes")


@pytest.mark.slow
def test_cap_pixels_leave_out_only_pixels_the_cap_cannot_reach():
    """:func:`cap_pixels` keeps a pixel iff its mirror direction lies within ``r + 6σ`` of the cap's centre
    (σ the widest lobe part the pixel weighs on), and every pixel it leaves out has a cap term (the 64-node
    rule) below 1e-7 of the glint's peak; a lobe part of weight 0 does not widen the reach."""
    from jkatana.models.microfacet import gaussian_normalisation
    from jkatana.render.caps import CAP_REACH, _cap_rule_terms, cap_pixels

    f32 = jnp.float32
    r, mu0, mu1 = math.radians(0.5), 0.02, 0.2
    env, _, _ = build_environment(np.ones((16, 32, GRID.size)), grid=GRID)
    env = dataclasses.replace(env, caps=Caps(jnp.asarray([[0.0, 0.0, 1.0]], f32), jnp.asarray([r], f32),
                                             jnp.ones((1, env.channels.shape[-1]), f32)))
    # normal +z, views in the xz plane: the mirror direction lies ψ = |θ_V| from the cap at the zenith
    psi = np.linspace(0.0, 0.9, 721)
    P = len(psi)
    V = np.stack([np.sin(psi), 0 * psi, np.cos(psi)], -1)
    px = Pixels(jnp.zeros((P, 3), f32), jnp.tile(jnp.asarray([[0.0, 0.0, 1.0]], f32), (P, 1)), jnp.asarray(V, f32),
                jnp.ones((P,), f32), jnp.full((P,), mu0, f32), jnp.full((P,), mu1, f32))
    plan = Plan(mode="prefiltered", samples=1, hiraji=True, hamon=True)
    near = np.asarray(cap_pixels(plan, env, px))  # w = 1: the hamon part weighs nothing
    reach = r + CAP_REACH * mu0 * math.sqrt(2.0 / math.log(2.0))
    assert near[psi < reach - 1e-4].all() and not near[psi > reach + 1e-4].any()
    assert not near.all() and near.any()
    wide = np.asarray(cap_pixels(plan, env, px._replace(w=jnp.full((P,), 0.5, f32))))
    assert wide.all()  # the hamon part (σ = 0.34) reaches every pixel of the sweep
    fr = tuple(jnp.tile(jnp.asarray(e, f32), (P, 1)) for e in np.eye(3))
    lobe = Gaussian(px.mu0, gaussian_normalisation(px.mu0))
    (a, _), = _cap_rule_terms([(lobe, px.w, None)], px.view, fr, jnp.asarray([0.0, 0.0, 1.0], f32),
                              jnp.asarray(r, f32), "nodes")
    a = np.asarray(a, np.float64)
    assert a.max() > 0 and a[~near].max() <= 1e-7 * a.max()
    assert a[near].min() > 0  # inside the reach the tail is still there


@pytest.mark.slow
def test_caps_on_their_own_pass_equal_the_one_pass(sun_map, monkeypatch):
    """A prefiltered frame whose caps are shaded on their own pass over the pixels :func:`cap_pixels` keeps
    (a narrow lobe on a sphere: a few of them) equals the frame shading them in the one pass with the
    environment, to float32 rounding."""
    from jkatana.render import dispatch
    from jkatana.render.caps import cap_pixels

    env, fac, _ = build_environment(sun_map, grid=GRID, split_sun=True, prefilter_mus=(0.02, 0.1))
    plan = Plan(mode="prefiltered", samples=1, hiraji=True, hamon=False, factored=fac)
    mat, maps = _iron(), _maps(1.0, 0.03, 0.15)
    px = _sphere_pixels()
    narrow = px._replace(w=jnp.ones_like(px.w), mu0=jnp.full_like(px.w, 0.03))  # the maps' pixels
    share = float(np.asarray(cap_pixels(plan, env, narrow)).mean())
    assert 0.0 < share < 0.5
    monkeypatch.setattr(dispatch, "CAP_PASS_MAX", 1.0)
    apart = render_frame(plan, mat, env, None, SPHERE, CAM, maps, CMF)
    monkeypatch.setattr(dispatch, "CAP_PASS_MAX", -1.0)
    one = render_frame(plan, mat, env, None, SPHERE, CAM, maps, CMF)
    m = one.mask
    assert np.asarray(one.xyz[m][:, 1]).max() > 10 * np.median(one.xyz[m][:, 1])  # the glint is in the frame
    np.testing.assert_allclose(apart.xyz, one.xyz, rtol=2e-6, atol=2e-6 * float(one.xyz.max()))


@pytest.mark.parametrize("mode, field, caps", [
    ("reference", None, 0), ("reference", True, 1), ("prefiltered", None, 1), ("prefiltered", False, 0)])
def test_the_scenes_split_sun_field_decides_the_split(mode, field, caps, tmp_path):
    """``render.split_sun``: unset, the mode's default (reference keeps the whole map, prefiltered splits);
    ``true``/``false`` override it. ``render.env_window`` reaches the plan. A sky with its sun at 64 × 128
    (the sun is compact there); the scene written back reads as the same scene."""
    from jkatana.render.renderer import prepare
    import tomllib

    from jkatana.render.scenefile import load_scene, scene_from_dict, scene_to_toml

    text = sphere_scene(8, 8, 1, spectral=(400.0, 700.0, 20.0)).replace("resolution = [16, 32]", "resolution = [64, 128]")
    extra = f'mode = "{mode}"\nenv_window = 2\n' + ("" if field is None else f"split_sun = {str(field).lower()}\n")
    (tmp_path / "scene.toml").write_text(text.replace("[render]\n", "[render]\n" + extra))
    scene = load_scene(tmp_path / "scene.toml")
    assert scene.render.split_sun is field and scene.render.env_window == 2.0
    assert scene_from_dict(tomllib.loads(scene_to_toml(scene)), tmp_path / "scene.toml") == scene
    prep = prepare(scene)
    assert prep.env_info["caps"] == caps
    assert prep.plan.env_window == 2.0
    assert prepare(scene, split_sun=not caps).env_info["caps"] == 1 - caps   # the argument wins over the field
