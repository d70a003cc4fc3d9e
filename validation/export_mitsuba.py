"""The Mitsuba 3 export checked by rendering it there: ``jkatana export --to mitsuba`` of a scene, rendered by
Mitsuba 3 from the XML it reads, against ``jkatana render``'s reference mode of the same scene.

Both frames are linear Rec. 709 in Mitsuba's film normalisation (jkatana's XYZ × Σȳ Δλ / 106.75, the
convention of :mod:`validation.mitsuba`), compared in CIE ΔE2000 on the object's pixels with the
reference's 99th-percentile luminance to display white on both sides (:func:`validation.mitsuba.compare`).
The jkatana frame is the reference; Mitsuba renders the exported files with its ``direct`` integrator.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np

from validation.mitsuba import MITSUBA_Y_NORM, compare, mitsuba_variant


def render_exported(xml: Path, *, spp: int, seed: int = 0, variant: str | None = None) -> np.ndarray:
    """Mitsuba 3 renders an exported ``scene.xml`` (``(H, W, 3)`` linear Rec. 709), in a subprocess so that
    an LLVM variant's JIT and memory stay out of the test process."""
    variant = variant or mitsuba_variant()
    out = Path(xml).with_name("mitsuba_frame.npy")
    code = ("import mitsuba as mi, numpy as np, sys; mi.set_variant(sys.argv[1]); "
            "s = mi.load_file(sys.argv[2]); "
            "np.save(sys.argv[3], np.asarray(mi.render(s, spp=int(sys.argv[4]), seed=int(sys.argv[5]))))")
    r = subprocess.run([sys.executable, "-c", code, variant, str(xml), str(out), str(spp), str(seed)],
                       capture_output=True, text=True, timeout=1800)
    if r.returncode != 0:
        raise RuntimeError(f"Mitsuba failed on {xml}:\n{r.stderr[-3000:]}")
    return np.load(out).astype(np.float64)


def render_jkatana(scene, *, spp: int, seed: int = 0, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``jkatana render``'s reference mode of ``scene``: ``(linear Rec. 709 (H, W, 3), object mask)``."""
    from jkatana.render.renderer import prepare, render_view
    from jkatana.spectral.colorimetry import xyz_to_linear_rgb, xyz_weights

    prep = prepare(scene, mode="reference", samples=spp)
    f = render_view(prep, seed=seed, supersample=supersample)
    scale = float(xyz_weights(prep.grid)[:, 1].sum()) / MITSUBA_Y_NORM
    return xyz_to_linear_rgb(np.asarray(f.xyz, np.float64) * scale, "ITU-R BT.709"), np.asarray(f.mask)


def agreement(scene, out_dir: Path, *, spp_mitsuba: int, spp_jkatana: int, seed: int = 0,
              supersample: int = 2) -> dict:
    """Export ``scene`` to ``out_dir`` (new), render both sides, and compare (module docstring): the
    ΔE2000 summary of :func:`validation.mitsuba.compare` plus both frames and the mask."""
    from jkatana.export.mitsuba import export_mitsuba

    export_mitsuba(scene, out_dir, spp=spp_mitsuba)
    rgb_mi = render_exported(Path(out_dir) / "scene.xml", spp=spp_mitsuba, seed=seed)
    rgb_jk, mask = render_jkatana(scene, spp=spp_jkatana, seed=seed, supersample=supersample)
    stats = compare(rgb_jk, rgb_mi, mask, erode=1)
    return {**stats, "mitsuba": rgb_mi, "jkatana": rgb_jk, "mask": mask}


def self_shadowed(scene, shape: tuple[int, int], *, cone: float, rays: int = 32, seed: int = 0) -> np.ndarray:
    """``(H, W)`` bool: pixels whose reflected lobe the object itself blocks.

    jkatana casts no shadow rays against the rendered object (only against ``[[occluders]]``), while
    Mitsuba's ``direct`` integrator shadows every light path by the whole scene: on a concave object the
    two integrals differ where the object hides part of the lobe's cone from the surface point. Per
    pixel centre (trimesh ray casting, Embree), ``rays`` directions uniform in the cone of half-angle
    ``cone`` about the mirror direction of the face normal are tested against the mesh.
    """
    from jkatana.render.renderer import camera_for, load_geometry

    mesh = load_geometry(scene)
    if isinstance(mesh, tuple):
        return np.zeros(shape, bool)
    cam = camera_for(scene)
    cam = dataclasses.replace(cam, width=shape[1], height=shape[0])
    origin, d = cam.rays()
    d = d.reshape(-1, 3)
    loc, ray, tri = mesh.ray.intersects_location(np.broadcast_to(origin, d.shape), d, multiple_hits=False)
    out = np.zeros(d.shape[0], bool)
    if not len(ray):
        return out.reshape(shape)
    n = mesh.face_normals[tri]
    n = np.where((np.sum(n * d[ray], -1) > 0)[:, None], -n, n)
    r = d[ray] - 2 * np.sum(d[ray] * n, -1, keepdims=True) * n
    rng = np.random.default_rng(seed)
    # directions uniform in the cone about r: a frame (t, b, r)
    t = np.cross(r, [0.0, 0.0, 1.0])
    t = np.where(np.linalg.norm(t, axis=-1, keepdims=True) < 1e-6, np.cross(r, [1.0, 0.0, 0.0]), t)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    b = np.cross(r, t)
    cos_t = 1 - rng.random((len(r), rays)) * (1 - np.cos(cone))
    sin_t = np.sqrt(1 - cos_t ** 2)
    phi = 2 * np.pi * rng.random((len(r), rays))
    dirs = (cos_t[..., None] * r[:, None] + (sin_t * np.cos(phi))[..., None] * t[:, None]
            + (sin_t * np.sin(phi))[..., None] * b[:, None]).reshape(-1, 3)
    start = np.repeat(loc + 1e-6 * n, rays, axis=0) + 1e-6 * dirs
    up = np.sum(dirs * np.repeat(n, rays, axis=0), -1) > 0  # below the surface the lobe is 0 anyway
    hit = np.zeros(len(dirs), bool)
    hit[up] = mesh.ray.intersects_any(start[up], dirs[up])
    out[ray] = hit.reshape(-1, rays).any(-1)
    return out.reshape(shape)
