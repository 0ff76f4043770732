"""Sample lists of one row per (direction pair, channel), pivoted to one row per pair.

Tidy data, as pandas' ``melt`` and R's ``pivot_longer`` write it, and as a spectral
gonioreflectometer exports a run: the four angles, a column that says which channel or
wavelength the row holds, and its value (and sigma)::

    theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,wavelength_nm,value
    30,0,30,180,400,0.081
    30,0,30,180,410,0.083
    ...

A **channel** column (``channel``, ``band``, ``color``, ``colour``, ``filter``) names R,
G and B in its cells (``r``, ``Red``, ...), or wavelengths (``450nm``); a **wavelength**
column (``wavelength``, ``wavelength_nm``, ``lambda``, ``lambda_nm``, ``wl``, ``nm``)
holds nanometres. The rows of one direction pair are those whose four angles are the
same numbers as written: every pair must give every channel (every wavelength) once,
as a wide file's row does, else the file is refused naming a row that lacks one. Only
the pivot is made here; the projection of spectra to RGB and every check of a sample
list's values and directions are the wide layout's own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from brdffit.io import spectra
from brdffit.io.measurements import Measurements, MeasurementsError

#: A channel cell's words for R, G and B (any case).
RGB_CELLS = {"r": 0, "red": 0, "g": 1, "green": 1, "b": 2, "blue": 2}


@dataclass(frozen=True)
class Pivoted:
    """A long list's rows as one row per direction pair: ``raw`` the four angles as
    written (each (n,)), ``values`` (n, k) in the channels' order (R, G, B, or
    ``wavelengths``, increasing), ``sigma`` likewise or None, ``rows`` each pair's first
    row (its number in the file, for the wide layout's messages)."""

    raw: list[np.ndarray]
    values: np.ndarray
    sigma: np.ndarray | None
    rows: np.ndarray
    wavelengths: list[float] | None
    summary: dict


#: How a wavelength's unit may be written: nanometres.
NANOMETRES = ("nm", "nanometre", "nanometres", "nanometer", "nanometers")


def refuse_other_units(unit: str | None, what: str, source: str) -> None:
    """Refuses wavelengths said to be in another unit than nm (``wavelength [um]``, an
    HDF5 ``units`` of ``um``): they were read as nm."""
    if unit is not None and unit.strip().lower() not in NANOMETRES:
        raise MeasurementsError(source, f"{what} gives wavelengths in {unit.strip()[:20]!r}: "
                                        "write them in nm")


def channel_keys(cells: list[str], column: str, source: str, rows: np.ndarray,
                 noun: str = "column") -> tuple[str, np.ndarray]:
    """A channel column's cells as ``("rgb", indices)`` (0, 1, 2 for R, G, B) or, where
    every cell names a wavelength (``450nm``), ``("wavelength", nm)``: refused where a
    cell is neither, or where the cells mix the two. ``noun``: what the refusals call
    the column (``dataset``)."""
    rgb, nm = [], []
    for k, cell in enumerate(cells):
        word = cell.strip().lower()
        if word in RGB_CELLS:
            rgb.append(RGB_CELLS[word])
        elif (lam := spectra.wavelength_of(word)) is not None:
            nm.append(lam)
        else:
            raise MeasurementsError(source, f"row {int(rows[k]) + 1}: {noun} {column!r} holds "
                                            f"{cell.strip()[:20]!r}, which names no channel "
                                            "(r, g, b, red, green, blue) nor a wavelength "
                                            "(450nm)")
        if rgb and nm:
            raise MeasurementsError(source, f"{noun} {column!r} names both RGB channels and "
                                            "wavelengths: keep one kind")
    return ("wavelength", np.array(nm, float)) if nm else ("rgb", np.array(rgb, float))


#: Angles of two rows this close (radians) are one direction pair written twice with
#: different digits (30 and 30.000001), not two measured directions: said, not merged.
NEAR_MISS_RAD = 1e-4


def _near_miss(raw, scales, seen, p: int, c: int, rows, names) -> str:
    """Where another pair's row gives the missing channel ``c`` at angles within
    :data:`NEAR_MISS_RAD` of pair ``p``'s, a clause naming it (rounded differently,
    most likely), else ''."""
    angles = np.column_stack([a * s for a, s in zip(raw, scales, strict=True)])
    mine = angles[seen[p][seen[p] >= 0].min()]
    candidates = seen[:, c][seen[:, c] >= 0]
    if candidates.size == 0:
        return ""
    gap = np.max(np.abs(angles[candidates] - mine), axis=1)
    best = int(np.argmin(gap))
    if not 0 < gap[best] <= NEAR_MISS_RAD:
        return ""
    row = int(candidates[best])
    column = int(np.argmax(np.abs(angles[row] - mine)))
    angle = ("theta_i", "phi_i", "theta_o", "phi_o")[column]
    name = (names or {}).get(angle, angle)  # as the file names it
    written = float(raw[column][row])
    return (f"; row {int(rows[row]) + 1} gives it at angles within "
            f"{np.degrees(gap[best]):.2g} degrees of these ({name} {written!r} there): the "
            "same direction written with other digits? write each row's angles alike")


def pivot(raw: list[np.ndarray], scales: list[float], keys, kind: str, column: str,
          values: np.ndarray, sigma: np.ndarray | None, rows: np.ndarray, source: str,
          noun: str = "column", names: dict[str, str] | None = None) -> Pivoted:
    """The rows (angles ``raw`` as written, each (N,), in radians times ``scales``; one
    channel's ``values`` and ``sigma`` (N,) each; ``rows`` their numbers in the file,
    ``names`` the angles' names there) pivoted by ``keys``: channel indices (``kind``
    ``"rgb"``) or wavelengths in nm (``kind`` ``"wavelength"``), from the column named
    ``column`` (``noun``: what the refusals call it).

    Each row is checked first as a wide list's sample is
    (:meth:`Measurements.from_angles`: the angles' and sigma's lengths, what is not
    finite, a sigma of 0), so that a refusal names the row and column it is in, not the
    pair's first row after the pivot (a sigma of 0 in a g row was "sigma_g ... row 5")."""
    Measurements.from_angles(*(a * scale for a, scale in zip(raw, scales, strict=True)),
                             values, sigma, source=source, rows=rows, names=names)
    keys = np.asarray(keys, float)
    if not np.all(np.isfinite(keys)):
        bad = int(np.flatnonzero(~np.isfinite(keys))[0])
        raise MeasurementsError(source, f"row {int(rows[bad]) + 1}: {noun} {column!r} is not "
                                        "a number")
    channels, channel = np.unique(keys, return_inverse=True)
    channel = np.ravel(channel)
    if kind == "rgb" and channels.size != 3:
        named = ", ".join("rgb"[int(c)] for c in channels)
        raise MeasurementsError(source, f"{noun} {column!r} names channel(s) {named} alone: "
                                        "every direction needs a row for each of r, g, b"
                                        + ("; if every row holds the same channel, drop the "
                                           "column to read the values as grey"
                                           if channels.size == 1 else ""))
    if kind == "wavelength" and channels[0] <= 0:
        raise MeasurementsError(source, f"{noun} {column!r} holds a wavelength of "
                                        f"{channels[0]:g} nm: a wavelength is > 0")
    if kind == "wavelength" and channels[-1] < 100:
        raise MeasurementsError(source, f"{noun} {column!r} holds wavelengths up to "
                                        f"{channels[-1]:g}: micrometres? Write them in nm")
    if kind == "wavelength" and channels.size < 2:
        raise MeasurementsError(source, f"{noun} {column!r} holds one wavelength "
                                        f"({channels[0]:g} nm) alone: a spectrum needs "
                                        "several; if every row has the same one, drop the "
                                        "column to read the values as grey")
    # a direction pair: the same four numbers, as written; in the order first seen
    pairs = np.column_stack(raw)
    _, first, pair = np.unique(pairs, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    pair = rank[np.ravel(pair)]
    n, k = order.size, channels.size
    cell = pair * k + channel  # each row's (pair, channel), flat
    count = np.bincount(cell, minlength=n * k)
    if (count > 1).any():
        twice = np.flatnonzero(cell == np.flatnonzero(count > 1)[0])[:2]
        raise MeasurementsError(
            source, f"rows {int(rows[twice[0]]) + 1} and {int(rows[twice[1]]) + 1} both give "
                    f"{_said(kind, channels[channel[twice[0]]])} of one direction pair: keep "
                    "one")
    seen = np.full(n * k, -1)
    seen[cell] = np.arange(cell.size)
    seen = seen.reshape(n, k)
    if (seen < 0).any():
        p, c = np.argwhere(seen < 0)[0]
        at = int(rows[seen[p][seen[p] >= 0].min()]) + 1
        raise MeasurementsError(
            source, f"the direction pair of row {at} has no row for {_said(kind, channels[c])}"
                    f" ({int((seen[p] >= 0).sum())} of the {k} the file holds): every pair "
                    "needs one row per " + ("channel" if kind == "rgb" else "wavelength")
                    + ", with the same four angles"
                    + _near_miss(raw, scales, seen, p, c, rows, names))
    first_rows = seen.min(axis=1)  # seen (n, k): the row of each pair's each channel
    return Pivoted(
        raw=[a[first_rows] for a in raw],
        values=values[seen],
        sigma=None if sigma is None else sigma[seen],
        rows=rows[first_rows],
        wavelengths=None if kind == "rgb" else [float(x) for x in channels],
        summary={"rows": int(keys.size), "column": column,
                 "per_sample": "r, g, b" if kind == "rgb" else f"{k} wavelengths"})


def _said(kind: str, key: float) -> str:
    return f"channel {'rgb'[int(key)]}" if kind == "rgb" else f"{key:g} nm"
