"""Piecewise tensor-product Bezier surfaces fitted to scan points by least squares (JAX).

The paper smooths its merged range scans with Bezier surfaces fitted to
corresponding points (Mochizuki et al., §4.1). Here a height field
``z = S(s, t)`` over a rectangular parameter domain is a grid of degree-``d``
tensor-product Bezier patches (Bernstein basis; Farin, *Curves and Surfaces
for CAGD*, 5th ed., 2002, ch. 16) that share their boundary control points,
so the surface is C0 across patch boundaries and may keep a crease there: put
a break (``breaks_s``/``breaks_t``) on a known sharp feature such as the
shinogi and the ridge is reproduced rather than rounded.

The fit minimises

    Σ_j (S(s_j, t_j) − z_j)²  +  λ · (N / M) · (‖Δ²_s C‖² + ‖Δ²_t C‖²)

over the control net C (M points), where Δ² are second differences of the
net (a discrete thin-plate energy; it also fills control points no data
touch). The normal equations are solved matrix-free by preconditioned
conjugate gradients in JAX (each product is a gather and a segment sum over
the N × (d+1)² basis values), so memory grows linearly with the point count.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import jax
import jax.numpy as jnp
import numpy as np

from jkatana.errors import InputError


@dataclass(frozen=True)
class BezierSurface:
    """A C0 grid of tensor-product Bezier patches ``z = S(s, t)``.

    **Fields:** `control` (Ms, Mt) with Ms = patches_s·d + 1; `breaks_s`,
    `breaks_t`: increasing patch boundaries (first and last span the domain);
    `degree`.
    """

    control: np.ndarray
    breaks_s: np.ndarray
    breaks_t: np.ndarray
    degree: int

    def __call__(self, s, t) -> np.ndarray:
        idx, w = _basis(np.asarray(s, float), np.asarray(t, float), self.breaks_s, self.breaks_t,
                        self.degree, self.control.shape[1])
        return np.sum(np.asarray(self.control).ravel()[idx] * w, axis=-1)


@dataclass(frozen=True)
class FitInfo:
    """Diagnostics: CG iterations, relative residual of the normal equations, data RMS."""

    iterations: int
    relative_residual: float
    converged: bool
    rms: float
    n_points: int
    n_control: int


def _bernstein(x: np.ndarray, d: int) -> np.ndarray:
    k = np.arange(d + 1)
    c = np.array([comb(d, int(i)) for i in k], float)
    return c * x[..., None] ** k * (1 - x[..., None]) ** (d - k)


def _locate(x: np.ndarray, breaks: np.ndarray):
    i = np.clip(np.searchsorted(breaks, x, side="right") - 1, 0, len(breaks) - 2)
    a = (x - breaks[i]) / (breaks[i + 1] - breaks[i])
    return i, np.clip(a, 0.0, 1.0)


def _basis(s, t, breaks_s, breaks_t, d, Mt):
    """Flat control indices and weights, both (N, (d+1)²)."""
    i, a = _locate(s, breaks_s)
    j, b = _locate(t, breaks_t)
    Bs, Bt = _bernstein(a, d), _bernstein(b, d)
    rows = i[:, None] * d + np.arange(d + 1)
    cols = j[:, None] * d + np.arange(d + 1)
    idx = (rows[:, :, None] * Mt + cols[:, None, :]).reshape(len(s), -1)
    w = (Bs[:, :, None] * Bt[:, None, :]).reshape(len(s), -1)
    return idx, w


def _breaks(breaks, patches, lo, hi, name):
    if breaks is None:
        return np.linspace(lo, hi, int(patches) + 1)
    b = np.asarray(breaks, float)
    if b.ndim != 1 or len(b) < 2 or np.any(np.diff(b) <= 0):
        raise InputError("breaks must be a strictly increasing list of at least 2 values", field=name)
    return b


def fit_bezier(s, t, z, *, degree: int = 3, patches: tuple[int, int] = (8, 4),
               breaks_s=None, breaks_t=None, smoothness: float = 1e-4, tol: float = 1e-8,
               max_iterations: int = 5000) -> tuple[BezierSurface, FitInfo]:
    """Least-squares fit of a Bezier patch grid to points ``(s_j, t_j) → z_j``.

    **Arguments:**

    - `s`, `t`, `z`: (N,) parameters and heights (finite; ``InputError`` otherwise).
    - `degree`: polynomial degree of every patch (1–7).
    - `patches`: number of patches along s and t (ignored where breaks are given).
    - `breaks_s`, `breaks_t`: explicit patch boundaries; put one on a crease.
    - `smoothness`: λ of the second-difference energy, per control point
      relative to the data term (0 = pure least squares).
    - `tol`, `max_iterations`: conjugate-gradient stopping rule on the
      relative residual of the normal equations.

    **Returns:** ``(surface, info)``; ``info.converged`` is False when CG
    stopped at ``max_iterations`` above ``tol``.
    """
    s, t, z = (np.asarray(x, float).ravel() for x in (s, t, z))
    if not (len(s) == len(t) == len(z)):
        raise InputError("s, t and z must have the same length", field="points")
    if len(z) == 0:
        raise InputError("no points to fit", field="points")
    bad = ~(np.isfinite(s) & np.isfinite(t) & np.isfinite(z))
    if bad.any():
        raise InputError(f"{int(bad.sum())} points are NaN or infinite", row=int(np.argmax(bad)),
                         field="points")
    if not 1 <= degree <= 7:
        raise InputError(f"degree must be 1..7, got {degree}", field="degree")
    bs = _breaks(breaks_s, patches[0], s.min(), s.max(), "breaks_s")
    bt = _breaks(breaks_t, patches[1], t.min(), t.max(), "breaks_t")
    d = degree
    Ms, Mt = (len(bs) - 1) * d + 1, (len(bt) - 1) * d + 1
    M = Ms * Mt
    if len(z) < 4:
        raise InputError(f"need at least 4 points, got {len(z)}", field="points")
    idx_np, w_np = _basis(s, t, bs, bt, d, Mt)
    dtype = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    idx = jnp.asarray(idx_np, jnp.int32)
    w = jnp.asarray(w_np, dtype)
    offset = float(np.mean(z))
    scale = float(np.std(z)) or 1.0
    zz = jnp.asarray((z - offset) / scale, dtype)
    lam = float(smoothness) * len(z) / M
    ctrl, info = _solve(idx, w, zz, jnp.asarray(lam, dtype), Ms, Mt, jnp.asarray(tol, dtype),
                        int(max_iterations))
    ctrl = np.asarray(ctrl).reshape(Ms, Mt) * scale + offset
    iters, rel = (int(info[0]), float(info[1]))
    surf = BezierSurface(ctrl, bs, bt, d)
    rms = float(np.sqrt(np.mean((np.sum(ctrl.ravel()[idx_np] * w_np, -1) - z) ** 2)))
    return surf, FitInfo(iters, rel, bool(rel <= tol), rms, len(z), M)


def _second_differences(c, Ms, Mt):
    C = c.reshape(Ms, Mt)
    parts = []
    if Ms >= 3:
        parts.append((C[2:] - 2 * C[1:-1] + C[:-2]).ravel())
    if Mt >= 3:
        parts.append((C[:, 2:] - 2 * C[:, 1:-1] + C[:, :-2]).ravel())
    return jnp.concatenate(parts) if parts else jnp.zeros((0,), c.dtype)


@jax.jit(static_argnums=(4, 5, 7))
def _solve(idx, w, z, lam, Ms, Mt, tol, max_iterations):
    M = Ms * Mt

    def A(c):
        return jnp.sum(c[idx] * w, axis=-1)

    def At(r):
        return jax.ops.segment_sum((w * r[:, None]).ravel(), idx.ravel(), num_segments=M)

    def reg(c):
        d2 = _second_differences(c, Ms, Mt)
        return jax.vjp(lambda x: _second_differences(x, Ms, Mt), c)[1](d2)[0]

    eps = 1e-10 * jnp.maximum(1.0, lam)

    def normal(c):
        return At(A(c)) + lam * reg(c) + eps * c

    diag = jax.ops.segment_sum((w * w).ravel(), idx.ravel(), num_segments=M) + 12 * lam + eps
    b = At(z)
    x = jnp.zeros(M, z.dtype)
    r = b - normal(x)
    y = r / diag
    p = y
    bnorm = jnp.linalg.norm(b) + 1e-30

    def cond(state):
        _, r, _, _, k = state
        return (jnp.linalg.norm(r) / bnorm > tol) & (k < max_iterations)

    def body(state):
        x, r, y, p, k = state
        Ap = normal(p)
        ry = r @ y
        alpha = ry / (p @ Ap)
        x = x + alpha * p
        r_new = r - alpha * Ap
        y_new = r_new / diag
        beta = (r_new @ y_new) / ry
        return x, r_new, y_new, y_new + beta * p, k + 1

    x, r, _, _, k = jax.lax.while_loop(cond, body, (x, r, y, p, 0))
    return x, (k, jnp.linalg.norm(b - normal(x)) / bnorm)


def tessellate(surface: BezierSurface, n_s: int = 200, n_t: int = 50):
    """Evaluate on a regular (n_s, n_t) grid over the domain: returns (S, T, Z), each (n_s, n_t)."""
    S, T = np.meshgrid(np.linspace(surface.breaks_s[0], surface.breaks_s[-1], n_s),
                       np.linspace(surface.breaks_t[0], surface.breaks_t[-1], n_t), indexing="ij")
    return S, T, surface(S.ravel(), T.ravel()).reshape(S.shape)


def grid_mesh(xyz: np.ndarray, uv: np.ndarray, flip: bool = False):
    """Triangles of a (R, C) grid of points: returns (vertices (R·C, 3), faces, uv (R·C, 2))."""
    R, C = xyz.shape[:2]
    ids = np.arange(R * C).reshape(R, C)
    a, b, c, d = ids[:-1, :-1], ids[1:, :-1], ids[1:, 1:], ids[:-1, 1:]
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return xyz.reshape(-1, 3), (f[:, ::-1] if flip else f), uv.reshape(-1, 2)
