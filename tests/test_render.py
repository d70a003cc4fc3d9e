"""Reference renderer: physics checks (furnace, mirror), modes, effects on demand, gradients, files, bad input."""

from __future__ import annotations

import json
import textwrap
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.models import Conductor
from jkatana.render.camera import Camera
from jkatana.render.film import film_weights
from jkatana.render.frame import render_frame
from jkatana.render.gbuffer import gbuffer_sphere
from jkatana.render.scenefile import load_scene, scene_from_dict, scene_to_toml
from jkatana.render.environment import build_environment
from jkatana.render.fresnel_fold import Material, fresnel_table
from jkatana.render.plan import Plan
from jkatana.spectral import DEFAULT_GRID

GRID = DEFAULT_GRID
CMF = film_weights(GRID)
SPHERE = ("sphere", (0.0, 0.0, 0.0), 1.0)


def _mat(dtype=jnp.float32, source="Fe-Johnson"):
    c = Conductor.from_table(source, GRID, dtype=dtype)
    return Material(fresnel_table(c.n, c.k), jnp.asarray(79000.0, dtype), jnp.asarray(43000.0, dtype)), c


def _cam(n=24):
    return Camera(position=(0.0, 0.0, 4.0), fov_deg=32.0, width=n, height=n)


def _maps(w, mu0, mu1):
    return np.array([[[w, mu0, mu1]]], np.float32).repeat(2, 0).repeat(2, 1)


def _sky(res=(32, 64)):
    from jkatana.light.sky import hosek_wilkie_sky

    return np.asarray(hosek_wilkie_sky(35.0, 160.0, 3.0, 0.1, res, GRID, sun_supersampling=4).radiance)


def _xyz_of(spectrum):
    return np.asarray(spectrum) @ CMF


# ----------------------------------------------------------------- physics


def test_mirror_sphere_in_white_furnace_shows_fresnel():
    """Perfect-mirror hiraji in a constant environment: each pixel is F(cos θv) exactly (no sampling)."""
    mat, c = _mat()
    env, factored, _ = build_environment(np.ones((8, 16, GRID.size), np.float32))
    assert factored and env.channels.shape[-1] == 1  # grey → one band
    plan = Plan(mode="reference", samples=4, hiraji=True, hamon=False, mirror=True, factored=True)
    cam = _cam()
    f = render_frame(plan, mat, env, None, SPHERE, cam, _maps(1.0, 0.0, 0.05), CMF)
    gb = gbuffer_sphere(cam)
    cos_v = np.sum(gb.normal * gb.view, -1)[gb.mask]
    expect = _xyz_of(np.asarray(c.fresnel(jnp.asarray(cos_v))))
    np.testing.assert_allclose(f.xyz[gb.mask], expect, rtol=2e-4, atol=1e-6)
    assert f.stats["pixels_shaded"] == gb.mask.sum() > 100


@pytest.mark.parametrize("mode", [pytest.param("reference", marks=pytest.mark.slow), "paper", "prefiltered"])
def test_rough_lobe_in_furnace_is_close_to_fresnel(mode):
    """Normalised lobe (μ = 0.05) in a white furnace: ∫ f cos dω ≈ F(θv) (energy within a few %, never > 1)."""
    mat, c = _mat()
    env_rad = np.ones((32, 64, GRID.size), np.float32)
    mus = (0.04, 0.05, 0.06) if mode == "prefiltered" else ()
    env, factored, _ = build_environment(env_rad, prefilter_mus=mus, prefilter_resolution=64)
    plan = Plan(mode=mode, samples=64, hiraji=True, hamon=True, factored=factored)
    cam = _cam()
    f = render_frame(plan, mat, env, None, SPHERE, cam, _maps(0.5, 0.05, 0.05), CMF)
    gb = gbuffer_sphere(cam)
    cos_v = np.sum(gb.normal * gb.view, -1)[gb.mask]
    inner = cos_v > 0.5  # away from grazing, where the lobe is cut by the horizon
    Y = f.xyz[gb.mask][inner, 1]
    F_Y = _xyz_of(np.asarray(c.fresnel(jnp.asarray(cos_v[inner]))))[:, 1]
    ratio = Y / F_Y
    assert np.all(np.isfinite(Y))
    assert abs(np.median(ratio) - 1) < 0.03, np.median(ratio)
    assert np.all(ratio < 1.2)  # per-pixel Monte Carlo noise at 64 spp; the median above is the energy check


@pytest.mark.slow
def test_factored_grey_equals_full_spectral():
    """A grey environment shaded as one band equals the 61-band path (same samples)."""
    mat, _ = _mat()
    sky = _sky()
    grey = sky.mean(-1, keepdims=True) * np.ones(GRID.size, np.float32)
    env_f, fac, _ = build_environment(grey)
    env_full, _, _ = build_environment(grey, rank=None)
    assert fac
    from jkatana.render.environment import Environment

    env_full = Environment(jnp.asarray(grey), jnp.eye(GRID.size, dtype=jnp.float32), env_f.rotation,
                           env_f.sampler, env_f.prefiltered, env_f.prefilter_mus)
    kw = dict(mode="reference", samples=8, hiraji=True, hamon=True)
    a = render_frame(Plan(**kw, factored=True), mat, env_f, None, SPHERE, _cam(16), _maps(0.5, 0.05, 0.08), CMF)
    b = render_frame(Plan(**kw, factored=False), mat, env_full, None, SPHERE, _cam(16), _maps(0.5, 0.05, 0.08), CMF)
    np.testing.assert_allclose(a.xyz, b.xyz, rtol=2e-3, atol=1e-5 * b.xyz.max())


@pytest.mark.slow
def test_reference_converges_and_modes_agree_with_it():
    """Error vs a 256-spp frame falls with samples; paper/prefiltered/lowrank land near the reference."""
    mat, _ = _mat()
    sky = _sky()
    env, _, _ = build_environment(sky)
    maps = _maps(0.5, 0.05, 0.08)
    cam = _cam(20)

    def frame(plan, e=env, seed=0):
        return render_frame(plan, mat, e, None, SPHERE, cam, maps, CMF, seed=seed)

    ref = frame(Plan(samples=256), seed=99)
    m = ref.mask
    err = lambda f: np.mean(np.abs(f.xyz[m, 1] - ref.xyz[m, 1])) / np.mean(ref.xyz[m, 1])  # noqa: E731
    e4, e64 = err(frame(Plan(samples=4))), err(frame(Plan(samples=64)))
    assert e64 < 0.5 * e4, (e4, e64)
    assert e64 < 0.05
    env_lr, fac, resid = build_environment(sky, rank=3)
    assert fac and resid < 0.02
    assert err(frame(Plan(mode="lowrank", samples=64, factored=True), env_lr)) < 0.06
    assert err(frame(Plan(mode="paper", samples=30))) < 0.15
    env_pf, _, _ = build_environment(sky, prefilter_mus=(0.04, 0.06, 0.09), prefilter_resolution=64)
    assert err(frame(Plan(mode="prefiltered"), env_pf)) < 0.2


@pytest.mark.slow
def test_point_light_matches_analytic_brdf():
    """A point light on a black environment: pixel = f cos θi · I / r² from the models' brdf_cos."""
    from jkatana.models import Hiraji
    from jkatana.render.plan import Light

    mat, _ = _mat(jnp.float32)
    env, fac, _ = build_environment(np.zeros((4, 8, GRID.size), np.float32) + 1e-20)
    pos = np.array([0.5, 0.4, 3.0])
    spec = np.ones(GRID.size)
    lights = Light(jnp.asarray([pos], jnp.float32), jnp.asarray([0.0], jnp.float32), jnp.asarray([spec], jnp.float32))
    plan = Plan(samples=1, hiraji=True, hamon=False, lights=1, factored=fac, env_sampling=True)
    cam = _cam(16)
    f = render_frame(plan, mat, env, lights, SPHERE, cam, _maps(1.0, 0.3, 0.3), CMF)
    gb = gbuffer_sphere(cam)
    P, N, V = gb.position[gb.mask], gb.normal[gb.mask], gb.view[gb.mask]
    Lw = pos - P
    r2 = np.sum(Lw**2, -1)
    Lw /= np.sqrt(r2)[:, None]
    from jkatana.models.geometry import tangent_frame, to_local

    t, b = tangent_frame(jnp.asarray(N))
    Ll, Vl = to_local(jnp.asarray(Lw), t, b, jnp.asarray(N)), to_local(jnp.asarray(V), t, b, jnp.asarray(N))
    fc = np.asarray(Hiraji(79000.0, 0.3).brdf_cos(Ll, Vl, Conductor.from_table("Fe-Johnson", GRID)))  # float64
    expect = _xyz_of(fc / r2[:, None])
    got = f.xyz[gb.mask]
    big = expect[:, 1] > 1e-3 * expect[:, 1].max()
    np.testing.assert_allclose(got[big], expect[big], rtol=2e-3)  # float32 shading vs float64 model


# ----------------------------------------------------------------- effects on demand


def test_effects_on_demand_are_static_choices(tmp_path):
    from jkatana.render.renderer import prepare

    raw = {"geometry": {"sphere": {"radius": 1.0}}, "material": {"w": 1.0, "mu0": 0.0, "mu1": 0.05},
           "environment": {"type": "constant", "radiance": 2.0}, "camera": {"type": "lookat",
           "position": [0, 0, 4], "look_at": [0, 0, 0], "resolution": [8, 8]}}
    p = prepare(scene_from_dict(raw))
    assert p.plan.mirror and not p.plan.hamon and p.plan.lights == 0  # mirror-only: no lobe, no T–S
    assert p.env_info["channels"] == 1  # grey environment → one band
    raw["material"] = {"w": 0.0, "mu1": 0.1}
    raw["environment"] = {"type": "sky", "resolution": [16, 32]}
    raw["lights"] = [{"type": "directional", "direction": [0, 1, 1]}]
    p = prepare(scene_from_dict(raw))
    assert p.plan.hamon and not p.plan.hiraji and p.plan.lights == 1
    assert p.env_info["channels"] == GRID.size


def test_prepare_overrides_are_checked_like_the_scene():
    from jkatana.render.renderer import prepare

    scene = scene_from_dict({"geometry": {"sphere": {"radius": 1.0}}, "material": {"w": 1.0}})
    for kw, field in (({"samples": 0}, "samples"), ({"samples": 10**9}, "samples"), ({"mode": "fast"}, "mode")):
        with pytest.raises(InputError) as err:
            prepare(scene, **kw)
        assert err.value.field == field


# ----------------------------------------------------------------- gradients


@pytest.mark.slow  # ~25 s CPU (float64 compile of value and gradient); runs in CI
def test_gradient_matches_finite_differences():
    """d(frame)/d(μ map, χ, environment) against central differences, float64, common random numbers."""
    from jkatana.render.frame import sample_map
    from jkatana.render.plan import Pixels
    from jkatana.render.shading import shade

    mat, _ = _mat(jnp.float64)
    sky = _sky((16, 32)).astype(np.float64)
    env, _, _ = build_environment(sky, dtype=jnp.float64)
    cam = _cam(10)
    gb = gbuffer_sphere(cam)
    m = gb.mask.reshape(-1)
    uv = jnp.asarray(gb.uv.reshape(-1, 2)[m])
    plan = Plan(samples=4, hiraji=True, hamon=True, calibration=1.0e5)
    cmf = jnp.asarray(CMF)
    key = jax.random.PRNGKey(3)

    @jax.jit
    def loss(maps, chi, channels):
        mp = sample_map(maps, uv)
        px = Pixels(jnp.asarray(gb.position.reshape(-1, 3)[m]), jnp.asarray(gb.normal.reshape(-1, 3)[m]),
                    jnp.asarray(gb.view.reshape(-1, 3)[m]), mp[:, 0], mp[:, 1], mp[:, 2])
        e = type(env)(channels, env.basis, env.rotation, env.sampler, env.prefiltered, env.prefilter_mus)
        xyz, _ = shade(plan, Material(mat.ftable, chi, mat.beta), e, None, px, cmf, key)
        return jnp.sum(xyz[:, 1])

    maps = jnp.asarray(_maps(0.6, 0.06, 0.08), jnp.float64)
    chi = jnp.asarray(79000.0)
    g_maps, g_chi, g_env = jax.grad(loss, argnums=(0, 1, 2))(maps, chi, env.channels)
    assert all(np.all(np.isfinite(np.asarray(g))) for g in (g_maps, g_chi, g_env))
    h = 1e-6
    for idx in [(0, 0, 1), (1, 1, 2), (0, 1, 0)]:
        d = jnp.zeros_like(maps).at[idx].set(h)
        fd = (loss(maps + d, chi, env.channels) - loss(maps - d, chi, env.channels)) / (2 * h)
        np.testing.assert_allclose(g_maps[idx], fd, rtol=1e-4, atol=1e-9 * abs(float(loss(maps, chi, env.channels))))
    fd = (loss(maps, chi * (1 + 1e-6), env.channels) - loss(maps, chi * (1 - 1e-6), env.channels)) / (2e-6 * chi)
    np.testing.assert_allclose(g_chi, fd, rtol=1e-5)
    j = np.unravel_index(np.argmax(np.abs(np.asarray(g_env))), g_env.shape)
    d = jnp.zeros_like(env.channels).at[j].set(1e-3)
    fd = (loss(maps, chi, env.channels + d) - loss(maps, chi, env.channels - d)) / 2e-3
    np.testing.assert_allclose(g_env[j], fd, rtol=1e-5)


# ----------------------------------------------------------------- scene files and bad input


def _write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


SMALL = """
[geometry]
sphere = {radius = 1.0}
[material]
w = 0.5
mu0 = 0.05
mu1 = 0.08
[environment]
type = "sky"
resolution = [16, 32]
[camera]
type = "lookat"
position = [0, 0, 4]
look_at = [0, 0, 0]
fov_deg = 35
resolution = [24, 18]
[render]
samples = 4
[output]
directory = "out"
name = "f"
"""


def test_scene_roundtrip_and_outputs(tmp_path):
    from jkatana.io.exr import read_exr
    from jkatana.render.renderer import prepare, render_view, write_outputs

    scene = load_scene(_write(tmp_path, SMALL))
    prep = prepare(scene)
    frame = render_view(prep)
    paths = write_outputs(prep, frame, tmp_path / "out" / "f")
    ch, hdr = read_exr(paths["exr"])
    assert set("XYZ") <= set(ch) and ch["X"].shape == (18, 24)
    assert np.allclose(ch["Y"], frame.xyz[..., 1])
    assert hdr["jkatana_samples"] == 4 and hdr["jkatana_mode"] == "reference"
    assert "shade_s" in json.loads(hdr["jkatana_timing"])
    assert scene_from_dict(tomllib.loads(hdr["jkatana_scene"]), scene.path) == scene  # the scene as TOML
    from PIL import Image

    im = Image.open(paths["png"])
    assert im.size == (24, 18) and im.text["jkatana_mode"] == "reference"


def test_spectral_output_of_a_mesh(tmp_path):
    """Spectral output with a mesh (whose G-buffer holds its camera rays lazily): the frame's spectra and
    its background are written, and the spectra integrate to the frame's XYZ."""
    from jkatana.render.renderer import prepare, render_view

    text = (SMALL.replace('name = "f"', 'name = "f"\nspectral = true')
            .replace("sphere = {radius = 1.0}", 'mesh = "builtin:katana"')
            .replace("position = [0, 0, 4]", "position = [0.35, 0, 1.5]")    # the blade's centre, face on
            .replace("look_at = [0, 0, 0]", "look_at = [0.35, 0, 0]"))
    frame = render_view(prepare(load_scene(_write(tmp_path, text))))
    assert frame.spectra is not None and frame.spectra.shape == (18, 24, GRID.size)
    assert frame.mask.sum() > 0  # the blade covers pixels: its spectra, not only the background's
    assert np.isfinite(frame.spectra).all() and frame.spectra[frame.mask].max() > 0
    np.testing.assert_allclose(frame.spectra @ CMF, frame.xyz, rtol=1e-4, atol=1e-6 * frame.xyz.max())


def test_spectral_exr_on_request(tmp_path):
    from jkatana.light.spectral_exr import is_spectral_exr, read_spectral_exr
    from jkatana.render.renderer import prepare, render_view, write_outputs

    scene = load_scene(_write(tmp_path, SMALL.replace('name = "f"', 'name = "f"\nspectral = true')))
    prep = prepare(scene)
    frame = render_view(prep)
    assert frame.spectra is not None and frame.spectra.shape == (18, 24, GRID.size)
    paths = write_outputs(prep, frame, tmp_path / "out" / "f")
    assert is_spectral_exr(paths["spectral"])
    back = read_spectral_exr(paths["spectral"], GRID)
    np.testing.assert_allclose(back, frame.spectra, rtol=1e-5, atol=1e-6 * frame.spectra.max())
    # the XYZ file is the film of the same spectra
    np.testing.assert_allclose(frame.spectra @ CMF, frame.xyz, rtol=1e-4, atol=1e-6 * frame.xyz.max())


@pytest.mark.parametrize("text, field", [
    ("[camera\nfov_deg = 3", None),                                                    # malformed TOML
    ("[material]\nmap = 'nope.exr'", "material.map"),                                  # missing file
    ("[film]\ncolourspace = 'sRGGB'", "film.colourspace"),                             # unknown colourspace
    ("[camera]\nresolution = [0, 600]", "camera.resolution"),                          # zero-area camera
    ("[render]\nmode = 'fast'", "render.mode"),
    ("[render]\nsamples = -3", "render.samples"),
    ("[environment]\ntype = 'exr'\npath = 'missing.exr'", "environment.path"),
    ("[camera]\nfovv = 3", "camera.fovv"),
    ("[lighting]\nx = 1", "lighting"),
])
def test_bad_scene_gives_one_clear_error(tmp_path, text, field):
    p = _write(tmp_path, text)
    with pytest.raises(InputError) as err:
        load_scene(p)
    assert str(tmp_path) in str(err.value)  # names the file (the scene, or the missing one)
    if field:
        assert err.value.field == field
    else:
        assert "malformed TOML" in str(err.value)


@pytest.mark.parametrize("text, field", [
    ("[output]\nspectral = 'false'", "output.spectral"),                              # a string is not a bool
    ("[environment]\nsun = 'false'", "environment.sun"),
    ("[environment]\nsun = 0", "environment.sun"),
    ("[render]\nsamples = 4.0", "render.samples"),                                   # ints are ints
    ("[render]\nsamples = true", "render.samples"),
    ("[render]\nsamples = 100000000", "render.samples"),                             # bounded
    ("[render]\nseed = -1", "render.seed"),
    ("[render]\nmode = 'lowrank'\nrank = 64", "render.rank"),                        # > 61 wavelengths
    ("[render]\nmode = 'lowrank'\nrank = 40\n[environment]\nresolution = [4, 8]", "render.rank"),
    ("[camera]\nresolution = [100000, 600]", "camera.resolution"),
    ("[camera]\nresolution = [800.0, 600]", "camera.resolution"),
    ("[camera]\nfov_deg = 180", "camera.fov_deg"),
    ("[environment]\nresolution = [100000, 100000]", "environment.resolution"),
    ("[environment]\nresolution = [4096, 4096]", "environment.resolution"),           # 8 GiB of float64
    ("[environment]\ntype = 'constant'\nresolution = [0, 8]", "environment.resolution"),
    ("[spectral]\nstep = 0.001", "spectral.step"),                                   # 300001 wavelengths
    ("[spectral]\nstep = 7.0", "spectral.step"),                                     # not a whole number of steps
    ("[spectral]\nstart = 100.0", "spectral.start"),                                 # outside the CMFs' domain
    ("[film]\nexposure = nan", "film.exposure"),
    ("[film]\nexposure = true", "film.exposure"),
    ("[[lights]]\nposition = [0, 1, 0]\nspectrum = 'D99'", "lights[0].spectrum"),
    ("[[lights]]\nposition = [0, 1, 0]\nspectrum = 100", "lights[0].spectrum"),
    ("[output]\nname = '..'", "output.name"),
])
def test_scene_types_and_ranges_are_strict(tmp_path, text, field):
    with pytest.raises(InputError) as err:
        load_scene(_write(tmp_path, text))
    assert err.value.field == field and str(tmp_path) in str(err.value)


def test_scene_is_typed_and_its_toml_text_reads_back(tmp_path):
    """Every section is a typed dataclass; scene_to_toml writes TOML that validates to the same scene."""
    text = SMALL + textwrap.dedent("""
        [[lights]]
        type = "directional"
        direction = [0, 1, 1]
        spectrum = 5000
        [[occluders]]
        sphere = 0.2
        center = [1, 0, 0]
        [film]
        transfer = 2.2
        exposure = 0.5
        """)
    scene = load_scene(_write(tmp_path, text))
    assert scene.render.samples == 4 and isinstance(scene.render.samples, int)
    assert scene.environment.sun is True and scene.output.spectral is False
    assert scene.material.uniform.mu1 == 0.08 and scene.lights[0].spectrum == 5000.0
    assert scene.spectral.grid.size == GRID.size and scene.occluders[0].radius == 0.2
    back = scene_from_dict(tomllib.loads(scene_to_toml(scene)), scene.path)
    assert back == scene
    moved = scene.with_output_directory(tmp_path / "elsewhere")
    assert moved.output.directory == tmp_path / "elsewhere" and scene.output.directory == tmp_path / "out"


def test_the_typed_scene_does_not_import_its_reader():
    """``jkatana.render.scene`` (the dataclasses) has no module-level import of ``jkatana.render.scenefile``
    (which imports it: no cycle); the reader's names are still reachable from it, as the reader's objects."""
    import ast
    import inspect

    import jkatana.render.scene as S
    import jkatana.render.scenefile as F

    tree = ast.parse(inspect.getsource(S))
    top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    names = [a.name for n in top for a in n.names] + [n.module for n in top if isinstance(n, ast.ImportFrom)]
    assert not any("scenefile" in (m or "") for m in names), names
    from jkatana.render.scene import DEMO_SCENE, default_scene, load_scene, scene_from_dict

    assert (load_scene, scene_from_dict, default_scene, DEMO_SCENE) == (F.load_scene, F.scene_from_dict,
                                                                       F.default_scene, F.DEMO_SCENE)
    with pytest.raises(AttributeError):
        S.no_such_name



def test_zero_area_and_degenerate_cameras():
    with pytest.raises(InputError, match="resolution"):
        Camera(width=0, height=10)
    with pytest.raises(InputError, match="look_at"):
        Camera(position=(1, 1, 1), look_at=(1, 1, 1))
    with pytest.raises(InputError, match="parallel"):
        Camera(position=(0, 2, 0), look_at=(0, 0, 0), up=(0, 1, 0))


def test_map_size_mismatch_is_refused(tmp_path):
    """A map transposed w.r.t. the blade's UV domain (rows along instead of across) is an input error."""
    from jkatana.maps.reflectance_map import ReflectanceMap
    from jkatana.render.renderer import prepare

    bad = ReflectanceMap.uniform((64, 16), w=1.0)
    bad.write(tmp_path / "map.exr")
    scene = load_scene(_write(tmp_path, "[material]\nmap = 'map.exr'\n[camera]\nresolution = [8, 6]"))
    with pytest.raises(InputError, match="does not match") as err:
        prepare(scene)
    assert err.value.field == "material.map" and "map.exr" in str(err.value)


def test_region_parameter_file_sets_mu(tmp_path):
    from jkatana.render.renderer import prepare

    (tmp_path / "hamon.json").write_text(json.dumps({
        "format": "jkatana-params/1", "region": "hamon", "model": "hamon",
        "values": {"beta": 40000.0, "mu": 0.12}, "optical_constants": "Fe-Johnson", "converged": True}))
    scene = load_scene(_write(tmp_path, SMALL.replace("mu1 = 0.08", "mu1 = 0.08\nhamon = 'hamon.json'")
                              .replace("w = 0.5\n", "")))
    prep = prepare(load_scene(_write(tmp_path, "[material]\nhamon = 'hamon.json'\n[camera]\nresolution = [8, 6]",
                                     "s2.toml")))
    w = prep.maps[..., 0]
    assert np.isclose(np.median(prep.maps[..., 2][w < 1]), 0.12, rtol=0.05)
    assert float(prep.material.beta) == 40000.0
    assert scene.material.hamon.name == "hamon.json"


def test_example_scene_validates():
    from pathlib import Path

    import jkatana.render

    scene = load_scene(Path(jkatana.render.__file__).parent / "example_scene.toml")
    assert scene.render.mode == "reference" and scene.camera.resolution == (400, 300)
