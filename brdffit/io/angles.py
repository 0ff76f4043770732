"""Rusinkiewicz half/difference angles and the MERL bin lookup (docs/models.md).

``dirs_to_half_diff`` / ``half_diff_to_dirs`` are the only places that convert
between direction pairs and (theta_h, theta_d, phi_d); everything else calls them.
They are written with ``numpy``-compatible array code and work on numpy arrays
(and, through ``xp=jax.numpy``, on JAX arrays).
"""

from __future__ import annotations

import numpy as np

N_THETA_H, N_THETA_D, N_PHI_D = 90, 90, 180
SHAPE = (N_THETA_H, N_THETA_D, N_PHI_D)
#: Bins in a table: a scene's or any per-bin weight has one value per bin.
N_BINS = N_THETA_H * N_THETA_D * N_PHI_D


def _rotate_z(v, angle, xp):
    c, s = xp.cos(angle), xp.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return xp.stack([c * x - s * y, s * x + c * y, z], axis=-1)


def _rotate_y(v, angle, xp):
    c, s = xp.cos(angle), xp.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return xp.stack([c * x + s * z, y, -s * x + c * z], axis=-1)


def dirs_to_half_diff(wi, wo, xp=np):
    """(wi, wo) unit vectors, shape (..., 3) -> (theta_h, theta_d, phi_d).

    h = normalize(wi + wo); the difference vector is wi rotated by -phi_h about z,
    then by -theta_h about y. phi_d is in (-pi, pi], as atan2 gives it.
    """
    h = wi + wo
    h = h / xp.maximum(xp.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    theta_h = xp.arccos(xp.clip(h[..., 2], -1.0, 1.0))
    phi_h = xp.arctan2(h[..., 1], h[..., 0])
    d = _rotate_y(_rotate_z(wi, -phi_h, xp), -theta_h, xp)
    theta_d = xp.arccos(xp.clip(d[..., 2], -1.0, 1.0))
    phi_d = xp.arctan2(d[..., 1], d[..., 0])
    return theta_h, theta_d, phi_d


def half_diff_to_dirs(theta_h, theta_d, phi_d, phi_h=0.0, xp=np):
    """(theta_h, theta_d, phi_d[, phi_h]) -> (wi, wo), the inverse of the above."""
    theta_h, theta_d, phi_d = (xp.asarray(a, dtype=float) for a in (theta_h, theta_d, phi_d))
    st_d = xp.sin(theta_d)
    d = xp.stack([st_d * xp.cos(phi_d), st_d * xp.sin(phi_d), xp.cos(theta_d)], axis=-1)
    phi_h = xp.broadcast_to(xp.asarray(phi_h, dtype=float), theta_h.shape)
    wi = _rotate_z(_rotate_y(d, theta_h, xp), phi_h, xp)
    z = xp.zeros(theta_h.shape + (3,)) + xp.asarray([0.0, 0.0, 1.0])
    h = _rotate_z(_rotate_y(z, theta_h, xp), phi_h, xp)
    wo = 2.0 * xp.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def half_diff_to_bins(theta_h, theta_d, phi_d):
    """Reference nearest-bin lookup (BRDFRead.cpp): angles -> (i_th, i_td, i_pd).

    theta_h uses the sqrt mapping (dense bins near the specular peak); phi_d < 0
    is folded by +pi (reciprocity). Each index is clamped to its range.
    """
    theta_h, theta_d, phi_d = (np.asarray(a, dtype=float) for a in (theta_h, theta_d, phi_d))
    th = np.where(theta_h <= 0, 0.0, np.sqrt(np.maximum(theta_h, 0.0) / (np.pi / 2)) * N_THETA_H)
    i_th = np.clip(np.floor(th), 0, N_THETA_H - 1).astype(np.int64)
    i_td = np.clip(np.floor(theta_d / (np.pi / 2) * N_THETA_D), 0, N_THETA_D - 1).astype(np.int64)
    phi = np.where(phi_d < 0, phi_d + np.pi, phi_d)
    i_pd = np.clip(np.floor(phi / np.pi * N_PHI_D), 0, N_PHI_D - 1).astype(np.int64)
    return i_th, i_td, i_pd


def bin_centres(i_th, i_td, i_pd):
    """Sample position of bins (docs/models.md: the bin centre) -> (theta_h, theta_d, phi_d)."""
    theta_h = ((np.asarray(i_th) + 0.5) / N_THETA_H) ** 2 * (np.pi / 2)
    theta_d = (np.asarray(i_td) + 0.5) / N_THETA_D * (np.pi / 2)
    phi_d = (np.asarray(i_pd) + 0.5) / N_PHI_D * np.pi
    return theta_h, theta_d, phi_d


def flat_index(i_th, i_td, i_pd):
    """Index inside one channel: phi_d fastest (docs/models.md)."""
    return np.asarray(i_pd) + N_PHI_D * np.asarray(i_td) + N_PHI_D * N_THETA_D * np.asarray(i_th)


def tangent_frames(n: np.ndarray) -> np.ndarray:
    """Rows: a local x, y and z (= n) axis per unit normal ``n`` (..., 3); any tangent
    will do (the tables are isotropic, only angles to the normal matter). ``frame @ d``
    is a world direction ``d`` in the local shading frame."""
    up = np.where(np.abs(n[..., 1:2]) < 0.99, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t = np.cross(up, n)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    return np.stack([t, np.cross(n, t), n], axis=-2)
