"""The interactive path's two ways to draw a frame shade the same: deferred (one G-buffer target with the
octahedral normal and the map coordinates, the view direction from the pixel's camera ray) and forward
(the shader on every rasterised fragment, the view direction from the interpolated position)."""

from __future__ import annotations

import numpy as np
import pytest

from jkatana.interactive import bake as B
from jkatana.interactive import glchunks as C
from jkatana.interactive import scene as S


@pytest.mark.gl
@pytest.mark.parametrize("closeup", [False, True])
def test_deferred_frame_is_the_forward_frame(glr, closeup):
    """Same pixels covered (interior: 1-pixel edges may differ by rasterisation of the full-screen pass) and,
    on them, the same 8-bit colour within 2 levels (float rounding of two different view-direction paths)
    everywhere and within 1 level on 99 % of them."""
    sc = S.default_scene("sky", 160, 120)
    view = S.closeup_view(sc.mesh, 160, 120) if closeup else sc.view
    studio = S.environment("studio", height=32)           # not symmetric about +Y: a turned light shows
    st = glr.ShadingState(B.cached_bake(studio, sc.grid, rank=3), sc.refl_map)
    frames = {}
    for deferred in (True, False):
        r = glr.BakedOffscreenRenderer(st, view.width, view.height, deferred=deferred)
        frames[deferred] = r.render(glr.build_scene(sc.mesh, view)).astype(int)
        r.delete()
    bg = frames[True][0, 0]
    cover = {k: np.any(f != bg, -1) for k, f in frames.items()}
    both = cover[True] & cover[False]
    assert both.sum() > 500 and (cover[True] ^ cover[False]).sum() < 0.02 * both.sum()
    d = np.abs(frames[True] - frames[False]).max(-1)[both]
    assert d.max() <= 2 and np.mean(d <= 1) >= 0.99, (d.max(), np.mean(d <= 1))
    # it can fail: the light turned by 90° about +Y (what a wrong view direction does) is far off
    st.env_rotation = np.deg2rad(90.0)
    r = glr.BakedOffscreenRenderer(st, view.width, view.height)
    turned = r.render(glr.build_scene(sc.mesh, view)).astype(int)
    r.delete()
    st.env_rotation = 0.0
    assert np.abs(turned - frames[False]).max(-1)[both].mean() > 5


@pytest.mark.gl
def test_culled_gbuffer_pass_changes_no_pixel(glr, monkeypatch):
    """The G-buffer pass draws only the run of triangles from the first to the last chunk in the frustum,
    and the shading pass is scissored to the drawn chunks' projected boxes: the frame is the one drawn with
    the whole mesh and an unscissored full-screen triangle, pixel for pixel, in views that see all, part or a
    sliver of the blade, and one whose camera sits beside it looking along it (no box: a corner is behind)."""
    sc = S.default_scene("sky", 200, 150)
    st = glr.ShadingState(B.cached_bake(sc.radiance, sc.grid, rank=3), sc.refl_map)
    beside = S.View(S.look_at(np.array([0.35, -0.02, 0.01]), np.array([0.7, -0.02, 0.0])), np.deg2rad(60.0), 200, 150)
    views = {"demo": sc.view, "closeup": S.closeup_view(sc.mesh, 200, 150),
             "orbit": S.orbit_views(sc.mesh, 3, 200, 150, distance=0.45)[1], "beside": beside}
    whole = C.visible_range

    def draw(view, full: bool):
        with monkeypatch.context() as m:
            if full:
                m.setattr(glr, "visible_range", lambda p, mvp: (0, len(p.indices), whole(p, mvp)[2]))
                m.setattr(glr, "screen_box", lambda c, w, h: None)
            r = glr.BakedOffscreenRenderer(st, view.width, view.height)
            scene = glr.build_scene(sc.mesh, view)
            frame = r.render(scene, mask=True)
            box = C.screen_box(r._r._renderer._drawn_corners, view.width, view.height)
            mask = r.last_mask.copy()
            r.delete()
        return frame, mask, box, scene

    for name, view in views.items():
        culled, mask, box, scene = draw(view, False)
        full, _, _, _ = draw(view, True)
        assert mask.sum() > 50, name
        assert np.array_equal(culled, full), (name, int(np.any(culled != full, -1).sum()))
        if name == "closeup":                     # the culling is on: most of the blade is not drawn
            prim = next(iter(scene.mesh_nodes)).mesh.primitives[0]
            V = np.linalg.inv(scene.get_pose(scene.main_camera_node))
            P = scene.main_camera_node.camera.get_projection_matrix(view.width, view.height)
            assert C.visible_range(prim, P @ V)[1] < 0.2 * len(prim.indices)
        assert (box is None) == (name == "beside"), (name, box)


def test_screen_box_holds_every_projected_corner(glr):
    """The scissor box holds every projected corner on the screen; a corner behind the camera's plane
    gives no box (the whole viewport); no chunk drawn, an empty box."""
    rng = np.random.default_rng(3)
    w, h = 320, 240
    c = np.ones((5, 8, 4))
    c[..., :2] = rng.normal(0.0, 0.3, (5, 8, 2))
    c[..., 3] = rng.uniform(0.5, 2.0, (5, 8))
    c[..., :2] *= c[..., 3:]
    x, y, bw, bh = C.screen_box([c], w, h)
    px = (c[..., :2].reshape(-1, 2) / c[..., 3].reshape(-1, 1) * 0.5 + 0.5) * (w, h)
    inside = px[(px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)]
    assert len(inside) > 20
    assert np.all(inside[:, 0] >= x) and np.all(inside[:, 0] <= x + bw)
    assert np.all(inside[:, 1] >= y) and np.all(inside[:, 1] <= y + bh)
    assert bw < w and bh < h                      # and is not the whole screen
    c[0, 0, 3] = -0.1
    assert C.screen_box([c], w, h) is None
    assert C.screen_box([], w, h) == (0, 0, 0, 0)


@pytest.mark.gl
def test_instanced_primitive_is_drawn_whole(glr):
    """A primitive with instance poses is not chunk-culled (its chunks' boxes ignore the instances): both
    instances are drawn, so a second copy of the blade moved up adds pixels."""
    sc = S.default_scene("sky", 160, 120)
    st = glr.ShadingState(B.cached_bake(sc.radiance, sc.grid, rank=3), sc.refl_map)
    counts = []
    for instanced in (False, True):
        scene = glr.build_scene(sc.mesh, sc.view)
        prim = next(iter(scene.mesh_nodes)).mesh.primitives[0]
        if instanced:
            up = np.eye(4)
            up[1, 3] = 0.03
            prim.poses = np.stack([np.eye(4), up])
        r = glr.BakedOffscreenRenderer(st, 160, 120)
        r.render(scene, mask=True)
        counts.append(int(r.last_mask.sum()))
        r.delete()
    assert counts[0] > 100 and counts[1] > 1.3 * counts[0], counts
