"""Directions of an isotropic BRDF: goniometer angles, standard vectors and Rusinkiewicz half/difference angles.

Every measured BRDF in :mod:`jkatana.brdf` is evaluated at a pair of unit
vectors (ωi, ωo) in the surface's tangent frame (z the normal). A goniometer
names the same pair by three angles (the convention of
:func:`jkatana.models.in_plane` extended out of the plane of incidence):

- θi: incidence, the light at azimuth 180° (the −x side);
- θo: the receiver's polar angle;
- ``azimuth`` ψ: the receiver's azimuth measured from the plane of
  incidence on the *forward* (specular) side, so ψ = 0 is the in-plane
  forward receiver (θo = θi is then the mirror direction) and ψ = 180° is
  back-scatter on the light's side.

MERL files are indexed by the half/difference angles of S. Rusinkiewicz
(1998), "A new change of variables for efficient BRDF representation",
Eurographics Workshop on Rendering: h = normalize(ωi + ωo), θh, φh its polar
and azimuth angles; d = ωi rotated by −φh about z then by −θh about y, θd, φd
its angles.
"""

from __future__ import annotations

import numpy as np


def goniometer_vectors(theta_i_deg, theta_o_deg, azimuth_deg=0.0) -> tuple[np.ndarray, np.ndarray]:
    """(ωi, ωo) unit vectors ``(..., 3)`` for goniometer angles in degrees (module docstring)."""
    ti, to, ps = (np.deg2rad(np.asarray(a, np.float64)) for a in (theta_i_deg, theta_o_deg, azimuth_deg))
    ti, to, ps = np.broadcast_arrays(ti, to, ps)
    wi = np.stack([-np.sin(ti), np.zeros_like(ti), np.cos(ti)], axis=-1)
    wo = np.stack([np.sin(to) * np.cos(ps), np.sin(to) * np.sin(ps), np.cos(to)], axis=-1)
    return wi, wo


def _rot_z(v, a):
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], axis=-1)


def _rot_y(v, a):
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * v[..., 0] + s * v[..., 2], v[..., 1], -s * v[..., 0] + c * v[..., 2]], axis=-1)


def half_diff(wi, wo) -> tuple[np.ndarray | float, np.ndarray | float, np.ndarray | float, np.ndarray | float]:
    """(θh, φh, θd, φd) in radians of direction pairs (Rusinkiewicz 1998; module docstring); floats for one
    pair, arrays of the batch shape otherwise."""
    wi = np.asarray(wi, np.float64)
    wo = np.asarray(wo, np.float64)
    h = wi + wo
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    h = np.where(n > 0, h / np.where(n > 0, n, 1.0), np.array([0.0, 0.0, 1.0]))
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    theta_d = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    phi_d = np.arctan2(d[..., 1], d[..., 0])
    return theta_h, phi_h, theta_d, phi_d


def from_half_diff(theta_h, phi_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray]:
    """(ωi, ωo) from half/difference angles (inverse of :func:`half_diff`)."""
    theta_h, phi_h, theta_d, phi_d = np.broadcast_arrays(*(np.asarray(a, np.float64)
                                                           for a in (theta_h, phi_h, theta_d, phi_d)))
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], axis=-1)
    wi = _rot_z(_rot_y(d, theta_h), phi_h)
    h = np.stack([np.sin(theta_h) * np.cos(phi_h), np.sin(theta_h) * np.sin(phi_h), np.cos(theta_h)], axis=-1)
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


__all__ = ["goniometer_vectors", "half_diff", "from_half_diff"]
