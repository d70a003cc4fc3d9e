"""Spectral environment maps (equirectangular, world frame Y up).

## Orientation convention

jkatana's world frame is right-handed with **Y up**. An environment map is an
equirectangular (latitude–longitude) image of ``H`` rows × ``W`` columns:

- ``u = 0.5 + atan2(d_x, −d_z) / (2π)`` (column coordinate in [0, 1)),
- ``v = acos(d_y) / π`` (row coordinate: ``v = 0`` is the zenith, row 0 is the
  top of the image, ``v = 1`` the nadir),
- texel ``(row j, column i)`` has its centre at ``((i + 0.5)/W, (j + 0.5)/H)``.

So the **centre of the image looks along −Z**, the left/right edges along +Z,
and ``u = 0.75`` looks along +X. Read as a compass (−Z = north, +X = east),
``u − 0.5`` is the azimuth measured clockwise from north (east = 90°), which is
how :mod:`jkatana.light.sky` places the sun; the image is seen from inside the
sphere (east is to the right of north), as Poly Haven panoramas are.

Other renderers (measured, not assumed): Mitsuba 3.9.1's ``envmap`` has the
same handedness and up axis but is turned **half a turn** about +Y — its
``u = atan2(d_x, −d_z)/(2π)`` without the ``+½``, so its image centre looks
along +Z — and its rows are corner-aligned (row ``j`` at ``v = j/(H − 1)``,
zenith and nadir on the first and last rows; columns are centred as ours).
To show a jkatana map in Mitsuba, or the reverse, rotate it by 180° about +Y
(``MITSUBA_ENV_ROTATION_DEG`` in the checkout's ``validation/mitsuba.py``);
``tests/test_render_mitsuba.py`` pins both facts against Mitsuba's own lookup.
pbrt-v4's image infinite lights use an equal-area octahedral square mapping
(Clarberg 2008), not a latitude–longitude one.

Radiance is spectral, last axis on a :class:`~jkatana.spectral.WavelengthGrid`,
in the map's own units (W m⁻² sr⁻¹ nm⁻¹ for the built-in sky; for an upsampled
RGB map, see :mod:`jkatana.light.upsampling`).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from jkatana.errors import InputError
from jkatana.spectral.grid import DEFAULT_GRID, WavelengthGrid


def direction_to_uv(d: Float[ArrayLike, "*#b 3"]) -> tuple[Float[Array, "*#b"], Float[Array, "*#b"]]:
    """World direction (need not be unit) → equirectangular ``(u, v)`` in [0, 1].

    ``u = 0.5 + atan2(d_x, −d_z)/(2π)``, ``v = acos(d_y/|d|)/π`` (row 0 = zenith).
    Uses ``atan2`` for the polar angle as well (no ``acos`` precision loss near
    the poles).
    """
    d = jnp.asarray(d)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    u = 0.5 + atan2(x, -z) / (2 * jnp.pi)
    rho = jnp.sqrt(x * x + z * z)
    v = atan2(rho, y) / jnp.pi
    return u, v


#: tan(π/8): Cephes' ``atanf`` reduces |y/x| ≤ 1 above it by atan a = π/4 + atan((a − 1)/(a + 1)).
_TAN_PI_8 = 0.41421356237309503


def atan2(y, x):
    """atan2(y, x) in [−π, π]: in float32 from a polynomial, as accurate as ``jnp.arctan2`` (≤ 3e-7 rad);
    any other dtype is ``jnp.arctan2`` itself (float64 keeps its full precision).

    Cephes' single-precision arctangent (Moshier 1992, *Methods and Programs for Mathematical
    Functions*, ``atanf.c``): the ratio a = min(|x|, |y|)/max(|x|, |y|) ∈ [0, 1], reduced to
    |a| ≤ tan(π/8) by atan a = π/4 + atan((a − 1)/(a + 1)), then a degree-9 odd minimax polynomial;
    the octant and quadrant restored from |y| > |x|, the sign of x and the sign bit of y (so that
    atan2(±0, x < 0) = ±π and atan2(0, 0) = 0, as ``jnp.arctan2``). Elementwise arithmetic only:
    XLA's CPU backend vectorises it, where ``jnp.arctan2`` is a scalar call per element (≈ 15×
    the time). Differentiable (the polynomial's derivative, within float32 of 1/(1 + a²)).
    """
    y, x = jnp.asarray(y), jnp.asarray(x)
    if jnp.result_type(y, x) != jnp.float32:
        return jnp.arctan2(y, x)
    ax, ay = jnp.abs(x), jnp.abs(y)
    hi, lo = jnp.maximum(ax, ay), jnp.minimum(ax, ay)
    a = lo / jnp.where(hi > 0, hi, 1.0)
    big = a > _TAN_PI_8
    a = jnp.where(big, (a - 1.0) / (a + 1.0), a)
    z = a * a
    r = (((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z * a + a
    r = jnp.where(big, r + np.pi / 4, r)
    r = jnp.where(ay > ax, np.pi / 2 - r, r)
    r = jnp.where(x < 0, np.pi - r, r)
    return jnp.where(jnp.signbit(y), -r, r)


def equirect_direction(u, cos_theta, sin_theta):
    """Unit world direction at column coordinate ``u`` and polar angle θ (given as ``cos θ``, ``sin θ``).

    ``(sin θ sin φ, cos θ, −sin θ cos φ)`` with azimuth ``φ = (u − 0.5)·2π``: the one statement of
    the equirectangular convention in this direction (see the module docstring), for NumPy and JAX
    arrays alike (the result is of the arguments' kind).
    """
    xp = np if all(isinstance(a, (np.ndarray, np.generic, float, int)) for a in (u, cos_theta, sin_theta)) else jnp
    phi = (u - 0.5) * 2 * np.pi
    return xp.stack(xp.broadcast_arrays(sin_theta * xp.sin(phi), cos_theta, -sin_theta * xp.cos(phi)), axis=-1)


def uv_to_direction(u, v) -> Float[Array, "*#b 3"]:
    """Equirectangular ``(u, v)`` → unit world direction (inverse of :func:`direction_to_uv`)."""
    u, v = jnp.broadcast_arrays(jnp.asarray(u), jnp.asarray(v))
    theta = v * jnp.pi
    return equirect_direction(u, jnp.cos(theta), jnp.sin(theta))


def texel_index(u, v, height: int, width: int):
    """``(row j, column i)`` of the texel containing equirectangular ``(u, v)`` (wraps in u, clamps in v)."""
    i = jnp.mod(jnp.floor(u * width).astype(jnp.int32), width)
    j = jnp.clip(jnp.floor(v * height).astype(jnp.int32), 0, height - 1)
    return j, i


class Taps(NamedTuple):
    """The four texels of a bilinear lookup and its weights (:func:`bilinear_taps`): flat texel indices
    ``row · W + column`` of (top left, top right, bottom left, bottom right) and the fractions ``fx``, ``fy``."""

    i00: Int[Array, "*b"]
    i01: Int[Array, "*b"]
    i10: Int[Array, "*b"]
    i11: Int[Array, "*b"]
    fx: Float[Array, "*b"]
    fy: Float[Array, "*b"]


def bilinear_taps(u, v, height: int, width: int) -> Taps:
    """The texels and weights of :func:`bilinear_uv` at ``(u, v)``: texel centres at ``((i + ½)/W, (j + ½)/H)``,
    wrapping in u (any u), clamped in v to the first and last rows of centres.

    Elementwise arithmetic only, apart from :func:`gather_taps`' loads: XLA's CPU backend vectorises a loop
    without gathers and runs one with a gather scalar, so a caller that computes the taps apart from the
    loads (the renderer: in the pass that draws its samples) keeps this arithmetic vectorised.
    """
    H, W = height, width
    x = u * W - 0.5
    y = jnp.clip(v * H - 0.5, 0.0, H - 1.0)
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    c0 = x0 - W * jnp.floor(x0 / W)  # the column modulo W, in floating point (exact for integers below 2^24)
    c0 = jnp.where(c0 >= W, c0 - W, jnp.where(c0 < 0, c0 + W, c0))
    c0 = jnp.clip(c0.astype(jnp.int32), 0, W - 1)  # huge or non-finite u round out of range; the loads trust it
    c1 = jnp.where(c0 == W - 1, 0, c0 + 1)
    r0 = jnp.clip(y0.astype(jnp.int32), 0, H - 1) * W
    r1 = jnp.minimum(r0 + W, (H - 1) * W)
    return Taps(r0 + c0, r0 + c1, r1 + c0, r1 + c1, x - x0, y - y0)


def gather_taps(image: Float[Array, "H W C"], taps: Taps) -> Float[Array, "*b C"]:
    """The bilinear blend of ``image``'s four texels ``taps`` (:func:`bilinear_taps`), ``(*b, C)``."""
    flat = image.reshape((image.shape[0] * image.shape[1],) + image.shape[2:])

    def tap(i):  # the indices are in range by construction: no clamping or negative-index code per load
        return flat.at[i.astype(jnp.uint32)].get(mode="promise_in_bounds")

    fx = taps.fx.astype(image.dtype)[..., None]
    fy = taps.fy.astype(image.dtype)[..., None]
    top = tap(taps.i00) * (1 - fx) + tap(taps.i01) * fx
    bottom = tap(taps.i10) * (1 - fx) + tap(taps.i11) * fx
    return top * (1 - fy) + bottom * fy


def bilinear_uv(image: Float[Array, "H W C"], u, v) -> Float[Array, "*b C"]:
    """Bilinear lookup of an equirectangular ``(H, W, C)`` image at ``(u, v)``, texel centres at
    ``((i + ½)/W, (j + ½)/H)``: wraps in u, clamps in v to the first and last rows of centres.

    For any number of channels (spectral bands or basis coefficients); :meth:`EnvMap.lookup` adds
    the blend towards each pole. :func:`gather_taps` of :func:`bilinear_taps`.
    """
    return gather_taps(image, bilinear_taps(u, v, image.shape[0], image.shape[1]))


def row_edges_cos(height: int) -> np.ndarray:
    """cos θ of the ``height + 1`` row edges (θ = jπ/H, from the zenith down), NumPy float64."""
    return np.cos(np.arange(height + 1) * (np.pi / height))


def texel_directions_np(height: int, width: int) -> np.ndarray:
    """Unit directions of the texel centres, NumPy float64 ``(H, W, 3)``."""
    u = (np.arange(width) + 0.5) / width
    theta = (np.arange(height) + 0.5) / height * np.pi
    return equirect_direction(u[None, :], np.cos(theta)[:, None], np.sin(theta)[:, None])


def texel_solid_angles_np(height: int, width: int) -> np.ndarray:
    """Exact texel solid angles ``(2π/W)(cos θ_top − cos θ_bottom)``, NumPy float64 ``(H, W)`` (sum 4π)."""
    edges = row_edges_cos(height)
    band = (edges[:-1] - edges[1:]) * (2 * np.pi / width)
    return np.broadcast_to(band[:, None], (height, width)).copy()


def irradiance_weights_np(height: int, width: int, normal=(0.0, 1.0, 0.0)) -> np.ndarray:
    """``max(d·n, 0)·Ω`` per texel, NumPy float64 ``(H, W)``: the irradiance on a plane with unit
    ``normal`` is ``Σ w L`` (texel-centre quadrature of ``∫ L cos θ dω``, unoccluded)."""
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    return np.maximum(texel_directions_np(height, width) @ n, 0.0) * texel_solid_angles_np(height, width)


def texel_directions(height: int, width: int, dtype=jnp.float32) -> Float[Array, "H W 3"]:
    """Unit directions of the texel centres of an ``height × width`` map."""
    return jnp.asarray(texel_directions_np(height, width), dtype)


def texel_solid_angles(height: int, width: int, dtype=jnp.float32) -> Float[Array, "H W"]:
    """Exact solid angle of each texel: ``(2π/W)·(cos θ_top − cos θ_bottom)`` (sums to 4π)."""
    return jnp.asarray(texel_solid_angles_np(height, width), dtype)


def box_downsample(image: Float[np.ndarray, "H W C"], factor: int, block: int | None = None
                   ) -> Float[np.ndarray, "h w C"]:
    """Box-filter an equirectangular ``(H, W, C)`` image by ``factor`` in both axes, each block weighted by
    its texels' solid angles (power-preserving: Σ L Ω unchanged), in float64.

    ``block``: about that many rows at a time (a multiple of ``factor``), so that a large float32 image is
    never copied whole to float64 (the streamed environments); ``None``: all rows at once."""
    H, W = image.shape[:2]
    f = int(factor)
    omega = texel_solid_angles_np(H, W)
    step = H if block is None else max(f, block // f * f)
    num = np.empty((H // f, W // f, image.shape[-1]))
    for r0 in range(0, H, step):
        r1 = min(H, r0 + step)
        part = image[r0:r1] * omega[r0:r1, :, None]
        num[r0 // f:r1 // f] = part.reshape((r1 - r0) // f, f, W // f, f, -1).sum(axis=(1, 3))
    return num / texel_solid_angles_np(H // f, W // f)[..., None]


class EnvMap(eqx.Module):
    """A spectral equirectangular environment map (see the module docstring for axes).

    **Fields:**

    - `radiance`: ``(H, W, wl)`` spectral radiance (float32 by default).
    - `grid`: the wavelength grid of the last axis (static).
    """

    radiance: Float[Array, "H W wl"]
    grid: WavelengthGrid = eqx.field(static=True, default=DEFAULT_GRID)

    def __check_init__(self):
        if self.radiance.ndim != 3 or self.radiance.shape[-1] != self.grid.size:
            raise InputError(f"radiance must be (H, W, {self.grid.size}) for {self.grid}, "
                             f"got {self.radiance.shape}", field="radiance")

    @property
    def height(self) -> int:
        return self.radiance.shape[0]

    @property
    def width(self) -> int:
        return self.radiance.shape[1]

    def directions(self) -> Float[Array, "H W 3"]:
        """Unit directions of the texel centres."""
        return texel_directions(self.height, self.width, self.radiance.dtype)

    def solid_angles(self) -> Float[Array, "H W"]:
        """Solid angle of every texel (sin θ weighting, exact per row; sums to 4π)."""
        return texel_solid_angles(self.height, self.width, self.radiance.dtype)

    def lookup(self, d: Float[ArrayLike, "*#b 3"]) -> Float[Array, "*#b wl"]:
        """Bilinear radiance in direction ``d``: wraps in ``u``; towards the poles (above the
        first / below the last row of texel centres) it blends with the pole value, the mean
        of the first / last row, so the lookup is continuous across each pole.

        Pure JAX: jittable, and differentiable in :attr:`radiance`.
        """
        u, v = direction_to_uv(d)
        H = self.height
        L = self.radiance
        dt = L.dtype
        inner = bilinear_uv(L, u, v)
        y = v * H - 0.5
        # polar caps: y in [-0.5, 0) and (H-1, H-0.5]
        north = jnp.mean(L[0], axis=0)
        south = jnp.mean(L[H - 1], axis=0)
        t_n = jnp.clip(-2.0 * y, 0.0, 1.0).astype(dt)[..., None]
        t_s = jnp.clip(2.0 * (y - (H - 1)), 0.0, 1.0).astype(dt)[..., None]
        return inner * (1 - t_n - t_s) + north * t_n + south * t_s

    def lookup_nearest(self, d: Float[ArrayLike, "*#b 3"]) -> Float[Array, "*#b wl"]:
        """Radiance of the texel containing ``d`` (piecewise constant: the density the sampler uses)."""
        j, i = texel_index(*direction_to_uv(d), self.height, self.width)
        return self.radiance[j, i]

    def is_grey(self, rtol: float = 1e-6) -> bool:
        """True when every texel's spectrum is flat (all bands equal to ``rtol``).

        A grey map lets the renderer shade one band and broadcast. Not jittable
        (returns a Python bool).
        """
        L = np.asarray(self.radiance)
        mean = L.mean(axis=-1, keepdims=True)
        return bool(np.all(np.abs(L - mean) <= rtol * np.maximum(np.abs(mean), np.finfo(L.dtype).tiny)))

    def rotate(self, azimuth) -> "EnvMap":
        """Rotate about +Y by ``azimuth`` radians (a feature at compass azimuth a moves to a + azimuth).

        Fractional texel shifts are linearly interpolated (a slight blur; integer
        multiples of ``2π/W`` are exact).
        """
        shift = jnp.asarray(azimuth) / (2 * jnp.pi) * self.width
        k = jnp.floor(shift)
        f = (shift - k).astype(self.radiance.dtype)
        k = k.astype(jnp.int32)
        idx = jnp.mod(jnp.arange(self.width, dtype=jnp.int32) - k, self.width)
        idx1 = jnp.mod(idx - 1, self.width)
        L = self.radiance[:, idx] * (1 - f) + self.radiance[:, idx1] * f
        return EnvMap(L, self.grid)

    def downsample(self, factor: int) -> "EnvMap":
        """Box-filter by an integer ``factor`` in both axes, weighting by texel solid angle.

        Power-preserving: ``Σ L Ω`` (every band) is unchanged up to rounding.
        """
        f = int(factor)
        H, W = self.height, self.width
        if f < 1 or H % f or W % f:
            raise InputError(f"downsample factor {factor} must divide the map size {H}×{W}", field="factor")
        L = box_downsample(np.asarray(self.radiance, np.float64), f)
        return EnvMap(jnp.asarray(L, self.radiance.dtype), self.grid)

    def resample_grid(self, grid: WavelengthGrid) -> "EnvMap":
        """Linearly resample the spectral axis onto ``grid`` (must lie within the map's range)."""
        from jkatana.spectral.grid import resample

        L = resample(self.grid.wavelengths, np.asarray(self.radiance, np.float64), grid, name="envmap")
        return EnvMap(jnp.asarray(L, self.radiance.dtype), grid)

    def scaled(self, factor) -> "EnvMap":
        return EnvMap(self.radiance * factor, self.grid)

    def xyz(self) -> Float[Array, "H W 3"]:
        """CIE XYZ per texel, ``k = 1`` (radiance units × nm)."""
        from jkatana.spectral.colorimetry import xyz_weights

        return self.radiance @ jnp.asarray(xyz_weights(self.grid), self.radiance.dtype)

    def luminance(self) -> Float[Array, "H W"]:
        """CIE Y per texel (``k = 1``), the quantity the sampler's density follows."""
        from jkatana.spectral.colorimetry import xyz_weights

        return self.radiance @ jnp.asarray(xyz_weights(self.grid)[:, 1], self.radiance.dtype)

    def irradiance(self, normal=(0.0, 1.0, 0.0)) -> Float[Array, "wl"]:
        """Spectral irradiance on a plane with ``normal`` (texel quadrature, unoccluded)."""
        w = jnp.asarray(irradiance_weights_np(self.height, self.width, normal), self.radiance.dtype)
        return jnp.einsum("hw,hwl->l", w, self.radiance)


def load_envmap(path: str | Path, grid: WavelengthGrid = DEFAULT_GRID, upsampling: str = "Jakob 2019",
                scale: float = 1.0, *, colourspace: str = "sRGB", dtype=np.float32) -> EnvMap:
    """Read an environment map into a spectral :class:`EnvMap`.

    **Arguments:**

    - `path`: a spectral OpenEXR in the Fichet et al. (2021) layout (resampled
      to `grid`), an RGB OpenEXR (any compression the OpenEXR library reads,
      DWAB included), or a Radiance ``.hdr`` (RGBE, through OpenImageIO).
    - `grid`: target wavelength grid.
    - `upsampling`: RGB → spectrum method name for RGB files (see
      :data:`jkatana.light.upsampling.UPSAMPLING_METHODS`); ignored for spectral files.
    - `scale`: multiplies the radiance.
    - `colourspace`: the RGB primaries of an RGB file (linear; default sRGB/Rec. 709).

    **Returns:** an :class:`EnvMap` with float32 (default) radiance.

    Raises :class:`InputError` naming the file when it is missing, unreadable, or
    not a 2:1-ish latitude–longitude image with RGB or spectral channels.
    """
    from jkatana.light import spectral_exr, upsampling as up

    path = Path(path)
    if not path.is_file():
        raise InputError("environment map not found", path=path)
    suffix = path.suffix.lower()
    if suffix == ".exr" and spectral_exr.is_spectral_exr(path):
        L = check_radiance(spectral_exr.read_spectral_exr(path, grid), path)
    else:
        rgb = read_rgb_image(path)
        L = up.rgb_to_spectrum(rgb, upsampling, grid, colourspace=colourspace)
    L = np.nan_to_num(np.asarray(L, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    L = np.maximum(L, 0.0) * scale
    return EnvMap(jnp.asarray(L, dtype), grid)


def read_rgb_image(path: str | Path) -> np.ndarray:
    """Linear RGB ``(H, W, 3)`` float32 from an RGB(A) OpenEXR or a Radiance ``.hdr``."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        from jkatana.io.exr import read_exr

        channels, _ = read_exr(path)
        names = {n.split(".")[-1].upper(): n for n in channels}
        missing = [c for c in "RGB" if c not in names]
        if missing:
            raise InputError(f"EXR has no {'/'.join(missing)} channel(s) and is not spectral "
                             f"(channels: {sorted(channels)[:8]})", path=path)
        rgb = np.stack([channels[names[c]] for c in "RGB"], axis=-1).astype(np.float32)
    elif suffix in (".hdr", ".pic", ".rgbe"):
        try:
            import OpenImageIO as oiio
        except ImportError as err:  # pragma: no cover
            raise InputError(f"reading .hdr needs OpenImageIO ({err})", path=path) from None
        buf = oiio.ImageBuf(str(path))
        if buf.has_error:
            raise InputError(f"not a readable Radiance HDR ({buf.geterror()})", path=path)
        px = buf.get_pixels(oiio.FLOAT)
        if buf.has_error:  # e.g. a header without its pixels: OpenImageIO returns the buffer's garbage
            raise InputError(f"not a readable Radiance HDR ({buf.geterror().splitlines()[0]})", path=path)
        if px is None or px.ndim != 3 or px.shape[2] < 3:
            raise InputError("not an RGB image", path=path)
        rgb = np.asarray(px[..., :3], np.float32)
    else:
        raise InputError(f"unsupported environment map type {suffix!r} (use .exr or .hdr)", path=path)
    if rgb.ndim != 3 or rgb.shape[0] < 2 or rgb.shape[1] < 2:
        raise InputError(f"image too small: {rgb.shape}", path=path)
    return check_radiance(rgb, path)


def check_radiance(values: np.ndarray, path) -> np.ndarray:
    """An environment's pixels ``(H, W, channels)`` as radiance: non-finite pixels refused, negative values clamped.

    A NaN or infinite pixel has no radiance to stand for (setting it to 0 would quietly remove light,
    perhaps the sun), so the file is refused, naming how many pixels and the first. A negative value is
    what an RGB image holds for a colour outside its primaries' gamut, and a radiance is never negative:
    it is clamped to 0, and one warning line says how many pixels were.
    """
    import warnings

    from jkatana.errors import SceneWarning

    values = np.asarray(values)
    bad = ~np.isfinite(values).all(axis=-1)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{int(bad.sum())} of {bad.size} pixels are NaN or infinite (the first at row {row}, "
                         f"column {col}); an environment's pixels are radiances", path=path)
    negative = (values < 0).any(axis=-1)
    if negative.any():
        warnings.warn(f"{path}: {int(negative.sum())} of {negative.size} pixels have negative values (outside the "
                      "gamut); clamped to 0", SceneWarning, stacklevel=2)
        values = np.maximum(values, 0).astype(values.dtype, copy=False)
    return values
