"""A scene's blade out as glTF 2.0 (``.glb``): mesh, UVs and a metallic-roughness material.

glTF 2.0's metallic-roughness material (Khronos Group 2017, glTF 2.0
specification, §3.9 and Appendix B "BRDF Implementation") is one Cook–Torrance
lobe with the GGX / Trowbridge–Reitz distribution (Trowbridge & Reitz 1975;
Walter, Marschner, Li & Torrance 2007) of α = roughness², Smith visibility and
Schlick's Fresnel F = F0 + (1 − F0)(1 − |V·H|)⁵ (Schlick 1994), where a metal's
F0 is its base colour. Blender, three.js and model-viewer read it. What
:func:`export_gltf` writes, and what is exact:

- **Mesh and UVs**: the mesh :func:`jkatana.render.renderer.load_geometry` gives
  ``jkatana render`` (the built-in blade, or the scene's file), with the
  renderer's vertex normals and its per-vertex UVs (trimesh's convention, so
  that the ``.glb`` read back by trimesh gives jkatana's UVs again; trimesh
  turns v into glTF's top-left convention on export). An analytic sphere is
  tessellated (:data:`SPHERE_SEGMENTS`) with the renderer's sphere UVs
  (u = ½ + atan2(x, z)/2π, v = colatitude/π).
- **Distribution**: a GGX lobe maps exactly: roughness = √α (glTF's α is
  roughness²). Every other lobe gets the GGX α of equal *reflected width*:
  ``α = σ/√2``, σ = the lobe's :meth:`~jkatana.models.lobes.Lobe.reflected_width`
  (the second moment of the reflected lobe; GGX's own is √2 α). The paper's
  Gaussian lobe of half-width μ (Mochizuki et al., eq. 1) becomes
  α = μ/√(ln 2) ≈ 1.20 μ. A heavy-tailed GTR or a two-lobe sum keeps its width,
  not its tails.
- **Blend** (eq. 5 of Mochizuki et al.): the renderer sums the hiraji lobe with
  weight w and the hamon lobe with 1 − w per texel. glTF has one lobe, so a texel
  gets α = w α₀ + (1 − w) α₁ (:data:`BLENDS` ``"linear"``; exact where w is 0 or
  1, most of the built-in blade). Measured against ``jkatana render`` on the
  413 pixels of the built-in blade's close-up where 0.05 < w < 0.95 (GGX fit,
  one directional light, pyrender's shader): ΔE2000 mean 0.85 / p95 2.0, against
  1.26 / 3.1 for the α of equal second moment √(w α₀² + (1 − w) α₁²) (``"moment"``,
  the form of :meth:`jkatana.models.lobes.Mixture.reflected_width`) and 3.8 / 6.4
  for the α of equal peak (``"peak"``).
- **Roughness texture**: glTF's ``metallicRoughnessTexture`` (linear, not sRGB):
  G = roughness (per texel, 8 bits, scaled so that the largest roughness of the
  map is 255 and ``roughnessFactor`` carries that largest value: a uniform
  roughness is exact in the factor), B = metallic = 1, R = 1 (occlusion, unused).
  The texels are the reflectance map's own (or resampled by the renderer's
  bilinear lookup, ``texture_size``); the sampler clamps at the edges, as
  jkatana's map lookup does.
- **Base colour**: the conductor's normal-incidence reflectance
  F0(λ) = ((n − 1)² + k²)/((n + 1)² + k²) (the Fresnel equations at θ = 0; Born &
  Wolf 1999, §14.2) seen under CIE D65 (the white of sRGB), integrated against the
  CIE 1931 observer (eq. 6) and converted to linear sRGB / Rec. 709 (eq. 7), as
  glTF's ``baseColorFactor`` is linear (spec §3.9.2). Written as floats (trimesh
  stores colours in 8 bits; the exact value is put back into the file).
- **Approximated** (listed in the notes file beside the ``.glb``): Schlick's
  Fresnel from F0 instead of the exact conductor Fresnel at every angle and
  wavelength (on iron up to 0.18 in F near grazing); RGB instead of spectra
  (exact at normal incidence under a D65 light, the base colour's white); one
  GGX lobe per texel instead of the blend of two lobes and their own shapes
  (the paper's V-cavity shadowing, a Gaussian's light tails, GTR's heavy ones);
  the glTF viewer's own visibility term (Appendix B: height-correlated Smith)
  instead of jkatana's separable Smith or V-cavity; 8-bit roughness.
- **Not expressible**, refused in one line (:class:`~jkatana.errors.InputError`):
  a roughness above 1 (α > 1: a lobe wider than glTF's roughness range) and the
  calibrated convention (``[material] calibration``: the lobes' gains χ/K, β/K,
  s/K are absolute reflectances a glTF metal, whose albedo is its Schlick
  Fresnel, does not carry).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from jkatana.errors import InputError

#: Format tag of the notes file written beside the ``.glb``.
NOTES_FORMAT = "jkatana-export-gltf/1"
#: (segments around, segments pole to pole) of a tessellated analytic sphere.
SPHERE_SEGMENTS = (128, 64)
#: glTF sampler constants (OpenGL enums, glTF 2.0 §5.26): linear filtering, clamp to edge.
_LINEAR, _LINEAR_MIPMAP_LINEAR, _CLAMP_TO_EDGE = 9729, 9987, 33071
#: The approximations every export makes (copied into the notes file).
APPROXIMATIONS = (
    "Fresnel: Schlick's F0 + (1 - F0)(1 - V.H)^5 from the normal-incidence reflectance (the base colour), "
    "not the exact conductor Fresnel of n + ik at every angle (Schlick 1994; iron: up to 0.18 in F near grazing)",
    "colour: RGB (linear Rec. 709) instead of spectra; the base colour is F0(lambda) under D65, exact at normal "
    "incidence under a D65 light",
    "lobe: one GGX lobe per texel; each region's alpha is that of equal reflected width (exact for GGX), the "
    "renderer's blend w * hiraji + (1 - w) * hamon becomes alpha = w * alpha_hiraji + (1 - w) * alpha_hamon; the "
    "lobes' own shapes (Gaussian, V-cavity shadowing, GTR tails, two-lobe haze) are not kept",
    "shadowing: the viewer's own (glTF 2.0 Appendix B: height-correlated Smith) instead of jkatana's",
    "roughness: 8 bits per texel (scaled to the map's largest roughness, carried exactly by roughnessFactor)",
)


def normal_incidence_reflectance(n: np.ndarray, k: np.ndarray) -> np.ndarray:
    """F0 = ((n − 1)² + k²) / ((n + 1)² + k²): a conductor's reflectance at normal incidence from air
    (the Fresnel equations at θ = 0; Born & Wolf 1999, *Principles of Optics*, §14.2)."""
    n, k = np.asarray(n, np.float64), np.asarray(k, np.float64)
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


def nearest_shipped_metal(base: np.ndarray) -> tuple[str, float]:
    """``(name, ΔE2000)``: the shipped optical-constant table whose :func:`base_colour` is nearest to the linear
    sRGB colour ``base`` (an imported material's metal, when the file names none jkatana ships)."""
    from jkatana.spectral import DEFAULT_GRID
    from jkatana.spectral.colorimetry import delta_e_2000, xyz_to_rgb_matrix
    from jkatana.spectral.optical_constants import SHIPPED
    from jkatana.spectral.optical_constants import load as load_oc

    to_xyz = np.linalg.inv(xyz_to_rgb_matrix("sRGB"))
    best, best_de = "", np.inf
    for name in sorted(SHIPPED):
        n, k = load_oc(name).on_grid(DEFAULT_GRID)
        de = float(delta_e_2000(to_xyz @ base_colour(n, k, DEFAULT_GRID), to_xyz @ np.asarray(base, np.float64)))
        if de < best_de:
            best, best_de = name, de
    return best, best_de


def base_colour(n: np.ndarray, k: np.ndarray, grid) -> np.ndarray:
    """``(3,)`` linear sRGB of the reflectance F0(λ) (:func:`normal_incidence_reflectance`) under CIE D65.

    XYZ = Σ F0 D65 x̄ȳz̄ Δλ / Σ D65 ȳ Δλ (CIE 1931 2° observer, eq. 6 of Mochizuki
    et al.), then sRGB's XYZ → RGB matrix (IEC 61966-2-1, eq. 7): a white
    reflector gives (1, 1, 1) up to D65's chromaticity on a truncated grid (0.3 % on the paper's
    400–700 nm), since D65 is sRGB's white.
    Linear, as glTF's ``baseColorFactor`` is (glTF 2.0 §3.9.2).
    """
    from jkatana.spectral.colorimetry import illuminant, xyz_to_linear_rgb, xyz_weights

    W = xyz_weights(grid)
    d65 = illuminant("D65", grid)
    xyz = (normal_incidence_reflectance(n, k) * d65) @ W / (d65 @ W[:, 1])
    return np.asarray(xyz_to_linear_rgb(xyz, "sRGB"), np.float64)


def region_alpha(region: str, key, width: np.ndarray) -> np.ndarray:
    """GGX α of equal reflected width of one region's lobe at the per-texel ``width`` (μ or α).

    ``key`` is the region's lobe key from :func:`~jkatana.render.renderer.load_material`
    (``None``: the paper's :class:`~jkatana.models.lobes.Gaussian` for the hiraji,
    :class:`~jkatana.models.lobes.GaussianVCavity` for the hamon); the lobe is built
    as the renderer builds it in the normalised convention
    (:meth:`~jkatana.models.lobe_id.LobeId.rendered`, :meth:`~jkatana.models.lobe_id.LobeId.at_width`). α = σ/√2 inverts GGX's
    reflected width σ = √2 α, so a GGX lobe maps to itself.
    """
    import jax.numpy as jnp

    from jkatana.models.lobes import Gaussian, GaussianVCavity

    mu = jnp.asarray(np.asarray(width, np.float32))
    if key is None:
        lobe = (Gaussian if region == "hiraji" else GaussianVCavity)(mu, normalised=True)
    else:
        lobe = key.rendered(None).at_width(mu, jnp.float32)
    sigma = np.asarray(lobe.reflected_width(), np.float64)
    return sigma / math.sqrt(2.0)


def _blend_moment(w, a0, a1):
    """√(w α₀² + (1 − w) α₁²): equal second moment (:meth:`jkatana.models.lobes.Mixture.reflected_width`)."""
    return np.sqrt(w * a0 ** 2 + (1.0 - w) * a1 ** 2)


def _blend_linear(w, a0, a1):
    """w α₀ + (1 − w) α₁: the widths interpolated as the map interpolates w."""
    return w * a0 + (1.0 - w) * a1


def _blend_peak(w, a0, a1):
    """(w α₀⁻² + (1 − w) α₁⁻²)^(−1/2): equal peak, GGX's D(H = N) = 1/(π α²) being the blend's there."""
    tiny = 1e-12
    return 1.0 / np.sqrt(w / np.maximum(a0, tiny) ** 2 + (1.0 - w) / np.maximum(a1, tiny) ** 2)


#: How a texel's two lobes (hiraji with weight w, hamon with 1 − w) become one GGX α, by name.
BLENDS = {"moment": _blend_moment, "linear": _blend_linear, "peak": _blend_peak}


def texel_alpha(maps: np.ndarray, lobes: dict, blend: str = "linear") -> tuple[np.ndarray, dict]:
    """``(α (H, W), {region: α (H, W)})``: the blend's GGX α per texel and each region's own.

    ``blend`` names a rule of :data:`BLENDS`; the default, ``"linear"``, w α₀ + (1 − w) α₁, matched
    ``jkatana render`` best where the regions blend (module docstring).
    """
    if blend not in BLENDS:
        raise InputError(f"must be one of {sorted(BLENDS)}, got {blend!r}", field="blend")
    w = np.clip(np.asarray(maps[..., 0], np.float64), 0.0, 1.0)
    a0 = region_alpha("hiraji", lobes["hiraji"], maps[..., 1])
    a1 = region_alpha("hamon", lobes["hamon"], maps[..., 2])
    return BLENDS[blend](w, a0, a1), {"hiraji": a0, "hamon": a1}


def _check_expressible(scene, maps, per_region: dict, alpha: np.ndarray) -> None:
    """One :class:`InputError` line for what a glTF metallic-roughness material cannot hold (module docstring)."""
    mat = scene.material
    if mat.calibration is not None:
        raise InputError("a calibrated scene's lobes carry absolute gains (chi/K, beta/K, s/K) that glTF's "
                         "metallic-roughness material (albedo = its Schlick Fresnel) cannot hold: export the "
                         "normalised scene (remove [material] calibration)", field="material.calibration")
    if not np.all(np.isfinite(alpha)):
        raise InputError("the map gives a non-finite lobe width", path=mat.map if mat.map != "builtin" else None,
                         field="material.map")
    w = np.asarray(maps[..., 0])
    for region, used in (("hiraji", w > 0), ("hamon", w < 1)):
        a = per_region[region][used]
        if a.size and float(a.max()) > 1.0:
            source = getattr(mat, region)
            field = f"material.{region}" if source is not None else (
                "material.map" if mat.map is not None else f"material.{'mu0' if region == 'hiraji' else 'mu1'}")
            raise InputError(f"the {region} lobe is wider than glTF can express: its GGX alpha of equal reflected "
                             f"width reaches {float(a.max()):.3g} > 1 (roughness > 1)",
                             path=source if source is not None else (
                                 mat.map if mat.map not in (None, "builtin") else None), field=field)


def _resample(maps: np.ndarray, size: int | None) -> np.ndarray:
    """The map at texel centres of a texture whose longer side is ``size`` (the renderer's bilinear lookup,
    :func:`jkatana.render.frame.sample_map`); the map itself when ``size`` is None or its own."""
    H, W = maps.shape[:2]
    if size is None or max(H, W) == size:
        return np.asarray(maps, np.float32)
    import jax.numpy as jnp

    from jkatana.render.frame import sample_map

    scale = size / max(H, W)
    h, w = max(1, round(H * scale)), max(1, round(W * scale))
    u, v = np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h)
    uv = np.stack([u.ravel(), v.ravel()], -1).astype(np.float32)
    out = sample_map(jnp.asarray(maps, jnp.float32), jnp.asarray(uv))
    return np.asarray(out, np.float32).reshape(h, w, -1)


def sphere_mesh(center, radius: float, segments: tuple[int, int] = SPHERE_SEGMENTS):
    """A latitude–longitude tessellation of the renderer's analytic sphere with its UVs
    (u = ½ + atan2(x, z)/2π, v = colatitude/π; :func:`jkatana.render.gbuffer.gbuffer_sphere`) and the exact
    normals; the seam's vertices are doubled so that u runs 0 → 1."""
    import trimesh

    nu, nv = segments
    u = np.linspace(0.0, 1.0, nu + 1)
    v = np.linspace(0.0, 1.0, nv + 1)
    U, V = np.meshgrid(u, v)                        # rows: v (pole to pole)
    phi, theta = (U - 0.5) * 2 * np.pi, V * np.pi   # atan2(x, z) = phi
    n = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), np.sin(theta) * np.cos(phi)], -1).reshape(-1, 3)
    idx = np.arange((nv + 1) * (nu + 1)).reshape(nv + 1, nu + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    # counter-clockwise seen from outside (outward face normals); the triangles with two vertices on a pole
    # (zero area) are left out
    faces = np.concatenate([np.stack([a, c, b], -1)[1:].reshape(-1, 3), np.stack([b, c, d], -1)[:-1].reshape(-1, 3)])
    verts = np.asarray(center, np.float64) + radius * n
    return trimesh.Trimesh(verts, faces, vertex_normals=n, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=np.stack([U.ravel(), V.ravel()], -1)))


def roughness_texture(alpha: np.ndarray) -> tuple[np.ndarray, float]:
    """``(texture (H, W, 3) uint8 in jkatana's row order, roughnessFactor)`` of a per-texel α.

    glTF packs roughness in G and metallic in B (spec §3.9.2); R is 255 (occlusion
    1 if a viewer reads an ORM texture). G = round(255 · √α / r_max) with
    ``roughnessFactor`` r_max = the largest √α, so the factor times the texel is
    the roughness to 8 bits, and exactly where the map is uniform.
    """
    r = np.sqrt(np.maximum(np.asarray(alpha, np.float64), 0.0))
    r_max = float(r.max()) if r.size else 0.0
    g = np.full(r.shape, 255, np.uint8) if r_max <= 0 else np.rint(255.0 * r / r_max).astype(np.uint8)
    tex = np.stack([np.full_like(g, 255), g, np.full_like(g, 255)], -1)
    return tex, r_max


def _tree_fix(base: np.ndarray, name: str):
    """trimesh's ``tree_postprocessor``: the exact float base colour (trimesh stores 8 bits), a clamp-to-edge
    sampler on every texture (jkatana's map lookup clamps at the borders), the generator's name."""
    def fix(tree: dict) -> None:
        for m in tree.get("materials", []):
            pbr = m.setdefault("pbrMetallicRoughness", {})
            pbr["baseColorFactor"] = [float(x) for x in base] + [1.0]
        if tree.get("textures"):
            tree["samplers"] = [{"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP_LINEAR,
                                 "wrapS": _CLAMP_TO_EDGE, "wrapT": _CLAMP_TO_EDGE}]
            for t in tree["textures"]:
                t["sampler"] = 0
        tree.setdefault("asset", {})["generator"] = f"jkatana glTF export ({name})"
    return fix


def _write_folder(out_dir: Path, files: dict) -> None:
    """Create ``out_dir`` holding ``files`` ({name: bytes}) all at once, never replacing anything
    (:func:`jkatana.io.atomic.atomic_folder`)."""
    from jkatana.io.atomic import atomic_folder

    def exists():
        return InputError("output folder exists: nothing was overwritten (choose a new folder)", path=out_dir,
                          field="output")

    with atomic_folder(out_dir, exists_error=exists) as tmp:
        for fname, data in files.items():
            (tmp / fname).write_bytes(data)


def export_gltf(scene, out_dir: Path, *, texture_size: int | None = None, blend: str = "linear") -> dict:
    """Write ``out_dir/<name>.glb`` (mesh, UVs, metallic-roughness material) and ``out_dir/<name>.gltf.json``
    (what was approximated) for a loaded, validated scene (:func:`jkatana.render.scenefile.load_scene`).

    **Arguments:**

    - `scene`: a :class:`jkatana.render.scene.Scene`; its geometry, map, region
      parameter files and optical constants are loaded by the renderer's own
      loaders, so the export holds what ``jkatana render`` shades.
    - `out_dir`: a folder that must not exist yet: the files are written into a
      temporary folder beside it, which is renamed to ``out_dir`` when complete
      (nothing is ever overwritten; an interrupted export leaves no ``out_dir``, at
      most an empty hidden ``.<out_dir>.*`` folder beside it).
    - `texture_size`: the roughness texture's longer side in texels (the map
      resampled by the renderer's bilinear lookup); ``None``: the map's own texels.
    - `blend`: how a texel's two lobes become one α (:data:`BLENDS`; ``"linear"``, module docstring).

    **Returns:** ``{"glb", "notes", "base_color" (linear sRGB), "roughness_factor", "alpha" ({region: {min,
    median, max}} over the texels the region covers, and "blend"), "texture" ([H, W]), "vertices", "faces"}``.

    **Raises:** :class:`~jkatana.errors.InputError` for an existing ``out_dir``, a
    missing asset (from the renderer's loaders) and what glTF cannot express
    (module docstring).
    """
    from jkatana.render.renderer import load_geometry, load_material
    from jkatana.spectral.optical_constants import load as load_oc

    out_dir = Path(out_dir)
    _check_request(out_dir, texture_size)
    name = scene.output.name
    geometry = load_geometry(scene)
    maps, _, _, lobes = load_material(scene, geometry)
    grid = scene.spectral.grid
    try:
        n, k = load_oc(scene.material.optical_constants).on_grid(grid)
    except InputError as err:
        raise InputError(str(err), field="material.optical_constants") from None
    alpha_full, per_region = texel_alpha(maps, lobes, blend)
    _check_expressible(scene, maps, per_region, alpha_full)
    tex_maps = _resample(maps, texture_size)
    alpha, _ = texel_alpha(tex_maps, lobes, blend)
    tex, r_max = roughness_texture(alpha)
    base = np.clip(base_colour(n, k, grid), 0.0, 1.0)
    if isinstance(geometry, tuple):
        _, center, radius = geometry
        mesh = sphere_mesh(center, radius)
    else:
        mesh = geometry
    glb, out_mesh = _glb(mesh, name, base, tex, r_max)
    summary = {"format": NOTES_FORMAT, "name": name, "base_color": base.tolist(),
               "base_color_space": "linear sRGB (Rec. 709 primaries, D65), glTF baseColorFactor",
               "roughness_factor": r_max, "metallic_factor": 1.0,
               "alpha": _alpha_stats(maps, lobes, per_region, alpha_full),
               "texture": [int(tex.shape[0]), int(tex.shape[1])], "vertices": int(len(out_mesh.vertices)),
               "faces": int(len(out_mesh.faces)), "blend": blend,
               "optical_constants": str(scene.material.optical_constants),
               "approximations": list(APPROXIMATIONS)}

    _write_folder(out_dir, {f"{name}.glb": glb,
                            f"{name}.gltf.json": (json.dumps(summary, indent=2) + "\n").encode("utf-8")})
    summary = {k: v for k, v in summary.items() if k not in ("format", "approximations")}
    return {"glb": out_dir / f"{name}.glb", "notes": out_dir / f"{name}.gltf.json", **summary}


def _check_request(out_dir: Path, texture_size) -> None:
    """An export refused before any work: an existing ``out_dir``, a texture size outside [1, 8192]."""
    if out_dir.exists() or out_dir.is_symlink():
        raise InputError("output folder exists: nothing was overwritten (choose a new folder)", path=out_dir,
                         field="output")
    if texture_size is not None and (isinstance(texture_size, bool) or not isinstance(texture_size, int)
                                     or not 1 <= texture_size <= 8192):
        raise InputError(f"texture size must be an integer in [1, 8192], got {texture_size!r}",
                         field="texture_size")


def _glb(mesh, name: str, base: np.ndarray, tex: np.ndarray, r_max: float):
    """The binary glTF of the mesh (normals, UVs) with its metallic-roughness material, and the mesh written."""
    import trimesh
    from PIL import Image

    normals = np.asarray(mesh.vertex_normals, np.float64)
    uv = np.asarray(mesh.visual.uv, np.float64)
    material = trimesh.visual.material.PBRMaterial(
        name=f"{name}-steel", baseColorFactor=np.append(base, 1.0), metallicFactor=1.0, roughnessFactor=r_max,
        metallicRoughnessTexture=Image.fromarray(np.ascontiguousarray(tex[::-1])),  # trimesh: image row 0 at v = 1
        doubleSided=False)
    out_mesh = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces), process=False,
                               vertex_normals=normals,
                               visual=trimesh.visual.TextureVisuals(uv=uv, material=material))
    glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(out_mesh), include_normals=True,
                                           tree_postprocessor=_tree_fix(base, name))
    return glb, out_mesh


def _alpha_stats(maps, lobes: dict, per_region: dict, alpha_full: np.ndarray) -> dict:
    """Each region's α (min, median, max) over the texels it covers, with its lobe, and the blend's over all."""
    w = np.asarray(maps[..., 0])
    stats = {}
    for region, used in (("hiraji", w > 0), ("hamon", w < 1)):
        a = per_region[region][used]
        if a.size:
            stats[region] = {"min": float(a.min()), "median": float(np.median(a)), "max": float(a.max()),
                             "lobe": "paper" if lobes[region] is None else lobes[region].family}
    stats["blend"] = {"min": float(alpha_full.min()), "median": float(np.median(alpha_full)),
                      "max": float(alpha_full.max())}
    return stats


def _glb_or_gltf_json(path: Path) -> dict:
    """The glTF JSON of a ``.glb`` (its first chunk, glTF 2.0 §4.4) or a ``.gltf`` file."""
    data = path.read_bytes()
    if data[:4] == b"glTF":
        import struct

        length, kind = struct.unpack("<I4s", data[12:20])
        if kind != b"JSON":
            raise InputError("first chunk of the .glb is not JSON", path=path)
        data = data[20:20 + length]
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError(f"not a glTF file ({err})", path=path) from None


def gltf_to_params(path: Path, *, region: str = "hiraji") -> dict:
    """A ``jkatana-params/1`` parameter file (model ``"ggx"``) from a glTF file's metallic-roughness material.

    The inverse of :func:`export_gltf` for one region: α = roughness² (glTF 2.0
    Appendix B) per texel of ``roughnessFactor`` × the roughness texture's G
    channel, and the file's width is their median (a parameter file holds one;
    the 5th–95th percentiles are kept under ``"import"``). The optical constants
    are the shipped table whose base colour (:func:`base_colour`) is nearest to the
    file's ``baseColorFactor`` in CIEDE2000 (the distance is kept): a base colour
    is three numbers, n and k are spectra, so this names the closest known metal
    rather than recovering n, k. The scale (camera units) is 1: the file renders in
    the normalised convention. ``converged`` is false (no fit was made).

    **Raises:** :class:`~jkatana.errors.InputError` when the file cannot be read,
    has no metallic-roughness material, names a texture that cannot be read
    (missing), or is not a metal (metallic < 1).
    """
    import trimesh

    from jkatana.fit.params import FORMAT, params_from_dict
    from jkatana.models.lobes import GGX

    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path=path)
    tree = _glb_or_gltf_json(path)
    mats = tree.get("materials") or []
    if not mats or "pbrMetallicRoughness" not in mats[0]:
        raise InputError("holds no metallic-roughness material", path=path, field="materials")
    pbr = mats[0]["pbrMetallicRoughness"]
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as err:  # trimesh raises many types, a missing image among them
        raise InputError(f"cannot be read ({type(err).__name__}: {err})", path=path) from None
    geoms = list(getattr(loaded, "geometry", {"": loaded}).values())
    mat = next((g.visual.material for g in geoms if isinstance(getattr(g.visual, "material", None),
                                                                trimesh.visual.material.PBRMaterial)), None)
    if mat is None:
        raise InputError("holds no metallic-roughness material trimesh can read", path=path, field="materials")
    rough = float(pbr.get("roughnessFactor", 1.0))
    metal = float(pbr.get("metallicFactor", 1.0))
    if "metallicRoughnessTexture" in pbr:
        tex = mat.metallicRoughnessTexture
        if tex is None:
            raise InputError("names a metallic-roughness texture that cannot be read (missing image?)", path=path,
                             field="materials[0].pbrMetallicRoughness.metallicRoughnessTexture")
        t = np.asarray(tex.convert("RGB"), np.float64) / 255.0
        r, m = rough * t[..., 1], metal * t[..., 2]
    else:
        r, m = np.full((1, 1), rough), np.full((1, 1), metal)
    if float(np.median(m)) < 0.99:
        raise InputError(f"is not a metal (metallic {float(np.median(m)):.3g}): jkatana's models are conductors",
                         path=path, field="materials[0].pbrMetallicRoughness.metallicFactor")
    alpha = np.maximum(r, 0.0) ** 2
    a = float(np.median(alpha))
    base = np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])[:3], np.float64)
    best, best_de = nearest_shipped_metal(base)
    d = {"format": FORMAT, "region": region, "model": "ggx",
         "lobe": {"lobe": GGX.name, "alpha": a},  # GGX.to_params() of α, without a float32 round trip
         "values": {"scale": 1.0, "alpha": a}, "optical_constants": best, "converged": False,
         "import": {"source": str(path), "alpha_p5_p95": [float(np.percentile(alpha, 5)),
                                                           float(np.percentile(alpha, 95))],
                    "base_color": base.tolist(), "optical_constants_dE2000": best_de}}
    params_from_dict(d, path)  # what a reader checks, naming the file
    return d


__all__ = ["export_gltf", "gltf_to_params", "BLENDS", "base_colour", "nearest_shipped_metal", "normal_incidence_reflectance", "region_alpha", "texel_alpha",
           "roughness_texture", "sphere_mesh", "APPROXIMATIONS"]
