"""The GL side: pyrender scene, a program cache that serves jkatana's shaders, float textures.

Two ways to draw a frame, the same shading (``shaders/shade.glsl``):

- **deferred** (headless default): pyrender's forward pass draws the mesh with
  ``gbuffer.frag`` into two RGBA32F targets (unit normal + u, world position + v)
  and a depth buffer; then one full-screen triangle on the far plane, depth test
  ``GL_GREATER`` against that depth, runs ``deferred.frag`` once per covered
  pixel. llvmpipe rasterises in 4×4 blocks and runs the fragment shader on every
  block a triangle touches, so on the dense blade mesh (51k triangles, most a few
  pixels) a forward shader runs 2–4× per covered pixel; deferred, the expensive
  shader runs once per pixel and the G-buffer pass costs a few stores per block.
- **forward** (``mesh.frag``; MSAA frames): shades the rasterised fragments directly.

A deferred frame is :meth:`SampleCountRenderer._forward_pass` (replacing pyrender's):
G-buffer pass (only depth is cleared: the shading pass reads the G-buffer only
where this frame wrote depth, so clearing two float targets, 1.3 ms at 800×600
on llvmpipe, is wasted), shading pass into an RGBA8 renderbuffer, then either the
read-back of colour only (offscreen; pyrender also blits, reads and linearises
depth) or a colour blit to the window (the Viewer). :meth:`BakedOffscreenRenderer.draw`
draws and waits without reading back, which is what a window pays.

Where a frame's time goes (EGL llvmpipe, 2 cores, 800×600, rank 3, three taps; glFinish-timed
stages and A/B shader variants, see :mod:`benchmarks.bench_interactive`): the fixed cost (vertex
processing of the 51k-triangle blade, depth clear, colour clear; read-back of the RGBA8 frame
< 0.1 ms) was 6.0 ms and is 2.3 ms since the G-buffer's colour is no longer cleared and depth no
longer read back. The rest is the shading pass, ~100 ns CPU per covered pixel: ~45 in the nine
trilinear environment fetches (3 taps × rank 3, ~5 ns each), ~17 in the equirectangular atan/acos
of the three taps, ~15 in the four lobe-LUT fetches. RGBA16F environment textures or G-buffer are
no faster (llvmpipe converts half floats per fetch; memory traffic is not the bound). A close-up
(~300k shaded pixels) therefore costs ~20 ms on an idle 2-core machine; the user's switches that
hold 60 fps there are ``--rank 2``, ``--taps 1`` and, while dragging, ``--drag-scale 0.5``.

pyrender chooses shaders by file name through its renderer's
``ShaderProgramCache`` and binds only its own uniforms and 8-bit textures.
:class:`BakedProgramCache` (a subclass, installed on the renderer) serves
``mesh.vert``/``mesh.frag`` from ``jkatana/interactive/shaders`` as
:class:`BakedProgram` objects, whose ``_bind`` also binds jkatana's float
textures (RGBA32F 3-D and 2-D-array textures, on units 8–15, above the ones pyrender
allocates from 0) and sets jkatana's uniforms. Every other shader pyrender
asks for is served from pyrender's own directory. jkatana's static switches
(rank, roughness, blend) are added to the defines, so each combination is its
own compiled program. Uniform names are checked once at link time
(:meth:`BakedProgram.check_uniforms`): pyrender's ``set_uniform`` ignores
misspelt names silently.

:class:`SampleCountRenderer` is pyrender's ``Renderer`` with the sample count
of its offscreen framebuffer as a parameter (pyrender hard-codes 4× MSAA,
2–4× slower on llvmpipe); 0 gives single-sample rendering, which is what the
reference renderer computes (one ray through each pixel centre).

Import this module only after :func:`jkatana.interactive.gl.import_pyrender`
(it imports pyrender and PyOpenGL).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jkatana.interactive.gl import import_pyrender

pyrender = import_pyrender()

from OpenGL import GL  # noqa: E402
from pyrender.renderer import Renderer  # noqa: E402
from pyrender.shader_program import ShaderProgram, ShaderProgramCache  # noqa: E402

from jkatana.interactive.bake import MAX_RANK, Baked  # noqa: E402

SHADER_DIR = Path(__file__).parent / "shaders"
_PYRENDER_SHADERS = Path(pyrender.__file__).parent / "shaders"
_OWN = {"mesh.vert", "mesh.frag", "gbuffer.frag", "deferred.vert", "deferred.frag", "background.frag"}
_UNIT0 = 8

#: Uniforms the fragment shader must expose (checked after linking).
UNIFORMS = ("jk_lut", "jk_map", "jk_transfer", "jk_xyz_to_rgb", "jk_env_rot", "jk_exposure",
            "jk_log_mu_first", "jk_log_mu_step", "jk_n_levels", "jk_n_cos", "jk_n_transfer", "cam_pos")


def _tex_layered(target: int, data: np.ndarray, wraps: tuple[int, ...], internal: int | None = None) -> int:
    """Upload ``(layers, H, W, 4)`` float32 to ``target`` as ``internal`` (default RGBA32F) (bilinear; s repeats,
    ``wraps`` clamp)."""
    data = np.ascontiguousarray(data, np.float32)
    layers, h, w, _ = data.shape
    tex = GL.glGenTextures(1)
    GL.glBindTexture(target, tex)
    GL.glTexImage3D(target, 0, GL.GL_RGBA32F if internal is None else internal, w, h, layers, 0, GL.GL_RGBA,
                    GL.GL_FLOAT, data)
    params = [(GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR), (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
              (GL.GL_TEXTURE_WRAP_S, GL.GL_REPEAT)] + [(wrap, GL.GL_CLAMP_TO_EDGE) for wrap in wraps]
    for p, v in params:
        GL.glTexParameteri(target, p, v)
    GL.glBindTexture(target, 0)
    return int(tex)


def _tex_array(data: np.ndarray) -> int:
    """GL_TEXTURE_2D_ARRAY: bilinear within a layer, s repeat, t clamp."""
    return _tex_layered(GL.GL_TEXTURE_2D_ARRAY, data, (GL.GL_TEXTURE_WRAP_T,))


#: GL internal format of the prefiltered environment textures (the shading's most-read tables).
#: RGBA16F was measured (bench_interactive ``env_f16``): no faster on llvmpipe, which converts
#: half floats on every fetch; float32 stays.
ENV_FORMAT = GL.GL_RGBA32F
#: GL internal format of the two G-buffer targets. RGBA16F (half the bytes written and read) was
#: measured (bench_interactive ``gbuffer_f16``): no faster on llvmpipe, where the shading's
#: arithmetic and filtered fetches, not memory traffic, bound the frame; float32 keeps positions exact.
GBUFFER_FORMAT = GL.GL_RGBA32F


def _tex_3d(data: np.ndarray) -> int:
    """GL_TEXTURE_3D: trilinear, s repeat, t and r clamp; stored as :data:`ENV_FORMAT`."""
    return _tex_layered(GL.GL_TEXTURE_3D, data, (GL.GL_TEXTURE_WRAP_T, GL.GL_TEXTURE_WRAP_R), ENV_FORMAT)


def _tex_2d(data: np.ndarray, wrap_s=GL.GL_CLAMP_TO_EDGE) -> int:
    data = np.ascontiguousarray(data, np.float32)
    h, w, _ = data.shape
    tex = GL.glGenTextures(1)
    GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
    GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA32F, w, h, 0, GL.GL_RGBA, GL.GL_FLOAT, data)
    for p, v in ((GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR), (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
                 (GL.GL_TEXTURE_WRAP_S, wrap_s), (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE)):
        GL.glTexParameteri(GL.GL_TEXTURE_2D, p, v)
    GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    return int(tex)


def _rgba(x: np.ndarray) -> np.ndarray:
    pad = np.zeros(x.shape[:-1] + (4 - x.shape[-1],), x.dtype)
    return np.concatenate([x, pad], -1)


class ShadingState:
    """What the shaders read: baked tables, reflectance map, and per-frame settings.

    - `baked`: :class:`jkatana.interactive.bake.Baked`; `refl_map`: ``(H, W, 3)`` w, μ0, μ1.
    - per frame: `exposure`, `env_rotation` (radians about +Y, turns the light around the blade),
      and the static switches `rank` (≤ baked rank), `rough`, `blend`, `two_tap` (anisotropic lobe:
      three (or, with `taps=5`, five) binomial prefiltered taps along the plane of incidence; off: one tap),
      `fit` (with three taps: their offsets, weights and filter width fitted to the lobe by
      :func:`jkatana.interactive.bake.tap_fit` — the default; off: moment-matched binomial taps, which
      miss the lobe's skew: ~10 % too dark on a sun inside the oblique hamon lobe; `taps=5` is always
      moment-matched). The baked caps (compact sources split off the map, :func:`~jkatana.interactive.bake.sun_caps`)
      are a static switch too (``JK_CAPS``, their number; 0: no cap code).
    """

    #: draw the environment behind the blade (deferred path; the `view` command turns it on); off: the
    #: scene's flat background colour, which tests and benchmarks use to find the blade's pixels
    background: bool = False

    def __init__(self, baked: Baked, refl_map: np.ndarray, *, exposure: float = 1.0, rank: int | None = None,
                 rough: bool = True, blend: bool = True, two_tap: bool = True, taps: int = 3, fit: bool = True):
        self.baked = baked
        self.refl_map = np.asarray(refl_map, np.float64)
        self.exposure = float(exposure)
        self.env_rotation = 0.0
        self.rank = baked.rank if rank is None else int(rank)
        if not 1 <= self.rank <= baked.rank:
            raise ValueError(f"rank must be 1..{baked.rank} (baked), got {self.rank}")
        self.rough = bool(rough)
        self.blend = bool(blend)
        self.two_tap = bool(two_tap)
        if taps not in (3, 5):
            raise ValueError(f"taps must be 3 or 5, got {taps}")
        self.taps = int(taps)
        self.fit = bool(fit)
        self._textures: dict[object, tuple[int, ...]] = {}

    def defines(self) -> dict:
        return {"JK_RANK": self.rank, "JK_ROUGH": int(self.rough), "JK_BLEND": int(self.blend),
                "JK_CAPS": self.baked.n_caps,
                "JK_TWO_TAP": int(self.two_tap and self.rough), "JK_TAPS": self.taps,
                "JK_TAP_FIT": int(self.fit and self.two_tap and self.rough and self.taps == 3)}

    def env_rot_matrix(self) -> np.ndarray:
        """World → environment-map rotation about +Y, as :func:`jkatana.render.renderer.rotation_y`
        (a feature at compass azimuth a moves to a + env_rotation)."""
        c, s = np.cos(self.env_rotation), np.sin(self.env_rotation)
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])

    def textures(self) -> tuple[int, ...]:
        """GL texture ids in the current context (uploaded on first use)."""
        import OpenGL.contextdata

        key = OpenGL.contextdata.getContext()
        if key not in self._textures:
            b = self.baked
            n_mu, rank, H, W, _ = b.env.shape
            lut = np.zeros((8,) + b.lut.shape[1:-1] + (MAX_RANK,))
            lut[:2, ..., :rank] = b.lut
            lut[2, ..., :3] = b.spread[0]                                # layer 2: hiraji lobe shape
            lut[3, ..., :3] = b.spread[1]                                # layer 3: hamon lobe shape
            T = (b.taps.shape[-1] - 1) // 2                              # fitted taps (bake.tap_fit):
            lut[4:6, ..., :1 + T] = b.taps[:, ..., :1 + T]               # layers 4, 5: log(μ_e/μ), offsets
            lut[6:8, ..., :T] = b.taps[:, ..., 1 + T:]                   # layers 6, 7: weights
            self._textures[key] = (
                _tex_array(lut),                                         # (2, n_mu, n_cos, 4)
                _tex_2d(_rgba(self.refl_map)),
                _tex_2d(_rgba(np.asarray(b.transfer, np.float64)[None, :, None])),
                *(_tex_3d(_rgba(b.env[:, r])) for r in range(rank)),     # (n_mu, H, W, 4) each
            )
        return self._textures[key]

    def forget_current_context(self):
        """Delete this context's textures and forget them; call while the context is current, before it is
        destroyed: a context made later may get the same handle and would be handed these stale ids."""
        import OpenGL.contextdata

        ids = self._textures.pop(OpenGL.contextdata.getContext(), None)
        if ids is not None:
            GL.glDeleteTextures(list(ids))

    def delete_textures(self):
        for ids in self._textures.values():
            GL.glDeleteTextures(list(ids))
        self._textures.clear()


def is_srgb_table(table) -> bool:
    """Whether a baked transfer table (:func:`jkatana.interactive.bake.transfer_table`) is the sRGB curve
    (IEC 61966-2-1), which the shader then evaluates instead of fetching (``JK_SRGB``)."""
    from jkatana.interactive.bake import transfer_table

    table = np.asarray(table, np.float64)
    return table.ndim == 1 and np.allclose(table, transfer_table("sRGB", len(table)), rtol=0.0, atol=1e-9)


def shader_source(path, defines: dict) -> str:
    """GLSL text of ``path`` with ``#include "name"`` lines expanded from :data:`SHADER_DIR` and
    ``#define NAME VALUE`` lines inserted after ``#version``."""
    import re

    text = Path(path).read_text()
    text = re.sub(r'^#include "([^"]+)"[ \t]*$', lambda m: (SHADER_DIR / m.group(1)).read_text(), text,
                  flags=re.MULTILINE)
    head, sep, rest = text.partition("\n")
    if not head.startswith("#version"):
        raise ValueError(f"{path}: the first line must be #version")
    lines = "".join(f"#define {k} {v}\n" for k, v in (defines or {}).items())
    return head + sep + lines + rest


class SourceProgram(ShaderProgram):
    """pyrender's ShaderProgram reading its source with :func:`shader_source` (the G-buffer pass)."""

    def _load(self, shader_filename):
        return shader_source(shader_filename, self.defines)


class BakedProgram(ShaderProgram):
    """pyrender's ShaderProgram whose ``_bind`` also binds jkatana's textures and uniforms."""

    state: ShadingState = None
    #: extra 2-D samplers (the G-buffer of the deferred pass): name → GL texture id, set before drawing
    gbuffer: dict = None

    def _load(self, shader_filename):
        """The shader's text with ``#include "file"`` lines expanded (from :data:`SHADER_DIR`) and one
        ``#define NAME VALUE`` line per define inserted after ``#version`` (pyrender's own ``_load``
        text-replaces define names anywhere in the source instead)."""
        return shader_source(shader_filename, self.defines)

    def _samplers(self):
        names = ["jk_lut", "jk_map", "jk_transfer"] + [f"jk_env{r}" for r in range(self.state.rank)]
        targets = [GL.GL_TEXTURE_2D_ARRAY, GL.GL_TEXTURE_2D, GL.GL_TEXTURE_2D] + [GL.GL_TEXTURE_3D] * self.state.rank
        if self.gbuffer is not None:
            names += list(self.gbuffer)
            targets += [GL.GL_TEXTURE_2D] * len(self.gbuffer)
        return names, targets

    def check_uniforms(self):
        optional = set()
        if not self.state.rough:
            optional |= {"jk_log_mu_first", "jk_log_mu_step"}
        if not (self.state.rough or self.state.blend):
            optional.add("jk_map")
        if self.defines.get("JK_SRGB"):
            optional |= {"jk_transfer", "jk_n_transfer"}
        caps = ("jk_cap", "jk_cap_q") if self.state.baked.n_caps else ()
        need = dict.fromkeys(u for u in UNIFORMS + caps + tuple(self._samplers()[0]) if u not in optional)
        missing = [u for u in need if GL.glGetUniformLocation(self._program_id, u) == -1]
        if missing:
            raise RuntimeError(f"shader {self.fragment_shader} lacks uniforms {missing} (misspelt or unused)")

    def _add_to_context(self):
        """Compile and link (as pyrender does), then point the samplers at their units before validating.

        PyOpenGL's ``compileProgram`` validates right after linking, when every
        sampler still refers to unit 0 — invalid for samplers of different
        types — so we link with plain GL calls and validate afterwards.
        """
        from OpenGL.GL import shaders as gl_shader_utils

        if self._program_id is not None:
            raise ValueError("Shader program already in context")
        ids = [gl_shader_utils.compileShader(self._load(self.vertex_shader), GL.GL_VERTEX_SHADER),
               gl_shader_utils.compileShader(self._load(self.fragment_shader), GL.GL_FRAGMENT_SHADER)]
        if self._vao_id is None:
            self._vao_id = GL.glGenVertexArrays(1)
        GL.glBindVertexArray(self._vao_id)
        pid = GL.glCreateProgram()
        for i in ids:
            GL.glAttachShader(pid, i)
        GL.glLinkProgram(pid)
        if GL.glGetProgramiv(pid, GL.GL_LINK_STATUS) != GL.GL_TRUE:
            raise RuntimeError(f"link failed: {GL.glGetProgramInfoLog(pid)!r}")
        for i in ids:
            GL.glDeleteShader(i)
        GL.glUseProgram(pid)
        for k, name in enumerate(self._samplers()[0]):
            GL.glUniform1i(GL.glGetUniformLocation(pid, name), _UNIT0 + k)
        GL.glUseProgram(0)
        GL.glBindVertexArray(0)
        self._program_id = pid
        self.check_uniforms()

    def _bind(self):
        super()._bind()
        st, b = self.state, self.state.baked
        pid = self._program_id
        names, targets = self._samplers()
        textures = st.textures()[:3 + st.rank] + tuple((self.gbuffer or {}).values())
        for i, (name, tex, target) in enumerate(zip(names, textures, targets)):
            GL.glActiveTexture(GL.GL_TEXTURE0 + _UNIT0 + i)
            GL.glBindTexture(target, tex)
            GL.glUniform1i(GL.glGetUniformLocation(pid, name), _UNIT0 + i)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        loc = GL.glGetUniformLocation
        GL.glUniformMatrix3fv(loc(pid, "jk_xyz_to_rgb"), 1, GL.GL_TRUE, np.asarray(b.xyz_to_rgb, np.float32))
        GL.glUniformMatrix3fv(loc(pid, "jk_env_rot"), 1, GL.GL_TRUE, st.env_rot_matrix().astype(np.float32))
        GL.glUniform1f(loc(pid, "jk_exposure"), st.exposure)
        GL.glUniform1f(loc(pid, "jk_log_mu_first"), float(np.log(b.mus[0])))
        GL.glUniform1f(loc(pid, "jk_log_mu_step"), float(np.log(b.mus[1] / b.mus[0])))
        GL.glUniform1f(loc(pid, "jk_n_levels"), float(len(b.mus)))
        GL.glUniform1f(loc(pid, "jk_n_cos"), float(b.lut.shape[2]))
        GL.glUniform1f(loc(pid, "jk_n_transfer"), float(len(b.transfer)))
        n = b.n_caps
        if n:                                  # the compact sources split off the map (bake.sun_caps)
            cap = np.zeros((n, 4), np.float32)
            cap[:, :3] = b.cap_dir
            cap[:, 3] = np.asarray(b.cap_radius) ** 2
            q = np.zeros((n, MAX_RANK, 3), np.float32)
            q[:, :b.rank] = b.cap_q
            GL.glUniform4fv(loc(pid, "jk_cap"), n, cap)
            GL.glUniform3fv(loc(pid, "jk_cap_q"), n * MAX_RANK, q)


class BackgroundProgram(BakedProgram):
    """``background.frag``: the environment where no mesh was drawn. It reads the environment textures
    and the display transform only, so the lobe table, map and roughness uniforms are optimised away."""

    def check_uniforms(self):
        need = ["jk_inv_vp", "jk_viewport", "jk_bg_coef", "jk_env_rot", "jk_exposure", "jk_xyz_to_rgb"]
        missing = [u for u in need if GL.glGetUniformLocation(self._program_id, u) == -1]
        if missing:
            raise RuntimeError(f"shader {self.fragment_shader} lacks uniforms {missing} (misspelt or unused)")


class BakedProgramCache(ShaderProgramCache):
    """Serves jkatana's ``mesh.vert``/``mesh.frag`` (with the state's defines); pyrender's shaders otherwise."""

    def __init__(self, state: ShadingState):
        super().__init__(shader_dir=str(SHADER_DIR))
        self.state = state
        #: True while a deferred renderer draws: pyrender's request for the mesh shader gets the G-buffer one
        self.deferred = False
        self._srgb = None       # (baked, whether its transfer table is sRGB), checked once per bake
        self._fallback = ShaderProgramCache(shader_dir=str(_PYRENDER_SHADERS))

    def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
        if vertex_shader not in _OWN or fragment_shader not in _OWN or geometry_shader is not None:
            return self._fallback.get_program(vertex_shader, fragment_shader, geometry_shader, defines)
        import OpenGL.contextdata

        if self.deferred and fragment_shader == "mesh.frag":
            fragment_shader = "gbuffer.frag"
        defines = dict(defines or {})
        if fragment_shader != "gbuffer.frag":
            defines.update(self.state.defines())
            baked = self.state.baked
            if self._srgb is None or self._srgb[0] is not baked:
                self._srgb = (baked, int(is_srgb_table(baked.transfer)))
            defines["JK_SRGB"] = self._srgb[1]
        key = (OpenGL.contextdata.getContext(), vertex_shader, fragment_shader, *sorted(defines.items()))
        if key not in self._program_cache:
            if fragment_shader == "gbuffer.frag":
                program = SourceProgram(str(SHADER_DIR / vertex_shader), str(SHADER_DIR / fragment_shader),
                                        defines=defines)
            else:
                program = BakedProgram(str(SHADER_DIR / vertex_shader), str(SHADER_DIR / fragment_shader),
                                       defines=defines)
                if fragment_shader == "background.frag":
                    program = BackgroundProgram(str(SHADER_DIR / vertex_shader),
                                                str(SHADER_DIR / fragment_shader), defines=defines)
                program.state = self.state
                if fragment_shader == "deferred.frag":
                    program.gbuffer = {"jk_g0": 0, "jk_g1": 0}
            self._program_cache[key] = program
        return self._program_cache[key]

    def clear(self):
        super().clear()
        self._fallback.clear()


class SampleCountRenderer(Renderer):
    """pyrender's Renderer with the offscreen framebuffer's MSAA sample count as a parameter (0 = none),
    and, with ``deferred=True`` (needs ``samples=0``), deferred shading (see the module docstring).

    Deferred: :meth:`_forward_pass` draws the meshes into :attr:`_main_fb_ms`, which here is the
    G-buffer framebuffer (two RGBA32F textures and a depth renderbuffer), then shades into
    :attr:`_main_fb` (an RGBA8 renderbuffer sharing that depth renderbuffer), which is read back
    (offscreen) or blitted to the window (on screen, pyrender's Viewer).
    After each frame :attr:`last_mask` holds the rasterised blade pixels (row 0 at the top) when
    :attr:`want_mask` is set.
    """

    def __init__(self, viewport_width, viewport_height, point_size=1.0, samples: int = 0,
                 deferred: bool = False):
        super().__init__(viewport_width, viewport_height, point_size)
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
            # G-buffer: two float textures + the output framebuffer's depth renderbuffer
            self._gtex = [int(x) for x in np.atleast_1d(GL.glGenTextures(2))]
            for tex in self._gtex:
                GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
                GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GBUFFER_FORMAT, w, h, 0, GL.GL_RGBA, GL.GL_FLOAT, None)
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
            GL.glDrawBuffers(2, [GL.GL_COLOR_ATTACHMENT0, GL.GL_COLOR_ATTACHMENT1])
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

    def _screen_box(self, scene, w, h):
        """``(x, y, width, height)`` pixel rectangle holding every mesh's projected world bounding box,
        or None when a corner lies behind the camera (then the whole viewport is shaded)."""
        V, P = self._get_camera_matrices(scene)
        lo, hi = scene.bounds
        corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        clip = corners @ (P @ V).T
        if np.any(clip[:, 3] <= 1e-9):
            return None
        ndc = clip[:, :2] / clip[:, 3:4]
        x0, y0 = np.floor((ndc.min(0) * 0.5 + 0.5) * (w, h)).astype(int) - 1
        x1, y1 = np.ceil((ndc.max(0) * 0.5 + 0.5) * (w, h)).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        return (int(x0), int(y0), int(max(x1 - x0, 0)), int(max(y1 - y0, 0)))

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
        pass reads the G-buffer only where this frame's depth is < 1, i.e. where this pass wrote it."""
        from pyrender.constants import ProgramFlags

        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb_ms)
        GL.glViewport(0, 0, w, h)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthRange(0.0, 1.0)
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
        GL.glDisable(GL.GL_MULTISAMPLE)
        V, P = self._get_camera_matrices(scene)
        program = None
        for node in self._sorted_mesh_nodes(scene):
            if not node.mesh.is_visible:
                continue
            for primitive in node.mesh.primitives:
                program = self._get_primitive_program(primitive, flags, ProgramFlags.USE_MATERIAL)
                program._bind()
                program.set_uniform("V", V)
                program.set_uniform("P", P)
                self._bind_and_draw_primitive(primitive=primitive, pose=scene.get_pose(node), program=program,
                                              flags=flags)
                self._reset_active_textures()
        if program is not None:
            program._unbind()

    def _shading_pass(self, scene, w, h):
        """Pass 2: one full-screen triangle, ``deferred.frag`` once per pixel the G-buffer pass covered,
        into :attr:`_main_fb` (RGBA8, sharing the G-buffer's depth)."""
        program = self._program_cache.get_program("deferred.vert", "deferred.frag")
        if not program._in_context():
            program._add_to_context()
        program.gbuffer = {"jk_g0": self._gtex[0], "jk_g1": self._gtex[1]}
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
        GL.glViewport(0, 0, w, h)
        GL.glClearColor(*scene.bg_color)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_FALSE)
        GL.glDepthFunc(GL.GL_GREATER)          # only where the G-buffer pass drew (its depth < 1)
        box = self._screen_box(scene, w, h)    # and only inside the meshes' projected bounding box
        if box is not None:
            GL.glEnable(GL.GL_SCISSOR_TEST)
            GL.glScissor(*box)
        GL.glDisable(GL.GL_BLEND)
        GL.glDisable(GL.GL_CULL_FACE)
        program._bind()
        GL.glUniform3fv(GL.glGetUniformLocation(program._program_id, "cam_pos"), 1,
                        np.asarray(scene.get_pose(scene.main_camera_node)[:3, 3], np.float32))
        GL.glBindVertexArray(program._vao_id)
        GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
        GL.glBindVertexArray(0)
        program._unbind()
        GL.glDisable(GL.GL_SCISSOR_TEST)
        if self._program_cache.state.background:
            self._background_pass(scene, w, h)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthMask(GL.GL_TRUE)

    def _background_pass(self, scene, w, h):
        """The environment behind the blade: ``background.frag`` on the far plane wherever the G-buffer
        pass left depth at 1 (``GL_LEQUAL``), as the reference renderer shows it for missed rays."""
        program = self._program_cache.get_program("deferred.vert", "background.frag")
        if not program._in_context():
            program._add_to_context()
        GL.glDepthFunc(GL.GL_LEQUAL)
        program._bind()
        pid = program._program_id
        V, P = self._get_camera_matrices(scene)
        inv_vp = np.linalg.inv(np.asarray(P, np.float64) @ np.asarray(V, np.float64)).astype(np.float32)
        GL.glUniformMatrix4fv(GL.glGetUniformLocation(pid, "jk_inv_vp"), 1, GL.GL_TRUE, inv_vp)
        GL.glUniform2f(GL.glGetUniformLocation(pid, "jk_viewport"), float(w), float(h))
        coef = np.zeros(4, np.float32)
        b = np.asarray(self._program_cache.state.baked.b, np.float64)
        coef[:len(b)] = b.sum(axis=1)  # the flat spectrum 1 on the orthonormal basis
        GL.glUniform4fv(GL.glGetUniformLocation(pid, "jk_bg_coef"), 1, coef)
        GL.glUniform3fv(GL.glGetUniformLocation(pid, "cam_pos"), 1,
                        np.asarray(scene.get_pose(scene.main_camera_node)[:3, 3], np.float32))
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
    """A pyrender Scene with the blade (smooth vertex normals and UVs) and a perspective camera."""
    material = pyrender.MetallicRoughnessMaterial(doubleSided=False)
    prim = pyrender.Mesh.from_trimesh(mesh, material=material, smooth=True)
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
    `deferred` (G-buffer pass then one shading pass per pixel; default: on unless ``samples``).
    After :meth:`render`, :attr:`last_mask` is the ``(H, W)`` mask of blade pixels (deferred only).
    """

    def __init__(self, state: ShadingState, width: int, height: int, samples: int = 0,
                 deferred: bool | None = None):
        self.state = state
        try:
            self._r = pyrender.OffscreenRenderer(width, height)
        except Exception as err:  # EGL/OSMesa cannot make a context
            from jkatana.interactive.gl import GLUnavailable, diagnose

            plat = os.environ.get("PYOPENGL_PLATFORM", "egl")
            raise GLUnavailable(f"no OpenGL context on {plat} ({type(err).__name__}: {err}); {diagnose(plat)}") from err
        _share_egl_display(self._r._platform)
        deferred = samples == 0 if deferred is None else bool(deferred)
        r = SampleCountRenderer(width, height, samples=samples, deferred=deferred)
        r._program_cache = BakedProgramCache(state)
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
