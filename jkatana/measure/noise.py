"""The noise of a measured value, one model for simulating measurements (:mod:`jkatana.measure.synthetic`)
and for weighting them in a fit (:mod:`jkatana.fit`), and its estimate from a table (:func:`estimate_noise`).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.errors import InputError


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """σ(ρ)² = (relative·ρ)² + shot·|ρ| + absolute² (camera units).

    One noise model for simulation and fitting: a multiplicative term (source
    flicker), a Poisson-like term (variance ∝ signal) and an absolute floor
    (read noise, quantisation, stray light). Without the floor the far tail of
    a mirror lobe (values at 1e-55 of the peak) would count as exact
    information. All terms default to 0 (no noise); every term must be finite
    and ≥ 0.

    **Arguments:**

    - `relative`: multiplicative standard deviation (e.g. 0.02 = 2 %).
    - `absolute`: absolute standard deviation (camera units).
    - `shot`: variance per unit signal (camera units).
    """

    relative: float = 0.0
    absolute: float = 0.0
    shot: float = 0.0

    def __post_init__(self):
        for name in ("relative", "absolute", "shot"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise InputError(f"noise parameter must be finite and >= 0, got {v!r}", field=name)

    def sigma(self, rho):
        """σ at ``rho``: a jax array for a jax input, numpy float64 otherwise."""
        xp = jnp if isinstance(rho, jax.Array) else np
        return _sigma(xp, rho if xp is jnp else np.asarray(rho, np.float64), self.relative, self.shot,
                      self.absolute)

    def weights(self, rho, use, dtype):
        """1/σ(ρ) at the points ``use`` marks, 0 elsewhere: one compiled program per shape and dtype (the noise
        terms are its arguments, so a fit of another table with another noise model compiles nothing)."""
        return _inverse_sigma(jnp.asarray(rho, dtype), use, *(np.asarray(v, dtype) for v in
                                                             (self.relative, self.shot, self.absolute)))

    @property
    def is_zero(self) -> bool:
        return self.relative == 0 and self.shot == 0 and self.absolute == 0

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def _sigma(xp, rho, relative, shot, absolute):
    rho = xp.abs(rho)
    return xp.sqrt((relative * rho) ** 2 + shot * rho + absolute**2)


@jax.jit
def _inverse_sigma(rho, use, relative, shot, absolute):
    return jnp.where(use, 1.0 / _sigma(jnp, rho, relative, shot, absolute), 0.0).astype(rho.dtype)


def estimate_noise(value, sigma=None, *, floor_fraction: float = 1e-4) -> NoiseModel:
    """Estimate a :class:`NoiseModel` from a table.

    With the table's per-point ``sigma`` (e.g. pixel scatter over the region),
    σ² = r² ρ² + s|ρ| + a² is fitted by non-negative least squares (weights 1/σ⁴, so
    every point counts relatively). Without it, the relative part defaults to
    2 % and the floor to the robust scatter (MAD) of the lowest tenth of the
    values. In both cases the floor is at least ``floor_fraction`` × peak
    (1e-4: roughly the quantisation step of a 14-bit RAW at the peak's
    exposure), so no point is ever believed beyond what a camera can deliver.
    """
    y = np.asarray(value, np.float64)
    finite = np.isfinite(y)
    peak = float(np.max(np.abs(y[finite]))) if finite.any() else 1.0
    peak = peak if peak > 0 else 1.0
    floor = floor_fraction * peak
    if sigma is not None:
        s = np.asarray(sigma, np.float64)
        ok = finite & np.isfinite(s) & (s > 0)
        if ok.sum() >= 3:
            A = np.stack([y[ok] ** 2, np.abs(y[ok]), np.ones(ok.sum())], axis=1) / s[ok, None] ** 2
            b = np.ones(ok.sum())
            from scipy.optimize import nnls

            (r2, shot, a2), _ = nnls(A, b)
            return NoiseModel(relative=float(math.sqrt(r2)), shot=float(shot),
                              absolute=float(max(math.sqrt(a2), floor)))
    low = np.sort(y[finite])[: max(3, finite.sum() // 10)]
    mad = float(1.4826 * np.median(np.abs(low - np.median(low)))) if low.size else 0.0
    return NoiseModel(relative=0.02, absolute=max(mad, floor))


__all__ = ["NoiseModel", "estimate_noise"]
