"""The windowed viewer: pyrender's Viewer with jkatana's shaders.

Mouse: pyrender's trackball (drag to orbit, scroll to zoom, shift-drag to
pan). Keys added by jkatana (pyrender's own keys still work, e.g. ``q`` quits):

- ``j`` / ``k``: turn the environment (the light) by −15° / +15° about +Y;
- ``e`` / ``d``: exposure × √2 / ÷ √2;
- ``p``: save the current frame as a PNG in the output folder.

Import this module only in a process that has not imported PyOpenGL for
headless use: it selects the windowed (GLX) platform.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jkatana.interactive.gl import import_pyrender

pyrender = import_pyrender(windowed=True)

from jkatana.interactive import glrender  # noqa: E402


class BladeViewer(pyrender.Viewer):
    """pyrender.Viewer whose renderer serves jkatana's shaders (:class:`~glrender.BakedProgramCache`).

    **Arguments:** `scene` (pyrender Scene from :func:`glrender.build_scene`), `state`
    (:class:`~glrender.ShadingState`), `out_dir` for saved frames, `screenshot` (a PNG
    path: save the frame after `screenshot_after` draws and close — for tests and batch use).
    """

    def __init__(self, scene, state: "glrender.ShadingState", *, viewport_size=(800, 600),
                 out_dir: str | Path = ".", screenshot: str | Path | None = None, screenshot_after: int = 3,
                 title: str = "jkatana view"):
        self._jk_state = state
        self._jk_out = Path(out_dir)
        self._jk_shot = None if screenshot is None else Path(screenshot)
        self._jk_after = screenshot_after
        self._jk_draws = 0
        self._jk_saved = 0
        keys = {"j": (BladeViewer._turn_light, [-15.0]), "k": (BladeViewer._turn_light, [15.0]),
                "e": (BladeViewer._expose, [np.sqrt(2.0)]), "d": (BladeViewer._expose, [1 / np.sqrt(2.0)]),
                "p": BladeViewer.save_frame}
        super().__init__(scene, viewport_size=viewport_size, registered_keys=keys, run_in_thread=False,
                         window_title=title, use_raymond_lighting=False, use_direct_lighting=False)

    def _init_and_start_app(self):
        self._renderer._program_cache = glrender.BakedProgramCache(self._jk_state)
        super()._init_and_start_app()

    def _turn_light(self, degrees: float):
        self._jk_state.env_rotation += np.deg2rad(degrees)
        self._message_text = f"light {np.rad2deg(self._jk_state.env_rotation) % 360:.0f}°"
        self._message_opac = 2.0

    def _expose(self, factor: float):
        self._jk_state.exposure *= factor
        self._message_text = f"exposure {self._jk_state.exposure:.3g}"
        self._message_opac = 2.0

    def grab(self, back: bool = False) -> np.ndarray:
        """The window contents as ``(H, W, 3)`` uint8: the front buffer (what is shown), or the back
        buffer (the frame just drawn, inside ``on_draw`` before the flip)."""
        if not back:
            return self._renderer.read_color_buf()
        from OpenGL import GL

        w, h = self._renderer.viewport_width, self._renderer.viewport_height
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, 0)
        GL.glReadBuffer(GL.GL_BACK)
        buf = GL.glReadPixels(0, 0, w, h, GL.GL_RGB, GL.GL_UNSIGNED_BYTE)
        return np.flip(np.frombuffer(buf, np.uint8).reshape(h, w, 3), axis=0).copy()

    def save_frame(self, path: str | Path | None = None, back: bool = False) -> Path:
        from PIL import Image

        if path is None:
            self._jk_out.mkdir(parents=True, exist_ok=True)
            path = self._jk_out / f"view_{self._jk_saved:04d}.png"
            self._jk_saved += 1
        from jkatana.io.atomic import atomic_path

        with atomic_path(path) as tmp:
            Image.fromarray(self.grab(back)).save(tmp, format="PNG")
        self._message_text = f"saved {path}"
        self._message_opac = 2.0
        return Path(path)

    def on_draw(self):
        super().on_draw()
        self._jk_draws += 1
        if self._jk_shot is not None and self._jk_draws == self._jk_after:
            self.save_frame(self._jk_shot, back=True)
            import pyglet

            pyglet.clock.schedule_once(lambda dt: self.on_close(), 0.0)
