"""A jkatana scene as a pbrt-v4 scene (Pharr, Jakob & Humphreys, *Physically Based Rendering*, 4th ed.,
2023; the scene file format of pbrt-v4's documentation, "pbrt-v4 File Format").

pbrt-v4 cannot be built here (no C++ renderer is installed from the package registries), so the files are
written from its documentation and checked by reading them back (``tests/test_export.py``), not by
rendering them. What each part becomes:

- **GGX lobes** → ``conductor`` (pbrt-v4's conductors use the Trowbridge–Reitz distribution) with
  ``roughness`` = α and ``remaproughness`` false, and the material's spectral η and k.
- **Every other lobe** (the paper's, Beckmann — pbrt-v4 has no Beckmann conductor —, GTR, two-lobe) →
  ``measured`` with the RGL ``.bsdf`` of :mod:`jkatana.export.tabulate` (pbrt-v4's ``MeasuredBxDF`` reads
  the spectral tables, with the camera side as the table's incident direction, as Mitsuba does).
- **The map** → ``mix`` of the hamon and the hiraji with ``amount`` an ``imagemap`` of w (pbrt-v4 picks
  one of the two per intersection with that probability: eq. 5 in expectation). pbrt's image textures
  put t = 0 at the image's bottom row, so ``w_pbrt.exr`` is the map flipped upside down.
- **The environment** → ``infinite`` light of an equal-area octahedral image (Clarberg 2008, pbrt-v4's
  ``EqualAreaSquareToSphere``), resampled from jkatana's latitude–longitude map with its rotation, turned
  so that the light's +z is the world's +Y; compact sources split off as caps → spheres far away with
  ``diffuse`` area lights of the cap's spectral radiance.
- **Camera** → ``perspective`` with ``fov`` the shorter image axis's angle, preceded by ``Scale -1 1 1``
  (pbrt's camera space is left-handed; the flip keeps a right-handed world's image unmirrored);
  ``Integrator "path"`` with ``maxdepth`` 1 (direct lighting, as jkatana renders).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from jkatana.export.scene import EXPORT_WAVELENGTHS, Resolved, environment_rgb, light_spectrum


def _spectrum(values, wavelengths=EXPORT_WAVELENGTHS) -> str:
    return "[ " + " ".join(f"{a:g} {b:.7g}" for a, b in zip(wavelengths, values)) + " ]"


def equal_area_square_to_sphere(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """pbrt-v4's ``EqualAreaSquareToSphere`` (Clarberg 2008): points of [0, 1]² → unit vectors (+z up)."""
    a, b = 2 * u - 1, 2 * v - 1
    ap, bp = np.abs(a), np.abs(b)
    signed = 1 - (ap + bp)
    r = 1 - np.abs(signed)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(r == 0, 1.0, (bp - ap) / np.where(r == 0, 1.0, r) + 1) * np.pi / 4
    z = np.copysign(1 - r * r, signed)
    s = r * np.sqrt(np.maximum(2 - r * r, 0.0))
    return np.stack([np.copysign(np.cos(phi), a) * s, np.copysign(np.sin(phi), b) * s, z], -1)


def equal_area_image(latlong_rgb: np.ndarray, rotation_deg: float, size: int) -> np.ndarray:
    """A jkatana latitude–longitude RGB map as pbrt-v4's equal-area square image (``size × size × 3``): texel
    (row j, column i) holds the radiance in the world direction Rx(−90°) · square_to_sphere((i + ½)/size,
    (j + ½)/size) (light +z → world +Y), looked up bilinearly with the scene's rotation."""
    from jkatana.light.envmap import direction_to_uv
    from jkatana.render.renderer import rotation_y

    c = (np.arange(size) + 0.5) / size
    U, V = np.meshgrid(c, c, indexing="xy")
    d = equal_area_square_to_sphere(U, V)
    world = np.stack([d[..., 0], d[..., 2], -d[..., 1]], -1)  # rotate −90° about x: z → y
    m = world @ rotation_y(rotation_deg).T
    u, v = (np.asarray(a, np.float64) for a in direction_to_uv(m))
    H, W = latlong_rgb.shape[:2]
    x = u * W - 0.5
    y = np.clip(v * H - 0.5, 0, H - 1)
    x0, y0 = np.floor(x).astype(int), np.minimum(np.floor(y).astype(int), H - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    img = latlong_rgb.astype(np.float64)
    g = lambda yy, xx: img[yy, xx % W]  # noqa: E731
    out = ((1 - fy) * ((1 - fx) * g(y0, x0) + fx * g(y0, x0 + 1)) + fy * ((1 - fx) * g(y0 + 1, x0) + fx * g(y0 + 1, x0 + 1)))
    return out.astype(np.float32)


def _material(res: Resolved, region, out_dir: Path, written: dict) -> str:
    """pbrt-v4 ``MakeNamedMaterial`` parameters of one region (module docstring)."""
    if region.mirror:
        return f'"string type" "conductor" "spectrum eta" {_spectrum(res.n)} "spectrum k" {_spectrum(res.k)} ' \
               f'"float roughness" 0'
    if region.lobe.name == "ggx" and region.gain == 1.0:
        return (f'"string type" "conductor" "spectrum eta" {_spectrum(res.n)} "spectrum k" {_spectrum(res.k)} '
                f'"float roughness" {float(region.lobe.alpha):.7g} "bool remaproughness" false')
    from jkatana.brdf.rgl import write_rgl
    from jkatana.export.tabulate import lobe_table

    name = f"{region.region}.bsdf"
    if name not in written:
        write_rgl(lobe_table(region, res.n, res.k, EXPORT_WAVELENGTHS,
                             description=f"jkatana {region.region}: {region.lobe.name} at width {region.width:.4g}"),
                  out_dir / name)
        written[name] = f"{region.lobe.name} lobe × Fresnel, RGL spectral table"
    return f'"string type" "measured" "string filename" "{name}"'


def scene_text(res: Resolved, out_dir: Path, *, spp: int | None = None) -> tuple[str, dict]:
    """``(pbrt-v4 scene text, {asset: what it is})``, writing the assets into ``out_dir``."""
    written: dict[str, str] = {}
    lines = (_camera_lines(res, spp) + _light_lines(res, out_dir, written) + _material_lines(res, out_dir, written)
             + _shape_lines(res, out_dir, written))
    return "\n".join(lines) + "\n", written


def _f3(t) -> str:
    return " ".join(f"{float(x):.9g}" for x in t)


def _camera_lines(res: Resolved, spp: int | None) -> list[str]:
    """The scene's options before ``WorldBegin``: camera (``fov`` the shorter image axis's angle, mirrored by
    ``Scale -1 1 1``), film, sampler, the direct-lighting integrator."""
    scene, cam = res.scene, res.camera
    fov_y = float(cam.fov_deg)
    fov = fov_y if cam.height <= cam.width else math.degrees(
        2 * math.atan(math.tan(math.radians(fov_y) / 2) * cam.width / cam.height))
    spp = int(scene.render.samples if spp is None else spp)
    return ["# written by jkatana export (jkatana.export.pbrt): pbrt-v4 scene format", "Scale -1 1 1",
            f"LookAt {_f3(cam.position)}  {_f3(cam.look_at)}  {_f3(cam.up)}",
            f'Camera "perspective" "float fov" [ {fov:.9g} ]',
            f'Film "rgb" "integer xresolution" [ {cam.width} ] "integer yresolution" [ {cam.height} ] '
            f'"string filename" [ "{scene.output.name}.exr" ] "string sensor" "cie1931"',
            'PixelFilter "box"', f'Sampler "zsobol" "integer pixelsamples" [ {spp} ]',
            'Integrator "path" "integer maxdepth" [ 1 ]', "", "WorldBegin", ""]


def _light_lines(res: Resolved, out_dir: Path, written: dict) -> list[str]:
    """The environment (an equal-area image, or a constant), its compact sources as far spherical area lights,
    and the point and distant lights."""
    from jkatana.io.exr import write_exr

    scene = res.scene
    lines = []
    rgb, caps = environment_rgb(scene)
    if rgb is not None:
        side = int(min(2048, 2 ** math.ceil(math.log2(max(rgb.shape[0], 16)))))
        sq = equal_area_image(rgb, float(scene.environment.rotation_deg), side)
        write_exr(out_dir / "environment_equalarea.exr", {"R": sq[..., 0], "G": sq[..., 1], "B": sq[..., 2]})
        written["environment_equalarea.exr"] = "environment, equal-area octahedral RGB (linear Rec. 709)"
        lines += ["AttributeBegin", '    Rotate -90 1 0 0',
                  '    LightSource "infinite" "string filename" "environment_equalarea.exr"', "AttributeEnd"]
    elif scene.environment.type == "constant" and scene.environment.radiance:
        from jkatana.export.scene import constant_radiance_rgb

        g = constant_radiance_rgb(scene)
        lines += [f'LightSource "infinite" "rgb L" [ {g:.7g} {g:.7g} {g:.7g} ]']
    reach = res.reach
    for cap in caps:
        dist = reach * 1e3
        lines += ["AttributeBegin", f"    Translate {_f3(np.asarray(cap.direction) * dist)}",
                  f'    AreaLightSource "diffuse" "spectrum L" {_spectrum(cap.radiance, cap.wavelengths)}',
                  f'    Shape "sphere" "float radius" [ {dist * math.sin(cap.radius):.9g} ]', "AttributeEnd"]
    for light in scene.lights:
        spec = _spectrum(light_spectrum(light))
        if light.type == "point":
            lines += [f'LightSource "point" "point3 from" [ {_f3(light.vector)} ] "spectrum I" {spec}']
        else:
            lines += [f'LightSource "distant" "point3 from" [ {_f3(light.vector)} ] "point3 to" [ 0 0 0 ] '
                      f'"spectrum L" {spec}']
    return lines


def _material_lines(res: Resolved, out_dir: Path, written: dict) -> list[str]:
    """Each region's named material, the two mixed by w (a uniform weight or ``w_pbrt.exr``) where both are
    present, and the material the object takes."""
    from jkatana.io.exr import write_exr

    lines = []
    hi, ha = res.regions["hiraji"], res.regions["hamon"]
    names = []
    for reg in (ha, hi):
        if reg is not None:
            lines.append(f'MakeNamedMaterial "{reg.region}" {_material(res, reg, out_dir, written)}')
            names.append(reg.region)
    if len(names) == 2:
        weight = res.uniform_w
        if weight is None:
            write_exr(out_dir / "w_pbrt.exr", {"Y": np.ascontiguousarray(res.w[::-1])})
            written["w_pbrt.exr"] = "blend weight w (eq. 5), flipped so pbrt's t = 0 is the image's bottom row"
            lines.append('Texture "w" "float" "imagemap" "string filename" "w_pbrt.exr" "string wrap" "clamp"')
            amount = '"texture amount" "w"'
        else:
            amount = f'"float amount" [ {weight:.7g} ]'
        lines.append(f'MakeNamedMaterial "blade" "string type" "mix" "string materials" [ "hamon" "hiraji" ] {amount}')
        names = ["blade"]
    lines.append(f'NamedMaterial "{names[0]}"')
    return lines


def _shape_lines(res: Resolved, out_dir: Path, written: dict) -> list[str]:
    """The object (a sphere, or ``mesh.ply``) and the black occluders (sphere, box, or their own mesh)."""
    from jkatana.export.mitsuba import write_ply

    lines = []
    geom = res.geometry
    if isinstance(geom, tuple):
        _, center, radius = geom
        lines += ["AttributeBegin", f"    Translate {_f3(center)}", f'    Shape "sphere" "float radius" [ {radius:.9g} ]',
                  "AttributeEnd"]
    else:
        write_ply(geom, out_dir / "mesh.ply")
        written["mesh.ply"] = "the object: vertices, normals, UVs (m)"
        lines.append('Shape "plymesh" "string filename" "mesh.ply"')
    for i, occ in enumerate(res.scene.occluders):
        lines += ["AttributeBegin", 'Material "diffuse" "rgb reflectance" [ 0 0 0 ]', f"    Translate {_f3(occ.center)}"]
        if occ.kind == "sphere":
            lines.append(f'    Shape "sphere" "float radius" [ {occ.radius:.9g} ]')
        elif occ.kind == "box":
            e = np.asarray(occ.extents, np.float64) / 2
            lines += [f"    Scale {_f3(e)}", _unit_cube()]
        else:
            import trimesh

            mesh = trimesh.load(occ.mesh, force="mesh", process=False)
            mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((len(mesh.vertices), 2)))
            write_ply(mesh, out_dir / f"occluder_{i}.ply")
            written[f"occluder_{i}.ply"] = "occluder mesh"
            lines += [f"    Scale {_f3([occ.scale or 1.0] * 3)}", f'    Shape "plymesh" "string filename" "occluder_{i}.ply"']
        lines.append("AttributeEnd")
    return lines


def _unit_cube() -> str:
    """A [−1, 1]³ box as a ``trianglemesh`` (outward faces)."""
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    idx = " ".join(str(int(i)) for i in box.faces.ravel())
    pts = " ".join(f"{x:g}" for x in box.vertices.ravel())
    return f'    Shape "trianglemesh" "integer indices" [ {idx} ] "point3 P" [ {pts} ]'


def export_pbrt(scene, out_dir: Path, *, spp: int | None = None) -> dict:
    """Write ``scene`` as ``out_dir/scene.pbrt`` with its assets and ``export.json`` (module docstring)."""
    from jkatana.export.mitsuba import approximations
    from jkatana.export.scene import resolve
    from jkatana.io.atomic import write_text

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    res = resolve(scene)
    text, written = scene_text(res, out_dir, spp=spp)
    write_text(out_dir / "scene.pbrt", text)
    notes = approximations(res, "pbrt-v4") + ["the blend of eq. 5 is pbrt's stochastic mix (exact in expectation)",
                                   "not rendered here: pbrt-v4 is not installable on this project's machines"]
    summary = {"target": "pbrt-v4", "scene": "scene.pbrt", "files": written, "approximations": notes}
    write_text(out_dir / "export.json", json.dumps(summary, indent=2) + "\n")
    return summary


__all__ = ["export_pbrt", "scene_text", "equal_area_square_to_sphere", "equal_area_image"]
