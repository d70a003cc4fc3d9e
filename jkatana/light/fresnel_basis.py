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


def svd_of_table(F) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(U, S, Vt)`` of a ``(m, wl)`` Fresnel table (NumPy, float64), signs fixed so each row of ``Vt`` has a
    positive sum (and ``U`` flipped with it, so ``U S Vt`` is unchanged)."""
    U, S, Vt = np.linalg.svd(np.asarray(F, np.float64), full_matrices=False)
    sgn = np.sign(Vt.sum(axis=1))
    sgn[sgn == 0] = 1.0
    return U * sgn, S, Vt * sgn[:, None]


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


__all__ = ["FresnelBasis", "basis_of_table", "fresnel_basis", "svd_of_table", "theta_uniform_cosines"]
