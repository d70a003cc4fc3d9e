"""The glTF export against ``jkatana render``: pyrender's own metallic-roughness shader renders the ``.glb``.

The built-in blade with a GGX fit in both regions (:func:`ggx_params`: the
parameter file ``jkatana fit --model ggx`` writes, through the fit model's own
``build``) is exported by :func:`jkatana.export.gltf.export_gltf`, read back
with trimesh (the ``.glb``'s own mesh, normals, UVs and material) and drawn by
pyrender's stock shader (``pyrender/shaders/mesh.frag``: GGX D of α =
roughness², Schlick Fresnel, Schlick–Smith shadowing with k = (r + 1)²/8,
the Khronos glTF-WebGL-PBR sample's direct-light terms), not by jkatana's. Both
renderers see one light and nothing else: a directional D65 light
(``[[lights]] type = "directional"`` in jkatana; a pyrender
``DirectionalLight`` of the same linear sRGB colour and irradiance), a black
environment in jkatana (constant radiance 1e-9: the scene file wants > 0) and
no ambient or image-based light in pyrender (it has none).

pyrender writes ``clamp(pow(c, 1/2.2), 0, 1)`` to an 8-bit buffer. The
comparison undoes that exactly: every frame is drawn at a few light scales
(exposure bracketing, :data:`BRACKETS`), each pixel is taken from the
brightest frame in which it is below :data:`SATURATED` (so none is clipped and
the 8-bit step is small), decoded with the power 2.2 and divided by its scale:
linear sRGB in the light's units, as jkatana's XYZ is.

:func:`compare_view` reports display-referred ΔE2000 (mean, p95, max;
:func:`jkatana.spectral.delta_e_display`, exposure from the reference's 99th
percentile) over the blade pixels both renderers cover (jkatana's mask eroded
by one pixel, pyrender's drawn pixels), and over the lit ones (reference
Y ≥ 1 % of that 99th percentile), with the mean ratio of luminances where lit.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np

#: The GGX fit of each region (α; the scale is a camera-unit gain, unused in the normalised convention):
#: the hiraji near the paper's μ0 = 0.05 (equal-width α = 0.06), the hamon near the built-in map's μ1 = 0.2.
GGX_ALPHA = {"hiraji": 0.06, "hamon": 0.24}
#: Light scales of the exposure bracket (each ×4 the previous one).
BRACKETS = (1.0, 4.0, 16.0, 64.0)
#: 8-bit level at and above which a pixel counts as clipped (pyrender clamps at 255).
SATURATED = 250
#: pyrender's output transfer: ``pow(c, 1/2.2)`` (mesh.frag).
PYRENDER_GAMMA = 2.2


def ggx_params(region: str, alpha: float) -> dict:
    """A ``jkatana-params/1`` file of a GGX fit of ``region`` (its ``lobe`` built by the fit model itself)."""
    import jax.numpy as jnp

    from jkatana.fit._model import FIT_MODELS

    fm = FIT_MODELS["ggx"]
    values = {"scale": 2000.0, "alpha": float(alpha)}
    lobe = fm.build(jnp.asarray(fm.shape_from_natural(values))).to_params()
    return {"format": "jkatana-params/1", "region": region, "model": "ggx", "lobe": lobe, "values": values,
            "optical_constants": "Fe-Johnson", "converged": True}


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def views(width: int = 200, height: int = 150) -> dict:
    """``{name: (View, light direction)}``: the views compared, each with its light (towards the light).

    - ``glint``: the light 25° off the flat's normal, the camera in its mirror
      direction (:func:`jkatana.interactive.scene.glint_view`): the peak of the lobe on the flat.
    - ``tail``: the same camera with the light turned 8° about +Y (30° off the normal): the flat shows
      the lobe's shoulder.
    - ``grazing``: the light 69° off the normal and its mirror camera: Fresnel and shadowing far from normal.
    - ``closeup``: :func:`jkatana.interactive.scene.closeup_view` (the flat near the hamon fills the
      frame) lit from its mirror direction.
    """
    from jkatana.interactive.scene import closeup_view, glint_view
    from jkatana.shape.katana import default_blade

    mesh = default_blade()
    l25 = _unit([0.25, 0.4, 1.0])
    c, s = np.cos(np.deg2rad(8.0)), np.sin(np.deg2rad(8.0))
    l_tail = np.array([c * l25[0] + s * l25[2], l25[1], -s * l25[0] + c * l25[2]])
    l70 = _unit([0.6, 2.5, 1.0])
    close = closeup_view(mesh, width, height)
    to_cam = np.asarray(close.pose)[:3, 2]     # the camera looks along its −z
    n = np.array([0.0, 0.0, 1.0])
    l_close = _unit(2 * (n @ to_cam) * n - to_cam)
    return {"glint": (glint_view(mesh, l25, width, height), l25),
            "tail": (glint_view(mesh, l25, width, height), l_tail),
            "grazing": (glint_view(mesh, l70, width, height), l70),
            "closeup": (close, l_close)}


def scene_dict(view, light_dir, folder: Path, *, samples: int = 16) -> dict:
    """The jkatana scene of one view: built-in blade and map, GGX files in ``folder``, one directional D65
    light, a black environment, reference mode."""
    pose = np.asarray(view.pose, np.float64)
    eye = pose[:3, 3]
    return {
        "geometry": {"mesh": "builtin:katana"},
        "material": {"map": "builtin", "optical_constants": "Fe-Johnson",
                     "hiraji": str(folder / "hiraji.json"), "hamon": str(folder / "hamon.json")},
        "environment": {"type": "constant", "radiance": 1e-9, "resolution": [4, 8]},
        "lights": [{"type": "directional", "direction": [float(x) for x in light_dir], "spectrum": "D65",
                    "intensity": 1.0}],
        "camera": {"type": "lookat", "position": eye.tolist(), "look_at": (eye - pose[:3, 2]).tolist(),
                   "up": pose[:3, 1].tolist(), "fov_deg": float(np.rad2deg(view.yfov)),
                   "resolution": [int(view.width), int(view.height)]},
        "render": {"mode": "reference", "samples": int(samples), "seed": 0, "precision": "float32"},
        "film": {"colourspace": "sRGB", "exposure": 1.0},
        "output": {"directory": str(folder / "out"), "name": "blade"},
    }


def write_params(folder: Path, alphas: dict | None = None) -> None:
    """The two GGX parameter files (:func:`ggx_params`) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    for region, a in (GGX_ALPHA if alphas is None else alphas).items():
        (folder / f"{region}.json").write_text(json.dumps(ggx_params(region, a)))


def write_scene_toml(path: Path, d: dict) -> Path:
    """``d`` (a :func:`scene_dict`) as a scene file :func:`jkatana.render.scenefile.load_scene` reads."""
    from jkatana.render.scenefile import scene_from_dict, scene_to_toml

    path.write_text(scene_to_toml(scene_from_dict(d)))
    return path


def light_rgb() -> np.ndarray:
    """Linear sRGB of the jkatana light (D65 / 100 × intensity, as :func:`jkatana.render.renderer.prepare`
    builds it) through the film's weights (:func:`jkatana.render.film.film_weights`): the colour and
    irradiance a pyrender light must have to match it."""
    from jkatana.render.film import film_weights
    from jkatana.spectral import DEFAULT_GRID
    from jkatana.spectral.colorimetry import illuminant, xyz_to_linear_rgb

    spec = illuminant("D65", DEFAULT_GRID) / 100.0 * 1.0
    return np.asarray(xyz_to_linear_rgb(spec @ film_weights(DEFAULT_GRID), "sRGB"), np.float64)


def reference(scene) -> tuple[np.ndarray, np.ndarray]:
    """``(XYZ (H, W, 3), mask)`` of ``jkatana render``'s reference mode for ``scene``."""
    from jkatana.render.renderer import prepare, render_view

    fr = render_view(prepare(scene))
    return np.asarray(fr.xyz, np.float64), np.asarray(fr.mask, bool)


def pyrender_linear(glb: Path, view, light_dir, rgb_light: np.ndarray, peak: float) -> tuple[np.ndarray, np.ndarray]:
    """``(linear sRGB (H, W, 3), drawn mask)`` of the ``.glb`` drawn by pyrender's own shader (module docstring).

    ``peak``: the expected largest linear value at light scale 1 (the reference's), which sets the first
    bracket so that it does not clip; if it still clips the whole bracket is lowered until it does not.
    """
    import trimesh

    from jkatana.interactive.gl import import_pyrender

    pyrender = import_pyrender()
    tm = trimesh.load(str(glb), process=False)
    geoms = list(tm.geometry.values())
    if len(geoms) != 1:
        raise ValueError(f"{glb}: expected one mesh, got {len(geoms)}")
    mesh = pyrender.Mesh.from_trimesh(geoms[0], smooth=True)
    z = _unit(light_dir)                       # pyrender's light shines along its node's −z
    x = _unit(np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z))
    light_pose = np.eye(4)
    light_pose[:3, :3] = np.stack([x, np.cross(z, x), z], -1)
    colour = rgb_light / rgb_light.max()
    r = pyrender.OffscreenRenderer(view.width, view.height)
    try:
        base = 0.8 / max(peak, 1e-12)
        while True:
            frames = []
            for b in BRACKETS:
                sc = pyrender.Scene(ambient_light=np.zeros(3), bg_color=np.zeros(4))
                sc.add(mesh)
                sc.add(pyrender.PerspectiveCamera(yfov=float(view.yfov), aspectRatio=view.width / view.height,
                                                  znear=1e-3, zfar=100.0),
                       pose=np.asarray(view.pose, np.float64))
                sc.add(pyrender.DirectionalLight(color=colour, intensity=float(rgb_light.max() * base * b)),
                       pose=light_pose)
                img, depth = r.render(sc)
                frames.append((np.asarray(img[..., :3]), base * b, depth > 0))
            if frames[0][0].max() < SATURATED:
                break
            base /= 8.0
    finally:
        r.delete()
    out = np.zeros(frames[0][0].shape, np.float64)
    done = np.zeros(out.shape[:2], bool)
    for img, scale, _ in reversed(frames):     # brightest first: the first unclipped frame of each pixel
        ok = (img.max(-1) < SATURATED) & ~done
        out[ok] = (img[ok] / 255.0) ** PYRENDER_GAMMA / scale
        done |= ok
    return out, frames[0][2]


def compare_view(xyz_ref: np.ndarray, ref_mask: np.ndarray, rgb_gl: np.ndarray, gl_mask: np.ndarray) -> dict:
    """ΔE2000 of the glTF frame (linear sRGB) against the reference (XYZ) over the blade pixels both cover
    (module docstring): ``{"blade": stats, "lit": stats, "lit_luminance_ratio", "pixels", "lit_pixels"}``."""
    from scipy.ndimage import binary_erosion

    from jkatana.spectral import delta_e_display, reference_exposure
    from jkatana.spectral.colorimetry import xyz_to_rgb_matrix

    m = binary_erosion(ref_mask, iterations=1) & gl_mask
    xyz_gl = rgb_gl @ np.linalg.inv(xyz_to_rgb_matrix("sRGB")).T
    ref, gl = xyz_ref[m], xyz_gl[m]
    exposure = reference_exposure(ref)
    blade = delta_e_display(ref, gl, exposure=exposure)
    lit = ref[:, 1] >= 0.01 / exposure
    out = {"blade": blade, "pixels": int(m.sum()), "lit_pixels": int(lit.sum())}
    if lit.any():
        out["lit"] = delta_e_display(ref[lit], gl[lit], exposure=exposure)
        out["lit_luminance_ratio"] = float(gl[lit, 1].sum() / ref[lit, 1].sum())
    return out


def term_ratios(incidence_deg: float, alpha: float, optical_constants: str = "Fe-Johnson") -> dict:
    """pyrender's factors over jkatana's at the peak of a lobe seen in the mirror direction (H = N,
    N·L = N·V = cos θ at ``incidence_deg``), luminance under a D65 light: what the ``lit_luminance_ratio``
    of a glint view should be.

    - ``fresnel``: Schlick's F0 + (1 − F0)(1 − cos θ)⁵ from the exported base colour (Schlick 1994),
      in linear sRGB, over the exact conductor Fresnel integrated over the spectrum (jkatana).
    - ``shadowing``: pyrender's Schlick–Smith G = Π cos/(cos (1 − k) + k), k = (r + 1)²/8, r = √α
      (Karis 2013, "Real shading in Unreal Engine 4", for analytic lights) over jkatana's separable
      Smith of GGX, G1 = 2/(1 + √(1 + α² tan²θ)) (Walter et al. 2007, eq. 34). glTF 2.0's Appendix B
      specifies height-correlated Smith, which at such α is within 1 % of jkatana's.
    - ``denominator``: 4 cos² θ/(4 cos² θ + 0.001): pyrender's guard in f = F G D/(4 N·L N·V + 0.001).
    - ``product``: the three multiplied.
    """
    import jax.numpy as jnp

    from jkatana.export.gltf import base_colour
    from jkatana.models.fresnel import fresnel_conductor
    from jkatana.render.film import film_weights
    from jkatana.spectral import DEFAULT_GRID
    from jkatana.spectral.colorimetry import illuminant, luminance_weights
    from jkatana.spectral.optical_constants import load as load_oc

    grid = DEFAULT_GRID
    n, k = load_oc(optical_constants).on_grid(grid)
    c = float(np.cos(np.deg2rad(incidence_deg)))
    light = illuminant("D65", grid) / 100.0
    f_exact = np.asarray(fresnel_conductor(jnp.asarray(c), jnp.asarray(n), jnp.asarray(k)), np.float64)
    y_exact = float((f_exact * light) @ film_weights(grid)[:, 1])
    f0 = base_colour(n, k, grid)
    schlick = f0 + (1.0 - f0) * (1.0 - c) ** 5
    y_schlick = float(luminance_weights("sRGB") @ (schlick * light_rgb()))
    r = max(float(np.sqrt(alpha)), 0.04)
    kk = (r + 1.0) ** 2 / 8.0
    g_pyr = (c / (c * (1.0 - kk) + kk)) ** 2
    tan2 = (1.0 - c * c) / (c * c)
    g_jk = (2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))) ** 2
    den = 4 * c * c / (4 * c * c + 0.001)
    out = {"fresnel": y_schlick / y_exact, "shadowing": float(g_pyr / g_jk), "denominator": den}
    out["product"] = out["fresnel"] * out["shadowing"] * out["denominator"]
    return out


def run(folder: Path, *, width: int = 200, height: int = 150, samples: int = 16, names=None) -> dict:
    """Export and compare every view of :func:`views` (or ``names``): ``{view: compare_view(...) + export}``."""
    from jkatana.export.gltf import export_gltf
    from jkatana.render.scenefile import load_scene

    folder = Path(folder)
    write_params(folder)
    rgb_light = light_rgb()
    results = {}
    for name, (view, light) in views(width, height).items():
        if names is not None and name not in names:
            continue
        scene = load_scene(write_scene_toml(folder / f"{name}.toml", scene_dict(view, light, folder,
                                                                              samples=samples)))
        summary = export_gltf(scene, folder / f"gltf_{name}")
        xyz, mask = reference(scene)
        from jkatana.spectral.colorimetry import xyz_to_linear_rgb

        peak = float(np.max(np.asarray(xyz_to_linear_rgb(xyz, "sRGB"))))
        rgb, drawn = pyrender_linear(summary["glb"], view, light, rgb_light, peak)
        res = compare_view(xyz, mask, rgb, drawn)
        res["light"] = [float(x) for x in light]
        results[name] = res
    return results


if __name__ == "__main__":  # pragma: no cover - a measurement script
    import sys
    import tempfile

    out = run(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp()))
    print(textwrap.indent(json.dumps(out, indent=1), ""))
