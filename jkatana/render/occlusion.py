"""Occluders on the host: what the camera cannot see, and which traced directions they shadow.

Occluders (:class:`~jkatana.render.gbuffer.Occluders`) are black: they hide what lies behind
them from the camera (:func:`primary_blocked`) and block the environment and lights along the
directions the shader traces (:func:`visibility`, from
:func:`~jkatana.render.shading.ray_directions`), which the shader then weighs by
(:class:`~jkatana.render.plan.Visibility`). Both are ray casts on the host.
"""

from __future__ import annotations

import numpy as np

from jkatana.render.camera import Camera
from jkatana.render.gbuffer import GBuffer
from jkatana.render.plan import Visibility


def primary_blocked(gb: GBuffer, camera: Camera, occluders) -> np.ndarray:
    """``(H·W,)`` bool: the camera rays whose first hit is an occluder in front of the object (or of the
    sky); those pixels are black."""
    H, W = gb.mask.shape
    origin, _ = camera.rays()
    d_occ = occluders.first_hit(np.broadcast_to(origin, (H * W, 3)), gb.ray.reshape(-1, 3))
    d_obj = np.full(H * W, np.inf)
    d_obj[gb.index] = np.linalg.norm(gb.hit_position - origin, axis=-1)
    return d_occ < d_obj


def visibility(occluders, rays, position, normal) -> Visibility:
    """Host step: ray-cast every direction of ``rays`` (NumPy :class:`Rays`) from the pixels against ``occluders``.

    Origins are the G-buffer positions nudged along the normal (relative to the
    scene's scale) so that an occluder touching the surface does not shadow it
    through round-off.
    """
    pos = np.asarray(position, np.float64)
    eps = 1e-5 * max(1.0, float(np.abs(pos).max(initial=0.0)))
    origin = pos + eps * np.asarray(normal, np.float64)

    def cast(d, max_dist=None):
        P, K = d.shape[0], d.shape[1]
        if K == 0:
            return np.ones((P, 0), np.float32)
        o = np.broadcast_to(origin[:, None, :], d.shape)
        md = None if max_dist is None else np.asarray(max_dist).reshape(-1)
        return occluders.visible(o.reshape(-1, 3), np.asarray(d).reshape(-1, 3), md, eps).reshape(P, K)

    return Visibility(cast(np.asarray(rays.mirror)[:, None])[:, 0], cast(np.asarray(rays.lobe)),
                      cast(np.asarray(rays.env)), cast(np.asarray(rays.lights), np.asarray(rays.light_dist)))
