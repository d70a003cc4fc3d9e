"""The interactive path's two ways to draw a frame shade the same: deferred (one G-buffer target with the
octahedral normal and the map coordinates, the view direction from the pixel's camera ray) and forward
(the shader on every rasterised fragment, the view direction from the interpolated position)."""

from __future__ import annotations

import numpy as np
import pytest

from jkatana.interactive import bake as B
from jkatana.interactive import scene as S


@pytest.fixture(scope="module")
def glr():
    from jkatana.interactive.gl import GLUnavailable

    try:
        from jkatana.interactive import glrender
    except GLUnavailable as err:                       # pragma: no cover - depends on the machine
        pytest.skip(str(err))
    return glrender


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
def test_culled_gbuffer_and_cover_polygon_change_no_pixel(glr, monkeypatch):
    """The G-buffer pass draws only the run of triangles from the first to the last chunk in the frustum,
    and the shading pass covers only the convex hull of the drawn chunks' projected boxes: the frame is the
    one drawn with the whole mesh and a full-screen triangle, pixel for pixel, in views that see all, part
    or a sliver of the blade, and one whose camera sits inside the blade's bounds (full-screen fallback)."""
    sc = S.default_scene("sky", 200, 150)
    st = glr.ShadingState(B.cached_bake(sc.radiance, sc.grid, rank=3), sc.refl_map)
    lo, hi = sc.mesh.bounds
    inside = S.View(S.look_at(np.array([0.35, -0.02, 0.01]), np.array([0.7, -0.02, 0.0])), np.deg2rad(60.0), 200, 150)
    views = {"demo": sc.view, "closeup": S.closeup_view(sc.mesh, 200, 150),
             "orbit": S.orbit_views(sc.mesh, 3, 200, 150, distance=0.45)[1], "inside": inside}
    whole = glr._visible_range

    def draw(view, full: bool):
        with monkeypatch.context() as m:
            if full:
                m.setattr(glr, "_visible_range", lambda p, mvp: (0, len(p.indices), whole(p, mvp)[2]))
                m.setattr(glr, "_cover_polygon", lambda c, w, h: glr._FULL_SCREEN)
            r = glr.BakedOffscreenRenderer(st, view.width, view.height)
            scene = glr.build_scene(sc.mesh, view)
            frame = r.render(scene, mask=True)
            rr = r._r._renderer
            cover = glr._cover_polygon(rr._cover_corners, view.width, view.height)
            mask = r.last_mask.copy()
            r.delete()
        return frame, mask, cover, scene

    for name, view in views.items():
        culled, mask, cover, scene = draw(view, False)
        full, _, _, _ = draw(view, True)
        assert mask.sum() > 50, name
        assert np.array_equal(culled, full), (name, int(np.any(culled != full, -1).sum()))
        if name == "closeup":                     # the culling is on: most of the blade is not drawn
            prim = next(iter(scene.mesh_nodes)).mesh.primitives[0]
            V = np.linalg.inv(scene.get_pose(scene.main_camera_node))
            P = scene.main_camera_node.camera.get_projection_matrix(view.width, view.height)
            assert glr._visible_range(prim, P @ V)[1] < 0.2 * len(prim.indices)
        if name == "demo":                        # the cover is far smaller than the screen
            x, y = ((cover * 0.5 + 0.5) * (view.width, view.height)).T
            area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
            assert area < 0.5 * view.width * view.height
        if name == "inside":
            assert np.array_equal(cover, glr._FULL_SCREEN)


def test_cover_polygon_holds_every_projected_corner_with_its_margin(glr):
    """Every projected box corner lies inside the cover polygon, at least COVER_MARGIN_PX from each edge;
    a corner behind the camera's plane gives the full-screen triangle; no chunk, no polygon."""
    rng = np.random.default_rng(3)
    w, h = 320, 240
    for _ in range(20):
        c = np.ones((5, 8, 4))
        c[..., :2] = rng.normal(0.0, 0.6, (5, 8, 2)) * rng.uniform(0.05, 1.0, 2)   # thin or fat clouds
        c[..., 3] = rng.uniform(0.5, 2.0, (5, 8))
        c[..., :2] *= c[..., 3:]
        poly = (glr._cover_polygon([c], w, h).astype(np.float64) * 0.5 + 0.5) * (w, h)
        pts = (c[..., :2].reshape(-1, 2) / c[..., 3].reshape(-1, 1) * 0.5 + 0.5) * (w, h)
        e = np.roll(poly, -1, axis=0) - poly
        nrm = np.stack([e[:, 1], -e[:, 0]], -1) / np.linalg.norm(e, axis=-1, keepdims=True)   # outward (CCW)
        dist = np.einsum("ek,pek->pe", nrm, poly[None] - pts[:, None])                       # ≥ 0: inside
        assert dist.min() >= glr.COVER_MARGIN_PX - 1e-3, dist.min()
    c[0, 0, 3] = -0.1
    assert np.array_equal(glr._cover_polygon([c], w, h), glr._FULL_SCREEN)
    assert glr._cover_polygon([], w, h).shape == (0, 2)
