"""A jkatana scene as a Mitsuba 3 scene: XML with its assets (PLY, EXR, RGL ``.bsdf``), or the same as a
Python dict for ``mitsuba.load_dict``.

What each part becomes (Mitsuba 3 plugin names; Jakob et al., mitsuba-renderer.org, 3.x documentation):

- **Beckmann and GGX lobes** → ``roughconductor`` with ``distribution`` beckmann / ggx, the lobe's α (the
  same α: √2 × RMS slope for Beckmann, Walter et al. 2007's α for GGX, both with separable Smith masking,
  as in :mod:`jkatana.models.lobes`), visible-normal sampling, and the material's spectral η and k on
  360–830 nm. Exact in the lobe.
- **The paper's lobes (Mochizuki et al., eqs. 1–2), GTR and the two-lobe mixture** → ``measured`` with an
  RGL ``.bsdf`` that :mod:`jkatana.export.tabulate` writes: the lobe times the conductor's spectral Fresnel
  factor, tabulated with the camera side as the table's incident direction (the hiraji lobe is not
  reciprocal). Exact to the table's interpolation.
- **A smooth hiraji** (μ0 below the renderer's mirror limit) → ``conductor``.
- **The reflectance map** → ``blendbsdf`` whose ``weight`` is a ``bitmap`` of w (``bsdf_0`` the hamon,
  ``bsdf_1`` the hiraji): eq. 5 itself. The map's per-texel widths (the hada grain) are not: each region
  goes out at one width (:mod:`jkatana.export.scene`).
- **The environment** → ``envmap`` of an RGB EXR (:func:`jkatana.export.scene.environment_rgb`), turned
  by ``to_world`` = rotation of 180° − ``rotation_deg`` about +Y: Mitsuba's latitude–longitude u origin is
  half a turn from jkatana's (:mod:`validation.mitsuba`). A sun the renderer splits off as a cap is part
  of the map here. A constant environment → ``constant``.
- **Directional and point lights** → ``directional`` (propagation = −direction) and ``point`` with the
  same spectral irradiance / intensity; **occluders** → black ``diffuse`` boxes, spheres or meshes.
- **Camera and film** → ``perspective`` (vertical field of view, the same look-at frame and roll) with an
  ``hdrfilm`` of the scene's resolution, box pixel filter, linear RGB; the ``direct`` integrator (one
  bounce: jkatana renders direct lighting only) with the scene's samples per pixel and the
  ``multijitter`` sampler.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from jkatana.errors import InputError
from jkatana.export.scene import (EXPORT_WAVELENGTHS, Resolved, constant_radiance_rgb, environment_rgb,
                                  light_spectrum)

#: The plugin category (XML tag) of each Mitsuba plugin type the exporter writes.
TAGS = {"perspective": "sensor", "hdrfilm": "film", "box": "rfilter", "multijitter": "sampler",
        "independent": "sampler", "direct": "integrator", "path": "integrator", "envmap": "emitter",
        "constant": "emitter", "directional": "emitter", "point": "emitter", "ply": "shape",
        "sphere": "shape", "cube": "shape", "area": "emitter", "bitmap": "texture", "blendbsdf": "bsdf", "roughconductor": "bsdf",
        "conductor": "bsdf", "measured": "bsdf", "diffuse": "bsdf"}
MICROFACET = {"beckmann": "beckmann", "ggx": "ggx"}
_BLACK = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}


@dataclasses.dataclass(frozen=True)
class Matrix:
    """A 4×4 transform (row-major), ``to_world`` of a plugin."""

    m: tuple


@dataclasses.dataclass(frozen=True)
class LookAt:
    """Mitsuba's look-at transform (camera to world)."""

    origin: tuple
    target: tuple
    up: tuple


def _spectrum(values: np.ndarray, wavelengths=EXPORT_WAVELENGTHS) -> dict:
    return {"type": "spectrum", "value": [(float(a), float(b)) for a, b in zip(wavelengths, values)]}


def _matrix(a: np.ndarray) -> Matrix:
    return Matrix(tuple(float(x) for x in np.asarray(a, np.float64).ravel()))


def _rotation_y4(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    m = np.eye(4)
    m[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    return m


# ---------------------------------------------------------------------------------------------- assets


def write_ply(mesh, path: Path) -> Path:
    """A triangle mesh as binary little-endian PLY with per-vertex normals and UVs (``u``, ``v``: the names
    Mitsuba's and pbrt-v4's PLY readers take), written atomically."""
    from jkatana.io.atomic import write_bytes

    v = np.asarray(mesh.vertices, np.float32)
    nrm = np.asarray(mesh.vertex_normals, np.float32)
    uv = np.asarray(mesh.visual.uv, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    head = ("ply\nformat binary_little_endian 1.0\ncomment jkatana export\n"
            f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\nproperty float u\nproperty float v\n"
            f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    verts = np.concatenate([v, nrm, uv], 1).astype("<f4").tobytes()
    rec = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"], rec["i"] = 3, f
    return write_bytes(path, head + verts + rec.tobytes())


def _bsdf(region, res: Resolved, out_dir: Path, written: dict) -> dict:
    """The Mitsuba BSDF of one region (module docstring), writing its table when it needs one."""
    if region.mirror:
        return {"type": "conductor", "eta": _spectrum(res.n), "k": _spectrum(res.k)}
    family = region.lobe.name
    if family in MICROFACET:
        d = {"type": "roughconductor", "distribution": MICROFACET[family], "alpha": float(region.lobe.alpha),
             "sample_visible": True, "eta": _spectrum(res.n), "k": _spectrum(res.k)}
        if region.gain != 1.0:
            d["specular_reflectance"] = {"type": "rgb", "value": [region.gain] * 3}
        return d
    from jkatana.brdf.rgl import write_rgl
    from jkatana.export.tabulate import lobe_table

    name = f"{region.region}.bsdf"
    table = lobe_table(region, res.n, res.k, EXPORT_WAVELENGTHS,
                       description=f"jkatana {region.region}: {family} at width {region.width:.4g}")
    write_rgl(table, out_dir / name)
    written[name] = (f"{family} lobe × the Fresnel factor of {res.scene.material.optical_constants}, "
                     f"RGL spectral table")
    return {"type": "measured", "filename": name}


def _material(res: Resolved, out_dir: Path, written: dict) -> dict:
    from jkatana.io.exr import write_exr

    hi, ha = res.regions["hiraji"], res.regions["hamon"]
    if hi is None:
        return _bsdf(ha, res, out_dir, written)
    if ha is None:
        return _bsdf(hi, res, out_dir, written)
    weight = res.uniform_w
    if weight is None:
        write_exr(out_dir / "w.exr", {"Y": res.w})
        written["w.exr"] = "blend weight w of eq. 5 (row 0 = v = 0, the mune)"
        weight = {"type": "bitmap", "filename": "w.exr", "raw": True, "filter_type": "bilinear",
                  "wrap_mode": "clamp"}
    return {"type": "blendbsdf", "weight": weight, "bsdf_0": _bsdf(ha, res, out_dir, written),
            "bsdf_1": _bsdf(hi, res, out_dir, written)}


def _occluder(occ, out_dir: Path, i: int, written: dict) -> dict:
    black = _BLACK
    c = np.asarray(occ.center, np.float64)
    if occ.kind == "sphere":
        return {"type": "sphere", "center": [float(x) for x in c], "radius": float(occ.radius), "bsdf": black}
    if occ.kind == "box":
        m = np.diag([*(np.asarray(occ.extents, np.float64) / 2), 1.0])
        m[:3, 3] = c
        return {"type": "cube", "to_world": _matrix(m), "bsdf": black}
    import trimesh

    mesh = trimesh.load(occ.mesh, force="mesh", process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((len(mesh.vertices), 2)))
    name = f"occluder_{i}.ply"
    write_ply(mesh, out_dir / name)
    written[name] = "occluder mesh"
    m = np.diag([float(occ.scale or 1.0)] * 3 + [1.0])
    m[:3, 3] = c
    return {"type": "ply", "filename": name, "to_world": _matrix(m), "bsdf": black}


def _mirror_only(res: Resolved) -> bool:
    """A perfect mirror and nothing else: a cap split off as a sphere far away would still be seen in it,
    but keeping the sun in the map keeps the one representation Mitsuba's ``conductor`` samples."""
    return all(v is None or v.mirror for v in res.regions.values())


def scene_dict(res: Resolved, out_dir: Path, *, spp: int | None = None) -> tuple[dict, dict, list]:
    """``(mitsuba scene dict with plain values, {asset file: what it is}, caps split off the environment)``,
    writing the assets into ``out_dir`` (module docstring). File names in the dict are relative to
    ``out_dir``."""
    from jkatana.io.exr import write_exr

    scene = res.scene
    written: dict[str, str] = {}
    cam = res.camera
    dist = float(np.linalg.norm(np.subtract(cam.position, cam.look_at)))
    spp = int(scene.render.samples if spp is None else spp)
    d: dict = {
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": float(cam.fov_deg), "fov_axis": "y",
                   "near_clip": dist * 1e-3, "far_clip": dist * 1e4,
                   "to_world": LookAt(tuple(map(float, cam.position)), tuple(map(float, cam.look_at)),
                                      tuple(map(float, cam.up))),
                   "film": {"type": "hdrfilm", "width": int(cam.width), "height": int(cam.height),
                            "pixel_format": "rgb", "rfilter": {"type": "box"}},
                   "sampler": {"type": "multijitter", "sample_count": spp}},
    }
    env = scene.environment
    rgb, caps = environment_rgb(scene, split=not _mirror_only(res))
    if rgb is not None:
        write_exr(out_dir / "environment.exr", {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})
        written["environment.exr"] = "environment, linear Rec. 709 RGB (Mitsuba's film normalisation)"
        d["environment"] = {"type": "envmap", "filename": "environment.exr",
                            "to_world": _matrix(_rotation_y4(180.0 - float(env.rotation_deg)))}
    elif env.radiance:
        d["environment"] = {"type": "constant", "radiance": {"type": "rgb", "value": [constant_radiance_rgb(scene)] * 3}}
    reach = res.reach
    for i, cap in enumerate(caps):
        # a cap of uniform radiance at infinity: a sphere emitter far outside the scene subtending its angle
        dist = reach * 1e3
        centre = [float(x) * dist for x in cap.direction]
        d[f"cap_{i}"] = {"type": "sphere", "center": centre, "radius": dist * float(np.sin(cap.radius)),
                         "emitter": {"type": "area", "radiance": _spectrum(cap.radiance, cap.wavelengths)},
                         "bsdf": _BLACK}
    for i, light in enumerate(scene.lights):
        spec = _spectrum(light_spectrum(light))
        vec = [float(x) for x in light.vector]
        if light.type == "point":
            d[f"light_{i}"] = {"type": "point", "position": vec, "intensity": spec}
        else:
            d[f"light_{i}"] = {"type": "directional", "direction": [-x for x in vec], "irradiance": spec}
    bsdf = _material(res, out_dir, written)
    geom = res.geometry
    if isinstance(geom, tuple):
        _, center, radius = geom
        d["object"] = {"type": "sphere", "center": [float(x) for x in center], "radius": float(radius), "bsdf": bsdf}
    else:
        write_ply(geom, out_dir / "mesh.ply")
        written["mesh.ply"] = "the object: vertices, normals, UVs (m)"
        d["object"] = {"type": "ply", "filename": "mesh.ply", "bsdf": bsdf}
    for i, occ in enumerate(scene.occluders):
        d[f"occluder_{i}"] = _occluder(occ, out_dir, i, written)
    return d, written, caps


# ------------------------------------------------------------------------------------------------ XML


def _xml_value(name: str, v, indent: str) -> list[str]:
    if isinstance(v, dict):
        return _xml_plugin(v, indent, name=name)
    if isinstance(v, LookAt):
        f = lambda t: ", ".join(f"{x:.9g}" for x in t)  # noqa: E731
        return [f'{indent}<transform name="{name}">',
                f'{indent}    <lookat origin="{f(v.origin)}" target="{f(v.target)}" up="{f(v.up)}"/>',
                f"{indent}</transform>"]
    if isinstance(v, Matrix):
        return [f'{indent}<transform name="{name}">', f'{indent}    <matrix value="{" ".join(f"{x:.9g}" for x in v.m)}"/>',
                f"{indent}</transform>"]
    if isinstance(v, bool):
        return [f'{indent}<boolean name="{name}" value="{str(v).lower()}"/>']
    if isinstance(v, int):
        return [f'{indent}<integer name="{name}" value="{v}"/>']
    if isinstance(v, float):
        return [f'{indent}<float name="{name}" value="{v:.9g}"/>']
    if isinstance(v, str):
        return [f'{indent}<string name="{name}" value="{v}"/>']
    if isinstance(v, (list, tuple)) and len(v) == 3:
        return [f'{indent}<point name="{name}" value="{", ".join(f"{float(x):.9g}" for x in v)}"/>']
    raise TypeError(f"no XML form for {name!r}: {v!r}")


def _xml_plugin(d: dict, indent: str, *, name: str | None = None, ident: str | None = None) -> list[str]:
    kind = d["type"]
    attr = (f' name="{name}"' if name else "") + (f' id="{ident}"' if ident else "")
    if kind == "spectrum":
        vals = ", ".join(f"{a:g}:{b:.9g}" for a, b in d["value"])
        return [f'{indent}<spectrum{attr} value="{vals}"/>']
    if kind == "rgb":
        return [f'{indent}<rgb{attr} value="{", ".join(f"{x:.9g}" for x in d["value"])}"/>']
    tag = TAGS[kind]
    lines = [f'{indent}<{tag} type="{kind}"{attr}>']
    for k, v in d.items():
        if k != "type":
            lines += _xml_value(k, v, indent + "    ")
    return lines + [f"{indent}</{tag}>"]


def to_xml(d: dict) -> str:
    """Mitsuba 3 scene XML (format version 3.0.0) of a :func:`scene_dict`."""
    lines = ['<?xml version="1.0" encoding="utf-8"?>', "<!-- written by jkatana export (jkatana.export.mitsuba) -->",
             '<scene version="3.0.0">']
    for key, v in d.items():
        if key == "type":
            continue
        lines += _xml_plugin(v, "    ", ident=key)
    return "\n".join(lines + ["</scene>", ""])


def for_load_dict(d: dict, base: Path):
    """The dict with transforms as ``mitsuba.ScalarTransform4f`` and file names absolute under ``base``, for
    ``mitsuba.load_dict`` (needs Mitsuba, the ``mitsuba`` extra, with a variant set)."""
    import mitsuba as mi

    def conv(k, v):
        if isinstance(v, dict):
            return {kk: conv(kk, vv) for kk, vv in v.items()}
        if isinstance(v, LookAt):
            return mi.ScalarTransform4f().look_at(origin=list(v.origin), target=list(v.target), up=list(v.up))
        if isinstance(v, Matrix):
            return mi.ScalarTransform4f(np.asarray(v.m, np.float64).reshape(4, 4).tolist())
        if k == "filename":
            return str(Path(base) / v)
        return v

    return conv(None, d)


def export_mitsuba(scene, out_dir: Path, *, spp: int | None = None) -> dict:
    """Write ``scene`` (a :class:`jkatana.render.scene.Scene`) as ``out_dir/scene.xml`` with its assets
    and ``export.json`` (what each file is, what was approximated); returns that summary. The caller
    provides an empty or new ``out_dir`` (:func:`jkatana.export.commands` writes into a temporary folder
    and renames it)."""
    from jkatana.export.scene import resolve
    from jkatana.io.atomic import write_text

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    res = resolve(scene)
    d, written, caps = scene_dict(res, out_dir, spp=spp)
    write_text(out_dir / "scene.xml", to_xml(d))
    summary = {"target": "mitsuba3", "scene": "scene.xml", "files": written,
               "regions": {r: None if v is None else {"lobe": v.family, "width": v.width,
                                                      "width_p5_p95": list(v.spread), "gain": v.gain}
                           for r, v in res.regions.items()},
               "caps": [{"direction": list(c.direction), "radius_deg": float(np.degrees(c.radius))} for c in caps],
               "approximations": approximations(res)}
    write_text(out_dir / "export.json", json.dumps(summary, indent=2) + "\n")
    return summary


def approximations(res: Resolved, renderer: str = "Mitsuba") -> list[str]:
    """What the exported scene does not hold exactly, in words a user reads."""
    out = []
    for r, v in res.regions.items():
        if v is not None and res.w.size > 1 and v.spread[1] > v.spread[0] * 1.001 and not v.mirror:
            out.append(f"{r}: one width {v.width:.4g} for the map's per-texel widths "
                       f"({v.spread[0]:.4g}–{v.spread[1]:.4g}, 5th–95th percentile)")
        if v is not None and not v.mirror and v.lobe.name not in MICROFACET:
            out.append(f"{r}: {v.lobe.name} lobe tabulated (RGL .bsdf, interpolated between table cells)")
    if res.scene.environment.type != "constant":
        out.append(f"environment as linear Rec. 709 RGB ({renderer} upsamples it to spectra)")
    out.append(f"the render mode and its sampling are jkatana's own: {renderer} renders direct lighting with "
               f"its own sampler")
    return out


# ------------------------------------------------------------------------------------------- import


def _named_values(el) -> dict:
    return {c.get("name"): c for c in el if c.get("name")}


def _spectrum_values(el, path, field) -> tuple[np.ndarray, np.ndarray] | None:
    """``(wavelengths, values)`` of a Mitsuba ``<spectrum value="λ:v, ..."/>``; ``None`` for a constant."""
    text = el.get("value", "")
    try:
        if ":" not in text:
            return None
        pairs = [tuple(float(x) for x in item.split(":")) for item in text.split(",") if item.strip()]
        wl, v = (np.asarray(a, np.float64) for a in zip(*pairs))
    except ValueError:
        raise InputError(f"is not a spectrum of 'wavelength:value' pairs ({text[:40]!r})", path=path,
                         field=field) from None
    return wl, v


def roughconductor_to_params(path, *, bsdf_id: str | None = None, region: str = "hiraji") -> dict:
    """A Mitsuba 3 ``roughconductor`` of a scene XML as a ``jkatana-params/1`` parameter file (a dict).

    The lobe is the file's: ``distribution`` ggx or beckmann (Mitsuba's default) and ``alpha`` (its default
    0.1; an anisotropic ``alpha_u`` ≠ ``alpha_v`` is refused: jkatana's lobes are isotropic), the same α as
    :class:`~jkatana.models.lobes.GGX` / :class:`~jkatana.models.lobes.Beckmann` take. The optical constants
    are the shipped table Mitsuba's ``material`` names (Fe, Cr, Ni, Mo, W), or, for η and k given as
    spectra, the shipped table of nearest normal-incidence colour (its ΔE2000 recorded under ``"import"``).
    ``bsdf_id`` picks one BSDF by its ``id`` (default: the only ``roughconductor``, possibly inside a
    ``twosided``). The scale is 1: a rendered material, not a fit to camera units.
    """
    import xml.etree.ElementTree as ET

    from jkatana.export.gltf import base_colour, nearest_shipped_metal
    from jkatana.fit.params import FORMAT, params_from_dict
    from jkatana.spectral.grid import WavelengthGrid
    from jkatana.spectral.optical_constants import ALIASES, SHIPPED

    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as err:
        raise InputError(f"not a readable Mitsuba XML file ({err})", path=path) from None
    found = [b for b in root.iter("bsdf") if b.get("type") == "roughconductor"
             and (bsdf_id is None or b.get("id") == bsdf_id or _parent_id(root, b) == bsdf_id)]
    if len(found) != 1:
        ids = [b.get("id") or _parent_id(root, b) for b in root.iter("bsdf") if b.get("type") == "roughconductor"]
        raise InputError(f"holds {len(found)} roughconductor BSDFs{'' if bsdf_id is None else f' with id {bsdf_id!r}'}"
                         f" (ids: {ids}); name one with its id", path=path, field="bsdf")
    el = _named_values(found[0])
    field = f"bsdf {found[0].get('id') or _parent_id(root, found[0]) or 'roughconductor'}"
    dist = el["distribution"].get("value") if "distribution" in el else "beckmann"
    if dist not in ("ggx", "beckmann"):
        raise InputError(f"distribution {dist!r} is not one jkatana renders (ggx, beckmann)", path=path, field=field)
    if "alpha_u" in el or "alpha_v" in el:
        au, av = (float(el[k].get("value", 0.1)) if k in el else 0.1 for k in ("alpha_u", "alpha_v"))
        if not np.isclose(au, av):
            raise InputError(f"is anisotropic (alpha_u {au:g}, alpha_v {av:g}): jkatana's lobes are isotropic",
                             path=path, field=field)
        alpha = au
    else:
        alpha = float(el["alpha"].get("value", 0.1)) if "alpha" in el else 0.1
    if not (np.isfinite(alpha) and alpha > 0):
        raise InputError(f"alpha must be finite and > 0, got {alpha!r}", path=path, field=f"{field}.alpha")
    imported = {"source": str(path), "distribution": dist}
    if "eta" in el and "k" in el:
        sp = [_spectrum_values(el[k], path, f"{field}.{k}") for k in ("eta", "k")]
        if sp[0] is None or sp[1] is None:
            raise InputError("eta and k must be spectra ('wavelength:value' pairs) to be matched to a metal",
                             path=path, field=field)
        grid = WavelengthGrid(400.0, 700.0, 5.0)
        n = np.interp(grid.wavelengths, *sp[0])
        k = np.interp(grid.wavelengths, *sp[1])
        oc, de = nearest_shipped_metal(base_colour(n, k, grid))
        imported["optical_constants_dE2000"] = de
    else:
        name = el["material"].get("value", "Cu") if "material" in el else "Cu"  # Mitsuba's default metal
        oc = ALIASES.get(name.lower())
        if oc is None or oc not in SHIPPED:
            raise InputError(f"material {name!r}: no shipped optical constants for it (shipped: "
                             f"{sorted(SHIPPED)}); give eta and k spectra instead", path=path, field=f"{field}.material")
        imported["material"] = name
    d = {"format": FORMAT, "region": region, "model": dist, "lobe": {"lobe": dist, "alpha": alpha},
         "values": {"scale": 1.0, "alpha": alpha}, "optical_constants": oc, "converged": False, "import": imported}
    params_from_dict(d, path)  # what every reader of a parameter file checks
    return d


def _parent_id(root, child) -> str | None:
    """The ``id`` of the ``twosided`` (or other) element that wraps ``child``, if any."""
    for parent in root.iter():
        if child in list(parent) and parent.get("id"):
            return parent.get("id")
    return None


__all__ = ["export_mitsuba", "scene_dict", "roughconductor_to_params", "to_xml", "for_load_dict", "write_ply", "Matrix", "LookAt", "TAGS"]
