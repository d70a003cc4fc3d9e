"""glTF 2.0 export (:mod:`jkatana.export.gltf`): what trimesh reads back, what pyrender's own shader draws.

The oracles are independent of the exporter: trimesh's glTF reader (mesh, UVs,
material, texture), colour-science's ``sd_to_XYZ`` for the base colour, the
renderer's own map lookup for the texture's orientation, and pyrender's stock
metallic-roughness shader against ``jkatana render`` (reference mode) for the
look (:mod:`validation.gltf_agreement`).
"""

from __future__ import annotations

import json
import struct
import textwrap

import numpy as np
import pytest

from jkatana.errors import InputError
from jkatana.export.gltf import export_gltf
from jkatana.render.scenefile import load_scene
from validation import gltf_agreement as GA


def _glb_json(path) -> dict:
    """The JSON chunk of a ``.glb`` (glTF 2.0 §4.4: 12-byte header, then chunk length, type, data)."""
    data = path.read_bytes()
    assert data[:4] == b"glTF" and struct.unpack("<I", data[4:8])[0] == 2
    length, kind = struct.unpack("<I4s", data[12:20])
    assert kind == b"JSON"
    return json.loads(data[20:20 + length])


def _uniform_scene(tmp_path, body: str = "", *, mu1: float = 0.2, w: float = 0.0):
    p = tmp_path / "scene.toml"
    p.write_text(textwrap.dedent(f"""
        [geometry]
        sphere = {{radius = 1.0}}
        [material]
        w = {w}
        mu0 = 0.05
        mu1 = {mu1}
        {body}
        [environment]
        type = "constant"
        radiance = 1.0
        resolution = [4, 8]
        [output]
        directory = "out"
        name = "ball"
        """))
    return load_scene(p)


@pytest.fixture(scope="module")
def ggx_blade(tmp_path_factory):
    """The built-in blade and map with a GGX fit in both regions, exported once."""
    folder = tmp_path_factory.mktemp("ggx")
    GA.write_params(folder)
    view, light = GA.views()["glint"]
    scene = load_scene(GA.write_scene_toml(folder / "scene.toml", GA.scene_dict(view, light, folder)))
    return scene, export_gltf(scene, folder / "gltf")


def test_trimesh_reads_back_the_mesh_uvs_and_material(ggx_blade):
    """trimesh's reader gives the renderer's mesh (vertices, normals, UVs) and the material written: the
    exact float base colour and roughnessFactor in the file, G·factor = √α per texel to 8 bits, B = 1, in
    the orientation in which the renderer's map lookup reads the map (trimesh: image row 0 at v = 1)."""
    import jax.numpy as jnp
    import trimesh

    from jkatana.export.gltf import texel_alpha
    from jkatana.render.frame import sample_map
    from jkatana.render.renderer import load_geometry, load_material

    scene, summary = ggx_blade
    glb = summary["glb"]
    tm = trimesh.load(str(glb), process=False)
    (mesh,) = tm.geometry.values()
    blade = load_geometry(scene)
    np.testing.assert_allclose(mesh.vertices, blade.vertices, atol=1e-6)      # float32 in the file
    np.testing.assert_array_equal(mesh.faces, blade.faces)
    np.testing.assert_allclose(mesh.vertex_normals, blade.vertex_normals, atol=1e-6)
    np.testing.assert_allclose(mesh.visual.uv, blade.visual.uv, atol=1e-6)
    mat = mesh.visual.material
    assert isinstance(mat, trimesh.visual.material.PBRMaterial)
    pbr = _glb_json(glb)["materials"][0]["pbrMetallicRoughness"]
    assert pbr["baseColorFactor"][:3] == summary["base_color"] and pbr["baseColorFactor"][3] == 1.0
    assert pbr["roughnessFactor"] == summary["roughness_factor"] and pbr["metallicFactor"] == 1.0
    np.testing.assert_allclose(np.asarray(mat.baseColorFactor[:3]) / 255, summary["base_color"], atol=0.5 / 255)
    tex = np.asarray(mat.metallicRoughnessTexture)
    assert tex.shape == (256, 1024, 3) and (tex[..., 2] == 255).all()
    # at every vertex the texel under its UV (trimesh's convention) holds √α of the map at that UV
    maps, _, _, lobes = load_material(scene, blade)
    uv = np.asarray(mesh.visual.uv)
    H, W = tex.shape[:2]
    col = np.clip((uv[:, 0] * W).astype(int), 0, W - 1)
    row = np.clip(((1.0 - uv[:, 1]) * H).astype(int), 0, H - 1)
    centre = np.stack([(col + 0.5) / W, 1.0 - (row + 0.5) / H], -1)           # that texel's centre in jkatana's v
    at = np.asarray(sample_map(jnp.asarray(maps), jnp.asarray(centre, jnp.float32)))
    alpha, per_region = texel_alpha(at[:, None, :], lobes)
    r = tex[row, col, 1] / 255.0 * summary["roughness_factor"]
    np.testing.assert_allclose(r, np.sqrt(alpha[:, 0]), atol=0.51 / 255 * summary["roughness_factor"])
    hamon, hiraji = at[:, 0] == 0.0, at[:, 0] == 1.0
    assert hamon.any() and hiraji.any() and r[hamon].mean() > 1.5 * r[hiraji].mean()   # not upside down
    # GGX maps exactly: α is the file's width (times the map's grain) in each pure region
    np.testing.assert_allclose(per_region["hiraji"][hiraji, 0], at[hiraji, 1], rtol=1e-6)
    np.testing.assert_allclose(per_region["hamon"][hamon, 0], at[hamon, 2], rtol=1e-6)
    assert abs(summary["alpha"]["hiraji"]["median"] - GA.GGX_ALPHA["hiraji"]) < 1e-3
    notes = json.loads(summary["notes"].read_text())
    assert notes["format"] == "jkatana-export-gltf/1" and any("Schlick" in a for a in notes["approximations"])


def test_base_colour_is_colour_sciences_reflectance_under_d65():
    """The base colour against colour-science's own integration (``sd_to_XYZ`` of F0 under D65, then
    ``XYZ_to_RGB`` to linear sRGB); a perfect reflector is white up to D65's chromaticity on the truncated
    400–700 nm grid (0.3 %)."""
    import colour

    from jkatana.export.gltf import base_colour, normal_incidence_reflectance
    from jkatana.spectral import DEFAULT_GRID
    from jkatana.spectral.optical_constants import load

    n, k = load("Fe-Johnson").on_grid(DEFAULT_GRID)
    wl = np.asarray(DEFAULT_GRID.wavelengths)
    sd = colour.SpectralDistribution(dict(zip(wl, normal_incidence_reflectance(n, k))))
    shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))
    xyz = colour.sd_to_XYZ(sd, colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape),
                           colour.SDS_ILLUMINANTS["D65"].copy().align(shape), method="Integration") / 100.0
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)
    np.testing.assert_allclose(base_colour(n, k, DEFAULT_GRID), rgb, atol=2e-4)
    assert 0.45 < rgb.min() and rgb.max() < 0.6                                # iron: grey, ~0.5
    huge_k = np.full_like(k, 1e6)
    np.testing.assert_allclose(base_colour(n, huge_k, DEFAULT_GRID), 1.0, atol=3e-3)


def test_paper_lobes_get_the_ggx_alpha_of_equal_reflected_width():
    """A Gaussian of half-width μ reflects with σ = μ √(2/ln 2), GGX with √2 α: α = μ/√ln 2; GGX maps to its own α."""
    import jax.numpy as jnp

    from jkatana.export.gltf import region_alpha
    from jkatana.models.lobes import GGX
    from jkatana.models.lobe_id import LobeId

    mu = np.array([[0.01, 0.05, 0.2]])
    np.testing.assert_allclose(region_alpha("hiraji", None, mu), mu / np.sqrt(np.log(2.0)), rtol=1e-6)
    np.testing.assert_allclose(region_alpha("hamon", None, mu), mu / np.sqrt(np.log(2.0)), rtol=1e-6)
    _, key = LobeId.shape_of(GGX(jnp.asarray(0.1)).to_params())
    np.testing.assert_allclose(region_alpha("hiraji", key, mu), mu, rtol=1e-6)


def test_sphere_exports_as_a_closed_outward_mesh_with_the_renderers_uvs(tmp_path):
    """An analytic sphere goes out tessellated, outward-facing, with u = ½ + atan2(x, z)/2π, v = θ/π."""
    import trimesh

    s = export_gltf(_uniform_scene(tmp_path), tmp_path / "out")
    (mesh,) = trimesh.load(str(s["glb"]), process=False).geometry.values()
    p = mesh.vertices
    np.testing.assert_allclose(np.linalg.norm(p, axis=-1), 1.0, atol=1e-6)
    assert (np.einsum("ij,ij->i", mesh.triangles_center, mesh.face_normals) > 0).all()
    assert mesh.area == pytest.approx(4 * np.pi, rel=2e-3)
    uv = mesh.visual.uv
    np.testing.assert_allclose(uv[:, 1], np.arccos(np.clip(p[:, 1], -1, 1)) / np.pi, atol=1e-6)
    ok = np.hypot(p[:, 0], p[:, 2]) > 1e-3
    u = 0.5 + np.arctan2(p[ok, 0], p[ok, 2]) / (2 * np.pi)
    d = np.abs(uv[ok, 0] - u)
    assert np.all(np.minimum(d, 1.0 - d) < 1e-6)                               # the seam: u = 0 and u = 1
    # uniform hamon μ1 = 0.2: roughness = √(0.2/√ln 2) exactly in the factor, G = 255
    assert s["roughness_factor"] == pytest.approx(np.sqrt(0.2 / np.sqrt(np.log(2.0))), rel=1e-6)


# ---------------------------------------------------------------- bad input: one line, nothing written


def test_a_lobe_wider_than_gltf_roughness_is_refused(tmp_path):
    """μ1 = 1 rad: GGX α of equal width 1.2 > 1 (roughness > 1) cannot be expressed: one line naming the
    field, and no output folder."""
    with pytest.raises(InputError, match=r"field 'material.mu1'.*wider than glTF can express"):
        export_gltf(_uniform_scene(tmp_path, mu1=1.0), tmp_path / "out")
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.*"))
    # the same width on a region the map never uses (w = 1 everywhere) is not refused
    export_gltf(_uniform_scene(tmp_path, mu1=1.0, w=1.0), tmp_path / "ok")


def test_a_calibrated_scene_is_refused(tmp_path):
    with pytest.raises(InputError, match=r"field 'material.calibration'"):
        export_gltf(_uniform_scene(tmp_path, "calibration = 1.0e5"), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_a_missing_asset_is_one_line_naming_it(tmp_path):
    """A mesh file gone between loading the scene and exporting it: the renderer's loader names it."""
    import trimesh

    mesh_path = tmp_path / "blob.ply"
    trimesh.creation.icosphere(subdivisions=1).export(mesh_path)
    p = tmp_path / "scene.toml"
    p.write_text(textwrap.dedent("""
        [geometry]
        mesh = "blob.ply"
        [material]
        w = 1.0
        mu0 = 0.05
        mu1 = 0.1
        [environment]
        type = "constant"
        radiance = 1.0
        """))
    scene = load_scene(p)
    mesh_path.unlink()
    with pytest.raises(InputError, match=r"blob\.ply.*field 'geometry.mesh'"):
        export_gltf(scene, tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("content", [None, "keep.txt"])
def test_an_existing_output_folder_is_refused_and_kept(tmp_path, content):
    """An output folder that exists, empty or not, is refused; what is in it stays as it was."""
    out = tmp_path / "out"
    out.mkdir()
    if content:
        (out / content).write_text("mine")
    with pytest.raises(InputError, match=r"out, field 'output': output folder exists"):
        export_gltf(_uniform_scene(tmp_path), out)
    assert sorted(p.name for p in out.iterdir()) == ([content] if content else [])
    if content:
        assert (out / content).read_text() == "mine"
    assert not list(tmp_path.glob(".out.*"))


# ---------------------------------------------------------------- a glTF material back as a parameter file


def test_an_exported_material_imports_back_as_the_ggx_file_it_came_from(ggx_blade, tmp_path):
    """Export, then import: model ggx with the median texel α (the hiraji's, the map's majority), Fe-Johnson
    recognised from the base colour (ΔE 0), and the file renders (the renderer's own reader accepts it)."""
    from jkatana.export.gltf import gltf_to_params
    from jkatana.fit.params import read_params, write_params

    _, summary = ggx_blade
    d = gltf_to_params(summary["glb"])
    assert d["model"] == "ggx" and d["optical_constants"] == "Fe-Johnson"
    assert d["import"]["optical_constants_dE2000"] < 1e-6
    assert d["values"]["alpha"] == pytest.approx(GA.GGX_ALPHA["hiraji"], rel=0.05)
    p = read_params(write_params(d, tmp_path / "imported.json"))
    assert p.model == "ggx" and p.mu == d["values"]["alpha"] and p.lobe == {"lobe": "ggx", "alpha": p.mu}


def test_a_gltf_written_by_trimesh_alone_imports(tmp_path):
    """A glTF not written by jkatana (trimesh's own writer, uniform factors, a copper-like colour):
    α = roughness², and the nearest shipped metal is named with its colour distance."""
    import trimesh

    from jkatana.export.gltf import gltf_to_params

    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(
        uv=np.zeros((len(mesh.vertices), 2)),
        material=trimesh.visual.material.PBRMaterial(baseColorFactor=[0.95, 0.64, 0.54, 1.0], metallicFactor=1.0,
                                                     roughnessFactor=0.3))
    path = tmp_path / "copper.glb"
    path.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh)))
    d = gltf_to_params(path, region="hamon")
    assert d["region"] == "hamon" and d["values"]["alpha"] == pytest.approx(0.09, rel=1e-6)
    assert d["import"]["optical_constants_dE2000"] > 5       # no shipped metal is copper: said, not hidden


def test_a_missing_texture_or_a_non_metal_is_one_line(tmp_path):
    """A ``.gltf`` whose roughness image is gone, and a dielectric: one :class:`InputError` line each."""
    import trimesh
    from PIL import Image

    from jkatana.export.gltf import gltf_to_params

    mesh = trimesh.creation.box()
    tex = Image.fromarray(np.tile(np.array([255, 200, 255], np.uint8), (4, 4, 1)))   # G roughness, B metal
    mesh.visual = trimesh.visual.TextureVisuals(
        uv=np.zeros((len(mesh.vertices), 2)),
        material=trimesh.visual.material.PBRMaterial(baseColorFactor=[0.5, 0.5, 0.5, 1.0], roughnessFactor=1.0,
                                                     metallicFactor=1.0, metallicRoughnessTexture=tex))
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(mesh))
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    gltf = next(tmp_path.glob("*.gltf"))
    tree = json.loads(gltf.read_text())          # the image as a separate file, as "glTF Separate" writes it
    tree["images"] = [{"uri": "rough.png", "mimeType": "image/png"}]
    gltf.write_text(json.dumps(tree))
    tex.save(tmp_path / "rough.png")
    assert gltf_to_params(gltf)["values"]["alpha"] == pytest.approx((200 / 255) ** 2, rel=1e-6)
    (tmp_path / "rough.png").unlink()
    with pytest.raises(InputError, match=r"\.gltf, field '.*metallicRoughnessTexture': .*cannot be read"):
        gltf_to_params(gltf)
    mesh.visual.material = trimesh.visual.material.PBRMaterial(baseColorFactor=[0.5, 0.5, 0.5, 1.0],
                                                               metallicFactor=0.0, roughnessFactor=0.5)
    plastic = tmp_path / "plastic.glb"
    plastic.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh)))
    with pytest.raises(InputError, match=r"plastic\.glb.*metallicFactor.*not a metal"):
        gltf_to_params(plastic)


# ---------------------------------------------------------------- pyrender's own shader against jkatana render


@pytest.fixture(scope="module")
def closeup(tmp_path_factory):
    """The close-up view's scene, its export and its reference frame (``jkatana render``, reference mode)."""
    folder = tmp_path_factory.mktemp("closeup")
    GA.write_params(folder)
    view, light = GA.views()["closeup"]
    scene = load_scene(GA.write_scene_toml(folder / "s.toml", GA.scene_dict(view, light, folder)))
    summary = export_gltf(scene, folder / "gltf")
    xyz, mask = GA.reference(scene)
    return {"view": view, "light": light, "summary": summary, "xyz": xyz, "mask": mask, "folder": folder}


def _pyrender_against_reference(c, glb) -> dict:
    from jkatana.spectral.colorimetry import xyz_to_linear_rgb

    peak = float(np.max(xyz_to_linear_rgb(c["xyz"], "sRGB")))
    rgb, drawn = GA.pyrender_linear(glb, c["view"], c["light"], GA.light_rgb(), peak)
    return GA.compare_view(c["xyz"], c["mask"], rgb, drawn)


@pytest.mark.gl
def test_pyrender_draws_the_closeup_as_jkatana_renders_it(glr, closeup):
    """ΔE2000 of pyrender's stock metallic-roughness frame of the ``.glb`` against ``jkatana render``
    (reference) in the close-up (the map's texels magnified, one directional light from the mirror
    direction): measured 0.54 mean, 1.08 p95 at 200×150 (0.38 / 0.41 with a uniform α: the rest is the
    8-bit, bilinearly filtered roughness texture); the lit pixels' luminance sums to 0.97 of the
    reference's (per pixel 0.99–0.996; one row on the shinogi crease falls on the other face)."""
    res = _pyrender_against_reference(closeup, closeup["summary"]["glb"])
    stats = res["blade"]
    assert stats["pixels"] > 10000, stats
    assert stats["dE2000_mean"] <= 1.0 and stats["dE2000_p95"] <= 2.0, res
    assert 0.94 <= res["lit_luminance_ratio"] <= 1.02, res


@pytest.mark.gl
@pytest.mark.slow  # two more pyrender frames; the close-up test itself is in the everyday suite
@pytest.mark.parametrize("mistake", ["srgb_base_colour", "roughness_is_alpha"])
def test_a_wrong_export_fails_the_closeup_bound(glr, closeup, mistake):
    """The close-up bounds are not loose: two classic mistakes leave them — the base colour written
    sRGB-encoded (glTF's factor is linear) and α written where glTF wants roughness √α."""
    import trimesh
    from PIL import Image

    s = closeup["summary"]
    (mesh,) = trimesh.load(str(s["glb"]), process=False).geometry.values()
    mat = mesh.visual.material
    if mistake == "srgb_base_colour":
        from jkatana.spectral.colorimetry import encode

        mat.baseColorFactor = np.append(np.rint(255 * encode(np.asarray(s["base_color"]))), 255).astype(np.uint8)
    else:
        tex = np.asarray(mat.metallicRoughnessTexture).copy()
        r = tex[..., 1] / 255.0
        tex[..., 1] = np.rint(255 * r * r)
        mat.roughnessFactor = s["roughness_factor"] ** 2
        mat.metallicRoughnessTexture = Image.fromarray(tex)
    bad = closeup["folder"] / f"{mistake}.glb"
    bad.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh), include_normals=True))
    stats = _pyrender_against_reference(closeup, bad)["blade"]
    assert stats["dE2000_mean"] > 1.0 or stats["dE2000_p95"] > 2.0, stats


@pytest.mark.gl
@pytest.mark.slow          # two more reference frames; the close-up test is the everyday one
def test_pyrender_agrees_at_the_glint_and_darkens_at_grazing_as_its_shadowing_predicts(glr, tmp_path):
    """The other views (bounds about 1.5× the values measured at 200×150):

    - ``glint`` (the map minified 5–17×: pyrender's mipmaps average the map's grain that jkatana samples
      at pixel centres; crease rows a pixel apart): 1.95 mean, 6.8 p95, lit luminance within 1 %;
    - ``grazing`` (69°): 5.4 / 13.0, pyrender 35 % darker: its Schlick–Smith shadowing with k = (r + 1)²/8
      and Schlick's Fresnel, whose product at the peak (:func:`validation.gltf_agreement.term_ratios`,
      0.642) the measured luminance ratio (0.645) must match.
    """
    res = GA.run(tmp_path, names=("glint", "grazing"))
    for name, (mean, p95) in {"glint": (3.0, 10.0), "grazing": (8.0, 18.0)}.items():
        stats = res[name]["blade"]
        assert stats["pixels"] > 800, (name, stats)
        assert stats["dE2000_mean"] <= mean and stats["dE2000_p95"] <= p95, (name, stats)
    assert 0.9 <= res["glint"]["lit_luminance_ratio"] <= 1.1, res["glint"]
    light = np.asarray(res["grazing"]["light"])
    predicted = GA.term_ratios(float(np.degrees(np.arccos(abs(light[2])))), GA.GGX_ALPHA["hiraji"])["product"]
    assert predicted < 0.7
    assert abs(res["grazing"]["lit_luminance_ratio"] - predicted) < 0.06, (res["grazing"], predicted)
