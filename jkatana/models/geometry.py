"""Directions and angles of the reflection geometry (SPEC §2).

Directions are unit 3-vectors in the *local shading frame*, normal N = +z,
last axis of length 3: L towards the light, V towards the viewer. From them:

- θi = ∠(N, L), θr = ∠(N, V);
- H = (L + V)/|L + V|, φ = ∠(N, H) the facet angle, θH = ∠(L, H) = ∠(V, H).

Numerics: in float32, ``acos(N·H)`` returns exactly 0 for
φ = 1e-4 and is 2× off at 1e-3 — the heart of a μ = 0.05 lobe — and its
derivative at N·H = 1 is infinite. The facet angle is therefore computed as
``atan2(|N × (L+V)|, N · (L+V))``: exact for small angles, scale-invariant
(so H needs no normalisation) and differentiable. L = −V makes H = 0/0,
which an ε in the norm does not cure; it is detected explicitly and reported
through ``valid`` so that models return 0 there with finite gradients.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jkatana.models._safe import norm, safe_atan2


def _cut(dtype) -> float:
    """|L + V| below which the half-vector is treated as undefined: the dtype's eps.

    In float32 that is 1.2e-7 (θH within 0.007° of 90°, the double-grazing
    back-to-back configuration, where every term is 0/0 or 1/0). Below it the
    derivatives of φ and of 1/(V·H) would overflow; the models return 0 there.
    """
    return float(jnp.finfo(dtype).eps)


def _half_vector_sum(L, V):
    """``(s, |s|, valid)`` of s = L + V, with s = N and |s| = 1 substituted where |s| ≤ :func:`_cut` ("double
    where": the half-vector functions below stay finite, values and gradients, at L = −V)."""
    s = L + V
    dtype = jnp.result_type(s)
    length = norm(s)
    valid = length > _cut(dtype)
    s_safe = jnp.where(valid[..., None], s, jnp.asarray([0.0, 0.0, 1.0], dtype))
    return s_safe, jnp.where(valid, length, 1.0), valid


def half_vector_terms(L: Float[ArrayLike, "*#b 3"], V: Float[ArrayLike, "*#b 3"]):
    """``(φ, cos φ, cos θH, valid)`` in one pass, guarded for the models.

    φ = atan2(|N × (L+V)|, N·(L+V)) (exact for small angles), cos φ = N·H,
    cos θH = |L+V|/2 (exact for unit L, V). ``valid`` is False where
    |L + V| ≤ eps of the dtype (L = −V and its rounding neighbourhood); there
    every output is computed on a substituted H = N ("double where"), so values
    *and* gradients are finite, and φ = 0, cos φ = cos θH = 0 are returned.
    """
    s_safe, length_safe, valid = _half_vector_sum(L, V)
    phi = jnp.where(valid, safe_atan2(norm(s_safe[..., :2]), s_safe[..., 2]), 0.0)
    cos_phi = jnp.where(valid, s_safe[..., 2] / length_safe, 0.0)
    cos_theta_h = jnp.where(valid, jnp.clip(0.5 * length_safe, 0.0, 1.0), 0.0)
    return phi, cos_phi, cos_theta_h, valid


def half_vector_tan_terms(L: Float[ArrayLike, "*#b 3"], V: Float[ArrayLike, "*#b 3"]):
    """``(tan φ, cos φ, cos θH, valid)``: :func:`half_vector_terms` with tan φ in place of φ.

    tan φ = |N × (L+V)| / N·(L+V): as exact for small angles as the ``atan2`` form
    (both read the same components of L + V) and free of transcendental calls, for
    the distributions of normals that depend on φ through tan φ and cos φ only
    (Beckmann, GGX, GTR). Where N·(L+V) ≤ 0 (φ ≥ π/2) tan φ is returned as 0 and
    cos φ ≤ 0, which those distributions read as D = 0; where |L + V| is below
    the dtype's eps every output is 0 with ``valid`` False, as in
    :func:`half_vector_terms` ("double where": finite values and gradients).
    """
    s_safe, length_safe, valid = _half_vector_sum(L, V)
    up = valid & (s_safe[..., 2] > 0)
    tan_phi = jnp.where(up, norm(s_safe[..., :2]) / jnp.where(up, s_safe[..., 2], 1.0), 0.0)
    cos_phi = jnp.where(valid, s_safe[..., 2] / length_safe, 0.0)
    cos_theta_h = jnp.where(valid, jnp.clip(0.5 * length_safe, 0.0, 1.0), 0.0)
    return tan_phi, cos_phi, cos_theta_h, valid


def facet_angle(L: Float[ArrayLike, "*#b 3"], V: Float[ArrayLike, "*#b 3"]) -> Float[Array, "*#b"]:
    """φ = ∠(N, H) via atan2(|N × (L+V)|, N·(L+V)), N = +z. 0 where L = −V.

    Never ``acos(N·H)``: in float32 that is exactly 0 at φ = 1e-4 and has an
    infinite derivative at N·H = 1. See :func:`half_vector_terms`.
    """
    return half_vector_terms(L, V)[0]


def half_vector_cos(L: Float[ArrayLike, "*#b 3"], V: Float[ArrayLike, "*#b 3"]):
    """``(cos φ, cos θH, valid)`` with cos φ = N·H, cos θH = L·H = V·H.

    ``valid`` is False where |L + V| ≤ eps of the dtype (L = −V): the
    half-vector is undefined there and the cosines are returned as 0. Uses
    ``cos θH = |L+V| / 2`` (exact for unit L, V), so no second normalisation.
    """
    _, cos_phi, cos_theta_h, valid = half_vector_terms(L, V)
    return cos_phi, cos_theta_h, valid


def in_plane(theta_i, theta_r):
    """Unit L and V for the goniometer's in-plane geometry (SPEC §4).

    The light is at incidence ``theta_i`` (radians) on the −x side, the
    receiver at ``theta_r`` on the +x side; ``theta_r = theta_i`` is the
    specular direction. Negative ``theta_r`` puts the receiver on the light's
    side (back-scatter). Returns ``(L, V)`` with shape ``(*b, 3)``.
    """
    theta_i = jnp.asarray(theta_i)
    theta_r = jnp.asarray(theta_r)
    zero = jnp.zeros(jnp.broadcast_shapes(theta_i.shape, theta_r.shape), theta_i.dtype)
    L = jnp.stack([-jnp.sin(theta_i) + zero, zero, jnp.cos(theta_i) + zero], axis=-1)
    V = jnp.stack([jnp.sin(theta_r) + zero, zero, jnp.cos(theta_r) + zero], axis=-1)
    return L, V


def in_plane_angles(theta_i, theta_r):
    """In-plane facet angle φ = (θr − θi)/2 and θH = (θi + θr)/2 (radians, signed φ)."""
    return 0.5 * (theta_r - theta_i), 0.5 * (theta_i + theta_r)


def tangent_frame(n: Float[Array, "*b 3"]) -> tuple[Float[Array, "*b 3"], Float[Array, "*b 3"]]:
    """Orthonormal tangents ``(t, b)`` completing unit normals ``n`` to a right-handed frame (t, b, n).

    Branchless construction of Duff, Burgess, Christensen, Hery, Kensler, Liani &
    Villemin (2017), "Building an orthonormal basis, revisited", JCGT 6(1):
    continuous except across n_z = 0 and exact for n = ±z. The shading frame of
    every renderer and sampler (local N = +z).
    """
    sign = jnp.where(n[..., 2] >= 0, 1.0, -1.0).astype(n.dtype)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    t = jnp.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], -1)
    bt = jnp.stack([b, sign + n[..., 1] ** 2 * a, -n[..., 1]], -1)
    return t, bt


def _dot3(a, b):
    """a·b over the last axis (length 3), written out: XLA's CPU backend runs a ``jnp.sum`` over an axis
    of 3 as a reduction loop per element, the written-out sum as vectorised arithmetic."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def to_local(v, t, b, n):
    """World vectors ``v`` in the frame (t, b, n): ``(v·t, v·b, v·n)``.

    Built by broadcasting onto the unit vectors, not ``jnp.stack`` (which XLA's CPU backend fuses
    into one unvectorised loop over the ``(*b, 3)`` output).
    """
    e = jnp.eye(3, dtype=jnp.result_type(v, t, b, n))
    return _dot3(v, t)[..., None] * e[0] + _dot3(v, b)[..., None] * e[1] + _dot3(v, n)[..., None] * e[2]


def to_world(v, t, b, n):
    """Local vectors ``v`` of the frame (t, b, n) in world coordinates."""
    return v[..., 0:1] * t + v[..., 1:2] * b + v[..., 2:3] * n
