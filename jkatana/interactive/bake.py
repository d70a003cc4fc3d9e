"""Tables baked from the JAX models for the GLSL shaders (no model is re-derived in GLSL).

The interactive path evaluates, per pixel, the environment-lit radiance of the
paper's blend of hiraji (eq. 1) and hamon (eq. 2) lobes,

    L_o(λ) = ∫ f_r(L, V; λ) cos θi L_env(L, λ) dω_i,

integrated to CIE XYZ (eq. 6), with three textures that are all computed here
from :mod:`jkatana.models` and :mod:`jkatana.spectral`:

1. **Low-rank spectral basis of the Fresnel term.** The SVD of iron's
   F(θ, λ) on a cos θ × λ grid gives F ≈ Σ_r a_r(θ) b_r(λ) (rank 3 is exact
   to ~1e-6 for iron; the benchmark measures ranks 1–4).
2. **Environment projected on the basis and prefiltered per roughness.**
   P_{r,c}(ω; μ) = Σ_λ b_r(λ) W_c(λ) L̃_μ(ω, λ), where W_c is the CIE 1931
   weighting of eq. (6) and L̃_μ the environment convolved with the lobe
   kernel of the paper's facet distribution D(φ, μ) = exp(−ln2 φ²/μ²) at
   normal incidence (the reflected direction is 2φ from the mirror direction,
   so K(α) = D(α/2, μ)/cos(α/2), normalised). The convolution is exact on the
   equirectangular grid (FFT along longitude: the kernel depends only on the
   two latitudes and the longitude difference). One layer per μ level,
   log-spaced.
3. **Lobe lookup table** A_r(cos θv, μ) = Σ_λ b_r(λ) ∫ f_r cos θi dω_i for
   the hiraji and hamon models exactly as :meth:`Hiraji.brdf_cos` and
   :meth:`Hamon.brdf_cos` define them (normalised, uncalibrated convention),
   by quadrature in half-vector space. It carries the Fresnel variation over
   the lobe, the V-cavity G of eq. (2) and the lobe's energy, so that per pixel

       XYZ_c = Σ_r A_r(cos θv, μ) · P_{r,c}(R; μ)            (R = reflect(−V, N))

   which is exact when the environment is constant over the lobe; the
   residual (lobe stretching at grazing view, environment gradients inside
   the lobe) is what :func:`jkatana.interactive.reference` measures. This is
   the split-sum approximation of Karis (2013), "Real Shading in Unreal
   Engine 4", with the spectral dimension factored by the SVD.

Plus the display transform: the XYZ → linear RGB matrix of
:func:`jkatana.spectral.xyz_to_rgb_matrix` (eq. 7) and a 1-D table of
:func:`jkatana.spectral.encode` (eq. 8) indexed by √x so that it is dense
near black.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.models import Conductor, Hamon, Hiraji, gaussian_facet
from jkatana.spectral import DEFAULT_GRID, WavelengthGrid
from jkatana.render.film import film_weights
from jkatana.spectral.colorimetry import encode, xyz_to_rgb_matrix

#: μ levels of the prefiltered environment (radians, log-spaced, ratio √2; 0.05 is a level).
MU_LEVELS = 0.0125 * np.sqrt(2.0) ** np.arange(11)
#: Largest rank the shaders support (one RGBA texel holds 4 coefficients).
MAX_RANK = 4


def fresnel_basis(conductor: Conductor, rank: int, n_cos: int = 256):
    """Low-rank SVD basis of F(θ, λ): ``F ≈ a @ b`` with ``a (n_cos, rank)``, ``b (rank, wl)``.

    **Arguments:**

    - `conductor`: n(λ), k(λ) on the rendering grid.
    - `rank`: number of spectral basis functions (1–4).
    - `n_cos`: samples of cos θ, uniform on [0, 1].

    **Returns:**

    ``(cos, a, b, rel_err)``: the cos grid, coefficients, orthonormal spectral
    basis (rows), and the max relative error of the reconstruction.
    """
    if not 1 <= rank <= MAX_RANK:
        raise ValueError(f"rank must be 1..{MAX_RANK}, got {rank}")
    cos = np.linspace(0.0, 1.0, n_cos)
    F = np.asarray(conductor.fresnel(jnp.asarray(cos, conductor.n.dtype)), np.float64)
    U, S, Vt = np.linalg.svd(F, full_matrices=False)
    a, b = U[:, :rank] * S[:rank], Vt[:rank]
    # sign convention: the first basis function positive
    sgn = np.sign(b.sum(axis=1, keepdims=True))
    sgn[sgn == 0] = 1.0
    a, b = a * sgn.T, b * sgn
    rel_err = float(np.max(np.abs(a @ b - F) / F))
    return cos, a, b, rel_err


def texel_directions(height: int, width: int) -> np.ndarray:
    """World directions of equirectangular texel centres (Y up, u = 0.5 + atan2(x, −z)/2π, v = acos(y)/π)."""
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    theta = v[:, None] * np.pi
    phi = 2.0 * np.pi * (u[None, :] - 0.5)
    return np.stack(np.broadcast_arrays(np.sin(theta) * np.sin(phi), np.cos(theta),
                                        -np.sin(theta) * np.cos(phi)), axis=-1)


def _kernel(cos_alpha, mu, n_table: int = 8192):
    """Prefilter kernel of the paper's lobe at normal incidence: D(α/2, μ)/cos(α/2), 0 beyond 90° facet tilt.

    D is evaluated by :func:`jkatana.models.gaussian_facet` on a dense table of
    α ∈ [0, min(12 μ, π)] (D(6μ) < 1e-10) and interpolated.
    """
    top = min(12.0 * mu, np.pi)
    alpha = np.linspace(0.0, top, n_table)
    half = alpha / 2.0
    d = np.asarray(gaussian_facet(jnp.asarray(half), jnp.asarray(mu, jnp.asarray(half).dtype)), np.float64)
    table = d / np.maximum(np.cos(half), 1e-6)
    a = np.arccos(np.clip(cos_alpha, -1.0, 1.0))
    return np.where(a <= top, np.interp(a, alpha, table), 0.0)


def prefilter(image: np.ndarray, mu: float) -> np.ndarray:
    """Convolve an equirectangular image ``(H, W, C)`` with the lobe kernel of width ``mu`` (exact, FFT in longitude)."""
    H, W = image.shape[:2]
    theta = (np.arange(H) + 0.5) / H * np.pi
    edges = np.linspace(0.0, np.pi, H + 1)
    d_omega = (2.0 * np.pi / W) * (np.cos(edges[:-1]) - np.cos(edges[1:]))          # (H,)
    dlon = 2.0 * np.pi * np.arange(W) / W
    cos_a = (np.cos(theta)[:, None, None] * np.cos(theta)[None, :, None]
             + np.sin(theta)[:, None, None] * np.sin(theta)[None, :, None] * np.cos(dlon))
    K = _kernel(cos_a, mu) * d_omega[None, :, None]                                  # (Ho, Hi, W)
    K /= K.sum(axis=(1, 2), keepdims=True)
    Kf = np.fft.rfft(K, axis=-1)                                                     # (Ho, Hi, F)
    If = np.fft.rfft(image, axis=1)                                                  # (Hi, F, C)
    out = np.fft.irfft(np.matmul(Kf.transpose(2, 0, 1), If.transpose(1, 0, 2)).transpose(1, 0, 2), n=W, axis=1)
    return out.astype(np.float64)


def halfvector_quadrature(mu, n_phi: int = 32, n_psi: int = 48, extent: float = 4.5):
    """Quadrature of the half-vector hemisphere around N = +z for a lobe of width μ.

    Gauss–Legendre in the facet angle φ ∈ [0, min(extent·μ, π/2)] (D < 1e-6
    beyond 4.5 μ), uniform in azimuth; ``mu`` may be a traced JAX scalar.
    **Returns** ``(H (Q, 3), dω_h (Q,))``.
    """
    x, wx = np.polynomial.legendre.leggauss(n_phi)
    top = jnp.minimum(extent * mu, jnp.pi / 2)
    phi = (jnp.asarray(x) + 1) / 2 * top
    wphi = jnp.asarray(wx) / 2 * top
    psi = (np.arange(n_psi) + 0.5) / n_psi * 2 * np.pi
    P, S = jnp.meshgrid(phi, jnp.asarray(psi), indexing="ij")
    Hh = jnp.stack([jnp.sin(P) * jnp.cos(S), jnp.sin(P) * jnp.sin(S), jnp.cos(P)], -1).reshape(-1, 3)
    w = (wphi[:, None] * jnp.sin(P) * (2 * np.pi / n_psi)).reshape(-1)
    return Hh, w


def lobe_integral(model, conductor: Conductor, V_local, n_phi=32, n_psi=48, moments: bool = False):
    """∫ f_r cos θi dω_i (spectral) of ``model`` (Hiraji or Hamon) for local view directions ``V (..., 3)``.

    Quadrature in half-vector space (:func:`halfvector_quadrature` scaled to
    ``model.mu``), dω_i = 4 (V·H) dω_h (Walter et al. 2007, eq. 14). With
    ``moments=True`` also returns the lobe's mean squared angle from the mirror
    direction (weights summed over λ).
    """
    dt = conductor.n.dtype
    Hh, wh = halfvector_quadrature(jnp.asarray(model.mu, dt), n_phi, n_psi)
    V = jnp.asarray(V_local, dt)[..., None, :]
    Hj = Hh.astype(dt)
    vh = jnp.sum(V * Hj, -1, keepdims=True)
    L = 2 * vh * Hj - V
    f = model.brdf_cos(L, V, conductor)                                             # (..., Q, wl)
    dw = 4.0 * jnp.maximum(vh, 0.0) * wh.astype(dt)[:, None]
    total = jnp.sum(f * dw, axis=-2)
    if not moments:
        return total
    # angles of L from the mirror direction R, along the plane of incidence (t, towards N) and across it (y)
    R = V * jnp.asarray([-1.0, -1.0, 1.0], dt)
    nt = jnp.asarray([0.0, 0.0, 1.0], dt) - R[..., 2:3] * R
    t = nt / jnp.maximum(jnp.linalg.norm(nt, axis=-1, keepdims=True), 1e-12)
    t = jnp.where(jnp.linalg.norm(nt, axis=-1, keepdims=True) > 1e-9, t, jnp.asarray([1.0, 0.0, 0.0], dt))
    y = jnp.cross(R, t)
    lr = jnp.sum(L * R, -1)
    a_par = jnp.arctan2(jnp.sum(L * t, -1), lr)
    a_perp = jnp.arctan2(jnp.sum(L * y, -1), lr)
    wsum = jnp.sum(f * dw, axis=-1)
    norm = jnp.maximum(jnp.sum(wsum, -1), 1e-30)
    mean = jnp.sum(wsum * a_par, -1) / norm
    var_par = jnp.sum(wsum * (a_par - mean[..., None]) ** 2, -1) / norm
    var_perp = jnp.sum(wsum * a_perp ** 2, -1) / norm
    return total, (mean, var_par, var_perp)


@jax.jit
def _lut_column(mu, conductor, V, b):
    out, shape = [], []
    for cls in (Hiraji, Hamon):
        model = cls(jnp.ones((), mu.dtype), mu)
        total, (mean, var_par, var_perp) = lobe_integral(model, conductor, V, moments=True)
        out.append(total @ b.T)
        iso = 0.5 * (var_par[-1] + var_perp[-1])                  # V[-1] is normal incidence: isotropic
        shape.append(jnp.stack([0.5 * jnp.log(var_perp / iso),       # across-plane width → prefilter level
                                jnp.sqrt(jnp.maximum(var_par - var_perp, 0.0)),   # ± tap offset (rad)
                                mean], -1))                          # lobe centre offset towards N (rad)
    return jnp.stack(out), jnp.stack(shape)


def lobe_lut(conductor: Conductor, b: np.ndarray, mus=MU_LEVELS, n_cos: int = 64):
    """A_r(cos θv, μ) for hiraji and hamon: ``(2, n_mu, n_cos, rank)``, cos grid uniform on [0, 1].

    Also returns ``shape (2, n_mu, n_cos, 3)``, the reflected lobe's moments
    from the same quadrature, in angles from the mirror direction R: (0) half
    the log of its variance across the plane of incidence relative to normal
    incidence, (1) the extra spread along the plane, √(var_par − var_perp),
    (2) the mean offset along the plane towards N. Off normal incidence the
    lobe narrows across the plane (by ≈ cos θ) but not along it; the shader
    reads the environment prefiltered for the across-plane width at three
    taps, R rotated in the plane by mean and mean ± √2·spread with weights
    ¼, ½, ¼ — a kernel with the lobe's first and second moments that keeps
    the peak of a small bright source (a sun) within ~10 %.
    """
    cos = np.linspace(0.0, 1.0, n_cos)
    cos_c = np.maximum(cos, 1e-3)
    V = np.stack([np.sqrt(1 - cos_c ** 2), np.zeros_like(cos_c), cos_c], -1)
    dt = conductor.n.dtype
    cols = [_lut_column(jnp.asarray(mu, dt), conductor, jnp.asarray(V, dt), jnp.asarray(b, dt)) for mu in mus]
    out = np.stack([np.asarray(c[0], np.float64) for c in cols], axis=1)
    shape = np.stack([np.asarray(c[1], np.float64) for c in cols], axis=1)
    return cos, out, shape


@dataclasses.dataclass
class Baked:
    """Everything the shaders read, as NumPy arrays (float32 on upload).

    - ``env`` ``(n_mu, rank, H, W, 3)``: P_{r,c}(ω; μ) (XYZ per basis function).
    - ``lut`` ``(2, n_mu, n_cos, rank)``: A_r for hiraji (0) and hamon (1).
    - ``spread`` ``(2, n_mu, n_cos, 3)``: lobe shape moments (see :func:`lobe_lut`).
    - ``mus``: the μ levels; ``b`` the spectral basis ``(rank, wl)``; ``fresnel_err``.
    - ``xyz_to_rgb`` 3×3; ``transfer`` 1-D table of encode(s²) for s uniform in [0, 1].
    """

    env: np.ndarray
    lut: np.ndarray
    spread: np.ndarray
    mus: np.ndarray
    b: np.ndarray
    fresnel_err: float
    xyz_to_rgb: np.ndarray
    transfer: np.ndarray
    colourspace: str

    @property
    def rank(self) -> int:
        return self.b.shape[0]


def transfer_table(transfer="sRGB", n: int = 2048) -> np.ndarray:
    """encode(s²) for s uniform on [0, 1] (eq. 8 as a table, dense near black)."""
    s = np.linspace(0.0, 1.0, n)
    return np.asarray(encode(s ** 2, transfer), np.float64)


def cached_bake(radiance: np.ndarray, grid: WavelengthGrid = DEFAULT_GRID, *, rank: int = 3, mus=MU_LEVELS,
                colourspace: str = "sRGB", transfer=None, source: str = "Fe-Johnson", cache_dir=None) -> Baked:
    """:func:`bake` with an on-disk cache (``$JKATANA_CACHE`` or ``~/.cache/jkatana``/interactive).

    The key hashes every input (radiance bytes, grid, rank, μ levels, display
    transform, optical-constant source) and this module's source, so a change
    to the baking code invalidates it.
    """
    import hashlib
    import os
    from pathlib import Path

    from jkatana.io.atomic import atomic_path

    h = hashlib.sha256()
    for part in (np.ascontiguousarray(radiance, np.float64).tobytes(), repr((grid.start, grid.stop, grid.step,
                 rank, list(np.round(mus, 12)), colourspace, transfer, source, radiance.shape)).encode(),
                 Path(__file__).read_bytes()):
        h.update(part)
    root = Path(cache_dir or os.environ.get("JKATANA_CACHE") or Path.home() / ".cache" / "jkatana") / "interactive"
    path = root / f"baked-{h.hexdigest()[:24]}.npz"
    if path.exists():
        with np.load(path) as z:
            return Baked(env=z["env"], lut=z["lut"], spread=z["spread"], mus=z["mus"], b=z["b"], fresnel_err=float(z["fresnel_err"]),
                         xyz_to_rgb=z["xyz_to_rgb"], transfer=z["transfer"], colourspace=str(z["colourspace"]))
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    baked = bake(radiance, grid, conductor=Conductor.from_table(source, grid, dtype=dt), rank=rank, mus=mus,
                 colourspace=colourspace, transfer=transfer)
    root.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **{k: np.asarray(v) for k, v in dataclasses.asdict(baked).items()})
    return baked


def bake(radiance: np.ndarray, grid: WavelengthGrid = DEFAULT_GRID, *, conductor: Conductor | None = None,
         rank: int = 3, mus=MU_LEVELS, colourspace: str = "sRGB", transfer=None) -> Baked:
    """Bake all shader tables for an environment ``radiance (H, W, wl)`` on ``grid``.

    **Arguments:**

    - `radiance`: equirectangular spectral radiance (Y up, see :func:`texel_directions`).
    - `conductor`: n, k (default iron, Johnson & Christy 1974).
    - `rank`: spectral basis rank (1–4); `mus`: prefilter levels.
    - `colourspace`, `transfer`: the display transform (as :func:`jkatana.spectral.to_display`).

    **Returns:** a :class:`Baked`.
    """
    radiance = np.asarray(radiance, np.float64)
    if radiance.ndim != 3 or radiance.shape[-1] != grid.size:
        raise ValueError(f"radiance must be (H, W, {grid.size}), got {radiance.shape}")
    if conductor is None:
        conductor = Conductor.from_table("Fe-Johnson", grid, dtype=jnp.float64 if jax.config.jax_enable_x64
                                         else jnp.float32)
    _, _, b, err = fresnel_basis(conductor, rank)
    W = film_weights(grid)            # (wl, 3); k = 1/∫ȳ dλ as jkatana.render: flat radiance 1 → Y = 1
    proj = np.einsum("hwl,rl,lc->hwrc", radiance, b, W).reshape(*radiance.shape[:2], rank * 3)
    env = np.stack([prefilter(proj, float(mu)) for mu in mus])                      # (n_mu, H, W, r*3)
    env = env.reshape(len(mus), *radiance.shape[:2], rank, 3).transpose(0, 3, 1, 2, 4)
    _, lut, spread = lobe_lut(conductor, b, mus)
    return Baked(env=env, lut=lut, spread=spread, mus=np.asarray(mus, np.float64), b=b, fresnel_err=err,
                 xyz_to_rgb=xyz_to_rgb_matrix(colourspace),
                 transfer=transfer_table(colourspace if transfer is None else transfer),
                 colourspace=colourspace)
