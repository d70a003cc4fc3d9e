"""The renderer renders the lobe a parameter file names: GGX, GTR, two-lobe, Beckmann as well as the paper's.

A sphere rendered in reference mode under a two-band environment (bright above
the horizon, dim below: the band edge crosses the lobes of the pixels that
mirror the horizon, so the lobe's shape and tails decide their value) is
compared with an independent quadrature of the same lobe (half-vector polar
grid, Gauss–Legendre in a width-adapted angle) within the Monte-Carlo bound
estimated from two renders with different seeds.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.fit._model import FIT_MODELS, MODELS, ModelSpec, from_natural, green, prepare as prepare_terms
from jkatana.models.lobes import lobe_from_params
from jkatana.models.lobe_id import LobeId, normalised_params
from jkatana.render.renderer import camera_for, prepare, render_view
from jkatana.render.scenefile import load_scene

#: Natural values of every fit model (widths where the lobes differ visibly on a sphere).
VALUES = {"hiraji": {"chi": 79000.0, "mu": 0.05}, "hamon": {"beta": 43000.0, "mu": 0.1},
          "beckmann": {"scale": 2000.0, "alpha": 0.08}, "ggx": {"scale": 2000.0, "alpha": 0.05},
          "gtr": {"scale": 2000.0, "alpha": 0.05, "gamma": 1.5},
          "two-lobe": {"scale": 2000.0, "alpha": 0.03, "alpha_haze": 0.3, "weight": 0.8}}

SCENE = """
[geometry]
sphere = {{radius = 1.0}}
[material]
w = {w}
mu0 = 0.04
mu1 = 0.06
{regions}
[environment]
type = "constant"
radiance = 1.0
resolution = [16, 32]
[camera]
type = "lookat"
position = [0, 0, 4]
look_at = [0, 0, 0]
fov_deg = 32
resolution = [{res}, {res}]
[render]
mode = "{mode}"
samples = {samples}
[output]
directory = "out"
name = "f"
"""


def params_dict(model: str, values: dict | None = None, region: str = "hiraji") -> dict:
    """A parameter file as ``jkatana fit`` writes it (its ``lobe`` from the fit model's own ``build``)."""
    values = dict(VALUES[model] if values is None else values)
    fm = FIT_MODELS[model]
    lobe = fm.build(jnp.asarray(fm.shape_from_natural(values))).to_params()
    return {"format": "jkatana-params/1", "region": region, "model": model, "lobe": lobe, "values": values,
            "optical_constants": "Fe-Johnson", "converged": True}


def write_scene(tmp_path, *, hiraji=None, hamon=None, w=1.0, mode="reference", samples=16, res=9):
    regions = []
    for region, d in (("hiraji", hiraji), ("hamon", hamon)):
        if d is not None:
            (tmp_path / f"{region}.json").write_text(json.dumps(d))
            regions.append(f'{region} = "{region}.json"')
    p = tmp_path / "scene.toml"
    p.write_text(textwrap.dedent(SCENE.format(w=w, regions="\n".join(regions), mode=mode, samples=samples, res=res)))
    return p


# ----------------------------------------------------------------- the plan records the file's lobe


@pytest.mark.parametrize("model", [m for m in MODELS if m not in ("hiraji", "hamon")])
def test_plan_records_the_lobe_and_rebuilds_it_at_the_fitted_width(tmp_path, model):
    d = params_dict(model)
    prep = prepare(load_scene(write_scene(tmp_path, hiraji=d)))
    key = prep.plan.hiraji_lobe
    assert key is not None and key.family == d["lobe"]["lobe"] and prep.plan.hamon_lobe is None
    hash(prep.plan)  # hashable: part of the compile key
    width = float(np.median(prep.maps[..., 1]))
    assert width == pytest.approx(LobeId.shape_of(d["lobe"])[0], rel=1e-6)
    rebuilt = key.at_width(jnp.float64(width), jnp.float64).to_params()
    assert _close(rebuilt, lobe_from_params(d["lobe"], jnp.float64).to_params())
    assert float(prep.material.chi) == pytest.approx(d["values"]["scale"])  # the calibrated scale s


def _close(a, b):
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, (bool, str)) or a is None:
        return a == b
    return np.allclose(a, b, rtol=1e-6)


def test_paper_files_keep_the_paper_path(tmp_path):
    prep = prepare(load_scene(write_scene(tmp_path, hiraji=params_dict("hiraji"),
                                          hamon=params_dict("hamon", region="hamon"), w=0.5)))
    assert prep.plan.hiraji_lobe is None and prep.plan.hamon_lobe is None
    assert float(np.median(prep.maps[..., 1])) == pytest.approx(0.05)
    assert float(np.median(prep.maps[..., 2])) == pytest.approx(0.1)


# ----------------------------------------------------------------- wrong combinations: one line


@pytest.mark.parametrize("mode", ["paper", "paper-published"])
def test_non_paper_lobe_in_a_paper_mode_is_refused(tmp_path, mode):
    scene = load_scene(write_scene(tmp_path, hiraji=params_dict("ggx"), mode=mode))
    with pytest.raises(InputError) as e:
        prepare(scene)
    msg = str(e.value)
    assert "\n" not in msg and "material.hiraji" in msg and "'ggx'" in msg
    assert "reference, lowrank, prefiltered" in msg and "tails" in msg  # the modes that work, and why not this one


def test_paper_file_in_the_other_region_is_refused(tmp_path):
    scene = load_scene(write_scene(tmp_path, hiraji=params_dict("hamon", region="hamon")))
    with pytest.raises(InputError, match="material.hiraji"):
        prepare(scene)


def test_bad_lobe_entry_is_refused(tmp_path):
    d = params_dict("ggx")
    d["lobe"] = {"lobe": "ggx", "alpha": 0.05, "sharpness": 2.0}
    with pytest.raises(InputError, match=r"material.hiraji \(lobe\)"):
        prepare(load_scene(write_scene(tmp_path, hiraji=d)))


def test_interactive_view_takes_the_lobe_of_a_parameter_file(tmp_path):
    """``jkatana view`` of a scene whose hiraji file holds a GTR lobe: the interactive scene carries that lobe
    (normalised, rebuilt at any width) for the bake's tables, the hamon the paper's, the map the fitted width."""
    from jkatana.interactive.scene import from_render_scene
    from jkatana.models.lobes import GTR, GaussianVCavity
    from jkatana.models.lobe_id import LobeId

    d = params_dict("gtr")
    text = write_scene(tmp_path, hiraji=d).read_text()
    text = text.replace("sphere = {radius = 1.0}", 'mesh = "builtin:katana"').replace(
        "w = 1.0\nmu0 = 0.04\nmu1 = 0.06\n", "")
    (tmp_path / "scene.toml").write_text(text)
    sc = from_render_scene(tmp_path / "scene.toml")
    hiraji, hamon = sc.lobes
    assert hamon is GaussianVCavity
    width = LobeId.shape_of(d["lobe"])[0]
    lobe = hiraji(jnp.float64(width))
    assert isinstance(lobe, GTR) and float(lobe.alpha) == pytest.approx(width)
    assert float(np.median(sc.refl_map[..., 1])) == pytest.approx(width, rel=1e-6)


def test_cli_prints_one_line_and_exits_2(tmp_path):
    scene = write_scene(tmp_path, hiraji=params_dict("two-lobe"), mode="paper")
    r = subprocess.run([sys.executable, "-m", "jkatana.cli", "render", str(scene)], capture_output=True,
                       text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "'mixture'" in lines[0] and "material.hiraji" in lines[0], r.stderr


# ----------------------------------------------------------------- rendered value = quadrature of the lobe

A_UP, B_DOWN, ENV_H = 1.0, 0.1, 64


def two_band(grid_size: int) -> np.ndarray:
    """Equirect map (row 0 = zenith): radiance A above the horizon, B below, flat spectra."""
    rad = np.full((ENV_H, 2 * ENV_H, grid_size), B_DOWN, np.float32)
    rad[: ENV_H // 2] = A_UP
    return rad


def band_value(y):
    """The renderer's bilinear lookup of :func:`two_band` at world direction y (linear across one texel row)."""
    theta = np.arccos(np.clip(y, -1.0, 1.0))
    d = np.pi / ENV_H
    t = np.clip((theta - (np.pi / 2 - d / 2)) / d, 0.0, 1.0)
    return A_UP + (B_DOWN - A_UP) * t


def quadrature_y(params: dict, N: np.ndarray, V: np.ndarray, conductor, cmf, n_t=192, n_phi=96) -> float:
    """Y of ∫ f_r cos θi F L_env dω at one point, by a polar grid of half vectors about N.

    θh = α t/(1 − t) with t on Gauss–Legendre nodes (dense where the lobe is, reaching
    its tails), φ uniform; dω_L = 4 (V·h) dω_h. The lobe is the normalised form of the
    file's lobe (the renderer's convention without calibration).
    """
    lobe = lobe_from_params(normalised_params(params), jnp.float64)
    alpha = LobeId.shape_of(params)[0]
    t_max = (np.pi / 2) / (np.pi / 2 + alpha)
    x, wx = np.polynomial.legendre.leggauss(n_t)
    t = 0.5 * t_max * (x + 1)
    wt = 0.5 * t_max * wx
    th = alpha * t / (1 - t)
    dth = wt * alpha / (1 - t) ** 2
    ph = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    # local frame about N (any: the lobe is isotropic)
    a = np.array([1.0, 0.0, 0.0]) if abs(N[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    tx = np.cross(a, N)
    tx /= np.linalg.norm(tx)
    ty = np.cross(N, tx)
    Vl = np.array([V @ tx, V @ ty, V @ N])
    s, c = np.sin(th)[:, None], np.cos(th)[:, None]
    h = np.stack([s * np.cos(ph), s * np.sin(ph), np.broadcast_to(c, (n_t, n_phi))], -1)
    vh = h @ Vl
    Ll = 2 * vh[..., None] * h - Vl
    w = np.where(vh > 0, 4 * vh * np.sin(th)[:, None] * dth[:, None] * (2 * np.pi / n_phi), 0.0)
    f = np.asarray(lobe.brdf_cos(jnp.asarray(Ll), jnp.asarray(np.broadcast_to(Vl, Ll.shape)), conductor))
    Ly = Ll @ np.stack([tx, ty, N])[:, 1]  # world y of L
    spec = np.einsum("ab,ab,abl->l", w, band_value(Ly), f)
    return float(spec @ np.asarray(cmf, np.float64)[:, 1])


def sphere_pixels(scene):
    """Normal and view direction of every pixel that sees the unit sphere (pinhole through pixel centres)."""
    o, d = camera_for(scene).rays()
    b = d @ o
    disc = b * b - (o @ o - 1.0)
    hit = disc > 0
    t = -b - np.sqrt(np.where(hit, disc, 0.0))
    p = o + t[..., None] * d
    return hit, p, -d


def render_vs_quadrature(tmp_path, d, quad_params=None, samples=64):
    """``(z over all pixels, z over the horizon band, ratio)`` of render − quadrature in Monte-Carlo units."""
    from jkatana.models.reflectance import Conductor

    scene = load_scene(write_scene(tmp_path, hiraji=d, samples=samples, res=15))
    prep = prepare(scene, env_radiance=two_band(scene.spectral.grid.size))
    y = np.stack([render_view(prep, seed=s).xyz[..., 1].astype(np.float64) for s in (0, 1)])
    hit, P, V = sphere_pixels(scene)
    cos_v = np.sum(P * V, -1)
    sel = hit & (cos_v > 0.5)
    conductor = Conductor.from_table("Fe-Johnson", scene.spectral.grid, dtype=jnp.float64)
    width = float(np.median(prep.maps[..., 1]))
    params = d["lobe"] if quad_params is None else quad_params
    scaled = (LobeId.shape_of(params)[1]).at_width(jnp.float64(width), jnp.float64).to_params()
    q = np.array([quadrature_y(scaled, P[i, j], V[i, j], conductor, prep.cmf) for i, j in zip(*np.nonzero(sel))])
    m = y.mean(0)[sel]
    r = m - q
    var = ((y[0] - y[1])[sel] ** 2) / 4.0  # variance of the two-render mean, from their difference
    # the deterministic allowance: Fresnel table and float32 shading (1e-3 of the value)
    allow = 1e-3 * np.abs(q)
    band = np.abs((2 * np.sum(P * V, -1)[..., None] * P - V)[..., 1])[sel] < 0.15  # mirrors near the horizon
    z = lambda k: (np.abs(r[k].sum()) - allow[k].sum()) / np.sqrt(var[k].sum())  # noqa: E731
    return z(np.ones_like(band)), z(band), float(m.sum() / q.sum())


@pytest.mark.slow
@pytest.mark.parametrize("model", ["ggx", "gtr", "two-lobe"])
def test_sphere_equals_quadrature_of_the_lobe(tmp_path, model):
    z_all, z_band, ratio = render_vs_quadrature(tmp_path, params_dict(model))
    assert z_all < 4.0 and z_band < 4.0, (model, z_all, z_band, ratio)


@pytest.mark.slow
def test_the_comparison_tells_lobes_apart(tmp_path):
    """The same statistic rejects the paper's Gaussian as the quadrature of a rendered two-lobe file."""
    gauss = {"lobe": "gaussian", "mu": 0.03, "scale": 1.0, "normalised": False}
    _, z_band, _ = render_vs_quadrature(tmp_path, params_dict("two-lobe"), quad_params=gauss)
    assert z_band > 5.0, z_band  # acceptance is < 4


# ----------------------------------------------------------------- fit → params file → render, every lobe


@pytest.mark.slow
@pytest.mark.parametrize("model", MODELS)
def test_every_lobe_round_trips_fit_to_render(tmp_path, model):
    """``fit_region`` on a synthetic table of the lobe → ``write_params`` → the renderer's plan and maps hold
    the fitted lobe (class, static parameters, width) and a frame renders finite."""
    from jkatana.fit import FitData, Setup, fit_region
    from jkatana.fit.params import write_params
    from jkatana.measure.protocol import Protocol, as_pairs

    jax.config.update("jax_enable_x64", True)
    setup = Setup()
    n, k = setup.nk()
    pairs = np.asarray(as_pairs(Protocol(incidences_deg=(25.0, 45.0))), np.float64)
    ti, tr = pairs[:, 0], pairs[:, 1]
    spec = ModelSpec(model)
    m = np.asarray(green(jnp.asarray(from_natural(VALUES[model], spec)), prepare_terms(model, ti, tr, n, k,
                                                                                       setup.weights()), spec))
    sig = 0.02 * m + 1e-3 * m.max()
    y = m + sig * np.random.default_rng(1).standard_normal(m.size)
    region = "hamon" if model == "hamon" else "hiraji"
    fit = fit_region(FitData(ti, tr, y, sig, region=region), model=model, per_incidence=False, robust=False)
    write_params(fit, tmp_path / f"{region}.json")
    d = json.loads((tmp_path / f"{region}.json").read_text())
    scene = write_scene(tmp_path, **{region: d}, w=1.0 if region == "hiraji" else 0.0, samples=4)
    prep = prepare(load_scene(scene))
    key = getattr(prep.plan, f"{region}_lobe")
    ch = 1 if region == "hiraji" else 2
    width = float(np.median(prep.maps[..., ch]))
    if model in ("hiraji", "hamon"):
        assert key is None and width == pytest.approx(fit.values["mu"], rel=1e-6)
    else:
        assert key == LobeId.shape_of(d["lobe"])[1]
        assert width == pytest.approx(fit.values["alpha"], rel=1e-6)
        assert _close(key.at_width(jnp.float64(width), jnp.float64).to_params(),
                      lobe_from_params(d["lobe"], jnp.float64).to_params())
    f = render_view(prep)
    assert np.isfinite(f.xyz).all() and f.xyz[f.mask].max() > 0


# ----------------------------------------------------------------- prefiltered mode: each region's own levels


@pytest.mark.parametrize("model", ["ggx", "two-lobe"])
def test_prefiltered_mode_builds_levels_of_the_region_lobe(tmp_path, model):
    from jkatana.render.environment import lobe_albedo

    scene = load_scene(write_scene(tmp_path, hiraji=params_dict(model), hamon=params_dict("hamon", region="hamon"),
                                   w=0.5, mode="prefiltered", res=7))
    prep = prepare(scene, env_radiance=two_band(scene.spectral.grid.size))
    env = prep.env
    M = len(env.prefiltered)
    assert len(env.lobe_prefiltered) == 2 and len(env.lobe_prefiltered[0]) == M and env.lobe_prefiltered[1] == ()
    # the region's levels carry its lobe's albedo: a constant map's level is albedo × the map
    key = prep.plan.hiraji_lobe.rendered(None)
    mu = float(env.prefilter_mus[0])
    flat = np.asarray(env.lobe_prefiltered[0][0])[0, 0] / np.asarray(env.prefiltered[0])[0, 0]  # zenith row: A_UP
    np.testing.assert_allclose(flat, lobe_albedo(key, mu), rtol=1e-4)
    f = render_view(prep)
    assert np.isfinite(f.xyz).all() and f.xyz[f.mask, 1].min() > 0


def test_paper_lobe_albedo_is_one_and_paper_files_build_no_levels(tmp_path):
    """The normalised paper lobe carries albedo 1 at normal incidence (what the paper's prefiltered path
    assumes), so a region's own levels (albedo included) are on the same footing; paper files add none."""
    from jkatana.models.lobes import Gaussian
    from jkatana.models.lobe_id import LobeId
    from jkatana.render.environment import lobe_albedo

    key = LobeId.shape_of(Gaussian(jnp.float64(0.05), normalised=True).to_params())[1]
    assert lobe_albedo(key, 0.05) == pytest.approx(1.0, abs=2e-3)
    scene = load_scene(write_scene(tmp_path, hiraji=params_dict("hiraji"), mode="prefiltered", res=7))
    assert prepare(scene, env_radiance=two_band(scene.spectral.grid.size)).env.lobe_prefiltered == ()


def prefiltered_vs_reference(tmp_path, d, own_levels=True):
    """``(Y ratio prefiltered/reference over the pixels seen at cos θv > 0.5, max |relative error| over those of
    them that mirror the horizon band)`` on the sphere under :func:`two_band` (reference: 2 × 256 spp)."""
    import dataclasses

    scene = load_scene(write_scene(tmp_path, hiraji=d, samples=256, res=15))
    env = two_band(scene.spectral.grid.size)
    ref = np.mean([render_view(prepare(scene, env_radiance=env), seed=s).xyz[..., 1] for s in (0, 1)], 0)
    prep = prepare(scene, mode="prefiltered", env_radiance=env)
    if not own_levels:  # the paper's Gaussian levels in the region's place
        prep.env = dataclasses.replace(prep.env, lobe_prefiltered=(prep.env.prefiltered, ()))
    y = render_view(prep).xyz[..., 1]
    hit, P, V = sphere_pixels(scene)
    cos_v = np.sum(P * V, -1)
    sel = hit & (cos_v > 0.5)
    band = sel & (np.abs((2 * cos_v[..., None] * P - V)[..., 1]) < 0.15)
    return float(y[sel].sum() / ref[sel].sum()), float(np.max(np.abs(y[band] / ref[band] - 1)))


@pytest.mark.slow
@pytest.mark.parametrize("model", ["ggx", "two-lobe"])
def test_prefiltered_sphere_matches_the_reference_for_any_lobe(tmp_path, model):
    """The split sum with the region's own lobe against the reference mode (256 spp × 2, MC noise ≈ 0.3 %).

    Bound: the split sum evaluates the lobe at normal incidence (N = V = R; Karis 2013). Its error grows with
    width × tan θv (the lobe stretches and its albedo falls at oblique views, Smith G), so only pixels seen at
    cos θv > 0.5 are held to it: the frame's Y within 1.5 % and every pixel that mirrors the horizon (where
    the band edge crosses the lobe, so its shape and tails decide the value) within 4 %. Measured: GGX
    0.1 % / 0.5 %, two-lobe 0.5 % / 1.7 %; the paper's Gaussian on the same sphere 0.06 % / 0.3 %.
    """
    ratio, band = prefiltered_vs_reference(tmp_path, params_dict(model))
    assert abs(ratio - 1.0) < 0.015 and band < 0.04, (model, ratio, band)


@pytest.mark.slow
def test_prefiltered_comparison_tells_lobes_apart(tmp_path):
    """The paper's Gaussian levels in place of the two-lobe's own fail the same bound (the haze is lost)."""
    ratio, band = prefiltered_vs_reference(tmp_path, params_dict("two-lobe"), own_levels=False)
    assert abs(ratio - 1.0) > 0.015 or band > 0.04, (ratio, band)
