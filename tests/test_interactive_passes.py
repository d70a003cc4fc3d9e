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
