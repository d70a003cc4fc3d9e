"""The windowed viewer: pyrender's Viewer with jkatana's shaders.

Mouse: pyrender's trackball (drag to orbit, scroll to zoom, shift-drag to
pan). Keys added by jkatana (pyrender's own keys still work, e.g. ``q`` quits):

- ``j`` / ``k``: turn the environment (the light) by −15° / +15° about +Y;
- ``e`` / ``d``: exposure × √2 / ÷ √2;
- ``p``: save the current frame as a PNG in the output folder.

The window draws on the same **deferred** path as the headless renderer
(:class:`~jkatana.interactive.glrender.SampleCountRenderer`: G-buffer pass, one
shading pass per covered pixel, then a colour blit to the window), so the
shading is the one the agreement tests check. Two changes to pyrender's Viewer
loop make the window cheap: a single-sample window (pyrender asks for 4× MSAA
first; the deferred frame is single-sample, and a multisampled window cannot
receive the blit), and one draw per timer tick (pyrender's timer callback calls
``on_draw`` and pyglet's event loop then draws again before the flip: every
displayed frame was rendered twice). The timer runs at ``refresh_rate`` (60 Hz
here; pyrender's default is 30).

``drag_scale`` (the CLI's default ``"auto"``; the class's default 1: off): while a mouse button is held (orbiting,
panning), shade at that fraction of the window's resolution and scale the
frame up; the full-resolution frame returns on release. At 0.5 a quarter of
the pixels are shaded, which holds the frame rate in a close-up on a software
rasteriser (bench_interactive, ``viewer`` rows). ``"auto"``: the fraction that
fits one frame in the refresh interval, from the measured time of the last
full-resolution draws (shading time ∝ pixels: s = 0.9 √(interval / t_full),
clamped to [0.25, 1]; 1 when full resolution already fits).

``calibrate=(colourspace, transfer)`` (the CLI passes it when the exposure is automatic): before the
first frame is shown, the window's own deferred frames are read back with their depth mask and the
exposure is set by :func:`jkatana.interactive.exposure.calibrate_exposure`, the rule `render` and
``view --offscreen`` use (:func:`jkatana.render.film.scene_exposure`), so all three show a scene alike.

``measure_frames=N`` draws N frames back to back (the light turning by 1° each;
at ``drag_scale``, as during a drag; ``"auto"`` chooses it from the three full-resolution
warm-up draws) and prints the measured frame interval — the
Viewer's real frame rate, flip to the X server included — then closes; with a
`screenshot` path, the last measured frame is saved there.

Import this module only in a process that has not imported PyOpenGL for
headless use: it selects the windowed (GLX) platform.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from jkatana.interactive.gl import import_pyrender

pyrender = import_pyrender(windowed=True)

from jkatana.interactive import glrender  # noqa: E402


class BladeViewer(pyrender.Viewer):
    """pyrender.Viewer whose renderer serves jkatana's shaders (:class:`~glrender.BakedProgramCache`).

    **Arguments:** `scene` (pyrender Scene from :func:`glrender.build_scene`), `state`
    (:class:`~glrender.ShadingState`), `out_dir` for saved frames, `screenshot` (a PNG
    path: save the frame after `screenshot_after` draws and close — for tests and batch use),
    `deferred` (default True; False: the forward shader on every rasterised fragment),
    `refresh_rate` (Hz of the redraw timer), `measure_frames` (draw that many frames back to back,
    print the frame rate, close), `drag_scale` (resolution fraction while a mouse button is held),
    `calibrate` (``(colourspace, transfer)`` of the scene: set the exposure on the first frame by the
    shared rule; None: keep ``state.exposure``).
    After a measuring run (`measure_frames`), :attr:`frame_times` holds the intervals between draws (seconds).
    """

    def __init__(self, scene, state: "glrender.ShadingState", *, viewport_size=(800, 600),
                 out_dir: str | Path = ".", screenshot: str | Path | None = None, screenshot_after: int = 3,
                 title: str = "jkatana view", deferred: bool = True, refresh_rate: float = 60.0,
                 measure_frames: int = 0, drag_scale: float | str = 1.0, calibrate: tuple | None = None):
        self._jk_auto = drag_scale == "auto"
        if not self._jk_auto:
            drag_scale = float(drag_scale)
            if not 0.0 < drag_scale <= 1.0:
                raise ValueError(f"drag_scale must be in (0, 1] or 'auto', got {drag_scale}")
        if (self._jk_auto or drag_scale < 1.0) and not deferred:
            raise ValueError("drag_scale other than 1 needs the deferred path")
        self._jk_drag_scale = 1.0 if self._jk_auto else drag_scale
        self._jk_full_s: float | None = None     # recent draw time at full resolution (for "auto")
        self._jk_state = state
        if calibrate is not None and not deferred:
            raise ValueError("calibrate needs the deferred path (the object mask is its depth)")
        self._jk_calibrate = calibrate
        self._jk_out = Path(out_dir)
        self._jk_shot = None if screenshot is None else Path(screenshot)
        self._jk_after = screenshot_after
        self._jk_draws = 0
        self._jk_saved = 0
        self._jk_deferred = bool(deferred)
        self._jk_measure = int(measure_frames)
        self._jk_stamps: list[float] = []
        self._jk_draw_s: list[float] = []
        self._jk_closing = False
        self.frame_times: list[float] = []
        keys = {"j": (BladeViewer._turn_light, [-15.0]), "k": (BladeViewer._turn_light, [15.0]),
                "e": (BladeViewer._expose, [np.sqrt(2.0)]), "d": (BladeViewer._expose, [1 / np.sqrt(2.0)]),
                "p": BladeViewer.save_frame}
        super().__init__(scene, viewport_size=viewport_size, registered_keys=keys, run_in_thread=False,
                         window_title=title, use_raymond_lighting=False, use_direct_lighting=False,
                         refresh_rate=float(refresh_rate))

    @property
    def pipeline(self) -> str:
        """'deferred' or 'forward': how the window's frames are shaded."""
        return "deferred" if self._jk_deferred else "forward"

    def _init_and_start_app(self):
        """pyrender's ``Viewer._init_and_start_app`` with jkatana's renderer, a single-sample window and
        :meth:`_tick` (one draw per tick) as the timer."""
        import pyglet
        from pyglet import clock
        from pyglet.gl import Config
        from pyrender.constants import (MIN_OPEN_GL_MAJOR, MIN_OPEN_GL_MINOR, TARGET_OPEN_GL_MAJOR,
                                        TARGET_OPEN_GL_MINOR)

        w, h = self._viewport_size
        r = glrender.SampleCountRenderer(w, h, self.render_flags["point_size"], samples=0,
                                         deferred=self._jk_deferred)
        r._program_cache = glrender.BakedProgramCache(self._jk_state)
        r._program_cache.deferred = self._jk_deferred
        if self._jk_measure and not self._jk_auto:
            r.render_scale = self._jk_drag_scale       # measure as during a drag ("auto": after the warm-up)
        self._renderer = r
        for major, minor in ((TARGET_OPEN_GL_MAJOR, TARGET_OPEN_GL_MINOR), (MIN_OPEN_GL_MAJOR, MIN_OPEN_GL_MINOR)):
            conf = Config(depth_size=24, double_buffer=True, major_version=major, minor_version=minor)
            try:
                super(pyrender.Viewer, self).__init__(config=conf, resizable=True, width=w, height=h)
                break
            except pyglet.window.NoSuchConfigException:
                pass
        if not self.context:
            raise ValueError("Unable to initialize an OpenGL 3+ context")
        if self._jk_measure:
            clock.schedule(BladeViewer._tick, self)           # every loop iteration: as fast as it draws
        else:
            clock.schedule_interval(BladeViewer._tick, 1.0 / self.viewer_flags["refresh_rate"], self)
        self.switch_to()
        self.set_caption(self.viewer_flags["window_title"])
        print(f"[view] window {w}×{h}, {self.pipeline} shading"
              + (", automatic resolution while dragging" if self._jk_auto else
                 f", {self._jk_drag_scale:.2f}× resolution while dragging" if self._jk_drag_scale < 1 else ""),
              file=sys.stderr, flush=True)
        if not self._jk_measure and self._jk_shot is None:
            print("[view] drag: orbit; j/k: turn the light; e/d: exposure; p: save a frame; q: quit. Slow on a "
                  "software rasteriser? --taps 1, --rank 2, --drag-scale 0.5 (jkatana view --help)",
                  file=sys.stderr, flush=True)
        pyglet.app.run()

    @staticmethod
    def _tick(dt, self):
        """pyrender's ``Viewer._time_event`` without its ``on_draw`` call: pyglet's event loop draws
        and flips every window after a scheduled function has run."""
        if not self._is_active:
            return
        if self.viewer_flags["record"]:
            self._record()
        if self.viewer_flags["rotate"] and not self.viewer_flags["mouse_pressed"]:
            self._rotate()
        if self._message_text is not None:
            if self._message_opac > 1.0:
                self._message_opac -= 1.0
            else:
                self._message_opac *= 0.90
            if self._message_opac < 0.05:
                self._message_opac = 1.0 + self._ticks_till_fade
                self._message_text = None
        if self._jk_measure:
            self._jk_state.env_rotation += np.deg2rad(1.0)
        if self._should_close:
            self.on_close()

    def auto_scale(self) -> float:
        """The drag resolution fraction that fits a frame in the refresh interval (``drag_scale="auto"``)."""
        if not self._jk_full_s:
            return 1.0
        budget = 1.0 / self.viewer_flags["refresh_rate"]
        return float(np.clip(0.9 * np.sqrt(budget / self._jk_full_s), 0.25, 1.0))

    def on_mouse_press(self, x, y, buttons, modifiers):
        if self._renderer is not None:
            self._renderer.render_scale = self.auto_scale() if self._jk_auto else self._jk_drag_scale
        super().on_mouse_press(x, y, buttons, modifiers)

    def on_mouse_release(self, x, y, button, modifiers):
        if self._renderer is not None:
            self._renderer.render_scale = 1.0
        super().on_mouse_release(x, y, button, modifiers)

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

    def _calibrate_exposure(self) -> float:
        """Set the exposure by the shared rule (:func:`~jkatana.interactive.exposure.calibrate_exposure`)
        on this window's frames: each round draws the view at full resolution into the renderer's colour
        target and reads it back with the depth mask (the window shows the last round's frame)."""
        from jkatana.interactive.exposure import calibrate_exposure

        colourspace, transfer = self._jk_calibrate
        self._jk_calibrate = None
        r = self._renderer
        scale, r.render_scale = r.render_scale, 1.0

        def frame():
            self._render()
            w, h = r._main_fb_dims
            r.want_mask = True
            try:
                img, _ = r._read_colour(w, h)
            finally:
                r.want_mask = False
            return img, r.last_mask

        try:
            e = calibrate_exposure(frame, self._jk_state, colourspace, transfer)
        finally:
            r.render_scale = scale
        print(f"[view] exposure {e:.4g} (the rule `render` uses: jkatana.render.film.scene_exposure)",
              file=sys.stderr, flush=True)
        return e

    def on_draw(self):
        if self._jk_calibrate is not None and self._renderer is not None:
            self.switch_to()
            self._calibrate_exposure()
        t0 = time.perf_counter()
        full = self._renderer is not None and self._renderer.render_scale == 1.0
        super().on_draw()
        if self._jk_measure or self._jk_auto:    # the draw itself, without the flip that follows
            from OpenGL import GL

            GL.glFinish()
            dt = time.perf_counter() - t0
            self._jk_draw_s.append(dt)
            if full and self._jk_draws > 0:    # not the first draw: it compiles shaders, uploads tables
                self._jk_full_s = dt if self._jk_full_s is None else 0.7 * self._jk_full_s + 0.3 * dt
            del self._jk_draw_s[:-1000]
        self._jk_draws += 1
        if self._jk_measure and self._jk_auto and self._jk_draws == 3 and self._renderer is not None:
            self._renderer.render_scale = self.auto_scale()
        if self._jk_measure:
            self._jk_stamps.append(time.perf_counter())
        close = False
        if self._jk_shot is not None and not self._jk_measure and self._jk_draws == self._jk_after:
            self.save_frame(self._jk_shot, back=True)
            close = True
        if self._jk_measure and self._jk_draws == self._jk_measure + 5:     # 4 warm-up draws, N intervals
            self.frame_times = list(np.diff(self._jk_stamps[4:]))
            med = float(np.median(self.frame_times))
            scale = self._renderer.render_scale if self._renderer is not None else 1.0
            print(f"[view] measured {len(self.frame_times)} frames {self.viewport_size[0]}×{self.viewport_size[1]} "
                  f"({self.pipeline}, shaded at {scale:.2f}× resolution): median interval {1e3 * med:.2f} ms = "
                  f"{1 / med:.1f} fps (min {1e3 * min(self.frame_times):.2f} ms); the draw alone (glFinish, no "
                  f"flip) {1e3 * float(np.median(self._jk_draw_s[-len(self.frame_times):])):.2f} ms", file=sys.stderr, flush=True)
            if self._jk_shot is not None:
                self.save_frame(self._jk_shot, back=True)
            close = True
        if close and not self._jk_closing:
            self._jk_closing = True
            import pyglet

            pyglet.clock.schedule_once(lambda dt: self.on_close(), 0.0)
