"""Monte Carlo sampling for the renderer (pure JAX, jittable).

Three strategies and their combination:

- **Environment** (:class:`EnvSampler`): a 2D piecewise-constant density
  over texels, proportional to ``luminance × solid angle`` (so ∝ sin θ on the
  equirectangular grid), built from marginal (rows) and conditional (columns)
  CDFs — Pharr, Jakob & Humphreys, *Physically Based Rendering* (4th ed. 2023),
  §A.5 "Sampling 2D functions" and §12.5 "Image infinite lights". Inside a
  texel the direction is uniform in *solid angle* (uniform in φ and in cos θ),
  so the density is exactly ``P(texel)/Ω(texel)``. A small spectral floor keeps
  the density positive wherever any band is, and the sun (a few texels that
  carry most of the power of a clear-sky map) is never missed: its texels get
  their full share of samples. :meth:`EnvSampler.sample_window` samples the
  same density restricted to a texel window (the renderer's: one bounding the
  lobe about the mirror direction), which MIS with the lobe strategy keeps
  unbiased whatever the window.
- **Lobes**: any :class:`jkatana.models.lobes.Lobe` (its ``sample`` and
  ``pdf``; the lobes live with their values in :mod:`jkatana.models.lobes`).
- **MIS** (:func:`mis_weight`): Veach & Guibas (1995), "Optimally Combining
  Sampling Techniques for Monte Carlo Rendering", SIGGRAPH: balance or power
  (β = 2) heuristic; :func:`reflected_radiance` is the combined one-sample-per-
  strategy estimator the tests check for bias and variance.

Frames: the lobes work in the local shading frame (N = +z, as
:mod:`jkatana.models`); :func:`frame_from_normal` gives the rotation to world
as a matrix (:func:`jkatana.models.geometry.tangent_frame`).
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from jkatana.light.envmap import (EnvMap, atan2, direction_to_uv, equirect_direction, row_edges_cos, texel_index,
                                  texel_solid_angles_np)
from jkatana.models import geometry
from jkatana.models.geometry import tangent_frame
from jkatana.models.lobes import reflect
from jkatana.spectral.colorimetry import equal_energy_xyz_weights


# ---------------------------------------------------------------- environment


class EnvSampler(eqx.Module):
    """Importance sampler of an :class:`EnvMap` by luminance × solid angle.

    **Fields:** `marginal` ``(H+1,)`` CDF over rows, `conditional` ``(H, W+1)``
    CDFs over columns per row, `texel_pdf` ``(H, W)`` density per steradian,
    `cos_edges` ``(H+1,)`` cos θ of the row edges; for sampling inside a texel
    window (:meth:`window`): `window_q` ``(H, W)`` the texel weights as integers,
    `window_table` ``(H+1, 2W+1)`` their 2D prefix sums over the columns taken
    twice (a summed-area table, Crow 1984), `window_rows` ``(H, 2W+1)`` their
    prefix sums per row, `inv_omega` ``(H,)`` 1 / texel solid angle per row.
    """

    marginal: Float[Array, "H1"]
    conditional: Float[Array, "H W1"]
    texel_pdf: Float[Array, "H W"]
    cos_edges: Float[Array, "H1"]
    window_table: Float[Array, "H1 W2"]
    window_rows: Float[Array, "H W2"]
    window_q: Float[Array, "H W"]
    inv_omega: Float[Array, "H"]

    @classmethod
    def build(cls, env: EnvMap, *, floor: float = 0.01, uniform: float = 1e-6,
              bilinear: bool | str = True, compensate: bool = False) -> "EnvSampler":
        """Tables from ``env``: weight per texel = ``(Y-weighted + floor·flat spectral mean)·Ω + uniform``.

        With ``bilinear`` (default) the weight is the texel's integral of the
        *bilinear* radiance that :meth:`EnvMap.lookup` returns — the separable
        ``(1, 6, 1)/8`` filter of the texel values (wrapping in u, clamped in v) —
        so that ``f/p`` stays bounded next to a one-texel sun (otherwise the
        bilinear spill of the sun into neighbouring texels, sampled at sky
        density, makes the estimator heavy-tailed: unbiased in expectation but
        low with high probability at practical sample counts).
        ``bilinear="max"`` instead takes the *largest* texel value of the 3×3
        neighbourhood (the bilinear lookup's support), which bounds ``f/p`` by
        the texel's own weight everywhere (at the price of over-sampling the
        ring around a sun); the reference renderer's choice.

        With ``compensate``, MIS compensation (Karlík, Šik, Vévoda, Skřivan &
        Křivánek 2019, "MIS Compensation: Optimizing Sampling Techniques in
        Multiple Importance Sampling", ACM TOG 38(6)): the weight is
        ``max(y − ȳ, 0)`` with ȳ its solid-angle mean, so environment samples
        go to what stands out (the sun) and the smooth rest is left to the BRDF
        strategy. Only for use *with* MIS: alone, the estimator keeps just the
        ``uniform`` floor elsewhere (still unbiased, but noisy).

        **Arguments:**

        - `floor`: fraction of the spectral weight given to a flat spectrum, so
          texels radiant only where ȳ ≈ 0 (deep blue/red) are still sampled.
        - `uniform`: fraction of the total weight spread uniformly over the
          sphere (keeps the density positive everywhere, e.g. on black maps and
          where bilinear lookups leak into zero texels).
        """
        L = np.asarray(env.radiance, np.float64)
        y = np.maximum(L, 0.0) @ cls.weights(env.grid, floor)
        return cls.from_luminance(y, env.radiance.dtype, uniform=uniform, bilinear=bilinear, compensate=compensate)

    @staticmethod
    def weights(grid, floor: float = 0.01) -> np.ndarray:
        """``(wl,)`` spectral weights of the texel luminance :meth:`build` samples by: CIE ȳ (equal-energy
        normalised) with a ``floor`` fraction of the flat mean; they sum to 1."""
        return (1 - floor) * equal_energy_xyz_weights(grid)[:, 1] + floor / grid.size

    @classmethod
    def from_luminance(cls, y: np.ndarray, dtype, *, uniform: float = 1e-6, bilinear: bool | str = True,
                       compensate: bool = False) -> "EnvSampler":
        """:meth:`build`'s tables from the texel luminances ``y (H, W)`` (``max(L, 0) @`` :meth:`weights`):
        one float per texel is all a map read in row blocks keeps for sampling."""
        y = np.asarray(y, np.float64)
        H, W = y.shape
        omega = texel_solid_angles_np(H, W)[:, 0]
        if bilinear not in (True, False, "max"):
            raise ValueError(f"bilinear must be True, False or 'max', got {bilinear!r}")
        if bilinear == "max":
            from scipy.ndimage import maximum_filter

            y = maximum_filter(y, size=3, mode=("nearest", "wrap"))
        elif bilinear:
            y = (np.roll(y, 1, axis=1) + 6 * y + np.roll(y, -1, axis=1)) / 8
            yp = np.concatenate([y[:1], y, y[-1:]], axis=0)
            y = (yp[:-2] + 6 * yp[1:-1] + yp[2:]) / 8
        if compensate:
            y = np.maximum(y - (y * omega[:, None]).sum() / (4 * np.pi), 0.0)
        f = y * omega[:, None]
        total = f.sum()
        f = f + (uniform * total if total > 0 else 1.0) * omega[:, None] / (4 * np.pi)
        row = f.sum(axis=1)
        marginal = np.concatenate([[0.0], np.cumsum(row)]) / row.sum()
        conditional = np.concatenate([np.zeros((H, 1)), np.cumsum(f, axis=1)], axis=1) / row[:, None]
        marginal[-1] = 1.0
        conditional[:, -1] = 1.0
        pdf = f / f.sum() / omega[:, None]
        cos_edges = row_edges_cos(H)
        dt = dtype
        # the windowed strategy's weights: the same texel weights as integers summing to ≤ WINDOW_TOTAL, so
        # that every partial sum below (≤ 2·WINDOW_TOTAL = 2^24) and every difference of two is exact in float32
        q = np.floor(f / f.sum() * WINDOW_TOTAL)
        q2 = np.concatenate([q, q], axis=1)  # the columns twice: a window may wrap past u = 1
        table = np.zeros((H + 1, 2 * W + 1))
        table[1:, 1:] = np.cumsum(np.cumsum(q2, axis=0), axis=1)
        row_table = np.concatenate([np.zeros((H, 1)), np.cumsum(q2, axis=1)], axis=1)
        return cls(jnp.asarray(marginal, dt), jnp.asarray(conditional, dt), jnp.asarray(pdf, dt),
                   jnp.asarray(cos_edges, dt), jnp.asarray(table, jnp.float32), jnp.asarray(row_table, jnp.float32),
                   jnp.asarray(q, jnp.float32), jnp.asarray(1.0 / omega, dt))

    @property
    def shape(self) -> tuple[int, int]:
        return self.texel_pdf.shape

    def _texel(self, u_row, u_col):
        """``(row j, column i)`` chosen by the marginal CDF at ``u_row`` and the row's conditional at ``u_col``."""
        j = jnp.clip(jnp.searchsorted(self.marginal, u_row, side="right") - 1, 0, self.shape[0] - 1)
        return j, _row_search(self.conditional, j, u_col)

    def sample(self, key, n: int) -> tuple[Float[Array, "n 3"], Float[Array, "n"]]:
        """``n`` world directions and their density (per steradian)."""
        return self.sample_uniform(jax.random.uniform(key, (n, 4), self.texel_pdf.dtype))

    def sample_uniform(self, u: Float[ArrayLike, "*#b 4"]) -> tuple[Float[Array, "*#b 3"], Float[Array, "*#b"]]:
        """Directions and densities from given uniforms ``u`` in [0, 1)⁴ (row, column, φ and cos θ
        inside the texel): the warp behind :meth:`sample`, for quasi-Monte Carlo points
        (the renderer's scrambled Sobol points)."""
        H, W = self.shape
        u = jnp.asarray(u, self.texel_pdf.dtype)
        shape = u.shape[:-1]
        u = u.reshape(-1, 4)
        j, i = self._texel(u[:, 0], u[:, 1])
        c0, c1 = self.cos_edges[j], self.cos_edges[j + 1]
        cos_t = c0 + (c1 - c0) * u[:, 3]
        sin_t = jnp.sqrt(jnp.maximum(1 - cos_t * cos_t, 0.0))
        d = equirect_direction((i.astype(u.dtype) + u[:, 2]) / W, cos_t, sin_t)
        return d.reshape(shape + (3,)), self.texel_pdf[j, i].reshape(shape)

    def sample_uniform2(self, u: Float[ArrayLike, "*#b 2"]):
        """Directions, densities and map ``(u, v)`` from *two* uniforms per sample.

        The same density as :meth:`sample_uniform`, but the position inside the
        chosen texel comes from where each uniform fell inside its CDF interval
        (the remainder, rescaled to [0, 1)): the inverse-CDF warp of the
        continuous piecewise-constant density, PBRT 4th ed. §A.5.3. It maps a
        well-stratified 2D point set (a Sobol net) to a well-stratified set of
        directions, which four independent dimensions do not. Also returns the
        equirectangular coordinates of each direction, so that a lookup needs
        no ``atan2``.

        **Returns:** ``(d (*b, 3), pdf (*b,), u (*b,), v (*b,))``.
        """
        u = jnp.asarray(u, self.texel_pdf.dtype)
        shape = u.shape[:-1]
        u = u.reshape(-1, 2)
        j, i = self._texel(u[:, 0], u[:, 1])
        m0, m1 = self.marginal[j], self.marginal[j + 1]
        r0 = jnp.clip((u[:, 0] - m0) / jnp.maximum(m1 - m0, 1e-30), 0.0, 1.0)
        c0, c1 = self.conditional[j, i], self.conditional[j, i + 1]
        r1 = jnp.clip((u[:, 1] - c0) / jnp.maximum(c1 - c0, 1e-30), 0.0, 1.0)
        d, uu, v = self._in_texel(j, i, r0, r1)
        return (d.reshape(shape + (3,)), self.texel_pdf[j, i].reshape(shape), uu.reshape(shape),
                v.reshape(shape))

    def _in_texel(self, j, i, f_row, f_col):
        """The direction at fractions ``(f_row, f_col)`` of texel ``(j, i)``, uniform in solid angle (linear in
        cos θ and in φ): ``(d, u, v)``, ``v`` kept inside the texel's row against the ``atan2``'s rounding."""
        H, W = self.shape
        uu = (i.astype(f_col.dtype) + f_col) / W
        e0, e1 = self.cos_edges[j], self.cos_edges[j + 1]
        cos_t = e0 + (e1 - e0) * f_row
        sin_t = jnp.sqrt(jnp.maximum(1 - cos_t * cos_t, 0.0))
        jf = j.astype(cos_t.dtype)
        v = jnp.clip(atan2(sin_t, cos_t) / jnp.pi, jf / H, (jf + 1.0) / H)
        return equirect_direction(uu, cos_t, sin_t), uu, v

    def pdf_uv(self, u: Float[ArrayLike, "*#b"], v: Float[ArrayLike, "*#b"]) -> Float[Array, "*#b"]:
        """Density (per steradian) at equirectangular ``(u, v)`` (as :meth:`pdf`, without the ``atan2``)."""
        j, i = texel_index(u, v, *self.shape)
        return self.texel_pdf[j, i]

    def pdf(self, d: Float[ArrayLike, "*#b 3"]) -> Float[Array, "*#b"]:
        """Density (per steradian) of :meth:`sample` at world directions ``d``."""
        return self.pdf_uv(*direction_to_uv(d))

    # ------------------------------------------------------------ windows

    def window(self, d_map: Float[ArrayLike, "n 3"], half_angle: Float[ArrayLike, "n"]) -> "Window":
        """The texel rectangle bounding the cone of ``half_angle`` (radians) about unit map-frame directions
        ``d_map``, and its weight: a :class:`Window` for :meth:`sample_window` and :meth:`pdf_window`.

        Rows span the cone's polar range; columns its azimuth range, ``±asin(sin a / sin θ)`` about the
        centre's (the tangent meridians of a spherical cap), all columns where the cone holds a pole. A
        range that wraps past u = 1 is kept as one run of columns on the tables' doubled width.
        """
        H, W = self.shape
        u, v = direction_to_uv(d_map)
        th = v * jnp.pi
        a = jnp.asarray(half_angle, th.dtype)
        lo, hi = th - a, th + a
        pole = (lo <= 0) | (hi >= jnp.pi)
        r0 = jnp.clip(jnp.floor(jnp.maximum(lo, 0.0) * (H / jnp.pi)), 0, H - 1).astype(jnp.int32)
        r1 = jnp.clip(jnp.ceil(jnp.minimum(hi, jnp.pi) * (H / jnp.pi)).astype(jnp.int32), r0 + 1, H)
        ratio = jnp.where(pole, 1.0, jnp.sin(jnp.minimum(a, 0.5 * jnp.pi)) / jnp.maximum(jnp.sin(th), 1e-30))
        half = jnp.arcsin(jnp.minimum(ratio, 1.0)) * (W / (2 * jnp.pi))
        c0f = jnp.floor(u * W - half)
        c1f = jnp.ceil(u * W + half)
        full = pole | (ratio >= 1.0) | (c1f - c0f >= W)
        c0 = jnp.where(full, 0, jnp.mod(c0f, W)).astype(jnp.int32)
        c1 = jnp.where(full, W, c0 + (c1f - c0f).astype(jnp.int32))
        above = self._rows_below(r0, c0, c1)
        return Window(r0, r1, c0, c1, self._rows_below(r1, c0, c1) - above, above)

    def _rows_below(self, r, c0, c1):
        """Weight of the rows above row ``r`` in columns ``[c0, c1)`` (exact: a difference of integer sums)."""
        tab, W1 = self.window_table.reshape(-1), self.window_table.shape[1]
        return (tab[r * W1 + c1] - tab[r * W1 + c0]).astype(self.texel_pdf.dtype)

    def sample_window(self, win: "Window", u: Float[ArrayLike, "n 2"]):
        """Directions, densities and map ``(u, v)`` sampled inside ``win`` from two uniforms per sample: the
        warp of :meth:`sample_uniform2` restricted to the window's texels (density ∝ the same texel weights,
        renormalised to the window). Rows by the window's cumulative row weights (a 2D summed-area table,
        Crow 1984; the windowed sampling of pbrt-v4's ``WindowedPiecewiseConstant2D``, Pharr, Jakob &
        Humphreys 2023), then the column within the row; the remainders place the direction inside the
        texel, so a stratified point set stays stratified. Zero density where the window weighs nothing
        (the lobe strategy of MIS covers it).

        **Returns:** ``(d (n, 3), pdf (n,), u (n,), v (n,))``.
        """
        H, W = self.shape
        r0, r1, c0, c1, Q, a0 = win
        u = jnp.asarray(u, self.texel_pdf.dtype)
        t = u[:, 0] * Q

        j = _bisect(lambda r: self._rows_below(r, c0, c1) - a0 <= t, r0, r1, H)
        m0 = self._rows_below(j, c0, c1) - a0
        m1 = self._rows_below(j + 1, c0, c1) - a0
        f0 = jnp.clip((t - m0) / jnp.maximum(m1 - m0, 1e-30), 0.0, 1.0)
        rt, rb = self.window_rows.reshape(-1), j * self.window_rows.shape[1]

        def left_of(c):  # weight of row j's columns [c0, c)
            return (rt[rb + c] - rt[rb + c0]).astype(u.dtype)

        t2 = u[:, 1] * (m1 - m0)
        lo = _bisect(lambda c: left_of(c) <= t2, c0, c1, W)
        n0, n1 = left_of(lo), left_of(lo + 1)
        f1 = jnp.clip((t2 - n0) / jnp.maximum(n1 - n0, 1e-30), 0.0, 1.0)
        d, uu, v = self._in_texel(j, jnp.where(lo >= W, lo - W, lo), f0, f1)
        pdf = jnp.where(Q > 0, (n1 - n0) / jnp.maximum(Q, 1.0), 0.0) * self.inv_omega[j]
        return d, pdf, uu, v

    def pdf_window(self, win: "Window", u, v):
        """Density (per steradian) of :meth:`sample_window` at equirectangular ``(u, v)``: 0 outside the window."""
        H, W = self.shape
        r0, r1, c0, c1, Q, _ = win
        j, i = texel_index(u, v, H, W)
        ie = jnp.where(i < c0, i + W, i)
        inside = (j >= r0) & (j < r1) & (ie < c1) & (Q > 0)
        return jnp.where(inside, self.window_q[j, i].astype(Q.dtype) / jnp.maximum(Q, 1.0) * self.inv_omega[j], 0.0)


class Window(NamedTuple):
    """A texel rectangle of an :class:`EnvSampler` per sample (:meth:`EnvSampler.window`): rows ``[r0, r1)``,
    columns ``[c0, c1)`` with ``0 ≤ c0 < W`` and ``c1 ≤ c0 + W`` (column ``c ≥ W`` is ``c − W``), ``Q`` its
    weight and ``above`` the weight of the rows above ``r0`` in its columns (integers, exact in float32; kept
    so that each sample's row search starts from it instead of looking it up again)."""

    r0: Int[Array, "n"]
    r1: Int[Array, "n"]
    c0: Int[Array, "n"]
    c1: Int[Array, "n"]
    Q: Float[Array, "n"]
    above: Float[Array, "n"]


#: Sum of the windowed strategy's integer texel weights: partial sums over the doubled columns stay ≤ 2^24, where
#: float32 holds every integer, so a window's weight and its cumulative row and column weights are exact.
WINDOW_TOTAL = float(2 ** 23)


def _row_search(cdf: Float[Array, "H W1"], j: Int[Array, "n"], x: Float[Array, "n"]) -> Int[Array, "n"]:
    """Largest ``i`` in [0, W−1] with ``cdf[j, i] ≤ x``: a vectorised binary search that gathers
    one entry per sample and step (O(n) memory, unlike gathering whole rows)."""
    W = cdf.shape[1] - 1
    lo = _bisect(lambda i: cdf[j, i] <= x, jnp.zeros_like(j), jnp.full_like(j, W), W)
    return jnp.clip(lo, 0, W - 1)


def _bisect(below: Callable, lo: Int[Array, "n"], hi: Int[Array, "n"], n: int) -> Int[Array, "n"]:
    """The last ``m`` in ``[lo, hi)`` with ``below(m)`` true, for a ``below`` that is true up to a point and false
    after it (true at ``lo``), brackets at most ``n`` wide: a vectorised binary search of ⌈log₂(n + 1)⌉ steps.

    A ``fori_loop``, not unrolled: XLA's CPU backend would re-run an unrolled search's steps inside each
    consumer's fusion."""
    def step(_, bracket):
        lo, hi = bracket
        mid = jnp.right_shift(lo + hi, 1)
        right = below(mid)
        return jnp.where(right, mid, lo), jnp.where(right, hi, mid)

    return jax.lax.fori_loop(0, max(1, math.ceil(math.log2(n + 1))), step, (lo, hi))[0]


# ---------------------------------------------------------------- frames


def frame_from_normal(n: Float[ArrayLike, "*#b 3"]) -> Float[Array, "*#b 3 3"]:
    """Rows (t, b, n): :func:`jkatana.models.geometry.tangent_frame` around unit ``n`` as a matrix.

    ``local = frame @ world`` and ``world = local @ frame`` (for row vectors).
    """
    n = jnp.asarray(n)
    t, b = tangent_frame(n)
    return jnp.stack([t, b, n], axis=-2)


def to_local(frame, d):
    """World directions ``d`` in the frame of :func:`frame_from_normal` (:func:`jkatana.models.geometry.to_local`)."""
    return geometry.to_local(d, frame[..., 0, :], frame[..., 1, :], frame[..., 2, :])


def to_world(frame, d):
    """Local directions ``d`` of a :func:`frame_from_normal` frame in world coordinates
    (:func:`jkatana.models.geometry.to_world`)."""
    return geometry.to_world(d, frame[..., 0, :], frame[..., 1, :], frame[..., 2, :])


# ---------------------------------------------------------------- MIS


def mis_weight(p_this, p_other, n_this=1, n_other=1, heuristic: str = "balance", *, valid=None,
               per_density: bool = False):
    """Veach's MIS weight of a sample drawn by one of two strategies (Veach & Guibas 1995, "Optimally
    Combining Sampling Techniques for Monte Carlo Rendering", eqs. 3 and 5): the balance heuristic
    ``w = n_this p_this / Σ n p`` or the power heuristic (β = 2) ``w = (n p)² / Σ (n p)²``.

    With ``per_density`` the weight divided by its own strategy's ``n_this p_this``: what the sample's
    ``f`` is multiplied by in the combined estimator ``Σ w f / (n p)`` (the balance heuristic's
    ``1 / Σ n p``, which needs no division by a density that may be 0). ``valid`` (default: the
    denominator > 0) says where the sample counts; elsewhere the result is 0. The renderer's strategies
    (:mod:`jkatana.render.integrators.mis`) all weigh their samples with this function.
    """
    a = n_this * p_this
    b = n_other * p_other
    num = 1.0 if per_density else a
    if heuristic == "power":
        num = a if per_density else a * a
        a, b = a * a, b * b
    elif heuristic != "balance":
        raise ValueError(f"heuristic must be 'balance' or 'power', got {heuristic!r}")
    den = a + b
    if valid is None:
        valid = den > 0
    return jnp.where(valid, num / jnp.where(valid, den, 1.0), 0.0)


def reflected_radiance(key, env: EnvMap, sampler: EnvSampler, brdf_cos: Callable, V_local, frame,
                       lobe, n_env: int, n_lobe: int,
                       strategy: str = "mis", heuristic: str = "balance") -> Float[Array, "wl"]:
    """One estimate of ``L_o(V) = ∫ L_env(ω) f_r cos θ dω`` at one shading point.

    **Arguments:**

    - `brdf_cos(L_local, V_local) -> (..., wl)`: f_r cos θ_i (0 below the surface).
    - `V_local`: view direction in the local frame; `frame`: from :func:`frame_from_normal`.
    - `lobe`: a :class:`jkatana.models.lobes.Lobe` (its ``sample`` and ``pdf``).
    - `strategy`: ``"env"`` (n_env samples), ``"lobe"`` (n_lobe samples) or
      ``"mis"`` (both, weighted by `heuristic`).
    """
    k1, k2 = jax.random.split(key)
    out = 0.0
    if strategy in ("env", "mis"):
        d, p_e = sampler.sample(k1, n_env)
        Ll = to_local(frame, d)
        f = brdf_cos(Ll, V_local) * env.lookup(d)
        w = mis_weight(p_e, lobe.pdf(Ll, V_local), n_env, n_lobe, heuristic) if strategy == "mis" else 1.0
        out = out + jnp.sum((w / jnp.where(p_e > 0, p_e, 1.0))[..., None] * f, axis=0) / n_env
    if strategy in ("lobe", "mis"):
        ku, kc = jax.random.split(k2)
        V = jnp.broadcast_to(V_local, (n_lobe,) + jnp.shape(V_local))
        Ll, p_b = lobe.sample(V, jax.random.uniform(ku, V.shape[:-1] + (2,), V.dtype),
                              jax.random.uniform(kc, V.shape[:-1], V.dtype))
        d = to_world(frame, Ll)
        f = brdf_cos(Ll, V_local) * env.lookup(d)
        w = mis_weight(p_b, sampler.pdf(d), n_lobe, n_env, heuristic) if strategy == "mis" else 1.0
        out = out + jnp.sum((w / jnp.where(p_b > 0, p_b, 1.0))[..., None] * f, axis=0) / n_lobe
    return out


def reflected_radiance_quadrature(env: EnvMap, brdf_cos: Callable, V_local, frame, extent: float,
                                  n_radial: int = 256, n_azimuth: int = 256) -> Float[Array, "wl"]:
    """Brute-force reference for :func:`reflected_radiance`: polar Gauss–Legendre quadrature
    around the mirror direction, out to angle ``extent`` (rad; e.g. 16 μ for the Gaussian lobe,
    beyond which D < 1e-11), with the same bilinear :meth:`EnvMap.lookup`.
    """
    V_local = jnp.asarray(V_local)
    R_local = reflect(V_local, jnp.asarray([0.0, 0.0, 1.0], V_local.dtype))  # the mirror direction
    x, w = np.polynomial.legendre.leggauss(n_radial)
    a = 0.5 * extent * (x + 1)
    wa = 0.5 * extent * w * np.sin(a)
    az = (np.arange(n_azimuth) + 0.5) / n_azimuth * 2 * np.pi
    loc = np.stack(np.broadcast_arrays(np.sin(a)[:, None] * np.cos(az)[None], np.sin(a)[:, None] * np.sin(az)[None],
                                       np.cos(a)[:, None]), -1)
    fr_R = frame_from_normal(R_local)
    Ll = to_world(fr_R, jnp.asarray(loc, V_local.dtype))  # local shading frame, around R
    vals = brdf_cos(Ll, V_local) * env.lookup(to_world(frame, Ll))
    return jnp.einsum("r,rl->l", jnp.asarray(wa * 2 * np.pi / n_azimuth, V_local.dtype), jnp.sum(vals, axis=1))
