"""The interactive path's GLSL programs: sources, uniforms and textures bound, and the program cache.

pyrender chooses shaders by file name through its renderer's ``ShaderProgramCache`` and binds only its own
uniforms and 8-bit textures. :class:`BakedProgramCache` (a subclass, installed on the renderer) serves
jkatana's shaders from :data:`SHADER_DIR` — ``mesh.vert``/``mesh.frag`` (forward), ``gbuffer.frag``,
``deferred.vert``/``deferred.frag`` and ``background.frag`` (deferred) — as :class:`BakedProgram` objects,
whose ``_bind`` also binds jkatana's float textures (:class:`~jkatana.interactive.glstate.ShadingState`, on
units 8–15, above the ones pyrender allocates from 0) and sets jkatana's uniforms. Every other shader
pyrender asks for is served from pyrender's own directory. jkatana's static switches (rank, roughness,
blend, taps, caps, sRGB) are ``#define`` lines (:func:`shader_source`), so each combination is its own
compiled program, cached per GL context. Uniform names are checked once at link time
(:meth:`BakedProgram.check_uniforms`): pyrender's ``set_uniform`` ignores misspelt names silently.

Import this module only after :func:`jkatana.interactive.gl.import_pyrender` (it imports pyrender and
PyOpenGL).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jkatana.interactive.gl import import_pyrender

pyrender = import_pyrender()

from OpenGL import GL  # noqa: E402
from pyrender.shader_program import ShaderProgram, ShaderProgramCache  # noqa: E402

from jkatana.interactive.bake import MAX_RANK  # noqa: E402
from jkatana.interactive.captable import EXTENT  # noqa: E402
from jkatana.interactive.glstate import ShadingState  # noqa: E402

SHADER_DIR = Path(__file__).parent / "shaders"
_PYRENDER_SHADERS = Path(pyrender.__file__).parent / "shaders"
_OWN = {"mesh.vert", "mesh.frag", "gbuffer.frag", "deferred.vert", "deferred.frag", "background.frag"}
_UNIT0 = 8

#: Uniforms the fragment shader must expose (checked after linking).
UNIFORMS = ("jk_lut", "jk_map", "jk_transfer", "jk_xyz_to_rgb", "jk_env_rot", "jk_exposure",
            "jk_log_mu_first", "jk_log_mu_step", "jk_n_levels", "jk_n_cos", "jk_n_transfer", "cam_pos")


def is_srgb_table(table) -> bool:
    """Whether a baked transfer table (:func:`jkatana.interactive.bake.transfer_table`) is the sRGB curve
    (IEC 61966-2-1), which the shader then evaluates instead of fetching (``JK_SRGB``)."""
    from jkatana.interactive.bake import transfer_table

    table = np.asarray(table, np.float64)
    return table.ndim == 1 and np.allclose(table, transfer_table("sRGB", len(table)), rtol=0.0, atol=1e-9)


def shader_source(path, defines: dict) -> str:
    """GLSL text of ``path`` with ``#include "name"`` lines expanded from ``path``'s folder and
    ``#define NAME VALUE`` lines inserted after ``#version``."""
    import re

    path = Path(path)
    text = path.read_text()
    text = re.sub(r'^#include "([^"]+)"[ \t]*$', lambda m: (path.parent / m.group(1)).read_text(), text,
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
        """The shader's text with ``#include "file"`` lines expanded (from the shader's folder) and one
        ``#define NAME VALUE`` line per define inserted after ``#version`` (pyrender's own ``_load``
        text-replaces define names anywhere in the source instead)."""
        return shader_source(shader_filename, self.defines)

    def _samplers(self):
        names = ["jk_lut", "jk_map", "jk_transfer"] + [f"jk_env{r}" for r in range(self.state.rank)]
        targets = [GL.GL_TEXTURE_2D_ARRAY, GL.GL_TEXTURE_2D, GL.GL_TEXTURE_2D] + [GL.GL_TEXTURE_3D] * self.state.rank
        if self.state.cap_table:
            names.append("jk_capk")
            targets.append(GL.GL_TEXTURE_3D)
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
        caps += ("jk_capk_dims", "jk_capk_ext") if self.state.cap_table else ()
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
        textures = (st.textures()[:3 + st.rank + int(st.cap_table)]
                    + tuple((self.gbuffer or {}).values()))
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
        if n:                                  # the compact sources split off the map (caps.sun_caps)
            cap = np.zeros((n, 4), np.float32)
            cap[:, :3] = b.cap_dir
            cap[:, 3] = np.asarray(b.cap_radius) ** 2
            q = np.zeros((n, MAX_RANK, 3), np.float32)
            q[:, :b.rank] = b.cap_q
            GL.glUniform4fv(loc(pid, "jk_cap"), n, cap)
            GL.glUniform3fv(loc(pid, "jk_cap_q"), n * MAX_RANK, q)
        if st.cap_table:                       # the caps' kernel table (captable.cap_kernel_table)
            _, n_mu, n_cos, n_v, n_u = b.cap_kernel.shape
            GL.glUniform4f(loc(pid, "jk_capk_dims"), float(n_u), float(n_v), float(n_cos), float(n_mu))
            GL.glUniform1f(loc(pid, "jk_capk_ext"), float(EXTENT))


class BackgroundProgram(BakedProgram):
    """``background.frag``: the environment where no mesh was drawn. It reads the environment textures
    and the display transform only, so the lobe table, map and roughness uniforms are optimised away."""

    def check_uniforms(self):
        need = ["jk_inv_vp", "jk_viewport", "jk_bg_coef", "jk_env_rot", "jk_exposure", "jk_xyz_to_rgb"]
        missing = [u for u in need if GL.glGetUniformLocation(self._program_id, u) == -1]
        if missing:
            raise RuntimeError(f"shader {self.fragment_shader} lacks uniforms {missing} (misspelt or unused)")


class BakedProgramCache(ShaderProgramCache):
    """Serves jkatana's shaders (with the state's defines) from ``shader_dir`` (default :data:`SHADER_DIR`;
    another folder of the same files, for A/B timing of shader variants); pyrender's shaders otherwise."""

    def __init__(self, state: ShadingState, shader_dir: str | Path = SHADER_DIR):
        super().__init__(shader_dir=str(shader_dir))
        self.state = state
        self._dir = Path(shader_dir)
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
                program = SourceProgram(str(self._dir / vertex_shader), str(self._dir / fragment_shader),
                                        defines=defines)
            else:
                program = BakedProgram(str(self._dir / vertex_shader), str(self._dir / fragment_shader),
                                       defines=defines)
                if fragment_shader == "background.frag":
                    program = BackgroundProgram(str(self._dir / vertex_shader),
                                                str(self._dir / fragment_shader), defines=defines)
                program.state = self.state
                if fragment_shader == "deferred.frag":
                    program.gbuffer = {"jk_g0": 0}
            self._program_cache[key] = program
        return self._program_cache[key]

    def clear(self):
        super().clear()
        self._fallback.clear()
