"""The viewer's exposure: a first guess from the environment before any frame exists (:func:`auto_exposure`), then
the rule ``jkatana render`` applies to its frames, measured on the GL frames (:func:`calibrate_exposure`). The
headless renderer (:mod:`jkatana.interactive.commands`) and the window (:mod:`jkatana.interactive.viewer`) both
use them.
"""

from __future__ import annotations

import numpy as np


def calibrate_exposure(frame, state, colourspace: str = "sRGB", transfer=None, rounds: int = 6) -> float:
    """Set ``state.exposure`` by the rule `render` applies to its frames
    (:func:`jkatana.render.film.scene_exposure`: the object's mean displayed luminance, clipped at white,
    at :data:`~jkatana.render.film.OBJECT_KEY`), measured on GL frames of the current view.

    `frame()` draws the view at ``state.exposure`` and returns ``(rgb8 (H, W, 3), mask (H, W))``: the 8-bit
    display RGB and the object's pixels (the depth mask). Each round decodes the frame
    (:func:`~jkatana.render.film.xyz_from_display` with the scene's `colourspace` and `transfer`), takes the
    object pixels' mean and scales the exposure by key / mean; the displayed mean is increasing and concave
    in the exposure, so the steps settle within a few rounds. The headless renderer
    (:func:`jkatana.interactive.commands._offscreen`) and the window (:class:`jkatana.interactive.viewer.BladeViewer`, on its first
    drawn frames) both calibrate through this function.
    """
    from jkatana.render.film import OBJECT_KEY, xyz_from_display

    for _ in range(rounds):
        img, mask = frame()
        if mask is None or not mask.any():
            break
        shown = float(np.mean(xyz_from_display(img, colourspace, transfer)[..., 1][mask]))
        state.exposure = float(state.exposure * OBJECT_KEY / max(shown, 1e-6))
    return state.exposure


def auto_exposure(radiance, grid, key: float = 0.85, percentile: float = 99.5) -> float:
    """First guess of the exposure before a frame exists: the environment's bright end (Y at ``percentile``)
    at ``key``/F̄ (F̄ ≈ 0.55 for iron)."""
    from jkatana.render.film import film_weights

    Y = np.asarray(radiance) @ film_weights(grid)[:, 1]
    return float(key / max(0.55 * np.percentile(Y, percentile), 1e-12))


__all__ = ["auto_exposure", "calibrate_exposure"]
