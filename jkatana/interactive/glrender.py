"""The interactive path's render passes: a pyrender renderer that shades with jkatana's programs.

Two ways to draw a frame, the same shading (``shaders/shade.glsl``, programs from
:mod:`jkatana.interactive.glprograms`, tables from :mod:`jkatana.interactive.glstate`):

- **deferred** (headless default): the mesh is drawn with ``gbuffer.frag`` into one
  G-buffer target (the unit normal in octahedral coordinates, u, v) and a depth
  buffer; then one full-screen triangle on the far plane, scissored to the drawn
  chunks' projected boxes, depth test ``GL_GREATER`` against that depth,
  runs ``deferred.frag`` once per covered pixel, with the view direction from the
  camera ray through the pixel. llvmpipe rasterises in 4×4 blocks and runs the
  fragment shader on every block a triangle touches, so on the dense blade mesh
  (51k triangles, most a few pixels) a forward shader runs 2–4× per covered pixel;
  deferred, the expensive shader runs once per pixel and the G-buffer pass costs a
  few stores per block. The G-buffer pass draws, per primitive, only the run of
  triangles between the first and the last of its chunks (:mod:`jkatana.interactive.glchunks`;
  :func:`build_scene` orders the triangles along the blade) that the view frustum
  touches: llvmpipe's vertex stage is single-threaded, and a close-up sees a tenth
  of the blade.
- **forward** (``mesh.frag``; MSAA frames): shades the rasterised fragments directly.

A deferred frame is :meth:`SampleCountRenderer._forward_pass` (replacing pyrender's):
G-buffer pass (only depth is cleared: the shading pass reads the G-buffer only
where this frame wrote depth), shading pass into an RGBA8 renderbuffer, restricted
to the drawn chunks' projected bounding box, then either the read-back of colour only
(offscreen; pyrender also blits, reads and linearises depth) or a colour blit to
the window (the Viewer). :meth:`BakedOffscreenRenderer.draw` draws and waits
without reading back, which is what a window pays. Where a frame's time goes is
measured by :mod:`benchmarks.bench_interactive` (glFinish-timed passes, A/B shader variants).

:class:`SampleCountRenderer` is pyrender's ``Renderer`` with the sample count
of its offscreen framebuffer as a parameter (pyrender hard-codes 4× MSAA,
several times slower on llvmpipe); 0 gives single-sample rendering, which is what the
reference renderer computes (one ray through each pixel centre).

Import this module only after :func:`jkatana.interactive.gl.import_pyrender`
(it imports pyrender and PyOpenGL).
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import numpy as np

from jkatana.interactive.gl import import_pyrender

pyrender = import_pyrender()

from OpenGL import GL  # noqa: E402
from pyrender.renderer import Renderer  # noqa: E402

from jkatana.interactive.glchunks import order_along_mesh, screen_box, visible_range  # noqa: E402
from jkatana.interactive.glprograms import SHADER_DIR, BakedProgramCache  # noqa: E402
from jkatana.interactive.glstate import ShadingState  # noqa: E402

#: Default GL internal format of the G-buffer target: float32 keeps the map coordinates exact; RGBA16F
#: (half the bytes) is no faster on llvmpipe, where the shading's arithmetic and filtered fetches, not
#: memory traffic, bound the frame (bench_interactive's ``gbuffer_f16`` case).
GBUFFER_FORMAT = GL.GL_RGBA32F


class SampleCountRenderer(Renderer):
    """pyrender's Renderer with the offscreen framebuffer's MSAA sample count as a parameter (0 = none),
    and, with ``deferred=True`` (needs ``samples=0``), deferred shading (see the module docstring).

    Deferred: :meth:`_forward_pass` draws the meshes into :attr:`_main_fb_ms`, which here is the
    G-buffer framebuffer (one RGBA32F texture and a depth renderbuffer), then shades into
    :attr:`_main_fb` (an RGBA8 renderbuffer sharing that depth renderbuffer), which is read back
    (offscreen) or blitted to the window (on screen, pyrender's Viewer).
    After each frame :attr:`last_mask` holds the rasterised blade pixels (row 0 at the top) when
    :attr:`want_mask` is set.
    """

    def __init__(self, viewport_width, viewport_height, point_size=1.0, samples: int = 0,
                 deferred: bool = False, gbuffer_format: int = GBUFFER_FORMAT):
        super().__init__(viewport_width, viewport_height, point_size)
        self.gbuffer_format = int(gbuffer_format)
        self.samples = int(samples)
        if deferred and self.samples:
            raise ValueError("deferred shading is single-sample (samples=0)")
        self.deferred = bool(deferred)
        self.want_mask = False
        #: False: an offscreen frame is drawn and waited for (glFinish) but not read back (timing)
        self.read_back = True
        #: offscreen deferred frames: glFinish after each pass and keep their wall times in
        #: :attr:`last_stages` (``gbuffer_s``, ``shading_s``, ``readback_s``); for profiling only
        self.time_stages = False
        self.last_stages: dict | None = None
        #: on-screen deferred frames only: shade at this fraction of the window's resolution and scale up
        #: (the Viewer sets it while a mouse button is held); offscreen frames are always full resolution
        self.render_scale = 1.0
        self.last_mask = None
        self._gtex = None

    def _configure_main_framebuffer(self):
        if self._main_fb is not None and (self.viewport_width, self.viewport_height) != self._main_fb_dims:
            self._delete_main_framebuffer()
        if self._main_fb is not None:
            return
        w, h = self.viewport_width, self.viewport_height

        def fbo(samples):
            cb, db = GL.glGenRenderbuffers(2)
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, cb)
            GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, samples, GL.GL_RGBA, w, h)
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, db)
            GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, samples, GL.GL_DEPTH_COMPONENT24, w, h)
            fb = GL.glGenFramebuffers(1)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, fb)
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, cb)
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, db)
            return fb, cb, db

        self._main_fb, self._main_cb, self._main_db = fbo(0)
        if not self.deferred:
            self._main_fb_ms, self._main_cb_ms, self._main_db_ms = fbo(self.samples)
        else:
            # G-buffer: one float texture (octahedral normal, u, v) + the output framebuffer's depth renderbuffer
            self._gtex = [int(x) for x in np.atleast_1d(GL.glGenTextures(1))]
            for tex in self._gtex:
                GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
                GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, self.gbuffer_format, w, h, 0, GL.GL_RGBA, GL.GL_FLOAT, None)
                for prm in (GL.GL_TEXTURE_MIN_FILTER, GL.GL_TEXTURE_MAG_FILTER):
                    GL.glTexParameteri(GL.GL_TEXTURE_2D, prm, GL.GL_NEAREST)
            GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
            fb = GL.glGenFramebuffers(1)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, fb)
            for i, tex in enumerate(self._gtex):
                GL.glFramebufferTexture2D(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0 + i, GL.GL_TEXTURE_2D,
                                          tex, 0)
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER,
                                         self._main_db)
            GL.glDrawBuffers(1, [GL.GL_COLOR_ATTACHMENT0])
            status = GL.glCheckFramebufferStatus(GL.GL_DRAW_FRAMEBUFFER)
            if status != GL.GL_FRAMEBUFFER_COMPLETE:
                raise RuntimeError(f"G-buffer framebuffer incomplete (status 0x{int(status):x})")
            self._main_fb_ms, self._main_cb_ms, self._main_db_ms = fb, None, None
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, 0)
        self._main_fb_dims = (w, h)

    def _delete_main_framebuffer(self):
        if not self.deferred:
            return super()._delete_main_framebuffer()
        if self._main_fb is not None:
            GL.glDeleteFramebuffers(2, [self._main_fb, self._main_fb_ms])
            GL.glDeleteRenderbuffers(2, [self._main_cb, self._main_db])
            GL.glDeleteTextures(self._gtex)
        self._main_fb = self._main_cb = self._main_db = None
        self._main_fb_ms = self._main_cb_ms = self._main_db_ms = None
        self._gtex = None
        self._main_fb_dims = (None, None)

    def _forward_pass(self, scene, flags, seg_node_map=None):
        """Deferred: G-buffer pass, shading pass, then the read-back (offscreen) or a colour blit to the
        window (on screen); pyrender's forward pass otherwise."""
        from pyrender.constants import RenderFlags

        if not self.deferred or flags & (RenderFlags.DEPTH_ONLY | RenderFlags.SEG | RenderFlags.RGBA):
            return super()._forward_pass(scene, flags, seg_node_map=seg_node_map)
        self._configure_main_framebuffer()
        w, h = self._main_fb_dims
        if not flags & RenderFlags.OFFSCREEN:      # the Viewer: shade, then copy the frame to the window
            # at render_scale < 1 both passes run in the lower-left fw × fh corner of the (full-size)
            # targets, and the blit scales it up (bilinear): fewer pixels to shade while the user drags
            fw, fh = (max(1, round(w * self.render_scale)), max(1, round(h * self.render_scale)))
            self._gbuffer_pass(scene, flags, fw, fh)
            self._shading_pass(scene, fw, fh)
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, 0)
            GL.glBlitFramebuffer(0, 0, fw, fh, 0, 0, w, h, GL.GL_COLOR_BUFFER_BIT,
                                 GL.GL_NEAREST if (fw, fh) == (w, h) else GL.GL_LINEAR)
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
            return None
        if not self.time_stages:
            self._gbuffer_pass(scene, flags, w, h)
            self._shading_pass(scene, w, h)
            if not self.read_back:                # timing of the frame as drawn: wait for it, read nothing
                GL.glFinish()
                return None, None
            return self._read_colour(w, h)
        import time

        t = [time.perf_counter()]
        for stage in (lambda: self._gbuffer_pass(scene, flags, w, h), lambda: self._shading_pass(scene, w, h),
                      lambda: self._read_colour(w, h) if self.read_back else (None, None)):
            out = stage()
            GL.glFinish()
            t.append(time.perf_counter())
        self.last_stages = {"gbuffer_s": t[1] - t[0], "shading_s": t[2] - t[1], "readback_s": t[3] - t[2]}
        return out

    def _gbuffer_pass(self, scene, flags, w, h):
        """Pass 1: the meshes with ``gbuffer.frag`` into the G-buffer. Only depth is cleared: the shading
        pass reads the G-buffer only where this frame's depth is < 1, i.e. where this pass wrote it.

        Each primitive is drawn as one range of its triangles: from its first to its last chunk
        (:func:`~jkatana.interactive.glchunks.mesh_chunks`) that the view frustum touches, so a close-up does not
        run the vertex stage (single-threaded in llvmpipe) on the part of the blade out of the picture. No blending (pyrender
        enables GL_BLEND with factors ONE, ZERO). The clip-space corners of the drawn chunks' boxes are kept
        for the shading pass's scissor box (:func:`~jkatana.interactive.glchunks.screen_box`)."""
        from pyrender.constants import ProgramFlags

        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb_ms)
        GL.glViewport(0, 0, w, h)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthRange(0.0, 1.0)
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
        GL.glDisable(GL.GL_MULTISAMPLE)
        GL.glDisable(GL.GL_BLEND)
        GL.glPolygonMode(GL.GL_FRONT_AND_BACK, GL.GL_FILL)
        GL.glCullFace(GL.GL_BACK)
        V, P = self._get_camera_matrices(scene)
        PV = np.asarray(P, np.float64) @ np.asarray(V, np.float64)
        self._drawn_corners = []
        program = None
        for node in self._sorted_mesh_nodes(scene):
            if not node.mesh.is_visible:
                continue
            pose = scene.get_pose(node)
            for primitive in node.mesh.primitives:
                program = self._get_primitive_program(primitive, flags, ProgramFlags.USE_MATERIAL)
                program._bind()
                program.set_uniform("V", V)
                program.set_uniform("P", P)
                program.set_uniform("M", pose)
                first, count, corners = visible_range(primitive, PV @ np.asarray(pose, np.float64))
                self._drawn_corners.append(corners)
                if count == 0:
                    continue
                if primitive.material.doubleSided:
                    GL.glDisable(GL.GL_CULL_FACE)
                else:
                    GL.glEnable(GL.GL_CULL_FACE)
                n_inst = 1 if primitive.poses is None else len(primitive.poses)
                primitive._bind()
                if count > 0:                       # a run of indexed triangles
                    GL.glDrawElementsInstanced(primitive.mode, 3 * count, GL.GL_UNSIGNED_INT,
                                               ctypes.c_void_p(12 * first), n_inst)
                elif primitive.indices is not None:
                    GL.glDrawElementsInstanced(primitive.mode, primitive.indices.size, GL.GL_UNSIGNED_INT,
                                               ctypes.c_void_p(0), n_inst)
                else:
                    GL.glDrawArraysInstanced(primitive.mode, 0, len(primitive.positions), n_inst)
                primitive._unbind()
        if program is not None:
            program._unbind()
        GL.glEnable(GL.GL_CULL_FACE)

    def _shading_pass(self, scene, w, h):
        """Pass 2: one full-screen triangle, ``deferred.frag`` once per pixel the G-buffer pass covered,
        into :attr:`_main_fb` (RGBA8, sharing the G-buffer's depth)."""
        program = self._program_cache.get_program("deferred.vert", "deferred.frag")
        if not program._in_context():
            program._add_to_context()
        program.gbuffer = {"jk_g0": self._gtex[0]}
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
        GL.glViewport(0, 0, w, h)
        GL.glClearColor(*scene.bg_color)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_FALSE)
        GL.glDepthFunc(GL.GL_GREATER)          # only where the G-buffer pass drew (its depth < 1)
        GL.glDisable(GL.GL_BLEND)
        GL.glDisable(GL.GL_CULL_FACE)
        box = screen_box(getattr(self, "_drawn_corners", None) or [], w, h)   # and only inside the drawn box
        if box is not None:
            GL.glEnable(GL.GL_SCISSOR_TEST)
            GL.glScissor(*box)
        program._bind()
        self._set_camera_ray_uniforms(program._program_id, scene, w, h)
        if box is None or box[2] * box[3] > 0:
            GL.glBindVertexArray(program._vao_id)
            GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
            GL.glBindVertexArray(0)
        program._unbind()
        GL.glDisable(GL.GL_SCISSOR_TEST)
        if self._program_cache.state.background:
            self._background_pass(scene, w, h)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthMask(GL.GL_TRUE)

    def _set_camera_ray_uniforms(self, pid, scene, w, h):
        """What a full-screen pass needs for the camera ray through each pixel: ``cam_pos``, ``jk_inv_vp``
        ((P V)⁻¹) and ``jk_viewport`` (the pass's w × h)."""
        V, P = self._get_camera_matrices(scene)
        inv_vp = np.linalg.inv(np.asarray(P, np.float64) @ np.asarray(V, np.float64)).astype(np.float32)
        GL.glUniformMatrix4fv(GL.glGetUniformLocation(pid, "jk_inv_vp"), 1, GL.GL_TRUE, inv_vp)
        GL.glUniform2f(GL.glGetUniformLocation(pid, "jk_viewport"), float(w), float(h))
        GL.glUniform3fv(GL.glGetUniformLocation(pid, "cam_pos"), 1,
                        np.asarray(scene.get_pose(scene.main_camera_node)[:3, 3], np.float32))

    def _background_pass(self, scene, w, h):
        """The environment behind the blade: ``background.frag`` on the far plane wherever the G-buffer
        pass left depth at 1 (``GL_LEQUAL``), as the reference renderer shows it for missed rays."""
        program = self._program_cache.get_program("deferred.vert", "background.frag")
        if not program._in_context():
            program._add_to_context()
        GL.glDepthFunc(GL.GL_LEQUAL)
        program._bind()
        pid = program._program_id
        self._set_camera_ray_uniforms(pid, scene, w, h)
        coef = np.zeros(4, np.float32)
        b = np.asarray(self._program_cache.state.baked.b, np.float64)
        coef[:len(b)] = b.sum(axis=1)  # the flat spectrum 1 on the orthonormal basis
        GL.glUniform4fv(GL.glGetUniformLocation(pid, "jk_bg_coef"), 1, coef)
        GL.glBindVertexArray(program._vao_id)
        GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
        GL.glBindVertexArray(0)
        program._unbind()

    def _read_main_framebuffer(self, scene, flags):
        """Forward offscreen frames: resolve the (MSAA) colour into :attr:`_main_fb` and read back colour
        only (pyrender also blits, reads and linearises depth, which nothing here uses)."""
        from pyrender.constants import RenderFlags

        if flags & (RenderFlags.DEPTH_ONLY | RenderFlags.SEG | RenderFlags.RGBA):
            return super()._read_main_framebuffer(scene, flags)
        w, h = self._main_fb_dims
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb_ms)
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
        GL.glBlitFramebuffer(0, 0, w, h, 0, 0, w, h, GL.GL_COLOR_BUFFER_BIT, GL.GL_NEAREST)
        if not self.read_back:
            GL.glFinish()
            return None, None
        return self._read_colour(w, h)

    def _read_colour(self, w, h):
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        # RGBA, the renderbuffer's own layout: a straight copy in Mesa (RGB would be converted per pixel);
        # no depth unless the mask is asked for (pyrender always reads and linearises depth)
        buf = GL.glReadPixels(0, 0, w, h, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE)
        color = np.frombuffer(buf, np.uint8).reshape(h, w, 4)[::-1, :, :3]
        if self.want_mask:
            d = GL.glReadPixels(0, 0, w, h, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT)
            self.last_mask = (np.frombuffer(d, np.float32).reshape(h, w) < 1.0)[::-1].copy()
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
        return color, None


def build_scene(mesh, view, bg=(0.08, 0.08, 0.09)):
    """A pyrender Scene with the blade (smooth vertex normals and UVs) and a perspective camera.

    The triangles are reordered by slab along the mesh's longest axis
    (:func:`~jkatana.interactive.glchunks.order_along_mesh`), so that the chunks' runs are compact slices of the
    blade for the G-buffer pass's frustum test."""
    material = pyrender.MetallicRoughnessMaterial(doubleSided=False)
    prim = pyrender.Mesh.from_trimesh(mesh, material=material, smooth=True)
    for p in prim.primitives:
        if p.indices is not None:
            order_along_mesh(p)
    scene = pyrender.Scene(bg_color=np.array([*bg, 1.0]), ambient_light=np.zeros(3))
    scene.add(prim, name="blade")
    cam = pyrender.PerspectiveCamera(yfov=view.yfov, aspectRatio=view.width / view.height,
                                     znear=0.005, zfar=20.0)
    scene.add(cam, pose=view.pose, name="camera")
    return scene


_EGL_LIVE: set[int] = set()


def _share_egl_display(platform) -> None:
    """Let several EGL renderers live in one process: pyrender's ``EGLPlatform.delete_context`` calls
    ``eglTerminate`` on the display, which every EGL context of the process shares (one per device),
    so deleting one renderer broke every other one (``eglMakeCurrent`` then fails with
    EGL_BAD_DISPLAY). Here a renderer's deletion destroys its own context, and the display is
    terminated with the last one."""
    from pyrender.platforms.egl import EGLPlatform

    if not isinstance(platform, EGLPlatform):
        return
    _EGL_LIVE.add(id(platform))

    def delete_context():
        from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent, eglTerminate

        _EGL_LIVE.discard(id(platform))
        if platform._egl_display is None:
            return
        if platform._egl_context is not None:
            eglMakeCurrent(platform._egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
            eglDestroyContext(platform._egl_display, platform._egl_context)
            platform._egl_context = None
        if not _EGL_LIVE:
            eglTerminate(platform._egl_display)
        platform._egl_display = None

    platform.delete_context = delete_context


class BakedOffscreenRenderer:
    """Headless renderer: pyrender's OffscreenRenderer with jkatana's program cache and no MSAA.

    **Arguments:** `state` (:class:`ShadingState`), `width`, `height`, `samples` (MSAA, default 0),
    `deferred` (G-buffer pass then one shading pass per pixel; default: on unless ``samples``),
    `gbuffer_format` (:data:`GBUFFER_FORMAT`), `shader_dir` (:class:`BakedProgramCache`).
    After :meth:`render`, :attr:`last_mask` is the ``(H, W)`` mask of blade pixels (deferred only).
    """

    def __init__(self, state: ShadingState, width: int, height: int, samples: int = 0,
                 deferred: bool | None = None, gbuffer_format: int = GBUFFER_FORMAT,
                 shader_dir: str | Path = SHADER_DIR):
        self.state = state
        try:
            self._r = pyrender.OffscreenRenderer(width, height)
        except Exception as err:  # EGL/OSMesa cannot make a context
            from jkatana.interactive.gl import GLUnavailable, diagnose

            plat = os.environ.get("PYOPENGL_PLATFORM", "egl")
            raise GLUnavailable(f"no OpenGL context on {plat} ({type(err).__name__}: {err}); {diagnose(plat)}") from err
        _share_egl_display(self._r._platform)
        deferred = samples == 0 if deferred is None else bool(deferred)
        r = SampleCountRenderer(width, height, samples=samples, deferred=deferred, gbuffer_format=gbuffer_format)
        r._program_cache = BakedProgramCache(state, shader_dir)
        r._program_cache.deferred = deferred
        self._r._renderer = r

    @property
    def last_mask(self):
        """``(H, W)`` bool: the pixels the mesh covered in the last :meth:`render` with ``mask=True``."""
        return self._r._renderer.last_mask

    def render(self, scene, mask: bool = False) -> np.ndarray:
        """One frame, ``(H, W, 3)`` uint8 display RGB (row 0 at the top); ``mask=True`` (deferred only)
        also reads the depth buffer back into :attr:`last_mask` (one more read-back: off for timing)."""
        r = self._r._renderer
        if mask and not r.deferred:
            raise ValueError("mask=True needs the deferred renderer")
        r.want_mask = bool(mask)
        color, _ = self._r.render(scene)
        return color

    def draw(self, scene) -> None:
        """One frame drawn and waited for (``glFinish``) but not read back: what a window shows, the
        cost of the frame without the copy to the CPU that :meth:`render` adds."""
        r = self._r._renderer
        r.want_mask, r.read_back = False, False
        try:
            self._r.render(scene)
        finally:
            r.read_back = True

    def delete(self):
        self._r._platform.make_current()
        self.state.forget_current_context()
        self._r.delete()
