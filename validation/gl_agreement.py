"""The GL frame against the project's reference renderer :mod:`jkatana.render`, same camera, light, exposure.

:func:`reference_frame` renders an :class:`~jkatana.interactive.scene.View`
with :func:`jkatana.render.renderer.prepare` / :func:`~jkatana.render.renderer.render_view`
(a ``lookat`` camera at the view's pose, the built-in blade and map, the same
spectral environment radiance passed as ``env_radiance``, no rotation, float32,
``reference`` mode: MIS of the lobe mixture and of the environment). Both paths
look the environment up with :func:`jkatana.light.envmap.direction_to_uv`'s
convention (u = 0.5 + atan2(x, −z)/2π, v = acos y/π, Y up) and weigh spectra with
:func:`jkatana.render.film.film_weights` (flat radiance 1 → Y = 1), and both
displays are :func:`jkatana.spectral.to_display` with one fixed exposure.

:func:`blade_mask` is the reference renderer's own G-buffer
(:func:`jkatana.render.gbuffer.gbuffer_mesh`, one ray per pixel centre) of the
same view: the pixels a rasteriser without MSAA should cover.

:func:`compare` gives ΔE2000 (mean, p95, max; :func:`jkatana.spectral.delta_e_2000_8bit`)
over the pixels that both paths call blade.
"""

from __future__ import annotations

import numpy as np

from jkatana.interactive.scene import View
from jkatana.render.camera import Camera


def render_scene(view: View, *, mode: str = "reference", samples: int = 256, exposure: float = 1.0,
                 seed: int = 0) -> dict:
    """A :mod:`jkatana.render` scene dict for ``view`` (environment replaced at :func:`reference_frame`)."""
    pose = np.asarray(view.pose, np.float64)
    eye = pose[:3, 3]
    return {
        "geometry": {"mesh": "builtin:katana"},
        "material": {"map": "builtin", "optical_constants": "Fe-Johnson"},
        "environment": {"type": "constant", "radiance": 1.0, "resolution": [4, 8]},
        "camera": {"type": "lookat", "position": eye.tolist(), "look_at": (eye - pose[:3, 2]).tolist(),
                   "up": pose[:3, 1].tolist(), "fov_deg": float(np.rad2deg(view.yfov)),
                   "resolution": [int(view.width), int(view.height)]},
        "render": {"mode": mode, "samples": int(samples), "seed": int(seed), "precision": "float32"},
        "film": {"colourspace": "sRGB", "exposure": float(exposure)},
    }


def shared_environment(name: str) -> np.ndarray:
    """Spectral radiance ``(H, W, 61)`` of a shared environment map (``envmaps/<name>`` of
    :func:`jkatana.shared.shared_data`) as ``jkatana render`` loads it (the scene's default upsampling and
    scale, through :func:`jkatana.render.renderer.load_environment` and its cache)."""
    from jkatana.render.renderer import load_environment
    from jkatana.render.scenefile import scene_from_dict
    from jkatana.shared import shared_data

    d = render_scene(View(np.eye(4), 0.5, 8, 6))
    d["environment"] = {"type": "exr" if name.endswith(".exr") else "hdr", "path": str(shared_data("envmaps", name))}
    sc = scene_from_dict(d)
    return np.asarray(load_environment(sc, sc.spectral.grid), np.float64)


def sun_glint_view(mesh, radiance: np.ndarray, width: int, height: int) -> View:
    """:func:`jkatana.interactive.scene.glint_view` at the most powerful compact source of ``radiance``
    (:func:`jkatana.light.sun.find_compact_sources`): the sun's glint on the blade's flat."""
    import jax.numpy as jnp

    from jkatana.interactive.scene import glint_view
    from jkatana.light.envmap import EnvMap
    from jkatana.light.sun import split_compact_sources
    from jkatana.spectral import DEFAULT_GRID

    split = split_compact_sources(EnvMap(jnp.asarray(radiance, jnp.float32), DEFAULT_GRID), max_sources=1)
    if split.cap is None:
        raise ValueError("the environment has no compact source to glint")
    return glint_view(mesh, np.asarray(split.cap.direction, np.float64), width, height)


def view_camera(view: View) -> Camera:
    """The :class:`jkatana.render.camera.Camera` of ``view`` (the camera :func:`render_scene` describes)."""
    from jkatana.render.renderer import camera_for
    from jkatana.render.scenefile import scene_from_dict

    return camera_for(scene_from_dict(render_scene(view)))


def blade_mask(mesh, view: View) -> np.ndarray:
    """``(H, W)`` bool: pixels whose centre ray hits ``mesh`` (:func:`jkatana.render.gbuffer.gbuffer_mesh`)."""
    from jkatana.render.gbuffer import gbuffer_mesh

    return gbuffer_mesh(mesh, view_camera(view)).mask


def reference_frame(radiance: np.ndarray, view: View, *, mode: str = "reference", samples: int = 256,
                    seed: int = 0):
    """:class:`jkatana.render.frame.Frame` of ``view`` under the spectral environment ``radiance (H, W, 61)``."""
    from jkatana.render.renderer import prepare, render_view
    from jkatana.render.scenefile import scene_from_dict

    sc = scene_from_dict(render_scene(view, mode=mode, samples=samples, seed=seed))
    prep = prepare(sc, env_radiance=np.asarray(radiance, np.float32))
    return render_view(prep)


def display255(xyz: np.ndarray, exposure: float) -> np.ndarray:
    """:func:`jkatana.spectral.to_display` (sRGB) × 255, NOT rounded: the reference side of a comparison
    (the GL frame's own 8-bit rounding then counts as its error; rounding both would add a second one)."""
    from jkatana.spectral import to_display

    return 255.0 * to_display(xyz, "sRGB", exposure=exposure)


def compare(gl8: np.ndarray, ref8: np.ndarray, mask: np.ndarray) -> tuple[dict, np.ndarray]:
    """ΔE2000 statistics over ``mask`` and the ΔE image; images are sRGB-encoded on a 0–255 scale
    (uint8, or float as :func:`display255`): ``{"mean", "p95", "max", "pixels"}``
    (:func:`jkatana.spectral.delta_e_stats`)."""
    from jkatana.spectral import delta_e_2000_8bit, delta_e_stats

    de = delta_e_2000_8bit(gl8, ref8)
    return {**delta_e_stats(de[mask], prefix=""), "pixels": int(mask.sum())}, de


def gl_frame(state, view: View, mesh, *, return_mask: bool = False):
    """The GL frame of ``view`` (EGL, no MSAA) and, on request, the mask of rasterised blade pixels."""
    from jkatana.interactive import glrender as G

    r = G.BakedOffscreenRenderer(state, view.width, view.height)
    img = r.render(G.build_scene(mesh, view), mask=return_mask)
    mask = r.last_mask.copy() if return_mask else None
    r.delete()
    return (img, mask) if return_mask else img


#: The hiraji lobe of each family case of the agreement checks (``tests/test_interactive_families.py``,
#: ``benchmarks/bench_interactive.py``): the demo map's hiraji width (μ ≈ 0.05) in each fit model's values.
FAMILY_FILES = {"ggx": {"scale": 2000.0, "alpha": 0.05},
                "gtr": {"scale": 2000.0, "alpha": 0.05, "gamma": 1.5},
                "two-lobe": {"scale": 2000.0, "alpha": 0.05, "alpha_haze": 0.3, "weight": 0.9}}


def params_file(path, model: str, region: str, values: dict) -> str:
    """A parameter file as ``jkatana fit`` writes it for ``model`` (a :data:`jkatana.models.fitted.FIT_MODELS`
    name), its ``lobe`` built by the fit model from the natural ``values``; returns its path."""
    import json
    from pathlib import Path

    import jax.numpy as jnp

    from jkatana.models.fitted import FIT_MODELS

    fm = FIT_MODELS[model]
    lobe = fm.build(jnp.asarray(fm.shape_from_natural(values))).to_params()
    Path(path).write_text(json.dumps({"format": "jkatana-params/1", "region": region, "model": model, "lobe": lobe,
                                      "values": values, "optical_constants": "Fe-Johnson", "converged": True}))
    return str(path)


def files_prepared(folder, view: View, radiance: np.ndarray, files: dict, *, samples: int = 256):
    """:func:`jkatana.render.renderer.prepare` of the built-in blade and map at ``view`` under ``radiance``
    (reference mode, ``samples`` per pixel), its regions' lobes from parameter files ``{region: (model, values)}``
    written into ``folder`` (:func:`params_file`)."""
    from pathlib import Path

    from jkatana.render.renderer import prepare
    from jkatana.render.scenefile import scene_from_dict

    d = render_scene(view, samples=samples)
    for region, (model, values) in files.items():
        d["material"][region] = params_file(Path(folder) / f"{region}.json", model, region, values)
    return prepare(scene_from_dict(d), env_radiance=np.asarray(radiance, np.float32))


def files_agreement(folder, view: View, radiance: np.ndarray, files: dict, *, samples: int = 256) -> dict:
    """The GL frame of :func:`files_prepared`'s scene against its :mod:`jkatana.render` frame (reference mode,
    the same parameter files; exposure :func:`jkatana.render.film.auto_exposure`'s): :func:`compare`'s ΔE2000
    statistics, and the wall times of the reference frame, of the bake (its lobe tables built or read in
    ``folder``/cache, as on a first use) and of the GL frame (``reference_s``, ``bake_s``, ``gl_s``), and the
    bake's ``tail`` (whether a region reads a tail tap)."""
    import time
    from pathlib import Path

    from jkatana.interactive import bake as B
    from jkatana.interactive import glrender as G
    from jkatana.interactive import scene as S
    from jkatana.interactive.lobe_tables import region_lobes
    from jkatana.render.film import auto_exposure
    from jkatana.render.renderer import render_view

    prep = files_prepared(folder, view, radiance, files, samples=samples)
    t0 = time.perf_counter()
    fr = render_view(prep)
    t1 = time.perf_counter()
    exposure = auto_exposure(fr.xyz, fr.mask, key=0.6, percentile=75.0)
    lobes = region_lobes({"hiraji": prep.plan.hiraji_lobe, "hamon": prep.plan.hamon_lobe})
    baked = B.cached_bake(radiance, rank=3, lobes=lobes, cache_dir=Path(folder) / "cache")
    t2 = time.perf_counter()
    st = G.ShadingState(baked, np.asarray(prep.maps, np.float64), exposure=exposure)
    img, gl_mask = gl_frame(st, view, S.blade(), return_mask=True)
    t3 = time.perf_counter()
    stats = compare(img, display255(fr.xyz, exposure), fr.mask & gl_mask)[0]
    return {**stats, "reference_s": t1 - t0, "bake_s": t2 - t1, "gl_s": t3 - t2,
            "tail": bool(np.any(baked.tail[..., 2] > 0))}
