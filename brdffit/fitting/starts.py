"""Data-driven starting points for a fit.

1. ``kd``: pi times a low percentile of the table over mid-angle bins, away from
   the highlight and from grazing Fresnel (a lobe only adds to the diffuse floor,
   so a low percentile is close to kd/pi).
2. The peak: the brightest measured bin near the normal and at small theta_d.
3. For each lobe shape on the model's ``shape_grid`` (e.g. ten alphas x two f0),
   the ``ks`` that puts the model's value at the peak bin on the measured one.

The candidates are then scored on the fit's own samples (one batched loss
evaluation) and the best ``starts`` of them seed the solver. This replaces a
guess of alpha by a cheap grid search over it: near-mirror and very rough lobes
start in the right basin.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import numpy as np

from brdffit import executables
from brdffit.io.grid import bin_grid, peak_bin
from brdffit.io.merl import MerlTable
from brdffit.models import AbstractBRDFModel, AbstractLobeModel, MonoKs
from brdffit.models.frame import shading_frame


@functools.cache
def _diffuse_region() -> np.ndarray:
    """Flat bins far from the highlight and from grazing Fresnel; every 3rd is plenty
    for a percentile and keeps this cheap."""
    g = bin_grid()
    sel = (
        (g.theta_h > 0.5)
        & (g.theta_h < 1.2)
        & (g.theta_d < 0.9)
        & (g.cos_i > 0.2)
        & (g.cos_o > 0.2)
    )
    return np.flatnonzero(sel)[::3]


#: Fewer usable bins far from the highlight than this, and :func:`diffuse_estimate`
#: reads every usable bin instead.
MID_ANGLE_BINS = 50


def _mid_angle_usable(usable: np.ndarray) -> np.ndarray:
    idx = _diffuse_region()
    return idx[usable[idx]]


def diffuse_estimate(table: MerlTable, usable: np.ndarray,
                     mid: np.ndarray | None = None) -> np.ndarray:
    """kd estimate (3,) from bins far from the highlight (``mid``: the usable ones of
    them, where already found)."""
    idx = _mid_angle_usable(usable) if mid is None else mid
    if idx.size < MID_ANGLE_BINS:  # tiny or oddly masked table: use what there is
        idx = np.flatnonzero(usable)
    values = table.rgb.reshape(3, -1)[:, idx]
    return np.pi * np.percentile(values, 20, axis=1)


class TableHints(NamedTuple):
    """What every model's starts read from one table: computed once per table and
    usable mask (``auto`` and a batch fit several models to it; ~5 ms a table)."""

    kd: np.ndarray  # diffuse_estimate
    peak: int  # brdffit.io.grid.peak_bin
    # whether kd was read from any bin far from the highlight (theta_h over ~29 deg) and
    # from grazing Fresnel (theta_d under ~52 deg): a table measured at its peak alone
    # read its peak as a diffuse floor, and one measured at theta_d >= 70 deg alone its
    # Fresnel rise (an albedo of 5.4 on an exact GGX fit, asked whether it was in 1/sr)
    kd_from_mid_angles: bool = True


def table_hints(table: MerlTable, usable: np.ndarray) -> TableHints:
    mid = _mid_angle_usable(usable)
    # every mid-angle bin lies beyond theta_h 0.5 and below theta_d 0.9; a sparse list's
    # bins may miss the every-third ones that ``mid`` keeps
    g = bin_grid()
    away = mid.size > 0 or bool(np.any((g.theta_h[usable] > 0.5) & (g.theta_d[usable] < 0.9)))
    return TableHints(diffuse_estimate(table, usable, mid), peak_bin(table, usable), away)


def candidates(model: AbstractBRDFModel, table: MerlTable, usable: np.ndarray,
               hints: TableHints | None = None) -> np.ndarray:
    """Unconstrained start vectors (K, n_params), one per ``shape_grid`` entry;
    ``hints`` (:func:`table_hints` of the same table and mask) when known."""
    hints = table_hints(table, usable) if hints is None else hints
    if isinstance(model, MonoKs):  # a grey-ks wrapper starts where its base would
        return model.grey_starts(candidates(model.base, table, usable, hints))
    kd = hints.kd
    # A model that is not one lobe over a diffuse base may seed itself (ggx2).
    if hasattr(model, "start_candidates"):
        return np.asarray(model.start_candidates(table, usable, kd))
    starts = []
    if isinstance(model, AbstractLobeModel):
        g = bin_grid()
        b = hints.peak
        f_peak = table.rgb.reshape(3, -1)[:, b]
        excess = np.maximum(f_peak - kd / np.pi, 1e-3 * np.maximum(f_peak, 1e-6))
        shapes = {k: np.array([s[k] for s in model.shape_grid]) for k in model.shape_grid[0]}
        lobes = np.asarray(_lobe_at(model, shapes, g.wi[b], g.wo[b]))
        for j, lobe in enumerate(lobes):
            p = {k: v[j] for k, v in shapes.items()}
            p["ks"] = np.clip(excess / max(float(lobe), 1e-12), 1e-6, 1e6)
            # with a lobe in play the diffuse floor estimate is an upper bound
            p["kd"] = 0.8 * kd
            starts.append(model.unconstrain(p))
    else:
        for shape in model.shape_grid:
            starts.append(model.unconstrain({"kd": kd, **shape}))
    return np.stack(starts)


@executables.jit
def _lobe_at(model, shapes, wi, wo):
    """The model's lobe at one direction pair for a batch of shape parameters."""
    frame = shading_frame(wi, wo)
    return jax.vmap(lambda sh: model.lobe(sh, frame))(shapes)
