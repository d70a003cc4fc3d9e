"""What the interactive shaders read: the baked tables as float GL textures, and the per-frame settings.

:class:`ShadingState` holds a :class:`~jkatana.interactive.bake.Baked` bake, the reflectance map and the
frame's settings (exposure, light rotation) and static switches (rank, roughness, blend, taps, caps: the
``#define`` lines of :meth:`ShadingState.defines`). It uploads its tables once per GL context
(:meth:`ShadingState.textures`): the lobe table and the tap patterns as one RGBA32F 2-D array texture, the
reflectance map and the display transform as 2-D textures, and each basis function's prefiltered environment
as a 3-D texture (u, v, μ level), so that one trilinear fetch interpolates the μ levels too. Every texture
is filtered linearly, without mipmaps (the shader reads them with ``textureLod(…, 0)``).

Import this module only after :func:`jkatana.interactive.gl.import_pyrender` has chosen the GL platform
(it imports PyOpenGL).
"""

from __future__ import annotations

import numpy as np

from jkatana.interactive.gl import import_pyrender

import_pyrender()

from OpenGL import GL  # noqa: E402

from jkatana.interactive.bake import MAX_RANK, Baked  # noqa: E402


def _tex_layered(target: int, data: np.ndarray, wraps: tuple[int, ...], internal: int | None = None) -> int:
    """Upload ``(layers, H, W, 3 or 4)`` float32 to ``target`` as ``internal`` (default RGBA32F) (bilinear;
    s repeats, ``wraps`` clamp). Three channels are uploaded as RGB (GL sets alpha to 1): a contiguous float32
    array is passed as it is, without a padded copy."""
    data = np.ascontiguousarray(data, np.float32)
    layers, h, w, c = data.shape
    tex = GL.glGenTextures(1)
    GL.glBindTexture(target, tex)
    GL.glTexImage3D(target, 0, GL.GL_RGBA32F if internal is None else internal, w, h, layers, 0,
                    {3: GL.GL_RGB, 4: GL.GL_RGBA}[c], GL.GL_FLOAT, data)
    params = [(GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR), (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
              (GL.GL_TEXTURE_WRAP_S, GL.GL_REPEAT)] + [(wrap, GL.GL_CLAMP_TO_EDGE) for wrap in wraps]
    for p, v in params:
        GL.glTexParameteri(target, p, v)
    GL.glBindTexture(target, 0)
    return int(tex)


def _tex_array(data: np.ndarray) -> int:
    """GL_TEXTURE_2D_ARRAY: bilinear within a layer, s repeat, t clamp."""
    return _tex_layered(GL.GL_TEXTURE_2D_ARRAY, data, (GL.GL_TEXTURE_WRAP_T,))


#: Default spectral rank of the shading (capped at the bake's): one 3-D environment fetch per rank and tap,
#: and on iron rank 2 agrees with jkatana.render as closely as rank 3 (the agreement views' ΔE2000 mean
#: and p95 within 0.015, bench_interactive).
DEFAULT_RANK = 2

#: Default GL internal format of the prefiltered environment textures (the shading's most-read tables):
#: float32, because llvmpipe converts half floats on every fetch, so RGBA16F is no faster
#: (bench_interactive's ``env_f16`` case) and loses precision.
ENV_FORMAT = GL.GL_RGBA32F


def _tex_3d(data: np.ndarray, internal: int = ENV_FORMAT) -> int:
    """GL_TEXTURE_3D: trilinear, s repeat, t and r clamp; stored as ``internal``."""
    return _tex_layered(GL.GL_TEXTURE_3D, data, (GL.GL_TEXTURE_WRAP_T, GL.GL_TEXTURE_WRAP_R), internal)


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


def lut_layers(b: Baked, rank: int) -> np.ndarray:
    """The lobe table and tap patterns as the shader's 2-D array texture ``(8 + 2 n_t, n_mu, n_cos, 4)`` (n_t =
    :func:`tail_taps`: with tail taps, layers 8 + 2t, 9 + 2t hold hiraji's, hamon's tail tap t (s_t, o_t, w_t),
    :func:`~jkatana.interactive.taps.tail_fit`): layers 0, 1
    the lobe tables A of hiraji, hamon (:func:`~jkatana.interactive.lobe_tables.lobe_lut`); 2, 3 their lobe
    shapes; 4, 5 the fitted taps' log(μ_e/μ) and offsets; 6, 7 their weights
    (:func:`~jkatana.interactive.taps.tap_fit`). At ``rank`` ≤ 2 layers 0, 1 have room: the first and last tap weight ride there in place of A_2, A_3 and
    the middle one is 1 − their sum (tap_fit normalises the weights), so the shader reads two layers fewer
    per pixel (``JK_RANK`` ≤ 2 in ``shade.glsl``)."""
    n_t = tail_taps(b)
    lut = np.zeros((8 + 2 * n_t,) + b.lut.shape[1:-1] + (MAX_RANK,))
    lut[:2, ..., :b.rank] = b.lut
    lut[2, ..., :3] = b.spread[0]
    lut[3, ..., :3] = b.spread[1]
    T = (b.taps.shape[-1] - 1) // 2
    lut[4:6, ..., :1 + T] = b.taps[:, ..., :1 + T]
    lut[6:8, ..., :T] = b.taps[:, ..., 1 + T:]
    if rank <= 2 and T == 3:
        lut[:2, ..., 2:4] = b.taps[:, ..., [1 + T, 2 * T]]
    for t in range(n_t):
        lut[8 + 2 * t:10 + 2 * t, ..., :3] = b.tail[..., t, :]
    return lut


def tail_taps(b: Baked) -> int:
    """How many tail taps the bake's regions read (0: none holds a long-tailed lobe; ``Baked.tail``): the shader
    reads no more than the widest-reaching region needs."""
    used = np.nonzero(np.any(b.tail[..., 2] > 0, axis=(0, 1, 2)))[0]
    return int(used[-1]) + 1 if used.size else 0


class ShadingState:
    """What the shaders read: baked tables, reflectance map, and per-frame settings.

    - `baked`: :class:`jkatana.interactive.bake.Baked`; `refl_map`: ``(H, W, 3)`` w, μ0, μ1.
    - per frame: `exposure`, `env_rotation` (radians about +Y, turns the light around the blade),
      and the static switches `rank` (≤ baked rank; default :data:`DEFAULT_RANK`), `rough`, `blend`, `two_tap` (anisotropic lobe:
      three (or, with `taps=5`, five) binomial prefiltered taps along the plane of incidence; off: one tap),
      `fit` (with three taps: their offsets, weights and filter width fitted to the lobe by
      :func:`jkatana.interactive.taps.tap_fit` — the default; off: moment-matched binomial taps, which
      miss the lobe's skew: ~10 % too dark on a sun inside the oblique hamon lobe; `taps=5` is always
      moment-matched). The baked caps (compact sources split off the map, :func:`~jkatana.interactive.caps.sun_caps`)
      are a static switch too (``JK_CAPS``, their number; 0: no cap code), and so is their kernel table
      (``JK_CAP_TABLE``: rough shading of a bake with a cap whose regions hold lobes other than the paper's,
      :mod:`jkatana.interactive.captable`; a 3-D texture (û, v̂, (region, μ level, cos θv)) after the
      environment textures). With the fitted taps, a bake whose regions hold a long-tailed lobe adds tail
      taps (``JK_TAIL``: their number, :func:`tail_taps`; further environment reads at wider levels,
      :func:`jkatana.interactive.taps.tail_fit`).
    - `env_format`: GL internal format of the environment textures (:data:`ENV_FORMAT`).
    """

    #: draw the environment behind the blade (deferred path; the `view` command turns it on); off: the
    #: scene's flat background colour, which tests and benchmarks use to find the blade's pixels
    background: bool = False

    def __init__(self, baked: Baked, refl_map: np.ndarray, *, exposure: float = 1.0, rank: int | None = None,
                 rough: bool = True, blend: bool = True, two_tap: bool = True, taps: int = 3, fit: bool = True,
                 env_format: int = ENV_FORMAT):
        self.baked = baked
        self.refl_map = np.asarray(refl_map, np.float64)
        self.exposure = float(exposure)
        self.env_rotation = 0.0
        self.rank = min(DEFAULT_RANK, baked.env.shape[1]) if rank is None else int(rank)
        if not 1 <= self.rank <= baked.env.shape[1]:
            raise ValueError(f"rank must be 1..{baked.env.shape[1]} (the bake's environment stacks), got {self.rank}")
        self.rough = bool(rough)
        self.blend = bool(blend)
        self.two_tap = bool(two_tap)
        if taps not in (3, 5):
            raise ValueError(f"taps must be 3 or 5, got {taps}")
        self.taps = int(taps)
        self.fit = bool(fit)
        self.env_format = int(env_format)
        self._textures: dict[object, tuple[int, ...]] = {}

    def defines(self) -> dict:
        return {"JK_RANK": self.rank, "JK_ROUGH": int(self.rough), "JK_BLEND": int(self.blend),
                "JK_CAPS": self.baked.n_caps, "JK_CAP_TABLE": int(self.cap_table),
                "JK_TWO_TAP": int(self.two_tap and self.rough), "JK_TAPS": self.taps,
                "JK_TAP_FIT": int(self.fit and self.two_tap and self.rough and self.taps == 3),
                "JK_TAIL": tail_taps(self.baked) if self.fit and self.two_tap and self.rough and self.taps == 3 else 0}

    @property
    def cap_table(self) -> bool:
        """Whether the shader reads the caps through the bake's kernel table (``JK_CAP_TABLE``)."""
        return bool(self.rough and self.baked.n_caps and self.baked.cap_kernel.size)

    def env_rot_matrix(self) -> np.ndarray:
        """World → environment-map rotation about +Y, as :func:`jkatana.render.renderer.rotation_y`
        (a feature at compass azimuth a moves to a + env_rotation)."""
        c, s = np.cos(self.env_rotation), np.sin(self.env_rotation)
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])

    def textures(self) -> tuple[int, ...]:
        """GL texture ids in the current context (uploaded on first use): the lobe table, the map, the transfer
        row, the environment stacks of the basis functions the shading reads (``rank`` of them, not the bake's:
        each is n_mu × H × W texels) and, where the bake has one, the caps' kernel table."""
        import OpenGL.contextdata

        key = OpenGL.contextdata.getContext()
        if key not in self._textures:
            b = self.baked
            lut = lut_layers(b, self.rank)
            self._textures[key] = (
                _tex_array(lut),                                         # (8 or 10, n_mu, n_cos, 4)
                _tex_2d(_rgba(self.refl_map)),
                _tex_2d(_rgba(np.asarray(b.transfer, np.float64)[None, :, None])),
                *(_tex_3d(b.env[:, r], self.env_format) for r in range(self.rank)),     # (n_mu, H, W, 3) each
            )
            if b.cap_kernel.size:                        # (2 n_mu n_cos, n_v, n_u, 4), clamped on every axis
                k = b.cap_kernel
                data = _rgba(k.reshape((-1,) + k.shape[-2:])[..., None])
                self._textures[key] += (_tex_layered(GL.GL_TEXTURE_3D, data, (GL.GL_TEXTURE_WRAP_S,
                                        GL.GL_TEXTURE_WRAP_T, GL.GL_TEXTURE_WRAP_R)),)
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
