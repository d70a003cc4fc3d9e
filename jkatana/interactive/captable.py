"""The cap kernel table: a compact source (a sun cap) integrated against each region's lobe, for lobes that
are not the paper's.

The shader's closed-form cap rule (:mod:`validation.shader_cap_rule`, its NumPy transcription for tests) is one Gaussian with the lobe's first
and second moments. That holds for the paper's Gaussian lobes and for Beckmann; a lobe with algebraic tails
(GGX / Trowbridge–Reitz, GTR, a two-lobe sum with haze) has a second moment set by its tails, so the Gaussian
is several times too low at the lobe's peak and far too high a few widths away. For such lobes the bake
tabulates the normalised kernel itself:

    K̄(cos θv, u, v; μ) = ∫_cap f_r(L, V) cos θL dω / (Ω_cap ∫_H² f_r(L, V) cos θL dω)

the cap's reflected radiance per unit cap radiance, per unit solid angle and per unit lobe energy (the lobe
table A carries the energy and the Fresnel factor), computed by the library's cap quadrature
(:func:`jkatana.light.capquad.cap_integral`) of the lobe's own
:meth:`~jkatana.models.lobes.Lobe.brdf_cos` and normalised by the lobe table's own quadrature
(:func:`jkatana.interactive.lobe_tables.lobe_integral`), with the conductor's Fresnel factor at one wavelength (the
normalisation cancels it but for its variation over the lobe, a few per cent of a per-cent-level
correction). The cap centre C is placed at the angles
``u = atan2(C·t, C·R)`` along the plane of incidence (t ⟂ R, towards N) and ``v = atan2(|C·y|, C·R)`` across
it (y = R × t) — the angles :func:`~jkatana.interactive.lobe_tables.lobe_integral` takes its moments in —
scaled by the level's width μ, on a grid dense near R: ``û = u/μ = ±E s²`` for s uniform on [−1, 1] (and
``v̂ = E s²``, s on [0, 1]), E = :data:`EXTENT`. Each entry holds ``ln(μ² K̄)`` (μ² K̄ is of order one at
every level; the logarithm, floored at :data:`LOG_FLOOR`, is what is interpolated, so that a Gaussian-like tail
between coarse nodes stays a fast decay instead of a chord far above it). Between two μ levels the shader
blends kernels of the same shape in units of their width: it reads both levels at the offsets in units of the
pixel's own μ and divides the blend of their μ² K̄ by μ². Beyond E widths the kernel is 0 (the shader skips the cap).

The cap's radius is folded in at bake time (the environment's largest cap; a sun is 0.25–0.3°).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.interactive.lobe_tables import PAPER_LOBES, lobe_integral
from jkatana.interactive.taps import view_frame
from jkatana.light.capquad import cap_integral
from jkatana.models import Conductor

#: The table's reach from the mirror direction, in units of the level's width μ (GGX at 12 α is ~1e-4 of
#: its peak).
EXTENT = 12.0
#: ln of the smallest tabulated μ² K̄ (0 beyond the horizon and the lobe's reach).
LOG_FLOOR = -69.0
#: Grid sizes: cos θv rows (uniform on [0, 1]), in-plane and across-plane offsets.
N_COS, N_U, N_V = 24, 33, 17


def needs_table(lobes: tuple) -> bool:
    """Whether any region's lobe family is not the paper's (the paper's lobes keep the closed-form rule)."""
    return any(f not in PAPER_LOBES for f in lobes)


def offset_grid() -> tuple[np.ndarray, np.ndarray]:
    """``(û (N_U,), v̂ (N_V,))``: the tabulated offsets in units of μ."""
    su = np.linspace(-1.0, 1.0, N_U)
    sv = np.linspace(0.0, 1.0, N_V)
    return np.sign(su) * EXTENT * su ** 2, EXTENT * sv ** 2


def table_frame(cos_v: np.ndarray):
    """:func:`~jkatana.interactive.taps.view_frame` (NumPy) at the table's view cosines, held at cos θv ≥ 1e-3 so
    that the grazing row has a plane of incidence."""
    return view_frame(np.maximum(cos_v, 1e-3), np)


def cap_directions(R, t, y, u, v) -> np.ndarray:
    """Unit C at in-plane angle ``u`` and across-plane angle ``v`` (rad, |u|, |v| < π/2) from R:
    ``C ∝ R + tan u t + tan v y`` (the inverse of u = atan2(C·t, C·R), v = atan2(C·y, C·R))."""
    d = R + np.tan(u)[..., None] * t + np.tan(v)[..., None] * y
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@functools.partial(jax.jit, static_argnames=("family",))
def _level(family, mu, conductor, V, C, radius):
    """μ² K̄ at one μ level: ``V (n_cos, 3)``, ``C (n_cos, n_v, n_u, 3)``."""
    lobe = family(mu)
    energy = jnp.sum(lobe_integral(lobe, conductor, V, width=mu, tails=family not in PAPER_LOBES), -1)
    sigma = lobe.reflected_width()
    Vb = jnp.broadcast_to(V[:, None, None, :], C.shape)
    got = jnp.sum(cap_integral(functools.partial(lobe.brdf_cos, conductor=conductor), Vb, C, radius, sigma,
                               n_radial=6, n_azimuth=16), -1)
    omega = 4.0 * jnp.pi * jnp.sin(0.5 * radius) ** 2
    return mu * mu * got / (omega * jnp.maximum(energy, 1e-30)[:, None, None])


def cap_kernel_table(lobes: tuple, mus, radius: float, conductor: Conductor) -> np.ndarray:
    """``(2, n_mu, N_COS, N_V, N_U)``: ln(μ² K̄) (floored at :data:`LOG_FLOOR`) for the hiraji and hamon
    families ``lobes`` at each μ of ``mus``, for a cap of angular ``radius`` (module docstring), with ``conductor``'s Fresnel factor at its middle
    wavelength."""
    mid = conductor.n.shape[-1] // 2
    conductor = Conductor(n=conductor.n[..., mid:mid + 1], k=conductor.k[..., mid:mid + 1])
    dt = conductor.n.dtype
    cos = np.linspace(0.0, 1.0, N_COS)
    V, R, t, y = table_frame(cos)
    uh, vh = offset_grid()
    out = np.zeros((2, len(mus), N_COS, N_V, N_U))
    for i, family in enumerate(lobes):
        for k, mu in enumerate(np.asarray(mus, np.float64)):
            u = np.broadcast_to(uh * mu, (N_V, N_U))
            v = np.broadcast_to((vh * mu)[:, None], (N_V, N_U))
            inside = (np.abs(u) < 1.45) & (v < 1.45)
            C = cap_directions(R[:, None, None], t[:, None, None], y[:, None, None],
                               np.where(inside, u, 0.0), np.where(inside, v, 0.0))
            got = np.asarray(_level(family, jnp.asarray(mu, dt), conductor, jnp.asarray(V, dt),
                                    jnp.asarray(C, dt), jnp.asarray(radius, dt)), np.float64)
            out[i, k] = np.where(inside & np.isfinite(got), np.maximum(got, 0.0), 0.0)
    return np.maximum(np.log(np.maximum(out, 1e-300)), LOG_FLOOR)


def table_kernel(table: np.ndarray, mus, region: int, level: float, cos_v: float, u, v) -> np.ndarray:
    """K̄ (1/sr) read from ``table`` as the shader reads it: the lobe of ``region`` (0 hiraji, 1 hamon) at the
    fractional μ ``level`` (index into ``mus``), view cosine ``cos_v``, cap at angles ``u``, ``v`` (rad) from
    R — in units of the pixel's width μ (that of ``level``), ln(μ² K̄) linear in the offsets' grid coordinates
    and in cos θv, then exponentiated, and linear between the two μ levels' μ² K̄ (exact for a family whose
    kernel scales with μ), divided by μ²;
    0 beyond :data:`EXTENT` widths."""
    from scipy.interpolate import RegularGridInterpolator

    mus = np.asarray(mus, np.float64)
    k0 = int(np.clip(np.floor(level), 0, len(mus) - 2))
    f = float(np.clip(level - k0, 0.0, 1.0))
    mu = float(mus[0] * (mus[1] / mus[0]) ** level)
    cos = np.linspace(0.0, 1.0, N_COS)
    su, sv = np.linspace(-1.0, 1.0, N_U), np.linspace(0.0, 1.0, N_V)
    uh, vh = np.asarray(u, np.float64) / mu, np.abs(np.asarray(v, np.float64)) / mu
    ok = (np.abs(uh) <= EXTENT) & (vh <= EXTENT)
    pts = np.stack(np.broadcast_arrays(np.full(np.shape(uh), cos_v), np.sqrt(np.minimum(vh, EXTENT) / EXTENT),
                                       np.sign(uh) * np.sqrt(np.minimum(np.abs(uh), EXTENT) / EXTENT)), -1)
    val = sum(wk * np.exp(RegularGridInterpolator((cos, sv, su), table[region, k])(pts))
              for k, wk in ((k0, 1.0 - f), (k0 + 1, f)))
    return np.where(ok, val, 0.0) / (mu * mu)
