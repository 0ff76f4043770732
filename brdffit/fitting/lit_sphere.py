"""How much of a lit sphere's picture each MERL bin covers, integrated over its normals.

A unit sphere seen orthographically along -z under one distant light: every normal
``n`` has the same light and view, so the same half vector ``h``, and the normals
about ``h`` at angle ``theta_h`` sweep the table's theta_h rows in order. The integral
over the normals is therefore done in those coordinates, on Gauss-Legendre nodes
inside each theta_h bin (the sqrt mapping's own edges) and evenly spaced azimuths
about ``h``: a near-mirror's peak rows, which cover ~1e-7 of the disc, get their
share exactly, where a pixel grid sees none of them (a 256-px sphere under the render
loss's eight lights saw no bin of theta_h rows 0 and 1, and 1 to 12 bins of rows 2
to 6, of the ~16,000 a light reflects in).

Two users, one quadrature: the verdict's colour integral (``brdffit.fitting.sphere``,
weight ``(n . l)(n . v) dOmega_n``: the picture's mean radiance) and the render loss's
views (``brdffit.fitting.render_loss``, weight ``(n . v) dOmega_n``: the picture's
area, as a pixel count is).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from brdffit.io.angles import N_THETA_H, SHAPE, dirs_to_half_diff, half_diff_to_bins, tangent_frames


class Nodes(NamedTuple):
    """The quadrature's nodes on the lit, visible normals: each node's flat MERL bin,
    its weight, and its local wi and wo ((k, 3) each)."""

    bins: np.ndarray
    weight: np.ndarray
    wi: np.ndarray
    wo: np.ndarray


def lit_nodes(light: np.ndarray, per_bin: int, per_degree: int, *,
              lit_by: bool = True) -> Nodes:
    """The nodes of the integral over the sphere's lit, visible normals of
    ``(n . v) dOmega_n``, times ``(n . l)`` where ``lit_by``: ``per_bin`` Gauss-Legendre
    nodes per theta_h bin, ``per_degree`` azimuths per degree about the half vector."""
    lgt = np.asarray(light, np.float64) / np.linalg.norm(light)
    view = np.array([0.0, 0.0, 1.0])
    h = (lgt + view) / np.linalg.norm(lgt + view)
    e1 = np.cross([0.0, 1.0, 0.0] if abs(h[1]) < 0.9 else [1.0, 0.0, 0.0], h)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(h, e1)
    x, w = np.polynomial.legendre.leggauss(per_bin)
    edges = (np.arange(N_THETA_H + 1) / N_THETA_H) ** 2 * (np.pi / 2)
    lo, hi = edges[:-1, None], edges[1:, None]
    theta = ((lo + hi) / 2 + (hi - lo) / 2 * x).ravel()
    w_theta = ((hi - lo) / 2 * w).ravel()
    k = 360 * per_degree
    psi = (np.arange(k) + 0.5) / k * 2 * np.pi
    t, p = np.meshgrid(theta, psi, indexing="ij")
    ring = (np.cos(p)[..., None] * e1 + np.sin(p)[..., None] * e2)
    n = (np.cos(t)[..., None] * h + np.sin(t)[..., None] * ring).reshape(-1, 3)
    cos_i, cos_o = n @ lgt, n @ view
    lit = (cos_i > 0) & (cos_o > 0)
    d_omega = (np.sin(t).ravel() * np.repeat(w_theta, k) * (2 * np.pi / k))[lit]
    dw = cos_o[lit] * d_omega * (cos_i[lit] if lit_by else 1.0)
    frame = tangent_frames(n[lit])
    wi, wo = frame @ lgt, frame @ view
    bins = np.ravel_multi_index(half_diff_to_bins(*dirs_to_half_diff(wi, wo)), SHAPE)
    return Nodes(bins, dw, wi, wo)


def summed_per_bin(nodes: Nodes, values: np.ndarray | None = None) -> np.ndarray:
    """The nodes' weights summed per flat MERL bin (n_flat,), or of the weights times
    ``values`` ((k, c) per node: (n_flat, c))."""
    n_flat = int(np.prod(SHAPE))
    if values is None:
        return np.bincount(nodes.bins, weights=nodes.weight, minlength=n_flat)
    return np.stack([np.bincount(nodes.bins, weights=nodes.weight * v, minlength=n_flat)
                     for v in values.T], axis=-1)


def bin_areas(light: np.ndarray, per_bin: int, per_degree: int, *,
              lit_by: bool = True) -> np.ndarray:
    """Per flat MERL bin, the integral of :func:`lit_nodes` over its normals."""
    return summed_per_bin(lit_nodes(light, per_bin, per_degree, lit_by=lit_by))
