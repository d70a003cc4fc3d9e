"""Which part of a mesh a view draws (:mod:`jkatana.interactive.glrender`'s deferred passes): a primitive's
triangles cut into consecutive runs (chunks) with their bounding boxes, the run of chunks inside a view's frustum
for the G-buffer pass, and the screen rectangle those chunks cover for the shading pass's scissor box.

The runs are compact slices of the blade when the triangles are ordered along the mesh
(:func:`order_along_mesh`, used by :func:`jkatana.interactive.glrender.build_scene`): llvmpipe's vertex stage is
single-threaded, and a close-up sees a tenth of the blade.
"""

from __future__ import annotations

import numpy as np


#: Chunks a mesh primitive's triangles are cut into for the G-buffer pass's frustum test and the shading
#: pass's scissor box (:func:`mesh_chunks`).
N_CHUNKS = 32
#: Slabs along the mesh's longest axis that :func:`order_along_mesh` orders the triangles by; within a slab the
#: mesh's own order (its strips) is kept, so that the vertex stage's cache still finds shared vertices.
SORT_SLABS = 4 * N_CHUNKS


def box_corners(lo, hi) -> np.ndarray:
    """The 8 homogeneous corners ``(8, 4)`` of the axis-aligned box ``[lo, hi]``."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return np.array([[(lo, hi)[i >> 2][0], (lo, hi)[(i >> 1) & 1][1], (lo, hi)[i & 1][2], 1.0] for i in range(8)])


def mesh_chunks(primitive, n: int = N_CHUNKS) -> tuple[np.ndarray, np.ndarray]:
    """``(starts, corners)``: the primitive's triangles (in index-buffer order) cut into ``n`` consecutive
    runs, ``starts`` ``(n + 1,)`` the first triangle of each run (and the count), ``corners`` ``(n, 8, 4)`` the
    homogeneous corners of each run's axis-aligned bounding box in model space. Cached on the primitive.
    The runs are compact when the triangles are ordered along the mesh (:func:`order_along_mesh`)."""
    cached = getattr(primitive, "_jk_chunks", None)
    if cached is not None:
        return cached
    tri = np.asarray(primitive.indices, np.int64).reshape(-1, 3)
    pos = np.asarray(primitive.positions, np.float64)
    n = max(1, min(n, len(tri)))
    starts = np.linspace(0, len(tri), n + 1).round().astype(np.int64)
    corners = np.stack([box_corners(p.min(0), p.max(0))
                        for p in (pos[tri[starts[k]:starts[k + 1]].ravel()] for k in range(n))])
    primitive._jk_chunks = (starts, corners)
    return primitive._jk_chunks


def visible_range(primitive, mvp: np.ndarray) -> tuple[int, int, np.ndarray]:
    """``(first, count, corners)``: the run of triangles from the first to the last chunk of the primitive
    whose box is not wholly outside one clip plane of ``mvp`` (model → clip), and those chunks' clip-space
    box corners ``(k, 8, 4)``. Primitives that are not single-instance indexed triangles are drawn whole:
    count -1, and the corners of their bounds (pyrender's, which hold the instances)."""
    from pyrender.constants import GLTF

    if primitive.indices is None or primitive.mode != GLTF.TRIANGLES or primitive.poses is not None:
        return 0, -1, (box_corners(*primitive.bounds) @ mvp.T)[None]
    starts, corners = mesh_chunks(primitive)
    clip = corners @ mvp.T                                        # (n, 8, 4)
    xyz, w = clip[..., :3], clip[..., 3:]
    outside = np.any(np.all(xyz < -w, axis=1) | np.all(xyz > w, axis=1), axis=-1)
    seen = np.flatnonzero(~outside)
    if len(seen) == 0:
        return 0, 0, clip[:0]
    first, last = int(seen[0]), int(seen[-1])
    return int(starts[first]), int(starts[last + 1] - starts[first]), clip[seen]


def screen_box(corners: list, w: int, h: int) -> tuple[int, int, int, int] | None:
    """``(x, y, width, height)`` pixel rectangle holding the projected clip-space box corners of the drawn
    chunks (:func:`visible_range`), one pixel wider on each side; ``(0, 0, 0, 0)`` where nothing was drawn;
    None (the whole viewport) where a corner lies behind the camera's plane."""
    c = np.concatenate([np.reshape(x, (-1, 4)) for x in corners]) if corners else np.zeros((0, 4))
    if len(c) == 0:
        return (0, 0, 0, 0)
    if np.any(c[:, 3] <= 1e-9):
        return None
    ndc = np.clip(c[:, :2] / c[:, 3:], -2.0, 2.0)
    x0, y0 = np.floor((ndc.min(0) * 0.5 + 0.5) * (w, h)).astype(int) - 1
    x1, y1 = np.ceil((ndc.max(0) * 0.5 + 0.5) * (w, h)).astype(int) + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    return (int(x0), int(y0), int(max(x1 - x0, 0)), int(max(y1 - y0, 0)))


def order_along_mesh(primitive) -> None:
    """Reorder an indexed primitive's triangles by slab along the mesh's longest axis (:data:`SORT_SLABS`;
    vertices, normals and UVs unchanged, the mesh's own order kept within a slab), so that :func:`mesh_chunks`'
    runs are compact slices of it."""
    tri = np.asarray(primitive.indices).reshape(-1, 3)
    pos = np.asarray(primitive.positions, np.float64)
    axis = int(np.argmax(np.ptp(pos, axis=0)))
    x = pos[tri.astype(np.int64), axis].mean(1)
    slab = np.floor((x - x.min()) / max(np.ptp(x), 1e-30) * SORT_SLABS).clip(0, SORT_SLABS - 1)
    primitive.indices = tri[np.argsort(slab, kind="stable")]


__all__ = ["N_CHUNKS", "SORT_SLABS", "box_corners", "mesh_chunks", "visible_range", "screen_box", "order_along_mesh"]
