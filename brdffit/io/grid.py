"""The MERL bin grid: each bin's centre directions and solid-angle weight.

Computed once per cache directory (about 0.2 s), then read from it; shared by
fitting, plotting and the synthetic tables.

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
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from brdffit.io import angles, array_cache

if TYPE_CHECKING:
    from brdffit.io.merl import MerlTable


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


_CACHE_VERSION = 2  # 2: the separable computation (equal to ~1e-16)


_GRID_LOCK = threading.Lock()


def bin_grid() -> BinGrid:
    """The grid, from brdffit's cache directory (``brdffit.runtime.cache_dir``; about
    20x faster than computing it, which matters for a new process's first fit) or
    computed and stored there. Made once per process: a thread that asks while
    another makes it (the command line starts it early, beside its imports) waits."""
    with _GRID_LOCK:
        return _bin_grid()


@functools.cache
def _bin_grid() -> BinGrid:
    fields = tuple(BinGrid.__dataclass_fields__)

    def compute() -> dict:
        grid = _compute_grid()
        return {k: getattr(grid, k) for k in fields}

    return BinGrid(**array_cache.load_or_compute(f"merl-grid-v{_CACHE_VERSION}", fields,
                                                 compute))


bin_grid.cache_clear = _bin_grid.cache_clear  # as functools.cache's (tests)
#: Wait for the grid's file (and any other array file) being written (tests).
wait_until_stored = array_cache.wait_until_stored


def _freeze(grid: BinGrid) -> BinGrid:
    for k in grid.__dataclass_fields__:
        getattr(grid, k).setflags(write=False)
    return grid


def _compute_grid() -> BinGrid:
    # The bins are a product of three 1-D axes, and with phi_h = 0 each direction's
    # components are products of one trigonometric term per axis: broadcasting them
    # costs a quarter of angles.half_diff_to_dirs on 1.46 M flat bins (a new process
    # with an empty cache pays this once). tests/test_angles.py checks it against
    # half_diff_to_dirs.
    th, td, pd = angles.bin_centres(
        np.arange(angles.N_THETA_H)[:, None, None],
        np.arange(angles.N_THETA_D)[None, :, None],
        np.arange(angles.N_PHI_D)[None, None, :])
    shape = angles.SHAPE
    cos_h, sin_h = np.cos(th), np.sin(th)
    cos_d, sin_d = np.cos(td), np.sin(td)
    dx, dy = sin_d * np.cos(pd), sin_d * np.sin(pd)  # the difference vector (z: cos_d)
    wi = np.stack([np.broadcast_to(cos_h * dx + sin_h * cos_d, shape),
                   np.broadcast_to(dy, shape),
                   np.broadcast_to(cos_h * cos_d - sin_h * dx, shape)], axis=-1).reshape(-1, 3)
    # wo = 2 (wi . h) h - wi, with h = (sin_h, 0, cos_h) and wi . h = cos_d exactly
    h = np.stack([np.broadcast_to(sin_h, shape), np.zeros(shape),
                  np.broadcast_to(cos_h, shape)], axis=-1).reshape(-1, 3)
    wo = 2.0 * np.broadcast_to(cos_d, shape).reshape(-1, 1) * h - wi
    theta_h, theta_d, phi_d = (np.broadcast_to(a, shape).ravel() for a in (th, td, pd))
    cos_i, cos_o = wi[:, 2], wo[:, 2]
    above = (cos_i > 0) & (cos_o > 0)
    u = (np.arange(angles.N_THETA_H)[:, None, None] + 0.5) / angles.N_THETA_H
    d_theta_h = np.pi * u / angles.N_THETA_H
    # separable too: cos_d sin_h sin_d d_theta_h, one factor per axis
    weight = np.broadcast_to(cos_d * sin_d * (sin_h * d_theta_h), shape).ravel()
    weight = np.where(above, weight, 0.0)
    weight /= weight.sum()
    return _freeze(BinGrid(theta_h, theta_d, phi_d, wi, wo, cos_i, cos_o, weight, above))


@functools.cache
def _peak_region() -> np.ndarray:
    """Flat bins near the mirror direction (theta_h < ~6 deg), both directions well
    above grazing, small theta_d: where any lobe peaks, and only ~5% of the table."""
    g = bin_grid()
    near = (g.theta_h < 0.1) & (g.cos_i > 0.3) & (g.cos_o > 0.3) & (g.theta_d < 0.6)
    return np.flatnonzero(near)


def peak_bin(table: MerlTable, usable: np.ndarray) -> int:
    """Flat index of the brightest usable bin with both directions well above grazing
    (where a fit's starts and a model's seeding read the highlight's height)."""
    idx = _peak_region()
    idx = idx[usable[idx]]
    if idx.size == 0:
        idx = np.flatnonzero(usable)
    lum = table.rgb.reshape(3, -1)[:, idx].sum(axis=0)
    return int(idx[np.argmax(lum)])
