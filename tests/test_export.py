"""``jkatana export``: Mitsuba 3 and pbrt-v4 scenes out of a jkatana scene.

The everyday tests read the files back by their formats' rules (XML, the pbrt-v4 text, RGL tables through
:mod:`jkatana.brdf.rgl`) and check the command's refusals; the ``mitsuba`` tests load the exported files in
Mitsuba 3 itself, and the slow ones render them there against ``jkatana render``'s reference mode
(:mod:`validation.export_mitsuba`).
"""

from __future__ import annotations

import copy
import json
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from jkatana.errors import InputError  # noqa: E402
from jkatana.export.commands import export_scene  # noqa: E402
from jkatana.export.scene import resolve  # noqa: E402
from jkatana.render.scenefile import DEMO_SCENE, load_scene, scene_from_dict  # noqa: E402
from tests._scenes import CLI, cli_env  # noqa: E402

#: Natural values of the parameter files used here (as ``jkatana fit`` writes them).
VALUES = {"ggx": {"scale": 2000.0, "alpha": 0.06}, "beckmann": {"scale": 2000.0, "alpha": 0.08},
          "two-lobe": {"scale": 2000.0, "alpha": 0.08, "alpha_haze": 0.3, "weight": 0.8}}


def params_file(path: Path, model: str, region: str) -> Path:
    """A parameter file as ``jkatana fit`` writes it: its ``lobe`` built by the fit model itself."""
    import jax.numpy as jnp

    from jkatana.models.fitted import FIT_MODELS

    fm = FIT_MODELS[model]
    lobe = fm.build(jnp.asarray(fm.shape_from_natural(VALUES[model]))).to_params()
    path.write_text(json.dumps({"format": "jkatana-params/1", "region": region, "model": model, "lobe": lobe,
                                "values": VALUES[model], "optical_constants": "Fe-Johnson", "converged": True}))
    return path


def sphere_ggx(tmp_path, *, env=None, rotation=0.0) -> Path:
    """A GGX sphere (uniform material, hiraji from a parameter file) under a small sky: no table to write."""
    params_file(tmp_path / "ggx.json", "ggx", "hiraji")
    env = env or 'type = "sky"\nresolution = [16, 32]'
    p = tmp_path / "scene.toml"
    p.write_text(f"""
[geometry]
sphere = {{radius = 1.0}}
[material]
w = 1.0
mu0 = 0.05
mu1 = 0.1
hiraji = "ggx.json"
[environment]
{env}
rotation_deg = {rotation}
[camera]
type = "orbit"
target = [0, 0, 0]
distance = 4.0
fov_deg = 35
resolution = [48, 32]
[render]
samples = 8
[output]
directory = "out"
name = "f"
""")
    return p


# ------------------------------------------------------------------------------------- the command


def _run(*args, cwd):
    return subprocess.run([*CLI, "export", *map(str, args)], capture_output=True, text=True, env=cli_env(),
                          cwd=cwd, timeout=600)


def test_export_refuses_an_existing_folder_and_a_missing_asset_in_one_line(tmp_path):
    scene = sphere_ggx(tmp_path)
    out = tmp_path / "mi"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    r = _run(scene, "--to", "mitsuba", "-o", out, cwd=tmp_path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "exists" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"] and (out / "keep.txt").read_text() == "mine"
    # a scene naming a parameter file that is not there: one line naming it, and no output folder
    text = scene.read_text().replace('hiraji = "ggx.json"', 'hiraji = "gone.json"')
    scene.write_text(text)
    r = _run(scene, "--to", "mitsuba", "-o", tmp_path / "out_mitsuba", cwd=tmp_path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "gone.json" in r.stderr, r.stderr
    assert not (tmp_path / "out_mitsuba").exists()
    for target in ("pbrt", "gltf"):  # the same refusal from the other writers (in process: one CLI start is enough)
        with pytest.raises(InputError, match="gone.json") as err:
            export_scene(load_scene(scene), target, tmp_path / f"out_{target}")
        assert len(str(err.value).splitlines()) == 1 and not (tmp_path / f"out_{target}").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out_")]  # no temporary left behind


def test_export_refuses_a_lobe_gltf_cannot_express_and_writes_nothing(tmp_path):
    """glTF's metallic-roughness material is one GGX lobe of roughness ≤ 1: a two-lobe hamon whose haze is
    wider than that is refused, naming the region; Mitsuba and pbrt tabulate it instead."""
    scene = sphere_ggx(tmp_path)
    VALUES["two-lobe-wide"] = {"scale": 2000.0, "alpha": 0.5, "alpha_haze": 2.5, "weight": 0.3}
    try:
        import jax.numpy as jnp

        from jkatana.models.fitted import FIT_MODELS

        fm = FIT_MODELS["two-lobe"]
        lobe = fm.build(jnp.asarray(fm.shape_from_natural(VALUES["two-lobe-wide"]))).to_params()
        (tmp_path / "wide.json").write_text(json.dumps({
            "format": "jkatana-params/1", "region": "hiraji", "model": "two-lobe", "lobe": lobe,
            "values": VALUES["two-lobe-wide"], "optical_constants": "Fe-Johnson", "converged": True}))
    finally:
        VALUES.pop("two-lobe-wide")
    scene.write_text(scene.read_text().replace('hiraji = "ggx.json"', 'hiraji = "wide.json"'))
    with pytest.raises(InputError) as err:
        export_scene(load_scene(scene), "gltf", tmp_path / "g")
    assert "hiraji" in str(err.value) and not (tmp_path / "g").exists()


# ------------------------------------------------------------------------------------------ Mitsuba


def test_mitsuba_xml_holds_the_scene(tmp_path):
    """The XML names a ``roughconductor`` GGX of the file's α with iron's η, k on 360–830 nm, the sky as an
    ``envmap`` turned by 180° − rotation about +Y, a perspective camera with the scene's vertical field of
    view; every file it names is in the folder."""
    scene = load_scene(sphere_ggx(tmp_path, rotation=30.0))
    summary = export_scene(scene, "mitsuba", tmp_path / "mi", spp=16)
    root = ET.parse(tmp_path / "mi" / "scene.xml").getroot()
    assert root.tag == "scene" and root.get("version") == "3.0.0"
    bsdf = root.find("shape/bsdf")
    assert bsdf.get("type") == "roughconductor"
    assert bsdf.find("string[@name='distribution']").get("value") == "ggx"
    assert float(bsdf.find("float[@name='alpha']").get("value")) == pytest.approx(VALUES["ggx"]["alpha"], rel=1e-6)
    eta = [tuple(map(float, s.split(":"))) for s in bsdf.find("spectrum[@name='eta']").get("value").split(",")]
    assert eta[0][0] == 360 and eta[-1][0] == 830 and all(1.9 < v < 3.0 for _, v in eta)  # iron's n (Johnson & Christy 1974)
    env = root.find("emitter[@type='envmap']")
    m = np.array(env.find("transform/matrix").get("value").split(), float).reshape(4, 4)
    a = np.radians(150.0)
    np.testing.assert_allclose(m[:3, :3], [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]],
                               atol=1e-8)
    sensor = root.find("sensor")
    assert float(sensor.find("float[@name='fov']").get("value")) == 35.0
    assert sensor.find("string[@name='fov_axis']").get("value") == "y"
    assert sensor.find("sampler/integer[@name='sample_count']").get("value") == "16"
    for el in root.iter("string"):
        if el.get("name") == "filename":
            assert (tmp_path / "mi" / el.get("value")).is_file()
    assert json.loads((tmp_path / "mi" / "export.json").read_text())["regions"]["hiraji"]["lobe"] == "ggx"
    assert summary["scene"] == "scene.xml"


@pytest.mark.slow
def test_exported_table_takes_the_camera_side_as_incident(tmp_path):
    """The paper's hiraji lobe is not reciprocal; its exported table returns f(ωi = V, ωo = L) — the lobe's
    value with V the camera — and not the swapped pair (by up to ×1.5 at 60° off normal here)."""
    import jax.numpy as jnp

    from jkatana.brdf.rgl import read_rgl
    from jkatana.export.scene import EXPORT_WAVELENGTHS
    from jkatana.export.tabulate import lobe_table
    from jkatana.models.reflectance import Conductor

    raw = copy.deepcopy(DEMO_SCENE)
    raw["material"] = {"optical_constants": "Fe-Johnson", "w": 1.0, "mu0": 0.12, "mu1": 0.2}
    res = resolve(scene_from_dict(raw))
    hi = res.regions["hiraji"]
    from jkatana.brdf.rgl import write_rgl

    write_rgl(lobe_table(hi, res.n, res.k, EXPORT_WAVELENGTHS), tmp_path / "h.bsdf")
    table = read_rgl(tmp_path / "h.bsdf")
    th_v, th_l = np.radians([10.0, 30.0, 60.0, 45.0]), np.radians([18.0, 22.0, 50.0, 58.0])
    V = np.stack([np.sin(th_v), 0 * th_v, np.cos(th_v)], -1)
    L = np.stack([-np.sin(th_l), 0 * th_l, np.cos(th_l)], -1)
    lam = 550.0
    cond = Conductor(jnp.asarray([np.interp(lam, EXPORT_WAVELENGTHS, res.n)]),
                     jnp.asarray([np.interp(lam, EXPORT_WAVELENGTHS, res.k)]))
    f = lambda l, v: np.asarray(hi.lobe.brdf_cos(jnp.asarray(l), jnp.asarray(v), cond))[:, 0] / l[:, 2]  # noqa: E731
    got = table.eval(V, L, f"{lam:g}nm")
    np.testing.assert_allclose(got, f(L, V), rtol=0.02)
    assert np.max(np.abs(f(V, L) / f(L, V) - 1)) > 0.2  # the swapped pair is another value


@pytest.mark.mitsuba
def test_mitsuba_loads_the_export_and_its_table_equals_the_lobe(tmp_path):
    """Mitsuba 3 loads the exported XML; its ``measured`` eval of the exported hiraji table at (si.wi = V,
    wo = L) is the renderer's lobe × Fresnel, f·cos θL, at three wavelengths within the table's interpolation
    (median relative error ≤ 1 %, p95 ≤ 5 % over the lobe's core)."""
    import jax.numpy as jnp

    from jkatana.export.scene import EXPORT_WAVELENGTHS
    from jkatana.models.reflectance import Conductor
    from validation import formats
    from validation.mitsuba import mitsuba_variant

    variant = mitsuba_variant()
    if variant is None:
        pytest.skip("Mitsuba 3 is not installed (the mitsuba extra)")
    raw = copy.deepcopy(DEMO_SCENE)
    raw["camera"]["resolution"] = [40, 30]
    scene = scene_from_dict(raw)
    export_scene(scene, "mitsuba", tmp_path / "mi", spp=4)
    code = ("import mitsuba as mi, sys; mi.set_variant(sys.argv[1]); s = mi.load_file(sys.argv[2]); "
            "print(len(s.shapes()), len(s.emitters()))")
    r = subprocess.run([__import__("sys").executable, "-c", code, variant, str(tmp_path / "mi" / "scene.xml")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split()[0] == "2"  # the blade and the sun's cap
    res = resolve(scene)
    hi = res.regions["hiraji"]
    rng = np.random.default_rng(3)
    V = rng.normal(size=(1000, 3))
    V[:, 2] = np.abs(V[:, 2]) + 0.3
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    L = V * np.array([-1, -1, 1]) + rng.normal(size=V.shape) * hi.width / 2
    L[:, 2] = np.abs(L[:, 2])
    L /= np.linalg.norm(L, axis=1, keepdims=True)
    for lam in (450.0, 550.0, 650.0):
        mi = formats.mitsuba_measured_eval(tmp_path / "mi" / "hiraji.bsdf", V, L, variant, wavelengths=[lam])[:, 0]
        cond = Conductor(jnp.asarray([np.interp(lam, EXPORT_WAVELENGTHS, res.n)]),
                         jnp.asarray([np.interp(lam, EXPORT_WAVELENGTHS, res.k)]))
        fcos = np.asarray(hi.lobe.brdf_cos(jnp.asarray(L), jnp.asarray(V), cond))[:, 0]  # f·cos θL
        core = fcos > 0.2 * np.percentile(fcos, 99)
        assert core.sum() > 100
        err = np.abs(mi[core] / fcos[core] - 1)
        assert np.median(err) <= 0.01 and np.percentile(err, 95) <= 0.05, (lam, np.median(err))


def _agreement(tmp_path, scene, spp_mitsuba, spp_jkatana):
    from validation.export_mitsuba import agreement
    from validation.mitsuba import mitsuba_variant

    if mitsuba_variant() is None:
        pytest.skip("Mitsuba 3 is not installed (the mitsuba extra)")
    return agreement(scene, tmp_path / "mi", spp_mitsuba=spp_mitsuba, spp_jkatana=spp_jkatana, supersample=4)


@pytest.mark.slow
@pytest.mark.mitsuba
def test_mitsuba_renders_the_exported_demo_scene_as_jkatana_does(tmp_path):
    """(a) The built-in demo scene (blade, map, the paper's lobes, sky with its sun): Mitsuba's frame of the
    export against jkatana's reference mode, ΔE2000 mean ≤ 0.5, p95 ≤ 2 on the blade's pixels."""
    raw = copy.deepcopy(DEMO_SCENE)
    raw["camera"]["resolution"] = [200, 150]
    r = _agreement(tmp_path, scene_from_dict(raw), 1024, 64)
    print({k: v for k, v in r.items() if not isinstance(v, np.ndarray)})
    assert r["dE2000_mean"] <= 0.5 and r["dE2000_p95"] <= 2.0, r


@pytest.mark.slow
@pytest.mark.mitsuba
def test_mitsuba_renders_an_exported_blade_with_ggx_and_two_lobe_fits_under_an_hdr(tmp_path):
    """(b) The built-in blade with a GGX hiraji and a two-lobe hamon (parameter files as ``jkatana fit``
    writes them) under ``sunrise.exr`` (its sun split off as a cap): ΔE2000 mean ≤ 0.5, p95 ≤ 2."""
    from jkatana.shared import shared_data

    raw = copy.deepcopy(DEMO_SCENE)
    raw["camera"]["resolution"] = [200, 150]
    raw["material"] = {"map": "builtin", "optical_constants": "Fe-Johnson",
                       "hiraji": str(params_file(tmp_path / "ggx.json", "ggx", "hiraji")),
                       "hamon": str(params_file(tmp_path / "two.json", "two-lobe", "hamon"))}
    raw["environment"] = {"type": "exr", "path": str(shared_data("envmaps", "sunrise.exr")), "rotation_deg": 40.0}
    r = _agreement(tmp_path, scene_from_dict(raw), 1024, 64)
    print({k: v for k, v in r.items() if not isinstance(v, np.ndarray)})
    assert r["dE2000_mean"] <= 0.5 and r["dE2000_p95"] <= 2.0, r


@pytest.mark.slow
@pytest.mark.mitsuba
def test_mitsuba_renders_an_exported_scan_with_a_uniform_beckmann_material(tmp_path):
    """(c) The hammer scan through ``jkatana shape`` (metres, xatlas UVs) with a uniform Beckmann material under
    a sky without its sun: ΔE2000 mean ≤ 0.5, p95 ≤ 2 on the pixels whose reflected lobe the hammer does not
    shadow itself (:func:`validation.export_mitsuba.self_shadowed`: jkatana casts no shadow rays against the
    rendered object, Mitsuba does; they are under 15 % of the hammer's pixels here, around the stamped logo's
    recess, and there the frames do differ)."""
    import trimesh

    from jkatana.shared import shared_data
    from validation.export_mitsuba import self_shadowed
    from validation.mitsuba import compare

    ply = tmp_path / "hammer.ply"
    r = subprocess.run([*CLI, "shape", str(shared_data("scans", "hammer", "hammer.obj")), "-o", str(ply),
                        "--uv", "xatlas"], capture_output=True, text=True, env=cli_env(), timeout=600)
    assert r.returncode == 0, r.stderr
    lo, hi = trimesh.load(ply, process=False).bounds
    centre = ((lo + hi) / 2).tolist()
    raw = {"geometry": {"mesh": str(ply)},
           "material": {"optical_constants": "Fe-Johnson", "w": 1.0, "mu0": 0.05, "mu1": 0.1,
                        "hiraji": str(params_file(tmp_path / "beckmann.json", "beckmann", "hiraji"))},
           "environment": {"type": "sky", "elevation_deg": 40.0, "azimuth_deg": 120.0, "sun": False,
                           "resolution": [128, 256]},
           "camera": {"type": "orbit", "target": centre, "distance": 0.085, "azimuth_deg": 30.0,
                      "elevation_deg": 20.0, "fov_deg": 40.0, "resolution": [160, 120]},
           "output": {"directory": str(tmp_path / "out"), "name": "hammer"}}
    scene = scene_from_dict(raw, tmp_path)
    res = _agreement(tmp_path, scene, 1024, 64)
    shadowed = self_shadowed(scene, res["mask"].shape, cone=3 * VALUES["beckmann"]["alpha"] * np.sqrt(2))
    keep = res["mask"] & ~shadowed
    assert keep.sum() > 0.85 * res["mask"].sum()
    stats = compare(res["jkatana"], res["mitsuba"], keep, erode=1)
    print({"all": {k: v for k, v in res.items() if not isinstance(v, np.ndarray)}, "unshadowed": stats})
    assert stats["dE2000_mean"] <= 0.5 and stats["dE2000_p95"] <= 2.0, stats


# --------------------------------------------------------------------------------------------- pbrt


def test_pbrt_scene_names_its_assets_and_its_environment_is_equal_area(tmp_path):
    """The pbrt-v4 text holds the GGX conductor with roughness = α unremapped, the camera flip, an infinite
    light of a square image and the sun as a far spherical area light; the image is the sky resampled by
    the equal-area mapping with the light's +z on the world's +Y: its radiance-weighted mean direction lies
    above the horizon due east (+X), towards the sun (elevation 60°, east), where the sun's sphere is."""
    from jkatana.export.pbrt import equal_area_square_to_sphere
    from jkatana.io.exr import read_exr

    scene = load_scene(sphere_ggx(tmp_path, env='type = "sky"\nresolution = [64, 128]\nelevation_deg = 60.0\n'
                                                  'azimuth_deg = 90.0'))
    export_scene(scene, "pbrt", tmp_path / "pb", spp=16)
    text = (tmp_path / "pb" / "scene.pbrt").read_text()
    assert "Scale -1 1 1" in text and 'Camera "perspective"' in text and "WorldBegin" in text
    assert f'"float roughness" {VALUES["ggx"]["alpha"]:.7g} "bool remaproughness" false' in text
    assert '"integer pixelsamples" [ 16 ]' in text
    assert 'LightSource "infinite" "string filename" "environment_equalarea.exr"' in text
    assert (tmp_path / "pb" / "environment_equalarea.exr").is_file()

    def elevation_azimuth(d):
        d = np.asarray(d, np.float64) / np.linalg.norm(d)
        return np.degrees(np.arcsin(d[1])), np.degrees(np.arctan2(d[0], -d[2]))  # azimuth from −Z towards +X

    sun = [ln for ln in text.splitlines() if ln.strip().startswith("Translate")][0].split()[1:]
    el, az = elevation_azimuth([float(x) for x in sun])
    assert abs(el - 60.0) < 1.0 and abs(az - 90.0) < 1.0
    ch, _ = read_exr(tmp_path / "pb" / "environment_equalarea.exr")
    y = ch["R"] + ch["G"] + ch["B"]
    n = y.shape[0]
    assert y.shape == (n, n)
    c = (np.arange(n) + 0.5) / n
    d = equal_area_square_to_sphere(*np.meshgrid(c, c, indexing="xy"))
    world = np.stack([d[..., 0], d[..., 2], -d[..., 1]], -1)  # the light's frame turned −90° about x
    mean = (world * y[..., None]).sum((0, 1))  # texels are equal in solid angle: a radiance-weighted mean
    el, az = elevation_azimuth(mean)
    assert 5.0 < el < 80.0 and abs(az - 90.0) < 10.0, (el, az)
    assert y[world[..., 1] > 0.2].mean() > 1.5 * y[world[..., 1] < -0.2].mean()  # sky above, dark ground
    # the mapping is area preserving: a uniform grid of the square lands uniformly on the sphere
    g = (np.arange(64) + 0.5) / 64
    d = equal_area_square_to_sphere(*np.meshgrid(g, g, indexing="xy")).reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    assert abs(d[:, 2].mean()) < 1e-3 and abs(np.mean(d[:, 2] > 0.5) - 0.25) < 0.01


def test_a_mitsuba_roughconductor_imports_as_a_parameter_file(tmp_path):
    """A ``roughconductor`` back as a ``jkatana-params/1`` file: one written by hand as Mitsuba's documentation
    writes it (named material, Beckmann by default), one from jkatana's own export (η, k spectra → the
    shipped iron table, ΔE 0), and the refusals (anisotropic, a metal jkatana does not ship), one line each."""
    from jkatana.export.mitsuba import roughconductor_to_params
    from jkatana.fit.params import params_from_dict

    hand = tmp_path / "hand.xml"
    hand.write_text('<scene version="3.0.0"><shape type="sphere"><bsdf type="twosided" id="steel">'
                    '<bsdf type="roughconductor"><string name="material" value="Cr"/>'
                    '<float name="alpha" value="0.15"/></bsdf></bsdf></shape></scene>')
    d = roughconductor_to_params(hand, bsdf_id="steel")
    assert d["model"] == "beckmann" and d["values"]["alpha"] == 0.15 and d["optical_constants"] == "Cr-Johnson"
    assert params_from_dict(d).model == "beckmann"
    export_scene(load_scene(sphere_ggx(tmp_path)), "mitsuba", tmp_path / "mi")
    back = roughconductor_to_params(tmp_path / "mi" / "scene.xml", region="hamon")
    assert back["model"] == "ggx" and back["values"]["alpha"] == pytest.approx(VALUES["ggx"]["alpha"], rel=1e-7)
    assert back["optical_constants"] == "Fe-Johnson" and back["import"]["optical_constants_dE2000"] < 1e-6
    for body, why in (('<float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/>', "anisotropic"),
                      ('<string name="material" value="Au"/>', "no shipped optical constants")):
        bad = tmp_path / "bad.xml"
        bad.write_text(f'<scene version="3.0.0"><bsdf type="roughconductor">{body}</bsdf></scene>')
        with pytest.raises(InputError, match=why) as err:
            roughconductor_to_params(bad)
        assert len(str(err.value).splitlines()) == 1 and "bad.xml" in str(err.value)
