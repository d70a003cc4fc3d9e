"""The low-rank spectral basis of a conductor's Fresnel reflectance, F(cos θ, λ) ≈ Σ_r c_r(cos θ) b_r(λ).

F of a metal is smooth in both angle and wavelength, so a truncated SVD of
its table over (cos θ, λ) (Eckart & Young 1936: optimal in the Frobenius norm
over the table) needs only a few spectra b_r. Every user of such a basis —
the split-sum prefilter (:mod:`jkatana.light.prefilter`), the renderer's
Fresnel folding (:func:`jkatana.render.fresnel_fold.fold_fresnel`) and the
interactive bake (:mod:`jkatana.interactive.bake`) — takes it from
:func:`basis_of_table`, so the factorisation and its sign convention live
in one place.

Conventions: the rows of ``basis`` are orthonormal spectra, the first one
with a positive sum (the SVD's sign is otherwise arbitrary; products
c_r b_r do not depend on it). The default cos θ table of
:func:`fresnel_basis` is uniform in θ (dense at grazing incidence, where F
varies fastest); a caller that tabulates F elsewhere (the renderer's
:func:`~jkatana.render.fresnel_fold.fresnel_table`, uniform in cos θ) passes its
own table to :func:`basis_of_table`.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jkatana.errors import InputError


class FresnelBasis(eqx.Module):
    """F(cos θ, λ) ≈ Σ_r c_r(cos θ) b_r(λ).

    **Fields:** `basis` ``(rank, wl)``, `cos_table` ``(m,)`` increasing cos θ,
    `coefficients` ``(m, rank)``, `singular_values` ``(min(m, wl),)`` (all of them,
    to judge the truncation).
    """

    basis: Float[Array, "rank wl"]
    cos_table: Float[Array, "m"]
    coefficients: Float[Array, "m rank"]
    singular_values: Float[Array, "s"]

    @property
    def rank(self) -> int:
        return self.basis.shape[0]

    def coeffs(self, cos_theta) -> Float[Array, "*b rank"]:
        """Coefficients at ``cos_theta`` (linear interpolation in the table)."""
        c = jnp.clip(jnp.asarray(cos_theta), 0.0, 1.0)
        return jnp.stack([jnp.interp(c, self.cos_table, self.coefficients[:, r]) for r in range(self.rank)], axis=-1)

    def reconstruct(self, cos_theta) -> Float[Array, "*b wl"]:
        """Rank-r F at ``cos_theta``."""
        return self.coeffs(cos_theta) @ self.basis


def basis_signs(Vt, xp=np):
    """The sign convention of every Fresnel basis: ``±1`` per row of ``Vt (k, wl)`` making its sum
    positive (+1 where the sum is 0). ``xp``: ``numpy`` or ``jax.numpy``, the array namespace of ``Vt``."""
    sgn = xp.sign(Vt.sum(axis=1))
    return xp.where(sgn == 0, 1.0, sgn)


def svd_of_table(F) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(U, S, Vt)`` of a ``(m, wl)`` Fresnel table (NumPy, float64), signs fixed so each row of ``Vt`` has a
    positive sum (:func:`basis_signs`; ``U`` flipped with it, so ``U S Vt`` is unchanged)."""
    U, S, Vt = np.linalg.svd(np.asarray(F, np.float64), full_matrices=False)
    sgn = basis_signs(Vt)
    return U * sgn, S, Vt * sgn[:, None]


def projection_matrix(basis, weights, channels=None, xp=jnp):
    """``M[j, r, c] = Σ_λ s_j(λ) b_r(λ) w_c(λ)``: the linear map from a texel's channels to its projection on
    the Fresnel basis ``b (rank, wl)``, XYZ per basis function (``weights (wl, 3)``: colour-matching
    functions × Δλ). ``channels (J, wl)``: the spectra ``s_j`` the channels stand for; ``None``: the
    channels are the spectrum itself (``M[λ, r, c] = b_r(λ) w_c(λ)``). ``xp``: ``numpy`` or ``jax.numpy``."""
    if channels is None:
        return xp.einsum("rl,lc->lrc", basis, weights)
    return xp.einsum("jl,rl,lc->jrc", channels, basis, weights)


def project_on_basis(values, basis, weights, channels=None, xp=jnp):
    """``P[..., r, c] = Σ_λ L(λ) b_r(λ) w_c(λ)``: radiance ``values (..., J)`` (spectra, or channels of
    ``channels``, :func:`projection_matrix`) projected on the Fresnel basis, XYZ per basis function. Shading
    then needs ``XYZ = Σ_r c_r(cos θ) P_r`` (a bilinear lookup or a lobe's integral commutes with this
    per-texel linear map). The renderer's fold (:func:`jkatana.render.fresnel_fold.fold_fresnel`), the
    interactive bake and its caps (:mod:`jkatana.interactive.bake`) and the prefilter
    (:func:`jkatana.light.prefilter.project_on_basis`) all project with this function."""
    M = projection_matrix(basis, weights, channels, xp)
    return xp.einsum("...j,jrc->...rc", values, M, optimize=True)


def basis_of_table(cos, F, rank: int) -> FresnelBasis:
    """The rank-``rank`` :class:`FresnelBasis` of F tabulated at cosines ``cos (m,)``: ``F (m, wl)``."""
    U, S, Vt = svd_of_table(F)
    if not (1 <= rank <= S.size):
        raise InputError(f"rank must be within 1..{S.size}, got {rank}", field="rank")
    return FresnelBasis(jnp.asarray(Vt[:rank]), jnp.asarray(np.asarray(cos, np.float64)),
                        jnp.asarray(U[:, :rank] * S[:rank]), jnp.asarray(S))


def theta_uniform_cosines(n_cos: int) -> np.ndarray:
    """``n_cos`` increasing cosines of angles uniform in θ ∈ [0, π/2] (exactly 0 and 1 at the ends)."""
    cos = np.cos(np.linspace(0.0, math.pi / 2, n_cos))[::-1].copy()
    cos[0] = 0.0
    return cos


def fresnel_basis(conductor, rank: int = 3, n_cos: int = 2049, cos=None) -> FresnelBasis:
    """Truncated SVD of a conductor's F(cos θ, λ) (:func:`basis_of_table`).

    **Arguments:**

    - `conductor`: a :class:`jkatana.models.Conductor` (its grid defines λ).
    - `rank`: number of spectral basis functions kept.
    - `n_cos`: table size, uniform in θ (:func:`theta_uniform_cosines`), unless
    - `cos`: the increasing cosines to tabulate F at.

    **Returns:** :class:`FresnelBasis` in float64.
    """
    cos = theta_uniform_cosines(n_cos) if cos is None else np.asarray(cos, np.float64)
    F = np.asarray(conductor.fresnel(jnp.asarray(cos, jnp.float64)), np.float64)  # (m, wl)
    return basis_of_table(cos, F, rank)


__all__ = ["FresnelBasis", "basis_of_table", "basis_signs", "fresnel_basis", "project_on_basis", "projection_matrix",
           "svd_of_table", "theta_uniform_cosines"]
