"""Which bins a fit looks at, and with what weight.

A fit sees a fixed-size set of bins (``samples``, default 16384) drawn from the
measured bins above the horizon, stratified by theta_h row: every one of the 90
rows gets an equal share, so the few rows that hold a near-mirror peak are as
well represented as the broad diffuse rows. Each chosen bin carries its
solid-angle weight divided by its row's sampling fraction (Horvitz-Thompson), so
the weighted loss over the subsample estimates the full-table loss without bias.

Fixed size matters for speed: every table, whatever its mask, gives arrays of
the same shape, so the compiled fit is reused (unused slots have weight 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from brdffit.io.angles import N_PHI_D, N_THETA_D, N_THETA_H
from brdffit.io.grid import bin_grid
from brdffit.io.merl import MerlTable

#: Chosen on the 100 real MERL materials (bench/results/real_materials_sweep.md):
#: 16k bins put blinn_phong, beckmann and ggx within 1.01x of the best-effort
#: full-table optimum on 100 of 100 and ggx2 on 99; 8k misses on 1-2 per model
#: (the subsample's optimum, not the solver, is what is off), 32k buys nothing
#: more, and more starts at 8k buy nothing at all.
DEFAULT_SAMPLES = 16384


#: The sample counts a fit's compiled programs are made for: a count up to the
#: largest is padded with zero-weight slots to the first bucket that holds it, so
#: ``samples=4096`` or ``5000`` runs the default fit's programs (compiled, or kept on
#: disk by ``brdffit.executables``) instead of compiling its own; zero weights add
#: nothing to any sum (tests/test_fitting.py checks the fits agree to 1e-9). A larger
#: count is padded to a multiple of the largest bucket: every bin of a real table
#: (``samples=None``, 0.9-1.3M usable bins) then shares its programs with the tables
#: whose counts round alike, where each table compiled its own (a batch of every bin
#: over 100 tables compiled ~100 solves), for at most 65535 more slots (~6% at 1.1M)
#: to sum per step; a ggx2 fit to every bin of red-plastic (1,096,216 bins, padded to
#: 1,114,112) took as long either way (min of 5 alternating runs 4.04 s vs 4.15 s).
SAMPLE_BUCKETS = (DEFAULT_SAMPLES, 2 * DEFAULT_SAMPLES, 4 * DEFAULT_SAMPLES)


@dataclass(frozen=True)
class SampleSet:
    """Flat bin indices and normalised weights (sum 1); padded slots have weight 0."""

    index: np.ndarray
    weight: np.ndarray
    n_used: int


@dataclass(frozen=True)
class BinCounts:
    """What a fit may use of a table, and what it must drop (and why)."""

    usable: np.ndarray  # bool over flat bins: measured, finite, above the horizon
    measured: int
    unmeasured: int
    nonfinite: int
    below_horizon: int


def usable_bins(table: MerlTable, scene_weight: np.ndarray | None = None) -> BinCounts:
    """The bins that may enter a loss; ``scene_weight`` (flat) can exclude more."""
    grid = bin_grid()
    measured = table.mask.ravel()
    usable = measured & grid.above_horizon
    if scene_weight is not None:
        usable &= scene_weight > 0
    n_bins = measured.size
    return BinCounts(
        usable=usable,
        measured=int(np.count_nonzero(measured)),
        unmeasured=int(n_bins - np.count_nonzero(measured) - table.n_nonfinite),
        nonfinite=int(table.n_nonfinite),
        below_horizon=int(np.count_nonzero(measured & ~grid.above_horizon)),
    )


def bin_weights(usable: np.ndarray, scene_weight: np.ndarray | None = None) -> np.ndarray:
    """Solid-angle weight (times an optional scene weight) over usable bins, sum 1."""
    w = np.where(usable, bin_grid().weight, 0.0)
    if scene_weight is not None:
        w = w * scene_weight
    total = w.sum()
    return w / total if total > 0 else w


def stratified_sample(weight: np.ndarray, samples: int | None, seed: int = 0) -> SampleSet:
    """Pick at most ``samples`` bins with weight > 0, an equal quota per theta_h row.

    ``samples=None`` keeps every usable bin (padded to the grid size so the shape
    is still fixed).
    """
    candidates = np.flatnonzero(weight > 0)
    if samples is None or samples >= candidates.size:
        size = weight.size if samples is None else samples
        index = np.zeros(size, dtype=np.int64)
        w = np.zeros(size)
        index[: candidates.size] = candidates
        w[: candidates.size] = weight[candidates]
        return SampleSet(index, w / w.sum(), int(candidates.size))

    row_count = np.bincount(candidates // (N_THETA_D * N_PHI_D), minlength=N_THETA_H)
    quota = row_quota(row_count, samples)
    # Systematic sampling inside each row: the k-th of a row's q picks sits at
    # position floor((k + offset) n / q) among its n candidates (sorted, so rows are
    # contiguous), i.e. q bins spread evenly over the row's (theta_d, phi_d)
    # sheet, with a random offset per row. O(samples) work after one flatnonzero.
    offset = np.random.default_rng(seed).random(N_THETA_H)
    row_start = np.concatenate([[0], np.cumsum(row_count)[:-1]])
    r = np.repeat(np.arange(N_THETA_H), quota)
    k = np.arange(r.size) - np.repeat(np.cumsum(quota) - quota, quota)
    pos = np.floor((k + offset[r]) * row_count[r] / quota[r]).astype(np.int64)
    index = candidates[row_start[r] + pos]
    w = weight[index] * row_count[r] / quota[r]
    padded_index = np.zeros(samples, dtype=np.int64)
    padded_w = np.zeros(samples)
    padded_index[: index.size] = index
    padded_w[: index.size] = w
    return SampleSet(padded_index, padded_w / padded_w.sum(), int(index.size))


def row_quota(row_count: np.ndarray, samples: int) -> np.ndarray:
    """Equal share of ``samples`` per non-empty row; a row with fewer bins than its
    share takes them all and the rest goes to the others."""
    quota = np.zeros_like(row_count)
    budget, open_rows = samples, row_count > 0
    while budget > 0 and open_rows.any():
        n_open = int(open_rows.sum())
        if budget < n_open:  # less than one more bin per row: the first rows get it
            open_rows &= np.cumsum(open_rows) <= budget
            n_open = budget
        share = budget // n_open
        take = np.minimum(row_count - quota, share) * open_rows
        quota += take
        budget -= int(take.sum())
        open_rows &= quota < row_count
    return quota


def bucket_size(n: int) -> int:
    """The length of a sample set of ``n`` slots once padded (:data:`SAMPLE_BUCKETS`,
    then multiples of the largest)."""
    top = SAMPLE_BUCKETS[-1]
    return next((b for b in SAMPLE_BUCKETS if n <= b), -(-n // top) * top)


def padded(sample_set: SampleSet) -> SampleSet:
    """``sample_set`` padded with zero-weight slots (bin 0) to its :func:`bucket_size`;
    the slots it had keep their order, so every k-th sample is still the same bin."""
    n = sample_set.index.size
    size = bucket_size(n)
    if size == n:
        return sample_set
    index = np.zeros(size, dtype=sample_set.index.dtype)
    weight = np.zeros(size, dtype=sample_set.weight.dtype)
    index[:n], weight[:n] = sample_set.index, sample_set.weight
    return SampleSet(index, weight, sample_set.n_used)
