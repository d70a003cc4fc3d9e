"""Direct per-pixel JAX evaluation of the same shading, for measuring the GL path.

Given the same camera and mesh, :func:`gbuffer` casts one ray through each
pixel centre (trimesh; Embree when installed) and interpolates the vertex
normals and UVs barycentrically, which is what the rasteriser does at pixel
centres without MSAA. :func:`shade` then integrates, per pixel and per
wavelength,

    L_o(λ) = ∫ [w f_hiraji(μ0) + (1 − w) f_hamon(μ1)](L, V; λ) cos θi L_env(L, λ) dω_i

with :meth:`jkatana.models.Hiraji.brdf_cos` / :meth:`~jkatana.models.Hamon.brdf_cos`
(exact conductor Fresnel, all 61 wavelengths, no low-rank basis, no
prefiltering) by Gauss–Legendre × uniform-azimuth quadrature of each lobe in
half-vector space (:func:`jkatana.interactive.bake.halfvector_quadrature`),
looking the *unfiltered* spectral environment up bilinearly with the GL
texture conventions. XYZ by eq. (6), display by
:func:`jkatana.spectral.to_display` and :func:`~jkatana.spectral.to_png8`.

Differences from the GL frame are therefore exactly the baked approximations
(split-sum prefiltering, low-rank Fresnel, level interpolation, the blended
environment level, float textures, 8-bit output) plus rasterisation at the
silhouette. :func:`delta_e_2000` compares two display images in CIELAB.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.interactive.bake import halfvector_quadrature
from jkatana.models import Conductor, Hamon, Hiraji
from jkatana.spectral import DEFAULT_GRID, WavelengthGrid
from jkatana.render.film import film_weights
from jkatana.spectral.colorimetry import to_display, to_png8


def camera_rays(view):
    """Origins and unit directions ``(H·W, 3)`` through pixel centres (row 0 at the top), world frame."""
    W, H = view.width, view.height
    t = np.tan(view.yfov / 2)
    x = (2 * (np.arange(W) + 0.5) / W - 1) * t * W / H
    y = (1 - 2 * (np.arange(H) + 0.5) / H) * t
    X, Y = np.meshgrid(x, y)
    d_cam = np.stack([X, Y, -np.ones_like(X)], -1).reshape(-1, 3)
    d = d_cam @ view.pose[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(view.pose[:3, 3], d.shape).copy(), d


def gbuffer(mesh, view) -> dict:
    """Ray-cast G-buffer: ``mask (H, W)``, and for hit pixels ``position``, ``normal``, ``uv`` ``(H, W, ·)``."""
    import trimesh

    o, d = camera_rays(view)
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector
        inter = RayMeshIntersector(mesh)
    except Exception:  # no Embree
        inter = mesh.ray
    loc, idx_ray, idx_tri = inter.intersects_location(o, d, multiple_hits=False)
    H, W = view.height, view.width
    mask = np.zeros(H * W, bool)
    mask[idx_ray] = True
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[idx_tri], loc)
    f = mesh.faces[idx_tri]
    n = np.einsum("pk,pkc->pc", bary, mesh.vertex_normals[f])
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    uv = np.einsum("pk,pkc->pc", bary, np.asarray(mesh.visual.uv)[f])
    out = {"mask": mask.reshape(H, W)}
    for name, val in (("position", loc), ("normal", n), ("uv", uv)):
        a = np.zeros((H * W, val.shape[1]))
        a[idx_ray] = val
        out[name] = a.reshape(H, W, -1)
    return out


def bilinear(image, s, t, wrap_s: bool):
    """GL_LINEAR lookup of ``image (H, W, C)`` at texture coordinates ``(s, t)`` (t = 0 is row 0)."""
    H, W = image.shape[:2]
    x = s * W - 0.5
    y = t * H - 0.5
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0, y0 = x0.astype(jnp.int32), y0.astype(jnp.int32)

    def col(i):
        return jnp.mod(i, W) if wrap_s else jnp.clip(i, 0, W - 1)

    r0, r1 = jnp.clip(y0, 0, H - 1), jnp.clip(y0 + 1, 0, H - 1)
    c0, c1 = col(x0), col(x0 + 1)
    return ((1 - fy) * ((1 - fx) * image[r0, c0] + fx * image[r0, c1])
            + fy * ((1 - fx) * image[r1, c0] + fx * image[r1, c1]))


def _frame(n):
    a = jnp.where(jnp.abs(n[..., :1]) < 0.9, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
    t = jnp.cross(a, n)
    t = t / jnp.linalg.norm(t, axis=-1, keepdims=True)
    return t, jnp.cross(n, t), n


@functools.partial(jax.jit, static_argnames=("n_phi", "n_psi"))
def _shade_chunk(N, Vw, w, mu0, mu1, env, env_rot, conductor, wxyz, n_phi, n_psi):
    t, b, n = _frame(N)
    Vl = jnp.stack([jnp.sum(Vw * t, -1), jnp.sum(Vw * b, -1), jnp.sum(Vw * n, -1)], -1)   # (P, 3)
    total = 0.0
    for model, mu, weight in ((Hiraji, mu0, w), (Hamon, mu1, 1.0 - w)):
        def one(V, m):
            Hh, wh = halfvector_quadrature(m, n_phi, n_psi)
            vh = Hh @ V
            L = 2 * vh[:, None] * Hh - V
            f = model(jnp.ones((), m.dtype), m).brdf_cos(L, jnp.broadcast_to(V, L.shape), conductor)
            return L, f * (4.0 * jnp.maximum(vh, 0.0) * wh)[:, None]
        L, fw = jax.vmap(one)(Vl, mu)                                                        # (P, Q, 3), (P, Q, wl)
        Lw = L[..., :1] * t[:, None] + L[..., 1:2] * b[:, None] + L[..., 2:] * n[:, None]
        Le = Lw @ env_rot.T
        u = 0.5 + jnp.arctan2(Le[..., 0], -Le[..., 2]) / (2 * jnp.pi)
        v = jnp.arccos(jnp.clip(Le[..., 1], -1.0, 1.0)) / jnp.pi
        rad = bilinear(env, u, v, wrap_s=True)                                               # (P, Q, wl)
        total = total + weight[:, None] * jnp.sum(fw * rad, axis=1)
    visible = jnp.sum(N * Vw, -1) > 0
    return jnp.where(visible[:, None], total @ wxyz, 0.0)


def shade(gbuf: dict, view, radiance: np.ndarray, refl_map: np.ndarray, *, grid: WavelengthGrid = DEFAULT_GRID,
          env_rotation: float = 0.0, source: str = "Fe-Johnson", n_phi: int = 24, n_psi: int = 32,
          chunk: int = 256, dtype=jnp.float32) -> np.ndarray:
    """Per-pixel XYZ ``(H, W, 3)`` of the blended lobes under the environment (0 where no hit)."""
    mask = gbuf["mask"]
    N = gbuf["normal"][mask]
    P = gbuf["position"][mask]
    Vw = view.pose[:3, 3] - P
    Vw /= np.linalg.norm(Vw, axis=-1, keepdims=True)
    uv = gbuf["uv"][mask]
    m = np.asarray(bilinear(jnp.asarray(refl_map, dtype), jnp.asarray(uv[:, 0], dtype),
                            jnp.asarray(uv[:, 1], dtype), wrap_s=False))
    c, s_ = np.cos(env_rotation), np.sin(env_rotation)
    env_rot = jnp.asarray([[c, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c]], dtype)
    conductor = Conductor.from_table(source, grid, dtype=dtype)
    env = jnp.asarray(radiance, dtype)
    wxyz = jnp.asarray(film_weights(grid), dtype)
    out = np.zeros((len(N), 3))
    n = len(N)
    for i in range(0, n, chunk):
        sl = slice(i, min(i + chunk, n))
        pad = chunk - (sl.stop - sl.start)

        def p(a):
            a = np.asarray(a[sl], np.float64)
            return jnp.asarray(np.concatenate([a, np.repeat(a[-1:], pad, 0)]) if pad else a, dtype)
        res = _shade_chunk(p(N), p(Vw), p(m[:, 0]), p(m[:, 1]), p(m[:, 2]), env, env_rot, conductor, wxyz,
                           n_phi=n_phi, n_psi=n_psi)
        out[sl] = np.asarray(res)[: sl.stop - sl.start]
    img = np.zeros(mask.shape + (3,))
    img[mask] = out
    return img


def display8(xyz: np.ndarray, exposure: float = 1.0, colourspace: str = "sRGB", transfer=None) -> np.ndarray:
    """The reference display transform: :func:`jkatana.spectral.to_display` then :func:`to_png8`."""
    return to_png8(to_display(xyz, colourspace, transfer, exposure=exposure))


def delta_e_2000(a8: np.ndarray, b8: np.ndarray) -> np.ndarray:
    """CIEDE2000 between two sRGB 8-bit images ``(H, W, 3)`` (colour-science, D65)."""
    import colour

    def lab(x):
        xyz = colour.sRGB_to_XYZ(np.asarray(x, np.float64) / 255.0)
        return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    return colour.delta_E(lab(a8), lab(b8), method="CIE 2000")
