"""The MERL bin grid: each bin's centre directions and solid-angle weight.

Computed once per process (about 0.2 s) and shared by fitting, plotting and the
synthetic tables.

Why these weights: the measure of direction pairs in half/difference angles is
dw_i dw_o = 4 cos(theta_d) sin(theta_h) sin(theta_d) dtheta_h dphi_h dtheta_d dphi_d
(Rusinkiewicz 1998). With the sqrt mapping a theta_h bin spans
dtheta_h = pi u / 90 at u = (i + 0.5) / 90. A sum over bins weighted this way
approximates an integral over (wi, wo), so a dense near-specular corner of the
table does not dominate a fit just by having many bins. The weights are
normalised to sum to 1 over the bins above the horizon.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from . import angles


@dataclass(frozen=True)
class BinGrid:
    """Arrays over all 90*90*180 bins, in flat (MERL channel) order."""

    theta_h: np.ndarray
    theta_d: np.ndarray
    phi_d: np.ndarray
    wi: np.ndarray  # (N, 3)
    wo: np.ndarray  # (N, 3)
    cos_i: np.ndarray
    cos_o: np.ndarray
    weight: np.ndarray  # solid-angle weight, 0 below the horizon
    above_horizon: np.ndarray  # bool


@functools.cache
def bin_grid() -> BinGrid:
    i_th, i_td, i_pd = np.meshgrid(
        np.arange(angles.N_THETA_H),
        np.arange(angles.N_THETA_D),
        np.arange(angles.N_PHI_D),
        indexing="ij",
    )
    theta_h, theta_d, phi_d = (a.ravel() for a in angles.bin_centres(i_th, i_td, i_pd))
    wi, wo = angles.half_diff_to_dirs(theta_h, theta_d, phi_d)
    cos_i, cos_o = wi[:, 2], wo[:, 2]
    above = (cos_i > 0) & (cos_o > 0)
    u = (i_th.ravel() + 0.5) / angles.N_THETA_H
    d_theta_h = np.pi * u / angles.N_THETA_H
    weight = np.cos(theta_d) * np.sin(theta_h) * np.sin(theta_d) * d_theta_h
    weight = np.where(above, weight, 0.0)
    weight /= weight.sum()
    for a in (theta_h, theta_d, phi_d, wi, wo, cos_i, cos_o, weight, above):
        a.setflags(write=False)
    return BinGrid(theta_h, theta_d, phi_d, wi, wo, cos_i, cos_o, weight, above)
