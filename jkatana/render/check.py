"""Scene check before a frame is shaded: is the object where the camera can see it, at a sensible size?

A user's mesh in millimetres read as metres is 1000× too large: the camera
ends up inside it and every ray hits a back face, or the frame is filled with
one texel's worth of surface; a mesh far off the camera's axis leaves the
frame empty. Each of these renders without an error, so :func:`check_scene`
looks before shading, with a coarse grid of the camera's own rays (at most
64 × 48, through the same intersector as the G-buffer), and returns at most
one message naming the likely cause and fix; :func:`warn_scene` issues it as a
:class:`SceneWarning`.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from jkatana.errors import SceneWarning

#: ratio of the object's size to the camera's distance from its target (the scale the camera is
#: placed for) beyond which the object cannot be the subject of the frame
TOO_LARGE = 20.0
#: fraction of the field of view below which the object is a speck
TOO_SMALL = 0.01


def _coarse(camera, max_w: int = 64):
    w, h = camera.width, camera.height
    s = max(1, math.ceil(max(w / max_w, h / (max_w * 3 // 4))))
    return dataclasses.replace(camera, width=max(1, w // s), height=max(1, h // s))


def check_scene(geometry, camera) -> str | None:
    """One message (cause and fix) when the camera is inside the object, the object's size is far from the
    camera's scale, or no pixel would cover it; ``None`` when the frame looks sane.

    `geometry` is :func:`jkatana.render.renderer.load_geometry`'s result (a trimesh mesh or
    ``("sphere", center, radius)``); `camera` a :class:`jkatana.render.camera.Camera`.
    """
    pos = np.asarray(camera.position, np.float64)
    fov = math.radians(camera.fov_deg)
    if isinstance(geometry, tuple):
        _, center, radius = geometry
        centre, size = np.asarray(center, np.float64), 2.0 * float(radius)
        inside = float(np.linalg.norm(pos - centre)) < float(radius)
        hits = None
    else:
        from jkatana.render.gbuffer import _intersector

        mesh = geometry
        centre = mesh.bounds.mean(0)
        size = float(np.linalg.norm(mesh.extents))
        origin, dirs = _coarse(camera).rays()
        d = dirs.reshape(-1, 3)
        isect, _ = _intersector(mesh)
        tri = np.asarray(isect.intersects_first(np.broadcast_to(origin, d.shape), d), np.int64)
        hit = tri >= 0
        hits = float(hit.mean())
        if mesh.is_watertight:
            inside = bool(mesh.contains(pos[None])[0])
        else:  # open mesh: most first hits seen from behind
            back = np.sum(mesh.face_normals[tri[hit]] * d[hit], -1) > 0
            inside = hit.mean() > 0.9 and back.mean() > 0.9
    # the camera's own scale: how far it stands from what it looks at
    dist = float(np.linalg.norm(pos - np.asarray(camera.look_at, np.float64)))
    span = f"{size:.3g} m across"
    units = ("a mesh in millimetres or centimetres read as metres (scenes are in metres): convert it with "
             "`jkatana shape MESH --units mm -o MESH.ply` (or cm)")
    if inside:
        return (f"the camera (at {np.round(pos, 4).tolist()}) is inside the object ({span}): nothing outside it "
                f"can be seen. Likely {units}; else move the camera out (camera.distance / position)")
    if dist > 0 and size / dist > TOO_LARGE:
        return (f"the object ({span}) is {size / dist:.0f}× larger than the camera's distance to its target "
                f"({dist:.3g} m): likely {units}")
    if dist > 0 and (size / dist) < TOO_SMALL * fov:
        return (f"the object ({span}) fills {math.degrees(size / dist):.2g}° of the camera's {camera.fov_deg:g}° "
                f"view at {dist:.3g} m: likely a mesh in metres placed in a scene written for millimetres, "
                "or a camera too far; check `jkatana shape`'s units report and camera.distance")
    if hits is not None and hits == 0.0:
        return (f"no pixel covers the object (centre {np.round(centre, 4).tolist()}, {span}); the camera at "
                f"{np.round(pos, 4).tolist()} looks at {np.round(camera.look_at, 4).tolist()}: aim camera.target "
                "/ look_at at the object (`jkatana shape` reports its frame and size)")
    return None


def warn_scene(geometry, camera) -> str | None:
    """:func:`check_scene`, issued as one :class:`SceneWarning`; returns the message (or ``None``)."""
    msg = check_scene(geometry, camera)
    if msg:
        warnings.warn(msg, SceneWarning, stacklevel=2)
    return msg
