"""Measured BRDF samples in any layout: direction pairs and their values.

A gonioreflectometer or a camera rig measures a list of (light, view) direction pairs
and a reflectance for each, sparse, noisy and often in-plane; a MERL table is one
dense, binned layout of the same thing. :class:`Measurements` holds the list:

- ``wi``, ``wo`` (n, 3): unit directions in the surface's local frame (normal +z), the
  light and the view, both on or above the horizon;
- ``rgb`` (n, 3): the BRDF f_r (1/sr), linear RGB; a one-channel measurement is grey
  (its three channels equal, ``provenance["channels"] == 1``);
- ``sigma`` (n, 3) or None: each value's standard deviation (1/sr, > 0);
- ``source`` and ``provenance``: where the samples came from, in which format, which
  columns and units, and what the reader did to them.

Every reader (:mod:`brdffit.io.readers`) builds one through :meth:`Measurements.from_angles`,
which refuses what no fit can use, in one line naming the file and the first bad row:
non-finite angles or values, angles out of range or below the horizon, negative
values, a sigma that is not > 0, no rows, more than :data:`MAX_SAMPLES` rows.

:meth:`Measurements.to_table` bins the samples onto the MERL grid (the mean of the
samples in each bin, weighted by 1 / sigma^2 where sigma is given; every other bin
unmeasured), so that every fit, plot, export and shell of brdffit takes them; what the
binning moved is reported (:class:`Binning`: how far each sample sat from its bin's
centre, how much samples that share a bin disagree).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from brdffit.errors import MerlFormatError
from brdffit.io.angles import (
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
    SHAPE,
    bin_centres,
    dirs_to_half_diff,
    flat_index,
    half_diff_to_bins,
)

#: Largest BRDF value (1/sr) a sample may hold: the MERL reader's bound (1e12).
MAX_VALUE = 1e12
#: Polar angles this little over 90 degrees (radians; 0.01 degrees, as
#: :data:`NORMAL_SLACK` below 0) are read as 90; beyond, a direction below the horizon
#: is refused, not clamped. A gonioreflectometer's 90.000 deg reads as 1.5707963 (a
#: little over pi / 2), and its 90.004 was refused where -0.004 at the normal was read.
HORIZON_SLACK = float(np.radians(0.01))
#: Polar angles this little below 0 (radians; 0.01 degrees) are read as 0: an
#: instrument's -0.0001 degrees at normal incidence is rounding, while an in-plane
#: file's signed angles, which are refused, reach far below it.
NORMAL_SLACK = float(np.radians(0.01))
#: The largest |phi| read (radians): two turns, for files that measure the view's
#: azimuth from the light's in -360..360 degrees.
MAX_AZIMUTH = 4 * np.pi
#: The most samples a sample list may hold. The densest layout brdffit reads, a MERL
#: table, has 1,458,000 bins; a gonioreflectometer's sweep holds thousands to a few
#: hundred thousand samples. A camera rig's list denser than that is more than the
#: MERL grid tells apart: bin it first (``Measurements.to_table``) or thin it (the
#: solver sees at most 16384 samples anyway). A fit of a million samples peaked at
#: 1.05 GB and 13 s on 2 cores, and grows with the list: 2 million is the cap.
MAX_SAMPLES = 2_000_000


def relative_sigma(sigma: np.ndarray, positive: np.ndarray) -> np.ndarray:
    """``sigma`` over the median of ``positive`` (the values of it that count), floored
    at a thousandth of their least: where only sigma's ratios count (a bin's weighted
    mean, a fit's normalised weights). Squared as it is, a sigma of 1e-160 overflowed
    to inf (a fit of NaNs) and one of 1e-170 underflowed to 0 (silently ignored); a
    sigma of 0 (the readers refuse one; Measurements built directly may hold it) is the
    most certain, not infinitely so. And at a millionth of their median: a sigma of
    1e-300 beside others of 0.01 made its bin's weight 1 / 0 (a NaN bin, dropped
    unsaid); no sample here weighs more than 1e12 times the median one."""
    scale = float(np.median(positive)) if positive.size else 1.0
    floor = max(float(np.min(positive, initial=scale)) / scale * 1e-3, 1e-6)
    return np.maximum(sigma / scale, floor)


class MeasurementsError(MerlFormatError):
    """Samples that no fit can use: the message names the source and the first bad row.
    A kind of MerlFormatError (a measured file that cannot be read as a table), so
    every shell that reports a bad table (exit 2, the service's 4xx, a batch's skipped
    file) reports these the same way."""


def too_many_samples(n: int) -> str | None:
    """Why a list of ``n`` samples is refused (:data:`MAX_SAMPLES`), or None."""
    if n <= MAX_SAMPLES:
        return None
    return (f"{n:,} samples: more than a sample list read here ({MAX_SAMPLES:,}; a MERL "
            "table has 1,458,000 bins); bin it onto the MERL grid or thin it first")


def _first_rows(bad: np.ndarray, rows: np.ndarray | None) -> str:
    """'N rows (first: row K)' of a boolean mask, K the file's own row number."""
    idx = np.flatnonzero(bad)
    first = int(idx[0]) if rows is None else int(rows[idx[0]])
    return f"{idx.size} row{'s' if idx.size != 1 else ''} (first: row {first + 1})"


def _positive_sigma(sigma: np.ndarray, source: str, rows: np.ndarray | None,
                    text: bool) -> None:
    """Refuses a sigma (n, 1) or (n, 3) that is not > 0 and finite, naming its column
    (``sigma``; a text file's ``sigma_r``, ``_g``, ``_b``, an HDF5 dataset's channel)
    and its rows. A sigma of 0 says a value is exact: its weight, 1 / sigma^2, was
    floored and capped, and reweighted the fit silently (a column of zeros weighed as
    exact)."""
    names = (["sigma"] if sigma.shape[1] == 1 else
             [f"sigma_{c}" if text else f"sigma's {c} channel" for c in "rgb"])
    for name, column in zip(names, sigma.T, strict=True):
        bad = ~(np.isfinite(column) & (column > 0))
        if not bad.any():
            continue
        kinds = [word for word, hit in (("0", column == 0), ("negative", column < 0),
                                        ("not finite", ~np.isfinite(column))) if hit.any()]
        raise MeasurementsError(
            source, f"{name} is {' or '.join(kinds)} in {_first_rows(bad, rows)}: a "
                    "standard deviation is > 0 (a sigma of 0 would weigh its value as "
                    "exact); drop the sigma columns (an HDF5 file's dataset sigma) to "
                    "weigh every sample the same, or give each value's measured standard "
                    "deviation (1/sr)")


_HALF_DIFF_RANGE = "theta_h and theta_d run from 0 to 90 degrees, as the MERL table's"
#: Why a polar angle is refused, by which angle it is: (past 90 degrees, why; negative,
#: why). A direction's (theta_i, theta_o) from the normal; a half or difference angle
#: (theta_h, theta_d) from 0 to 90 degrees, as the MERL table's (the mapping made a
#: pair of a negative one, and it was fitted unsaid).
_POLAR_RANGE = {
    "direction": ("is below the horizon (more than 90 degrees from the normal)",
                  "a reflectance sample has both directions above the surface",
                  "polar angles are measured from the normal, 0 to 90 degrees (an in-plane "
                  "file's signed angle is theta = |angle|, with phi turned by 180 degrees "
                  "on the negative side)"),
    "half_diff": ("is over 90 degrees", _HALF_DIFF_RANGE, _HALF_DIFF_RANGE),
}


def angles_checked(angles: dict[str, np.ndarray], source: str,
                   rows: np.ndarray | None = None, named=lambda angle: angle) -> None:
    """Refuses angles no sample has, naming the first row (``rows``: each sample's row
    in its file, 0-based): one that is not finite, an azimuth (``phi_*``) beyond
    :data:`MAX_AZIMUTH`, a polar angle (``theta_*``) over 90 degrees or negative (beyond
    :data:`HORIZON_SLACK`, :data:`NORMAL_SLACK`). ``angles``: name -> radians, (n,)
    each, in the file's order; a direction's (``theta_i``, ``phi_i``, ...) or the half
    and difference angles (``theta_h``, ``theta_d``, ``phi_d``, ``phi_h``), whose range
    is the same. ``named(angle)``: the angle as its file names it."""
    for name, a in angles.items():
        if not np.all(np.isfinite(a)):
            raise MeasurementsError(source, f"{named(name)} is not finite in "
                                            f"{_first_rows(~np.isfinite(a), rows)}")
    for name, a in angles.items():
        # any azimuth is within a turn of 0; one of 1e300 degrees has lost every
        # digit of its angle (in radians, a 1e300 degrees value is 1.7e298)
        beyond = np.abs(a) > MAX_AZIMUTH
        if name.startswith("phi") and beyond.any():
            raise MeasurementsError(
                source, f"{named(name)} is beyond +-{np.degrees(MAX_AZIMUTH):.0f} degrees in "
                        f"{_first_rows(beyond, rows)}: an azimuth is within a turn or "
                        "two of 0 (angles in another unit?)")
    for name, a in angles.items():
        if not name.startswith("theta"):
            continue
        over, why_over, why_negative = _POLAR_RANGE[
            "half_diff" if name in ("theta_h", "theta_d") else "direction"]
        below = a > np.pi / 2 + HORIZON_SLACK
        if below.any():
            raise MeasurementsError(
                source, f"{named(name)} {over} in {_first_rows(below, rows)}: {why_over}")
        negative = a < -NORMAL_SLACK
        if negative.any():
            raise MeasurementsError(
                source, f"{named(name)} is negative in {_first_rows(negative, rows)}: "
                        f"{why_negative}")


def direction(theta, phi) -> np.ndarray:
    """Unit vectors (..., 3) of polar angle ``theta`` from the normal and azimuth ``phi``."""
    theta, phi = np.asarray(theta, float), np.asarray(phi, float)
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


@dataclass(frozen=True, eq=False)
class Measurements:
    """BRDF samples at arbitrary direction pairs (module docstring)."""

    wi: np.ndarray
    wo: np.ndarray
    rgb: np.ndarray
    sigma: np.ndarray | None = None
    source: str = "<memory>"
    provenance: dict = field(default_factory=dict)

    def __post_init__(self):
        # read-only, as a MerlTable's: a fit keeps what it derives with the object (its
        # binned table, folds), and samples changed in place were fitted from the old
        for name in ("wi", "wo", "rgb", "sigma"):
            a = getattr(self, name)
            if a is None or (isinstance(a, np.ndarray) and not a.flags.writeable):
                continue
            a = np.array(a, dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def n(self) -> int:
        return int(self.rgb.shape[0])

    @classmethod
    def from_angles(cls, theta_i, phi_i, theta_o, phi_o, values, sigma=None, *,
                    source: str = "<memory>", provenance: dict | None = None,
                    rows: np.ndarray | None = None,
                    names: dict[str, str] | None = None) -> Measurements:
        """Samples from polar angles (radians; light ``_i``, view ``_o``) and values
        (n,) or (n, 3); ``sigma`` likewise. ``rows``: each sample's row number in its
        file (0-based), and ``names``: each angle's name in it (``theta_s`` for
        ``theta_o``), for the messages. Raises :class:`MeasurementsError` on what no
        fit can use (module docstring)."""
        def named(angle: str) -> str:  # as the file names it
            said = (names or {}).get(angle, angle)
            return said if said.lower().startswith(angle) else f"{said} (read as {angle})"

        if values is None:
            raise MeasurementsError(source, "no values: (n,) or (n, 3), one per sample")
        angles = [np.asarray(a, float).ravel() for a in (theta_i, phi_i, theta_o, phi_o)]
        values = np.asarray(values, float)
        if values.size == 0:
            raise MeasurementsError(source, "no data: the file holds no sample rows")
        one_channel = values.ndim == 1
        if values.ndim > 2 or values.ndim == 2 and values.shape[1] not in (1, 3):
            raise MeasurementsError(source, f"values have shape {values.shape}: expected "
                                            "(n,) or (n, 3), one per sample")
        values = values.reshape(values.shape[0], -1) if values.ndim else values.reshape(1, 1)
        n = values.shape[0]
        if (why := too_many_samples(n)) is not None:  # the readers refuse it before reading
            raise MeasurementsError(source, why)
        if any(a.size != n for a in angles):
            raise MeasurementsError(source, f"{n} values but angles of "
                                            f"{[a.size for a in angles]} rows")
        angles_checked(dict(zip(("theta_i", "phi_i", "theta_o", "phi_o"), angles,
                                strict=True)), source, rows, named)
        if not np.all(np.isfinite(values)):
            raise MeasurementsError(source, "a value is not finite in "
                                            f"{_first_rows(~np.all(np.isfinite(values), 1), rows)}")
        if np.any(values < 0):
            raise MeasurementsError(
                source, f"a value is negative in {_first_rows(np.any(values < 0, 1), rows)}: "
                        "a BRDF is >= 0 (a background subtraction below zero is noise; "
                        "clip it to 0 knowingly before fitting)")
        if np.any(values > MAX_VALUE):
            raise MeasurementsError(
                source, f"a value is above {MAX_VALUE:g} 1/sr in "
                        f"{_first_rows(np.any(values > MAX_VALUE, 1), rows)}: another unit, "
                        "or a corrupt value")
        rgb = np.repeat(values, 3, axis=1) if values.shape[1] == 1 else values
        if sigma is not None:
            sigma = np.asarray(sigma, float)
            # one per value: (n,) or (n, 1) for every channel, or (n, 3); a (3, n) array
            # reshaped would hand one sample's sigma to another, silently
            if sigma.shape not in ((n,), (n, 1), (n, 3)):
                raise MeasurementsError(source, f"sigma has shape {sigma.shape}: expected "
                                                f"({n},) or ({n}, 3), one per sample")
            sigma = sigma.reshape(n, -1)
            _positive_sigma(sigma, source, rows,
                            text=(provenance or {}).get("format") in ("csv", "astm"))
            sigma = np.repeat(sigma, 3, axis=1) if sigma.shape[1] == 1 else sigma
            if np.any(sigma > MAX_VALUE):
                # its weight, 1 / sigma^2, is 0 in float64 from ~1e154: the samples
                # weighed nothing, and the table was refused as blank
                raise MeasurementsError(
                    source, f"sigma is above {MAX_VALUE:g} 1/sr in "
                            f"{_first_rows(np.any(sigma > MAX_VALUE, 1), rows)}: another "
                            "unit, or a corrupt value")
        theta_i, phi_i, theta_o, phi_o = (np.clip(a, 0.0, np.pi / 2) if k % 2 == 0 else a
                                          for k, a in enumerate(angles))
        info = {"channels": 1 if one_channel or values.shape[1] == 1 else 3,
                **(provenance or {})}
        return cls(direction(theta_i, phi_i), direction(theta_o, phi_o), rgb, sigma, source,
                   info)

    def to_table(self):
        """The samples binned onto the MERL grid: ``(MerlTable, Binning)`` (module
        docstring). Bins no sample falls in are unmeasured."""
        from brdffit.io.merl import MIN_PEAK, MerlTable, too_dark

        brightest = float(self.rgb[np.isfinite(self.rgb)].max(initial=0.0))
        if not brightest >= MIN_PEAK:  # said of samples, not in a binned table's words
            raise MeasurementsError(self.source, too_dark(f"sample is {brightest:.3g} 1/sr",
                                                          "list"))
        theta_h, theta_d, phi_d = dirs_to_half_diff(self.wi, self.wo)
        bins = half_diff_to_bins(theta_h, theta_d, phi_d)
        flat = flat_index(*bins)
        n_bins = N_THETA_H * N_THETA_D * N_PHI_D
        if self.sigma is None:
            w = np.ones_like(self.rgb)
        else:  # 1 / sigma^2 (only ratios count in a bin's mean)
            w = 1.0 / relative_sigma(self.sigma, self.sigma[self.sigma > 0]) ** 2
        total = np.stack([np.bincount(flat, w[:, c] * self.rgb[:, c], n_bins) for c in range(3)])
        weight = np.stack([np.bincount(flat, w[:, c], n_bins) for c in range(3)])
        count = np.bincount(flat, minlength=n_bins)
        measured = count > 0
        mean = np.where(measured, total / np.where(weight > 0, weight, 1.0), 0.0)
        # how much the samples that share a bin disagree (relative to their mean)
        spread = np.abs(self.rgb.T - mean[:, flat]) / np.maximum(mean[:, flat], 1e-12)
        shared = count[flat] > 1
        c_th, c_td, c_pd = bin_centres(*bins)
        folded = np.where(phi_d < 0, phi_d + np.pi, phi_d)
        offset = np.degrees(np.stack([np.abs(theta_h - c_th), np.abs(theta_d - c_td),
                                      np.abs(folded - c_pd)]))
        binning = Binning(
            samples=self.n, bins=int(measured.sum()),
            most_in_a_bin=int(count.max()),
            offset_deg={k: {"median": float(np.median(o)), "max": float(o.max())}
                        for k, o in zip(("theta_h", "theta_d", "phi_d"), offset, strict=True)},
            spread_in_bins=(None if not shared.any() else
                            {"median": float(np.median(spread[:, shared])),
                             "max": float(spread[:, shared].max())}))
        table = MerlTable.from_values(mean.reshape(3, *SHAPE), measured.reshape(SHAPE),
                                      source=self.source)
        return table, binning


@dataclass(frozen=True)
class Binning:
    """What binning samples onto the MERL grid did: ``samples`` into ``bins`` (at most
    ``most_in_a_bin`` in one), each sample moved to its bin's centre by
    ``offset_deg`` (median, max per angle: theta_h's bins are 0.02-2 degrees wide, the
    others 1 degree), and ``spread_in_bins``: the relative disagreement of samples
    that share a bin (None where none do)."""

    samples: int
    bins: int
    most_in_a_bin: int
    offset_deg: dict
    spread_in_bins: dict | None

    def summary(self) -> dict:
        return {"samples": self.samples, "bins": self.bins, "most_in_a_bin": self.most_in_a_bin,
                "offset_deg": self.offset_deg, "spread_in_bins": self.spread_in_bins}

    def describe(self) -> str:
        """One line for a person: how the samples became a table."""
        th = self.offset_deg["theta_h"]
        spread = ("" if self.spread_in_bins is None else
                  f"; samples sharing a bin differ by {100 * self.spread_in_bins['median']:.2g}% "
                  f"(median)")
        return (f"binned {self.samples} samples into {self.bins} MERL bins (at most "
                f"{self.most_in_a_bin} in one); each moved to its bin's centre by at most "
                f"{max(o['max'] for o in self.offset_deg.values()):.2g} deg (theta_h median "
                f"{th['median']:.2g} deg){spread}")
