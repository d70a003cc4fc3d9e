"""The material's Fresnel table and its fold into the environment.

F(cos θ, λ) of the conductor is tabulated on cosines (exact conductor Fresnel,
:func:`jkatana.models.fresnel_conductor`) and looked up linearly. Because F is
of low rank in (cos θ, λ), the renderer folds its leading spectra
(:func:`jkatana.light.fresnel_basis.svd_of_table`) and the colour-matching
functions into the environment: per sample a ``3R``-channel lookup and ``R``
coefficients instead of one lookup per wavelength, exact up to the rank.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.light.fresnel_basis import basis_signs, project_on_basis, svd_of_table
from jkatana.models.fresnel import fresnel_conductor
from jkatana.render.plan import Plan

if TYPE_CHECKING:
    from jkatana.render.environment import Environment

#: Cosine samples of the Fresnel table (linear interpolation error < 1e-6 for iron).
FRESNEL_TABLE = 1024
#: Largest |F − F_R| (absolute reflectance) accepted for a rank-R Fresnel table (:func:`fresnel_rank_for`).
FRESNEL_RANK_TOL = 1e-5
#: The same bound for the sampled modes (:data:`~jkatana.render.plan.SAMPLED_MODES`). Their frames carry
#: Monte Carlo noise, so the table need not be exact to 1e-5: 5e-3 in reflectance (under 1 % of a
#: metal's F ≥ 0.5) is a colour bias well below the noise of a sampled frame, and each rank fewer removes
#: three channels from every sample's lookup and one coefficient from its Fresnel row (iron: rank 3,
#: not 5). The bias is bounded per pixel by max |F − F_R| / min F of the frame itself, since every
#: sample's weight and radiance are non-negative. ``Plan(fresnel_rank=0)`` keeps full spectra, an
#: explicit rank that rank.
FRESNEL_RANK_TOL_SAMPLED = 5e-3


class Material(eqx.Module):
    """Differentiable material inputs: Fresnel table and the fitted scales (calibrated convention)."""

    ftable: Float[Array, "T wl"]
    chi: Float[Array, ""]
    beta: Float[Array, ""]


def fresnel_table(n, k, size: int = FRESNEL_TABLE):
    """F(cos θ, λ) on ``size`` cosines uniformly in [0, 1] (exact conductor Fresnel, differentiable in n, k)."""
    c = jnp.linspace(0.0, 1.0, size, dtype=n.dtype)
    return fresnel_conductor(c[:, None], n, k)


def table_lookup(table, cos):
    """Linear interpolation of a ``(T, ...)`` table at cosines in [0, 1]."""
    T = table.shape[0]
    x = jnp.clip(cos, 0.0, 1.0) * (T - 1)
    i0 = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, T - 2)
    f = (x - i0.astype(x.dtype)).astype(table.dtype)
    f = f.reshape(f.shape + (1,) * (table.ndim - 1))
    return table[i0] * (1 - f) + table[i0 + 1] * f


def fresnel_rank_for(ftable, tol: float = FRESNEL_RANK_TOL, max_rank: int = 8, *, _basis_too: bool = False
                     ) -> int | tuple[int, np.ndarray]:
    """Smallest R with max |F − F_R| ≤ ``tol`` over the table (truncated SVD in λ), 0 if none ≤ ``max_rank``.

    F(cos θ, λ) of a conductor is smooth in both arguments (see DESIGN.md); the
    SVD is :func:`jkatana.light.fresnel_basis.svd_of_table`'s. Host-side
    (NumPy float64) on a concrete table.
    """
    import hashlib

    F = np.ascontiguousarray(np.asarray(ftable))
    key = (hashlib.blake2b(F.tobytes(), digest_size=16).hexdigest(), F.shape, str(F.dtype), tol, max_rank)
    if key not in _RANK_CACHE:  # the host SVD runs once per table, not once per frame
        F = F.astype(np.float64)
        u, s, vt = svd_of_table(F)
        _RANK_CACHE[key] = (0, vt)
        for r in range(1, min(max_rank, len(s)) + 1):
            if np.max(np.abs(F - (u[:, :r] * s[:r]) @ vt[:r])) <= tol:
                _RANK_CACHE[key] = (r, vt)
                break
    return _RANK_CACHE[key][0] if not _basis_too else _RANK_CACHE[key]


_RANK_CACHE: dict = {}


def fold_fresnel(rank: int, mat: Material, env: Environment, cmf, basis=None) -> tuple[Material, Environment]:
    """Fold a rank-``R`` Fresnel factorisation and the CMFs into the environment (exact up to that rank).

    With ``F(c, λ) ≈ Σ_r a_r(c) b_r(λ)`` (``b`` the leading right singular
    vectors of the table with :func:`jkatana.light.fresnel_basis.basis_signs`' sign convention, held fixed —
    no gradient through the SVD; ``a = F bᵀ``
    is differentiable in the table) the XYZ radiance of one sample is
    ``Σ_r a_r(cos θ) G_r(L)`` with ``G_r = Σ_λ b_r(λ) E(L, λ) x̄ȳz̄(λ)``: a
    ``3R``-channel map. Bilinear lookups commute with this per-texel linear map,
    so the only approximation is the Fresnel rank. Per sample a ``3R``-channel
    lookup (9 channels for R = 3) replaces a ``wl``-band one. **Returns:** ``(material with ftable (T, R), environment with
    channels (H, W, 3R) and folded prefiltered levels, the regions' own included)``; pass both to
    :func:`shade` with ``Plan(fresnel_rank=R)``. ``basis``: the ``(R, wl)`` spectra
    if already known (the frame passes the host SVD of :func:`fresnel_rank_for`),
    else the SVD runs here.
    """
    F = mat.ftable
    if basis is None:
        _, _, vt = jnp.linalg.svd(jax.lax.stop_gradient(F), full_matrices=False)
        basis = vt[:rank] * basis_signs(vt[:rank], jnp)[:, None]
    b = jnp.asarray(basis, F.dtype)  # (R, wl)
    a = F @ b.T  # (T, R)

    def fold(img):
        return project_on_basis(img, b, cmf.astype(F.dtype), env.basis).reshape(img.shape[:2] + (3 * rank,))

    env2 = eqx.tree_at(lambda e: (e.channels, e.prefiltered), env,
                       (fold(env.channels), tuple(fold(lvl) for lvl in env.prefiltered)))
    if env.lobe_prefiltered:  # (tree_at: the folded channels no longer match the spectral basis' size)
        env2 = eqx.tree_at(lambda e: e.lobe_prefiltered, env2,
                           tuple(tuple(fold(lvl) for lvl in lv) for lv in env.lobe_prefiltered))
    return Material(a, mat.chi, mat.beta), env2


def is_folded(plan: Plan) -> bool:
    return bool(plan.fresnel_rank) and not plan.factored
