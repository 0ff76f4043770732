"""Readers of measured BRDF files, registered by suffix and recognised by content.

``read_measured(path)`` returns a :class:`~brdffit.io.merl.MerlTable` for a MERL
``.binary`` file (its own fast paths) and :class:`~brdffit.io.measurements.Measurements`
for every sample layout; ``read_table(path)`` gives a table either way (samples binned
onto the MERL grid, with what the binning did). The layouts (docs/measurements.md):

- **MERL** ``.binary`` (:mod:`brdffit.io.merl`).
- **ASTM E1392**, as Cornell's gonioreflectometer files and ALTA's reader have them
  (``.astm``): header lines ``KEY value`` (``NUM_POINTS n``, ``VARS`` naming the
  columns, e.g. ``theta_i,phi_i,theta_s,phi_s,R,G,B``), then one comma-separated row
  per sample; angles in radians.
- **CSV / TSV** (``.csv``, ``.tsv``, ``.txt``; a ``.txt`` with a ``VARS`` line is ASTM): a
  header row naming the columns;
  ``theta_i``, ``phi_i``, ``theta_o``, ``phi_o`` (``theta_r``/``theta_s``/``theta_v`` and
  their ``phi`` read as ``_o``), each with its unit, ``theta_i_deg`` or
  ``theta_i_rad``, or one line ``# angles: degrees`` (or radians) before the header;
  the values ``r, g, b`` or one channel ``value`` (also ``brdf``, ``y``), or spectral
  columns named by their wavelength (``450nm``; projected to RGB under D65,
  :mod:`brdffit.io.spectra`); optional ``sigma_r, sigma_g, sigma_b`` or ``sigma``.
  Lines starting with ``#`` are comments.
- **HDF5** (``.h5``, ``.hdf5``): datasets ``theta_i``, ``phi_i``, ``theta_o``, ``phi_o``
  (1-d, an attribute ``units`` of ``degrees`` or ``radians``, on each or on the file, or
  the unit in the name: ``theta_i_deg``), ``rgb`` (n, 3), ``r``, ``g`` and ``b`` (n,)
  each, ``value`` (n,; also ``brdf``, ``y``), as a CSV's columns in any case, or
  ``spectral`` (n, k) with ``wavelengths`` (k,, nm); optional ``sigma`` (n, 3) or (n,), or
  ``sigma_r``, ``sigma_g``, ``sigma_b`` (n,) each.
- **MATLAB** ``.mat`` files: ``-v7.3`` is HDF5 and read as such, its matrices as
  MATLAB holds them (it stores an n x 3 matrix column-major, (3, n) to HDF5); version
  5 and ``-v7`` (``save``'s default) through :mod:`brdffit.io.matlab`, as the same
  variables saved ``-v7.3``. ``save`` writes no attributes, so the angles' names carry
  their unit.
- **NumPy** ``.npz`` archives (``np.savez``): their arrays as the HDF5 datasets of the
  same names (:mod:`brdffit.io.npz`).

A file that is not what its suffix says, or whose content no reader recognises, gets
one line naming the file and what was expected. A list of more samples than
``brdffit.io.measurements.MAX_SAMPLES`` is refused before a number is read (an HDF5
file by its datasets' declared shapes: a few MB compressed may declare GBs).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from brdffit.errors import MerlFormatError
from brdffit.io import matlab, merl, npz, spectra
from brdffit.io.measurements import (
    HORIZON_SLACK,
    Measurements,
    MeasurementsError,
    too_many_samples,
)

#: HDF5's file signature (its first eight bytes).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: Where HDF5's signature may stand: at 0, or after a user block of 512, 1024 or 2048
#: bytes, as MATLAB's ``save -v7.3`` writes its own 512-byte header first (such a
#: .mat file was read as a MERL table, or called not text).
HDF5_OFFSETS = (0, 512, 1024, 2048)
#: The first bytes of a MATLAB -v7.3 .mat file's user block.
MATLAB_73 = b"MATLAB 7.3 MAT-file"
#: UTF-16's byte-order marks (little- and big-endian), as Excel's "Unicode text" starts.
UTF16_MARKS = (b"\xff\xfe", b"\xfe\xff")
#: The most numbers one HDF5 dataset may hold: 10^8 float64 (800 MB), ten million
#: RGB samples with room to spare.
MAX_NUMBERS = 10**8

#: The most bytes read from a stream (a pipe, /dev/stdin), which is copied to a file
#: first: a MERL table is 35 MB, a sample list of ten million rows about 1 GB; an
#: endless one (/dev/zero) was copied until the disk was full.
MAX_STREAM_BYTES = 2 * 2**30
#: Column name -> the canonical name (light ``_i``, view ``_o``).
ANGLE_ALIASES = {
    "theta_i": "theta_i", "phi_i": "phi_i", "theta_in": "theta_i", "phi_in": "phi_i",
    "theta_l": "theta_i", "phi_l": "phi_i",
    "theta_o": "theta_o", "phi_o": "phi_o", "theta_out": "theta_o", "phi_out": "phi_o",
    "theta_r": "theta_o", "phi_r": "phi_o", "theta_s": "theta_o", "phi_s": "phi_o",
    "theta_v": "theta_o", "phi_v": "phi_o",
}
CHANNELS = ("r", "g", "b")
ONE_CHANNEL = ("value", "brdf", "y")
#: Columns that say which channel, wavelength or polarisation a row holds: a file of
#: one row per (direction, channel), a "long" layout. Such a column is not read, so
#: every row was fitted as a grey sample of its direction (a coloured GGX, kd 0.4,
#: 0.15, 0.05, fitted to kd 0.197 in each channel, without a word).
LONG_LAYOUT_COLUMNS = ("channel", "band", "wavelength", "wavelength_nm", "lambda",
                       "lambda_nm", "wl", "nm", "color", "colour", "filter",
                       "polarization", "polarisation", "polarizer", "polariser", "pol")
ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")


def _unit_scale(unit: str, source: str) -> float:
    unit = unit.strip().lower()
    if unit in ("deg", "degree", "degrees"):
        return np.pi / 180.0
    if unit in ("rad", "radian", "radians"):
        return 1.0
    raise MeasurementsError(source, f"unknown angle unit {unit!r}: degrees or radians")


#: A value column's unit written after its name, which is the BRDF's own (1/sr): read
#: as the name alone (``r [1/sr]``, ``brdf (sr^-1)``). Any other unit is not stripped,
#: so that such a column is not read as a BRDF.
_PER_STERADIAN = re.compile(r"[\[(]\s*(?:1\s*/\s*sr|sr\s*\^?\s*-\s*1|sr⁻¹)\s*[\])]")
#: Spelled-out channel names, as some instruments' exports write them.
_CHANNEL_WORDS = {"red": "r", "green": "g", "blue": "b"}


def _value_name(name: str) -> str:
    """A lower-case column name without a per-steradian unit, its channel spelled
    as brdffit's (``Red [1/sr]`` is ``r``)."""
    # from the last bracket on: a pattern searched from the start would try each
    # space of a long run before it (quadratic in the name)
    last = max(name.rfind("["), name.rfind("("))
    if last >= 0 and _PER_STERADIAN.fullmatch(name, last):
        name = name[:last].rstrip()
    return _CHANNEL_WORDS.get(name, name)


def _unit_suffixed(name: str) -> str:
    """An angle column's name with its unit written as a suffix: ``theta_i [deg]``,
    ``theta_i (deg)``, ``theta_i (°)``, ``theta_i deg`` and ``theta_i/rad`` are read as
    ``theta_i_deg`` and ``theta_i_rad``, as lab software and spreadsheets write them.

    Read from the end with string methods, in time linear in the name: one regular
    expression for all four forms could split a run of spaces between its parts in
    cubic many ways (a 16 KB header with a long run of spaces in one name took 110 s
    to read)."""
    name = name.replace("°", "deg").replace("º", "deg")
    for opening, closing in ("[]", "()"):
        if name.endswith(closing):
            head, found, unit = name[:-1].rpartition(opening)
            unit = unit.strip()
            if found and _WORD.fullmatch(unit):
                return f"{head.rstrip()}_{unit}"
            return name
    start = len(name)
    while start > 0 and _WORD.fullmatch(name[start - 1]):
        start -= 1
    unit, before = name[start:], name[:start].rstrip()
    if unit and before.endswith("/"):
        return f"{before[:-1].rstrip()}_{unit}"
    if unit and 0 < start and name[start - 1].isspace():
        return f"{before}_{unit}"
    return name


_WORD = re.compile(r"\w+")


def _columns(names: list[str], source: str, default_unit: str | None) -> dict:
    """Which column holds what: ``{"theta_i": (index, scale), ..., "values": [idx...],
    "sigma": [idx...] or None}``; refuses duplicated, missing or unit-less columns."""
    seen: dict[str, int] = {}
    for k, raw in enumerate(names):
        name = _value_name(raw.strip().lower())
        if not name and k == 0 and len(names) > 1:
            continue  # a row index, as pandas' to_csv and R's write.csv write it: not read
        if not name:
            raise MeasurementsError(source, f"column {k + 1} of the header has no name")
        if name in seen:
            raise MeasurementsError(source, f"column {raw.strip()[:80]!r} appears twice in "
                                            "the header")
        seen[name] = k
    _refuse_long_layout(names, seen, source)
    _unread_uncertainty(seen, names, source)
    out: dict = {}
    for name, k in seen.items():
        m = _angle_name(name)
        if m is None:
            continue
        canonical = ANGLE_ALIASES[f"{m[1]}_{m[2]}"]
        if canonical in out:
            raise MeasurementsError(source, f"two columns give {canonical} "
                                            f"({names[out[canonical][0]].strip()!r} and "
                                            f"{names[k].strip()!r})")
        unit = m[3] or default_unit
        if unit is None:
            raise MeasurementsError(
                source, f"column {names[k].strip()!r} has no unit: name it {canonical}_deg or "
                        f"{canonical}_rad, or put '# angles: degrees' (or radians) before "
                        "the header")
        out[canonical] = (k, _unit_scale(unit, source))
        out.setdefault("names", {})[canonical] = names[k].strip()[:40]
    missing = [a for a in ANGLES if a not in out]
    if missing:
        # in-plane data often leaves the azimuths out, and which side a signed theta is
        # on differs between instruments: asked for, not guessed
        in_plane = ("; in-plane samples still need them: phi_i 0 and phi_o 180 on the "
                    "side opposite the light (the specular side), 0 on the light's side"
                    if set(missing) <= {"phi_i", "phi_o"} else "")
        listed = ", ".join(n.strip() for n in names)
        listed = listed if len(listed) <= 200 else f"{listed[:200]}... ({len(names)} columns)"
        raise MeasurementsError(source, f"no column for {', '.join(missing)} (the header has "
                                        f"{listed}){in_plane}")
    rgb = [seen.get(c) for c in CHANNELS]
    one = [seen[c] for c in ONE_CHANNEL if c in seen]
    spectral = sorted((lam, k) for name, k in seen.items()
                      if (lam := spectra.wavelength_of(name)) is not None)
    if spectral and (all(k is not None for k in rgb) or one):
        raise MeasurementsError(source, "both RGB (or one-channel) and spectral value "
                                        "columns: keep one kind")
    if spectral:
        if any(n.startswith("sigma") for n in seen):
            raise MeasurementsError(source, "sigma of spectral samples is not read yet: drop "
                                            "the sigma columns (or project to RGB with them)")
        out["values"] = [k for _, k in spectral]
        out["wavelengths"] = [lam for lam, _ in spectral]
        out["sigma"] = None
    elif any(k is not None for k in rgb) and one:
        # which of them is the value would be a guess: refused, not dropped
        given = [c for c, k in zip(CHANNELS, rgb, strict=True) if k is not None]
        raise MeasurementsError(
            source, f"value columns of two kinds: {', '.join(given)} (RGB) and "
                    f"{', '.join(c for c in ONE_CHANNEL if c in seen)} (one channel): keep "
                    "r, g, b or one single-channel column")
    elif all(k is not None for k in rgb):
        out["values"] = rgb
        out["sigma"] = _sigma_columns(seen, source, rgb=True)
    elif len(one) == 1:
        if xyz := _cie_xyz(seen):
            # CIE XYZ: y is its luminance, but x and z were dropped unsaid and a coloured
            # material fitted grey
            said = ", ".join(names[seen[n]].strip() for n in xyz)
            raise MeasurementsError(source, f"columns {said}: " + _XYZ_WHY)
        out["values"] = one
        out["sigma"] = _sigma_columns(seen, source, rgb=False)
    else:
        some = [c for c, k in zip(CHANNELS, rgb, strict=True) if k is not None]
        raise MeasurementsError(
            source, "no value columns: r, g, b (RGB), one of value, brdf, y (one channel), "
                    "or spectral ones named by wavelength (450nm, ...)"
                    + (f"; only {', '.join(some)} of r, g, b" if some else "")
                    + ("" if len(one) < 2 else "; more than one single-channel column")
                    + _other_units(seen))
    return out


#: A column of CIE XYZ by its name: ``CIE_X``, ``X (CIE)``, ``xyz_z``.
_CIE_NAME = re.compile(r"(?:cie|xyz)[\s_.-]*[xyz]|[xyz][\s_.-]*[\[(]?cie[\])]?")


def _cie_xyz(names) -> list[str]:
    """Those of the lower-case column or dataset ``names`` that hold CIE XYZ, where
    they do: ``x``, ``y`` and ``z``, or any named as CIE's (``CIE_X`` beside a ``Y``
    read ``Y`` alone as grey); else none."""
    bare = {"x", "y", "z"} & set(names)
    xyz = [n for n in names if n in bare or _CIE_NAME.fullmatch(n)]
    return xyz if len(bare) == 3 or len(xyz) > len(bare) else []


#: Why CIE XYZ values are refused (a CSV's x, y, z columns; HDF5's X, Y, Z datasets).
_XYZ_WHY = ("CIE XYZ? A fit reads linear RGB (r, g, b: Rec. 709 primaries) or one grey "
            "channel: convert XYZ to linear sRGB, or keep y alone (named value) to fit the "
            "luminance")
#: Why a file of one row per (direction, channel) is refused.
_LONG_WHY = ("a file of one row per (direction, channel) is not read (its rows would be "
             "fitted as grey samples of the same directions). Write one row per direction "
             "pair, with r, g, b, or spectral values named by wavelength (450nm, ...)")


def _refuse_long_layout(names: list[str], seen: dict[str, int], source: str) -> None:
    """Refuses a column of :data:`LONG_LAYOUT_COLUMNS` (its name, less a unit:
    ``wavelength [nm]``), which no reader takes."""
    for name, k in seen.items():
        word = re.match(r"[^\s\[(/]+", name)
        if word is None or word[0] not in LONG_LAYOUT_COLUMNS:
            continue
        said = names[k].strip()[:40]
        raise MeasurementsError(
            source, f"column {said!r} says which channel, wavelength or polarisation each "
                    f"row holds: {_LONG_WHY}; if every row has the same {said}, drop the "
                    "column")


def _other_units(seen: dict[str, int]) -> str:
    """Value columns named with a unit that is not a BRDF's (``r [%]``): said, so that a
    reflectance in percent is not taken for a file without values."""
    other = [n for n in seen
             if (m := re.fullmatch(r"(\w+)\s*[\[(].*[\])]", n))
             and _value_name(m[1]) in (*CHANNELS, *ONE_CHANNEL)]
    return (f"; {', '.join(repr(n) for n in other)}: a unit that is not 1/sr (a BRDF's; "
            "a reflectance in % or a radiance is not one)" if other else "")


#: A column of each value's uncertainty by another name than brdffit's ``sigma_r``:
#: ``r_std``, ``std_r``, ``R_err``, ``uncertainty``. It was dropped unsaid, and the fit
#: weighted every sample alike.
_VALUE_WORDS = "|".join((*CHANNELS, *_CHANNEL_WORDS, *ONE_CHANNEL, "rgb"))
_UNCERTAINTY = re.compile(
    rf"(?:(?:{_VALUE_WORDS})[\s_.-]*)?"
    r"(?:std|stdev|stddev|std_dev|sd|se|sem|stderr|std_err|sigma|err|error|unc|uncertainty"
    r"|var|variance|ci|ci95|ci_95|conf)"
    rf"(?:[\s_.-]*(?:{_VALUE_WORDS}))?")


#: What a refused uncertainty column or dataset is told: what sigma is, what to do.
_SIGMA_IS = ("their standard deviation, in 1/sr. Rename it so to weigh the fit by it, or "
             "drop it")


def _unread_uncertainty(seen: dict[str, int], names: list[str], source: str) -> None:
    """Refuses a column of :data:`_UNCERTAINTY` that is not a sigma column read here,
    saying what to name it."""
    for name, k in seen.items():
        if (name in ("sigma", *(f"sigma_{c}" for c in CHANNELS), *CHANNELS, *ONE_CHANNEL)
                or not _UNCERTAINTY.fullmatch(name)):
            continue  # read as sigma or as values, or no uncertainty
        said = names[k].strip()[:40]
        raise MeasurementsError(
            source, f"column {said!r} looks like each value's uncertainty, which is read "
                    f"from columns sigma_r, sigma_g, sigma_b (or one sigma): {_SIGMA_IS}")


def _sigma_columns(seen: dict[str, int], source: str, rgb: bool) -> list[int] | None:
    """The sigma columns' indices: none, one ``sigma`` for every channel, or (RGB
    values) ``sigma_r, sigma_g, sigma_b``. Any other mix is refused: a fit without the
    sigma it was given, or with one channel's for another's, would be silently wrong."""
    per_channel = [f"sigma_{c}" for c in CHANNELS]
    given = [name for name in ("sigma", *per_channel) if name in seen]
    if not given:
        return None
    if given == ["sigma"]:
        return [seen["sigma"]]
    if rgb and given == per_channel:
        return [seen[name] for name in per_channel]
    expected = "sigma, or sigma_r, sigma_g and sigma_b" if rgb else "one column sigma"
    raise MeasurementsError(source, f"sigma columns {', '.join(given)}: expected {expected} "
                                    "(each value's standard deviation, 1/sr)")


def _from_rows(rows: np.ndarray, row_numbers: np.ndarray, cols: dict, source: str,
               provenance: dict) -> Measurements:
    raw = [rows[:, cols[a][0]] for a in ANGLES]
    scales = [cols[a][1] for a in ANGLES]
    _radians_said_to_be_degrees(raw, scales, source)
    provenance.update(azimuths_within(raw, scales))
    angles = [a * scale for a, scale in zip(raw, scales, strict=True)]
    values = rows[:, cols["values"]]
    if "wavelengths" in cols:
        values, provenance["spectral"] = _projected(values, cols["wavelengths"], source,
                                                    row_numbers)
    sigma = None if cols["sigma"] is None else rows[:, cols["sigma"]]
    return Measurements.from_angles(*angles, values[:, 0] if values.shape[1] == 1 else values,
                                    sigma, source=source, provenance=provenance,
                                    rows=row_numbers, names=cols["names"])


#: Fewer samples than this are not judged by :func:`_radians_said_to_be_degrees`.
_JUDGED_FROM = 3


def _radians_said_to_be_degrees(raw: list[np.ndarray], scales: list[float],
                                source: str) -> None:
    """Refuses polar angles in degrees (``scales``) whose numbers all fit radians' range,
    pi/2: read as degrees, the whole list sits within 1.6 degrees of the normal, where
    no lobe can be fitted. The azimuths are not asked: a lab that writes its polar angles
    in radians and its azimuths in degrees had its fit called good, ks 0.0004 for 0.8.
    The other mistake (degrees said to be radians) is refused by the angles' bounds."""
    n = raw[0].size
    if n < _JUDGED_FROM or any(scale == 1.0 for scale in scales[0::2]):
        return
    polar, azimuth = np.abs(np.concatenate(raw[0::2])), np.abs(np.concatenate(raw[1::2]))
    if np.all(polar <= np.pi / 2 + HORIZON_SLACK) and np.max(polar) > 0.2:
        mixed = ("" if np.all(azimuth <= 2 * np.pi + 1e-6) else
                 "; the azimuths reach beyond 2 pi, as degrees do: polar angles in radians "
                 "beside azimuths in degrees?")
        raise MeasurementsError(
            source, f"the angles are said to be in degrees, but all {n} samples' polar "
                    f"angles are within {np.pi / 2:.4f}, radians' range (as degrees, every "
                    f"direction would be within 1.6 degrees of the normal){mixed}. If the "
                    "polar angles are radians, name their columns _rad (theta_i_rad beside "
                    "phi_i_deg is read), or put '# angles: radians' before the header (HDF5: "
                    "a units attribute 'radians')")


#: From this many samples, azimuths are judged by :func:`azimuths_within`.
_AZIMUTHS_JUDGED_FROM = 20


def azimuths_within(raw: list[np.ndarray], scales: list[float]) -> dict:
    """``{"azimuths_within_deg": x}`` where the azimuths are said to be in degrees yet
    all lie within 2 pi, reach beyond pi, and are mostly not whole degrees: radians under
    a degrees header, most likely (every direction then sits within 6.3 degrees of one
    azimuth, and the fit was made without a word). Only noted (the fit's notes), not
    refused: a list measured close to its plane of incidence reads so too."""
    if raw[0].size < _AZIMUTHS_JUDGED_FROM or any(scale == 1.0 for scale in scales[1::2]):
        return {}
    azimuth = np.abs(np.concatenate(raw[1::2]))
    azimuth = azimuth[azimuth != 0]  # phi_i 0, by a common convention, says nothing
    if azimuth.size < _AZIMUTHS_JUDGED_FROM or not np.all(np.isfinite(azimuth)):
        return {}
    largest = float(azimuth.max())
    whole = np.mean(azimuth == np.round(azimuth))
    if largest <= 2 * np.pi + 1e-6 and largest > np.pi and whole < 0.5:
        return {"azimuths_within_deg": largest}
    return {}


def _projected(values: np.ndarray, wavelengths, source: str, row_numbers=None):
    """Spectra (n, k) checked as any value is, then projected to RGB
    (:mod:`brdffit.io.spectra`)."""
    bad = ~np.all(np.isfinite(values), axis=1) | np.any(values < 0, axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        row = first if row_numbers is None else int(row_numbers[first])
        raise MeasurementsError(source, f"a spectral value is negative or not finite in "
                                        f"{int(bad.sum())} rows (first: row {row + 1})")
    return spectra.to_rgb(values, wavelengths, source)


def _decimal_comma(lines: list[tuple[int, str]], delimiter: str | None,
                   used: list[int] | None = None, source: str = "") -> bool:
    """Whether the numbers are written with a decimal comma, as spreadsheets in many
    locales export them (``0,25;0;45;180;0,0937``): cells split by a semicolon or a
    tab, commas in them, and no point anywhere in the columns read, ``used`` (a point
    beside a comma could be a thousands separator: such a file is refused, row by row,
    not guessed at). A date or a sample's name in a column not read (``05.05.2024``)
    had a German export refused."""
    if delimiter not in (";", "\t"):
        return False
    text = _read_cells(lines, delimiter, used, source)
    return any("," in t for t in text) and not any("." in t for t in text)


def _read_cells(lines: list[tuple[int, str]], delimiter: str | None,
                used: list[int] | None, source: str) -> list[str]:
    """Each line's cells in the columns ``used`` (all of each line where None), joined
    by a blank: what :func:`_decimal_comma` judges."""
    if used is None:
        return [line for _, line in lines]
    out = []
    for number, line in lines:
        cells = _cells(line, delimiter, source, number)
        out.append(" ".join(cells[k] for k in used if k < len(cells)))
    return out


def _other_delimiter(line: str, delimiter: str | None, width: int) -> str:
    """Where a row splits into the header's columns by another delimiter than the
    header's (a comma header over semicolon rows, as pasted from two exports): said,
    as a row "of 1 values" left its reader to guess why."""
    said = {",": "commas", ";": "semicolons", "\t": "tabs", None: "spaces"}
    for other in (",", ";", "\t", None):
        if other != delimiter and len(line.split(other)) == width:
            return (f" (this row is split by {said[other]}, the header by "
                    f"{said.get(delimiter, repr(delimiter))}: use one delimiter for both)")
    return ""


def _numbers(lines: list[tuple[int, str]], delimiter: str | None, width: int,
             source: str, comma: bool = False,
             used: list[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The data lines as floats (rows, width), and their line numbers (0-based);
    ``comma``: a decimal comma (:func:`_decimal_comma`); ``used``: the columns read as
    numbers (default all; the others, a sample's name or a note, are NaN)."""
    used = list(range(width)) if used is None else used
    if (why := too_many_samples(len(lines))) is not None:  # before a row is parsed
        raise MeasurementsError(source, why)
    out = np.full((len(lines), width), np.nan)
    for j, (number, line) in enumerate(lines):
        cells = _cells(line, delimiter, source, number)
        if len(cells) > width and not any(c.strip() for c in cells[width:]):
            cells = cells[:width]  # empty cells after the last column, as Excel leaves
        if len(cells) != width:
            raise MeasurementsError(source, f"row {number + 1} has {len(cells)} values, the "
                                            f"header names {width} columns"
                                            + _other_delimiter(line, delimiter, width))
        try:
            read = [cells[k] for k in used]
            # Python's float() also reads 1_0 as 10, and any script's digits (Arabic-
            # Indic "١" as 1): no data file means either
            if any("_" in c or not c.strip().isascii() for c in read):
                raise ValueError
            out[j, used] = [float(c.replace(",", ".") if comma else c) for c in read]
        except ValueError:
            raise MeasurementsError(source, f"row {number + 1} is not all numbers: "
                                            f"{line.strip()[:80]!r}"
                                    + _comma_why(read, lines, delimiter, comma)) from None
    return out, np.array([n for n, _ in lines])


def _comma_why(cells: list[str], lines: list[tuple[int, str]], delimiter: str | None,
               comma: bool) -> str:
    """Why a row with a decimal comma was not read (:func:`_decimal_comma`); "" if its
    cells hold none. The row alone said only that it was not numbers."""
    bad = next((c for c in cells if "," in c), None)
    if bad is None or comma:
        return ""
    if delimiter in (";", "\t"):
        k, point = next(((k, t) for k, t in lines if "." in t), (lines[0][0], lines[0][1]))
        return (f": {bad.strip()!r} has a decimal comma, and row {k + 1} a point "
                f"({point.strip()[:40]!r}); with both, a point may be a thousands "
                "separator, which is not guessed at: write the numbers with one decimal mark")
    split = {",": "commas", None: "blanks"}.get(delimiter, repr(delimiter))
    if re.fullmatch(r"[-+]?\d{1,3}(,\d{3})+(\.\d*)?", bad.strip()):
        # "1,069.548", as a spreadsheet formats a number with digit grouping
        return (f": {bad.strip()!r} has a thousands separator: write the numbers without "
                "one (a spreadsheet's number format with digit grouping writes them so)")
    return (f": {bad.strip()!r} has a decimal comma in a file whose cells are split by "
            f"{split}: split them by semicolons or tabs, or write decimal points")


def _cells(line: str, delimiter: str | None, source: str, number: int) -> list[str]:
    """One line's cells: split at ``delimiter`` (None: at blanks), a quoted cell ("55",
    as spreadsheets and pandas' QUOTE_ALL write it) read as what is inside its quotes.
    Each line is split on its own, so that a stray quote cannot open a cell that
    swallows the lines after it (the file read as one CSV stream did so, and failed
    past 128 KiB with the csv module's "field larger than field limit")."""
    if delimiter is None:
        return line.split()
    if '"' not in line:
        return line.split(delimiter)
    try:
        return next(csv.reader([line], delimiter=delimiter, strict=True))
    except csv.Error:
        raise MeasurementsError(source, f"row {number + 1} has a quote that is not closed "
                                        f"where its cell ends: {line.strip()[:80]!r}") from None


def _lines(text: str) -> list[str]:
    """``text``'s lines, split at CR, LF and CRLF only: ``str.splitlines`` also splits at
    U+2028, form feeds, \\x1c-\\x1e and \\x85, which a comment may hold (its tail was
    read as the header)."""
    return re.split(r"\r\n|\r|\n", text)


def _text(path: Path) -> str:
    """The file as text: UTF-8, or Windows-1252 (Latin-1) where only its comments and
    its header lines hold other characters (``# measured at 25°C``, ``theta_i (°)``,
    ``SAMPLE_NAME Müller``, as Windows lab software writes them); its rows of numbers
    are ASCII either way."""
    data = path.read_bytes()
    refused = MeasurementsError(str(path), "not a text file (not UTF-8): a sample list is "
                                           "text (ASTM, CSV) or HDF5")
    if data.startswith(UTF16_MARKS):
        # UTF-16 with its byte-order mark: Excel's "Unicode text" export
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError:
            raise refused from None
    kind = merl.other_format(data)
    if kind is not None:  # it said "holds NUL bytes: binary, or UTF-16 ..." of a workbook
        hint = (" (an Excel .xlsx workbook? save the sheet as CSV)" if kind == "a zip archive"
                else " (decompress it first)" if kind == "a gzip archive" else "")
        raise MeasurementsError(str(path), f"{kind}, not a text sample list (by its first "
                                           f"bytes){hint}")
    if b"\x00" in data:
        # binary, or UTF-16 without a mark: no text read here holds a NUL (it decoded
        # as UTF-8, and its header was quoted back with a NUL between every letter)
        raise MeasurementsError(str(path), "not a text file (it holds NUL bytes: binary, "
                                           "or UTF-16 without a byte-order mark; save it "
                                           "as UTF-8): a sample list is text (ASTM, CSV) "
                                           "or HDF5")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        pass
    text = data.removeprefix(b"\xef\xbb\xbf").decode("cp1252", errors="replace")
    row = next(((k, line) for k, line in enumerate(_lines(text))
                if not line.isascii() and re.match(r"\s*[-+.\d]", line)), None)
    if row is not None:  # in a row of numbers: not text of a kind read here
        k, line = row
        odd = next(c for c in line if not c.isascii())
        raise MeasurementsError(str(path), f"line {k + 1} is a row of numbers with a "
                                           f"character that is not UTF-8 ({odd!r} as "
                                           f"Windows-1252: {line.strip()[:60]!r}): save the "
                                           "file as UTF-8, or take the character out")
    return text


def _a_number(line: str) -> bool:
    """Whether ``line`` starts with a number as Python reads one, ``nan`` and ``inf``
    too: a data row (a row of NaN before the first numeric one was read as a header
    key, and silently dropped)."""
    try:
        float(re.split(r"[,\s]+", line, maxsplit=1)[0])
    except ValueError:
        return False
    return True


def read_astm(path: str | os.PathLike) -> Measurements:
    """An ASTM E1392 file as Cornell's and ALTA's (module docstring)."""
    return _astm_samples(_text(Path(path)), str(path))


def _astm_samples(text: str, source: str) -> Measurements:
    header: dict[str, str] = {}
    data: list[tuple[int, str]] = []
    for number, line in enumerate(_lines(text)):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if data or re.match(r"^[-+.\d]", stripped) or _a_number(stripped):
            data.append((number, stripped))
            continue
        key, value = (re.split(r"\s+", stripped, maxsplit=1) + [""])[:2]  # a tab too
        key, value = key.upper(), value.strip()
        if key in header and header[key] != value:
            if key not in ("VARS", "NUM_POINTS"):
                # free text (COMMENT, as Cornell's files have several): kept, in order
                header[key] = f"{header[key]}\n{value}"
                continue
            # which one the rows follow would be a guess (a second VARS that swaps two
            # columns within their ranges would be fitted, silently)
            raise MeasurementsError(source, f"{key} is given twice: {header[key]!r} and "
                                            f"{value!r} (line {number + 1}); keep one")
        header[key] = value
    if "VARS" not in header:
        raise MeasurementsError(source, "no VARS line: an ASTM E1392 file names its columns "
                                        "(VARS theta_i,phi_i,theta_s,phi_s,R,G,B)")
    names = [n for n in re.split(r"[,\s]+", header["VARS"]) if n]
    cols = _columns(names, source, default_unit="radians")
    # rows split by commas, as the standard's examples; by blanks where a file has none
    commas = not data or "," in data[0][1]
    rows, numbers = _numbers(data, "," if commas else None, len(names), source)
    _degrees_in_astm(rows, cols, names, source)
    if "NUM_POINTS" in header:
        try:
            promised = int(header["NUM_POINTS"])
        except ValueError:
            raise MeasurementsError(source, f"NUM_POINTS {header['NUM_POINTS']!r} is not "
                                            "a count") from None
        if promised != len(rows):
            raise MeasurementsError(source, f"NUM_POINTS says {promised} rows, the file has "
                                            f"{len(rows)} (truncated?)")
    return _from_rows(rows, numbers, cols, source,
                      {"format": "astm", "columns": names, "angle_unit": "radians",
                       "header": header})


def _degrees_in_astm(rows: np.ndarray, cols: dict, names: list[str], source: str) -> None:
    """Refuses an ASTM file whose angles are degrees (the standard's are radians), said
    as that, with the file's own column names: it read "phi_o is beyond +-720 degrees"
    of a file whose phi_s held 295, or "theta_i is below the horizon" of 30."""
    theta = [rows[:, cols[a][0]] for a in ("theta_i", "theta_o")]
    phi = [rows[:, cols[a][0]] for a in ("phi_i", "phi_o")]
    if not rows.size or not all(np.all(np.isfinite(a)) for a in (*theta, *phi)):
        return
    top = max(float(np.max(np.abs(a))) for a in theta)
    if top <= 2 * np.pi or top > 90.0 + 1e-3:
        # radians (a polar angle past the horizon in radians is refused as such, row by
        # row), or angles of neither unit
        return
    shown = ", ".join(names[cols[a][0]] for a in ANGLES)
    raise MeasurementsError(source, f"an ASTM E1392 file's angles are radians, and {shown} "
                                    f"hold polar angles up to {top:.4g}: degrees? Convert "
                                    "them to radians (or write the list as a CSV, whose "
                                    "columns name their unit: theta_i_deg, ...)")


#: What a units row under the header may hold, cell by cell.
_UNIT_CELL = re.compile(r"(deg|degrees?|rad|radians?|°|1\s*/\s*sr|sr\s*\^?\s*-\s*1|%|"
                        # arbitrary units: read as a row of units, so that the values'
                        # columns are refused as not a BRDF's, not the angles' as unitless
                        r"a\.?\s*u\.?|arb\.?(\s*units?)?|)",
                        re.IGNORECASE)


def _names_a_unit(name: str) -> bool:
    """Whether a column's name already carries its unit (``theta_i_deg``, ``r [1/sr]``)."""
    name = name.strip().lower()
    return bool(re.search(r"[\[(/]|_(deg|rad|degrees|radians)$", name))


def _units_row(row: tuple[int, str] | None, delimiter: str | None, width: int,
               source: str) -> list[str] | None:
    """The cells of a row of units under the header (``deg,deg,deg,deg,1/sr,1/sr,
    1/sr``), brackets dropped; None where the row is not one (a data row)."""
    if row is None:
        return None
    cells = [c.strip().strip("[]()").strip() for c in _cells(row[1], delimiter, source, row[0])]
    if len(cells) != width or not any(cells) or not all(_UNIT_CELL.fullmatch(c) for c in cells):
        return None
    return cells

#: How much of a header line the delimiter is guessed from: ``csv.Sniffer`` takes time
#: quadratic in its text (a one-line JSON file of 517 KB ran for minutes before its
#: refusal); 4 KiB holds a spectral header of 400 wavelengths.
SNIFF_CHARS = 4096


def _delimiter(header: str) -> str:
    """The header line's delimiter: comma, semicolon, tab or blank."""
    try:
        return csv.Sniffer().sniff(header[:SNIFF_CHARS], delimiters=",;\t ").delimiter
    except csv.Error:
        return ","


def _numbers_for_a_header(names: list[str], comments: list[tuple[int, str]],
                          source: str) -> None:
    """Refuses a first row of numbers, saying where its header went: ``np.savetxt``
    writes ``header=`` as a comment (``# theta_i_deg,...``), which is skipped here."""
    try:
        [float(n) for n in names]
    except ValueError:
        return
    named = [(k, c) for k, c in comments if re.search(r"theta|phi", c, re.IGNORECASE)]
    hint = (f"; line {named[-1][0] + 1} looks like one written as a comment "
            f"({named[-1][1][:60]!r}): take away its '#' (numpy's savetxt writes its "
            "header so unless given comments='')" if named else
            ": name the columns on the first line (theta_i_deg, phi_i_deg, theta_o_deg, "
            "phi_o_deg, r, g, b)")
    raise MeasurementsError(source, f"no header: the first row is numbers{hint}")


def _angle_name(name: str) -> re.Match | None:
    """An angle column's name read (``theta_i_deg``, ``Theta_S [rad]``, ``phi_o``):
    groups the angle's name and its unit, if any; None for any other column."""
    # every spelling _unit_scale reads: a units row of "degree" was accepted, then its
    # columns (theta_i [degree]) found no angle
    m = re.fullmatch(r"(theta|phi)_([a-z]+?)(?:_(deg|rad|degrees?|radians?))?",
                     _unit_suffixed(_value_name(name.strip().lower())))
    return m if m is not None and f"{m[1]}_{m[2]}" in ANGLE_ALIASES else None


def _same_units(names: list[str], units: list[str], stated: str | None, source: str) -> None:
    """Refuses two statements of one angle column's unit that disagree: its name's, the
    units row's cell under it, and a ``# angles:`` line (``stated``). Which one the
    numbers are in would be a guess."""
    def words(unit: str | None) -> str | None:
        unit = (unit or "").strip().lower().replace("°", "deg")
        return ("degrees" if unit.startswith("deg") else "radians" if unit.startswith("rad")
                else None)

    for name, cell in zip(names, units, strict=True):
        m = _angle_name(name)
        if m is None:
            continue
        said = {what: u for what, u in (("its name", words(m[3])),
                                        ("the units row", words(cell)),
                                        ("the '# angles:' line", words(stated)))
                if u is not None}
        if len(set(said.values())) > 1:
            told = ", ".join(f"{what} {u}" for what, u in said.items())
            raise MeasurementsError(source, f"column {name.strip()!r}: two units ({told}); "
                                            "keep the one its numbers are in")


def read_csv(path: str | os.PathLike) -> Measurements:
    """A CSV or TSV file with a header row (module docstring); an ASTM file named .csv
    is read as one (its VARS line was refused as a header without theta_i)."""
    return read_text_samples(path)


def _csv_samples(text: str, source: str) -> Measurements:
    unit = unit_line = None
    lines: list[tuple[int, str]] = []
    comments: list[tuple[int, str]] = []  # those before the header
    for number, line in enumerate(_lines(text)):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if not lines:
                comments.append((number, stripped))
            m = re.fullmatch(r"#\s*angles\s*[:=]\s*(\w+)", stripped, re.IGNORECASE)
            if m:
                # refused before any row is read, even where every column has its own
                scale = _unit_scale(m[1], source)
                if unit is not None and scale != _unit_scale(unit, source):
                    raise MeasurementsError(
                        source, f"two angle units: {unit!r} (line {unit_line + 1}) and "
                                f"{m[1]!r} (line {number + 1}); keep the one the angles are in")
                unit, unit_line = m[1], number
            continue
        lines.append((number, stripped))
    if not lines:
        raise MeasurementsError(source, "no header and no data: the file is empty")
    if m := re.fullmatch(r"sep=(.)", lines[0][1]):  # Excel's line naming the delimiter
        delimiter, lines = m[1], lines[1:]
        if not lines:
            raise MeasurementsError(source, "no header and no data after its 'sep=' line")
    else:
        delimiter = _delimiter(lines[0][1])
    split_at = None if delimiter == " " else delimiter  # blanks: any run of them
    names = _cells(lines[0][1], split_at, source, lines[0][0])
    while len(names) > 1 and not names[-1].strip():
        names.pop()  # unnamed columns at the end, as Excel leaves them: empty cells
    # rows of empty cells (",,,,,,", a spreadsheet's formatted but empty rows) are
    # skipped as blank lines are
    lines = [lines[0], *(line for line in lines[1:]
                         if line[1].strip(f"{delimiter} \t"))]
    _numbers_for_a_header(names, comments, source)
    units = _units_row(lines[1] if len(lines) > 1 else None, split_at, len(names), source)
    _same_units(names, units or [""] * len(names), unit, source)
    if units is not None:  # a second header line of units, as instruments export them
        names = [f"{n.strip()} [{u}]" if u and not _names_a_unit(n) else n
                 for n, u in zip(names, units, strict=True)]
        lines = [lines[0], *lines[2:]]
    try:
        cols = _columns(names, source, default_unit=unit)
    except MeasurementsError:
        _header_below(lines, source)
        raise
    # only the columns read are numbers: a column of sample names or notes is left
    used = sorted({cols[a][0] for a in ANGLES} | set(cols["values"]) | set(cols["sigma"] or ()))
    comma = _decimal_comma(lines[1:], delimiter, used, source)
    rows, numbers = _numbers(lines[1:], split_at, len(names), source, comma=comma, used=used)
    return _from_rows(rows, numbers, cols, source,
                      {"format": "csv", "columns": [n.strip() for n in names],
                       "angle_unit": unit or "per column",
                       **({"decimal_comma": True} if comma else {})})


def _header_below(lines: list[tuple[int, str]], source: str) -> None:
    """Refuses a file whose header is not its first line but a later one, before any
    row of numbers: a title or a note above the header (``Measured 2024-05-05``) was
    read as the header, and the message named that line's words as columns."""
    for number, line in lines[1:20]:
        if _a_number(line):
            return
        if len(re.findall(r"\b(?:theta|phi)", line, re.IGNORECASE)) >= 2:
            raise MeasurementsError(
                source, f"line {lines[0][0] + 1} ({lines[0][1][:60]!r}) is read as the "
                        f"header, and line {number + 1} names the columns: make the lines "
                        "above it comments ('# ...') or take them out")


def _hdf5_angles(f, source: str) -> dict[str, tuple[str, str | None]]:
    """Canonical angle -> the file's dataset that holds it and the unit its name says:
    ``theta_i``, any name a CSV column may have (``theta_in``, ``Theta_S``, ...), with
    its unit (``theta_i_deg``: a MATLAB ``save`` writes no attribute); two datasets for
    one angle are refused."""
    named: dict[str, tuple[str, str | None]] = {}
    for key in f.keys():
        m = _angle_name(key)
        if m is None:
            continue
        canonical = ANGLE_ALIASES[f"{m[1]}_{m[2]}"]
        if canonical in named:
            raise MeasurementsError(source, f"two datasets give {canonical} "
                                            f"({named[canonical][0]!r} and {key!r})")
        named[canonical] = (key, m[3])
    return named


def _written_by_matlab(f, path) -> bool:
    """Whether the open HDF5 file ``f`` is a MATLAB -v7.3 .mat file: its user block
    says so, or its datasets carry MATLAB's ``MATLAB_class`` attribute."""
    if f.userblock_size:
        with open(path, "rb") as raw:
            if raw.read(len(MATLAB_73)) == MATLAB_73:
                return True
    return any(d is not None and "MATLAB_class" in d.attrs
               for d in (_opened(f, name) for name in f.keys()))


def read_hdf5(path: str | os.PathLike) -> Measurements:
    """An HDF5 file of sample datasets (module docstring)."""
    import h5py

    source = str(path)
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        with open(path, "rb") as raw:
            head = raw.read(64)
        kind = merl.other_format(head)
        raise MeasurementsError(source, f"{kind}, not HDF5 (by its first bytes)" if kind
                                else f"not a readable HDF5 file ({e})") from None
    with f:
        if not _written_by_matlab(f, path):
            return _hdf5_samples(f, source, False)
        with _in_words("variable"):
            return _hdf5_samples(f, source, True, file_format="mat")


def read_mat(path: str | os.PathLike) -> Measurements:
    """A MATLAB ``.mat`` file: ``-v7.3`` (HDF5, :func:`read_hdf5`) or version 5
    (``save``'s default and ``-v7``: its variables, through :mod:`brdffit.io.matlab`,
    read as the same variables of a ``-v7.3`` file are)."""
    source = str(path)
    with open(path, "rb") as raw:
        head = raw.read(HDF5_OFFSETS[-1] + len(HDF5_SIGNATURE))
    if _hdf5(head):
        return read_hdf5(path)
    if not matlab.is_v5(head):
        kind = merl.other_format(head)
        raise MeasurementsError(source, (f"{kind}, not" if kind else "not") + " a MATLAB "
                                        ".mat file of version 5, 7 or 7.3 (by its first "
                                        "bytes; save's default and -v7.3 are read)")
    return _named_arrays(path, matlab.as_hdf5, matlab=True, file_format="mat")


def read_npz(path: str | os.PathLike) -> Measurements:
    """A NumPy ``.npz`` archive of named arrays (:mod:`brdffit.io.npz`), read as an
    HDF5 file of the same datasets is."""
    if not npz.is_npz(path):
        with open(path, "rb") as raw:
            kind = merl.other_format(raw.read(64))
        raise MeasurementsError(str(path), (f"{kind}, not" if kind else "not") + " a NumPy "
                                           ".npz archive of .npy arrays (by its content)")
    return _named_arrays(path, npz.as_hdf5, matlab=False, file_format="npz")


def _named_arrays(path, as_hdf5: Callable, *, matlab: bool, file_format: str) -> Measurements:
    """The sample list of a file of named arrays (a MATLAB file's variables, an
    archive's arrays) that ``as_hdf5`` gives as an in-memory HDF5 file: what it declares
    weighed first, before a number is read (``before_reading``), then read as HDF5
    datasets are."""
    source = str(path)
    with _in_words("variable" if matlab else "array"), as_hdf5(
            path, source, max_numbers=MAX_NUMBERS, wanted=_read_here,
            before_reading=lambda declared: _declared_angles(declared, source)) as f:
        return _hdf5_samples(f, source, matlab, file_format=file_format)


def _read_here(name: str) -> bool:
    """Whether the sample reader reads a dataset of this name's numbers (an angle, the
    values, their sigma, wavelengths): a file of named arrays reads only these."""
    key = name.strip().lower()
    return (_angle_name(name) is not None
            or any(key in names for names in _VALUE_DATASETS.values()))


#: The HDF5 reader's words, as a MATLAB or NumPy user says them (a -v7.3 file's
#: datasets are its variables): "no dataset theta_i" of a .mat file sent its user
#: looking for HDF5.
_GROUP_SAID = (re.compile(r"\bis an HDF5 group, not a dataset"),
               "is a struct or cell, not a matrix")
_DATASETS, _DATASET = re.compile(r"\bdatasets\b"), re.compile(r"\bdataset\b")


@contextlib.contextmanager
def _in_words(noun: str):
    """Refusals raised within, with ``noun`` (``variable``, ``array``) for dataset."""
    try:
        yield
    except MeasurementsError as e:
        pattern, words = _GROUP_SAID
        problem = _DATASET.sub(noun, _DATASETS.sub(f"{noun}s", pattern.sub(words, e.problem)))
        raise MeasurementsError(e.source, problem) from None


def _hdf5_samples(f, source: str, matlab: bool, file_format: str = "hdf5") -> Measurements:
    """The sample list of the open HDF5 file ``f`` (``matlab``: a MATLAB file's,
    matrices transposed back to MATLAB's rows; ``file_format``: the file's format, as
    ``input.format`` reports it)."""
    named = _declared_angles(f, source)
    raw, scales = [], []
    for canonical in ANGLES:
        name, in_name = named[canonical]
        own, shared = _dataset(f, name, source).attrs.get("units"), f.attrs.get("units")
        if in_name is not None:
            said = _attr_text(own, "units", source)
            if said is not None and _unit_scale(said, source) != _unit_scale(in_name,
                                                                              source):
                raise MeasurementsError(source, f"dataset {name}: two units (its name's "
                                                f"{in_name!r}, its 'units' {said!r})")
            own = in_name
        if own is None and shared is None:
            no_attributes = ("MATLAB's save writes no attributes" if matlab
                             else "an .npz archive holds no attributes"
                             if file_format == "npz" else None)
            raise MeasurementsError(
                source, f"dataset {name} has no unit: name it {canonical}_deg or "
                        f"{canonical}_rad ({no_attributes})" if no_attributes
                else f"dataset {name} has no 'units' attribute (degrees or radians), nor "
                     f"has the file; or name it {canonical}_deg or {canonical}_rad")
        stated = [_attr_text(u, "units", source) for u in (own, shared) if u is not None]
        if own is not None and len(stated) == 2 and not _an_angle_unit(stated[1]):
            stated = stated[:1]  # the file's units are its values' (1/sr), not angles'
        scale = _unit_scale(stated[0], source)
        if len(stated) == 2 and _unit_scale(stated[1], source) != scale:
            # as a CSV's two statements of one column's unit are: which one the
            # numbers are in would be a guess (the dataset's won, unsaid)
            raise MeasurementsError(source, f"dataset {name}: two units (its own 'units' "
                                            f"{stated[0]!r}, the file's {stated[1]!r})")
        raw.append(_one_per_sample(f, name, source, matlab))
        scales.append(scale)
    _radians_said_to_be_degrees(raw, scales, source)
    angles = [a * scale for a, scale in zip(raw, scales, strict=True)]
    provenance = _stored_provenance(f.attrs.get("provenance"), file_format)
    provenance.update(azimuths_within(raw, scales))
    v = _value_names(f, source)
    _refuse_other_layouts(f, v, source)
    channels = [v[c] for c in CHANNELS if c in v]
    kinds = [v[k] for k in ("rgb", "value", "spectral") if k in v] + (
        [", ".join(channels)] if channels else [])
    if len(kinds) > 1:
        raise MeasurementsError(source, f"datasets {' and '.join(kinds)}: values of more "
                                        "than one kind, keep one")
    for name in v.values():
        if name != v.get("wavelengths"):
            _per_steradian(f, name, source)
    if "value" in v and _stored_shape(f, v["value"], matlab)[1:] == (3,):
        v["rgb"] = v.pop("value")  # brdf (n, 3): a MATLAB user's RGB by another name
    if channels:  # r, g and b each a dataset of its own, as a CSV's columns
        if len(channels) < len(CHANNELS):
            raise MeasurementsError(source, f"datasets {', '.join(channels)}: only "
                                            f"{len(channels)} of r, g, b")
        values = np.column_stack([_one_per_sample(f, name, source, matlab)
                                  for name in channels])
    elif "rgb" in v:
        values = _numeric(f, v["rgb"], source, matlab)
        if values.ndim != 2 or values.shape[1] != 3:
            raise MeasurementsError(source, f"{_shape_said(v['rgb'], values, matlab)}, not "
                                            + ("n x 3" if matlab else "(n, 3)")
                                            + _transposed_hint(v["rgb"], values, matlab))
    elif "value" in v:
        values = _one_per_sample(f, v["value"], source, matlab)
    elif "spectral" in v:
        if "wavelengths" not in v:
            raise MeasurementsError(source, f"dataset {v['spectral']} needs a dataset "
                                            "wavelengths (nm)")
        if sigmas := [v[k] for k in _SIGMAS if k in v]:
            raise MeasurementsError(source, f"{', '.join(sigmas)} of spectral samples: not "
                                            "read yet")
        spectral = _numeric(f, v["spectral"], source, matlab)
        wavelengths = _numeric(f, v["wavelengths"], source, matlab)
        if wavelengths.ndim == 2 and 1 in wavelengths.shape:  # a row or a column
            wavelengths = wavelengths.ravel()
        if (spectral.ndim != 2 or wavelengths.ndim != 1
                or spectral.shape[1] != wavelengths.size):
            raise MeasurementsError(
                source, f"dataset {v['spectral']} has shape {spectral.shape} and "
                        f"{v['wavelengths']} {wavelengths.shape}: expected (n, k) and (k,)")
        values, provenance["spectral"] = _projected(spectral, wavelengths, source)
    else:
        raise MeasurementsError(source, "no values: a dataset rgb (n, 3), r, g and b "
                                        "(n,) each, value (n,; also brdf or y), or "
                                        "spectral (n, k) with wavelengths (k,)")
    sigma = _hdf5_sigma(f, v, source, matlab, rgb=values.ndim == 2, n=len(values))
    if provenance.get("channels") == 1 and not (
            values.ndim == 1 or np.all(values == values[:, :1])):
        del provenance["channels"]  # said of grey values: these are coloured
    return Measurements.from_angles(*angles, values, sigma, source=source,
                                    provenance=provenance,
                                    names={a: named[a][0] for a in ANGLES})


#: The datasets of an HDF5 sample list besides its angles: kind -> the names it may have
#: (case does not matter), as a CSV's columns may (``value``, ``brdf``, ``y``).
_VALUE_DATASETS = {"rgb": ("rgb",), "value": ONE_CHANNEL, "spectral": ("spectral",),
                   "sigma": ("sigma",), "wavelengths": ("wavelengths",),
                   **{c: (c, *(w for w, cc in _CHANNEL_WORDS.items() if cc == c))
                      for c in CHANNELS},
                   **{f"sigma_{c}": (f"sigma_{c}",) for c in CHANNELS}}
#: The kinds that are a value's standard deviation, as a CSV's sigma columns.
_SIGMAS = ("sigma", *(f"sigma_{c}" for c in CHANNELS))
#: Those that hold one row per sample.
_PER_SAMPLE = ("rgb", "value", "spectral", *_SIGMAS, *CHANNELS)


def _refuse_other_layouts(f, v: dict[str, str], source: str) -> None:
    """Refuses the HDF5 (MATLAB, .npz) files a CSV of the same columns is refused as:
    CIE XYZ (``X``, ``Y``, ``Z``: Y was read as a grey value and X and Z dropped), and a
    "long" layout, one row per (direction, channel), said by a dataset of
    :data:`LONG_LAYOUT_COLUMNS` or by ``wavelengths`` beside no ``spectral`` (its rows
    were fitted as grey samples of the same directions)."""
    keys = {k.strip().lower(): k for k in f.keys()}
    if "value" in v and (xyz := _cie_xyz(keys)):
        raise MeasurementsError(source, f"datasets {', '.join(keys[n] for n in xyz)}: "
                                        + _XYZ_WHY)
    long = next((k for key, k in keys.items() if re.sub(r"[\s_]*[\[(].*$", "", key)
                 in LONG_LAYOUT_COLUMNS and np.prod(_stored_shape(f, k, False)) > 1), None)
    if long is None and "wavelengths" in v and "spectral" not in v:
        long = v["wavelengths"]
    if long is not None:
        raise MeasurementsError(source, f"dataset {long!r} says which channel, wavelength or "
                                        "polarisation each row holds: " + _LONG_WHY
                                        + f"; if every row has the same {long}, drop it")


def _hdf5_sigma(f, v: dict[str, str], source: str, matlab: bool, rgb: bool,
                n: int) -> np.ndarray | None:
    """The values' standard deviations (``n`` samples): a dataset ``sigma`` ((n, 3) or
    (n,); a MATLAB file's 1 x n too), or
    ``sigma_r``, ``sigma_g``, ``sigma_b`` (n,) each, as a CSV's sigma columns (RGB
    values only), or None. Any other dataset named as an uncertainty (``rgb_std``,
    ``R_err``, ``uncertainty``) is refused, as such a CSV column is: it was dropped
    unsaid, and the fit weighed every sample alike."""
    read = set(v.values())
    for key in f.keys():
        if key not in read and _UNCERTAINTY.fullmatch(key.strip().lower()):
            raise MeasurementsError(
                source, f"dataset {key!r} looks like each value's uncertainty, which is "
                        "read from a dataset sigma ((n, 3) or (n,)) or sigma_r, sigma_g, "
                        f"sigma_b: {_SIGMA_IS}")
    given = [v[k] for k in _SIGMAS if k in v]
    if not given:
        return None
    if given == [v.get("sigma")]:
        sigma = _numeric(f, v["sigma"], source, matlab)
        row = matlab and sigma.shape == (1, n) and n > 1  # a MATLAB row vector, as angles
        return sigma.ravel() if row or (sigma.ndim == 2 and sigma.shape[1] == 1) else sigma
    if rgb and "sigma" not in v and len(given) == len(CHANNELS):
        return np.column_stack([_one_per_sample(f, name, source, matlab) for name in given])
    expected = "sigma, or sigma_r, sigma_g and sigma_b" if rgb else "one dataset sigma"
    raise MeasurementsError(source, f"datasets {', '.join(given)}: expected {expected} "
                                    "(each value's standard deviation, 1/sr)")


def _value_names(f, source: str) -> dict[str, str]:
    """Kind (:data:`_VALUE_DATASETS`) -> the name of the open HDF5 file ``f``'s dataset
    of it (``RGB``, ``BRDF``: a MATLAB variable's case was "no values"); two for one
    kind are refused."""
    out: dict[str, str] = {}
    for key in f.keys():
        kind = next((k for k, names in _VALUE_DATASETS.items()
                     if key.strip().lower() in names), None)
        if kind is None:
            continue
        if kind in out:
            raise MeasurementsError(source, f"two datasets give {kind} ({out[kind]!r} and "
                                            f"{key!r}): keep one")
        out[kind] = key
    return out


def _stored_shape(f, name: str, matlab: bool) -> tuple:
    """Dataset ``name``'s shape as it is read (a MATLAB matrix's transposed), from its
    declaration alone; () where it is no dataset (refused where it is read)."""
    import h5py

    d = _opened(f, name)
    shape = tuple(d.shape or ()) if isinstance(d, h5py.Dataset) else ()
    return shape[::-1] if matlab and len(shape) == 2 else shape


def _opened(f, name: str):
    """Object ``name`` of the open HDF5 file ``f``, or None where it is not opened
    here: an external link (not followed; :func:`_dataset` refuses it) or a link to
    nothing (RuntimeError: a soft link loop; refused where it is read). For a look at
    what a file declares, before or beside its reading."""
    if _external_link(f, name):
        return None
    try:
        return f[name]
    except (KeyError, OSError, RuntimeError):
        return None


def _linked(f, name: str) -> bool:
    """Whether the open HDF5 file ``f`` has a link ``name``, without following it
    (``name in f`` opens what it points to: another file, for an external link)."""
    return f.get(name, getlink=True) is not None


def _external_link(f, name: str) -> bool:
    """Whether link ``name`` of ``f`` points into another file (not followed)."""
    import h5py

    return isinstance(f.get(name, getlink=True), h5py.ExternalLink)


def _declared_samples(f, angles: list[str]) -> int:
    """The most rows any of the open HDF5 file ``f``'s per-sample datasets declares
    (the angle datasets ``angles``, the values, sigma), from their shapes alone: no
    number is read. A group, a link to nothing or a null dataspace counts none (they
    are refused, or read as empty, where they are read)."""
    import h5py

    most = 0
    try:
        values = _value_names(f, "")
    except MeasurementsError:  # two of one kind: refused where they are read
        values = {}
    for name in (*angles, *(values[k] for k in _PER_SAMPLE if k in values)):
        d = _opened(f, name)
        if isinstance(d, h5py.Dataset) and d.shape:
            # any axis: a column-major writer (MATLAB) stores n samples as (3, n)
            most = max(most, max(int(k) for k in d.shape))
    return most


def _declared_angles(f, source: str) -> dict[str, tuple[str, str | None]]:
    """The open HDF5 file ``f``'s angle datasets (:func:`_hdf5_angles`), refused where
    one is missing or where the datasets declare more rows than a sample list may hold
    (``MAX_SAMPLES``), before a number is read: a 2.7 MB gzip-compressed file of 2e7
    rows of one value decompressed to GBs, and ran a fit for minutes."""
    import h5py

    named = _hdf5_angles(f, source)
    missing = [a for a in ANGLES if a not in named]
    if missing:
        # a file that says what it is (a batch's results), or a MATLAB struct of them
        kind = _attr_text(f.attrs.get("format"), "format", source)
        structs = [k for k in f.keys() if isinstance(d := _opened(f, k), h5py.Group)
                   and _attr_text(d.attrs.get("MATLAB_class"), "MATLAB_class", source)
                   == "struct"]
        raise MeasurementsError(
            source, f"no dataset {', '.join(missing)} (the file has "
                    f"{', '.join(f.keys()) or 'none'})"
            + (f": a {kind} file, not a sample list" if isinstance(kind, str) else "")
            + (f"; {structs[0]} is a MATLAB struct: save its fields as variables, "
               f"save('file.mat', '-struct', '{structs[0]}')" if structs else ""))
    if (why := too_many_samples(_declared_samples(f, [named[a][0] for a in ANGLES]))):
        raise MeasurementsError(source, f"its datasets declare {why}")
    return named


def declared_samples(path: str | os.PathLike, name: str | None = None) -> int | None:
    """How many samples an HDF5 sample list declares (its datasets' rows, read from
    their shapes: no number is read), for a caller that weighs a file before reading
    it (the service, what it would store); None for any other layout, or an HDF5 file
    without the four angles (its reader says what is wrong with it)."""
    import h5py

    reader = reader_for(path, name)
    if reader not in (read_hdf5, read_mat, read_npz):
        return None
    # reader_for gives read_mat to a version-5 file alone (a -v7.3 one is read_hdf5's)
    declared = {read_mat: matlab.as_hdf5, read_npz: npz.as_hdf5}.get(reader)
    try:
        with (declared(path, str(path), max_numbers=MAX_NUMBERS, wanted=_read_here,
                       values=False) if declared else h5py.File(path, "r")) as f:
            named = _hdf5_angles(f, str(path))
            if any(a not in named for a in ANGLES):
                return None
            return _declared_samples(f, [named[a][0] for a in ANGLES])
    except (OSError, MeasurementsError):
        return None


#: The formats a sample list brdffit stored (brdffit.io.writers) was read from.
_STORED_FORMATS = ("astm", "csv", "hdf5")


def _stored_provenance(stored, file_format: str) -> dict:
    """What a sample list's file says of where it came from: where brdffit stored it
    (brdffit.io.writers), the provenance it wrote, read from which format; any other
    file's attribute of that name (a lab's own JSON, of its instrument and operator) is
    not brdffit's, and what was read here is said instead: a file's attribute replaced
    the reader's facts (``input.format`` null, a one-channel claim on RGB values)."""
    try:
        said = json.loads(stored)
    except (TypeError, ValueError):
        said = None
    if isinstance(said, dict) and said.get("format") in _STORED_FORMATS:
        return {**said, "stored_as": file_format}
    return {"format": file_format}


def _attr_text(value, what: str, source: str) -> str | None:
    """An HDF5 attribute's text (bytes decoded as UTF-8); None where it is absent. A
    one-element array of text (as some writers store a string) is that text: it read
    as the unit "[b'degrees']"."""
    if value is None:
        return None
    if isinstance(value, np.ndarray) and value.size == 1 and value.dtype.kind in "SUO":
        value = value.ravel()[0]
    if isinstance(value, bytes):
        try:
            return value.decode()
        except UnicodeDecodeError:
            raise MeasurementsError(source, f"attribute {what} is not UTF-8 text "
                                            f"({value[:40]!r})") from None
    return str(value)


def _dataset(f, name: str, source: str):
    """Object ``name`` of the open HDF5 file ``f``; refused, with its name, where it is
    a link to nothing (a soft link whose target is gone, or that points to itself:
    h5py lists such a link and raises when it is opened), and where its values live in
    another file: an external link, external storage or a virtual dataset. A sample
    list is read from its own bytes alone: the service reads uploads, and such a file
    made it read any file on the server (a FIFO there hung the upload)."""
    import h5py

    if _external_link(f, name):
        raise MeasurementsError(source, f"{name} is an external link to another file: a "
                                        "sample list is read from its own file alone")
    try:
        d = f[name]
    except (KeyError, OSError, RuntimeError) as e:
        raise MeasurementsError(source, f"{name} is a link to an object that cannot be "
                                        f"opened ({' '.join(str(e).split())})") from None
    if isinstance(d, h5py.Dataset) and (d.external or d.is_virtual):
        raise MeasurementsError(source, f"dataset {name} keeps its values in other files "
                                        "(external storage or a virtual dataset): a sample "
                                        "list is read from its own file alone")
    return d


def _unpacked(d, a: np.ndarray, name: str, source: str) -> np.ndarray:
    """``a`` with the CF packing of dataset ``d`` applied (``a * scale_factor +
    add_offset``, as netCDF readers do and h5py does not): a uint16 rgb of
    scale_factor 1e-4 was fitted as kd 4000."""
    packing = []
    for key, default in (("scale_factor", 1.0), ("add_offset", 0.0)):
        v = d.attrs.get(key)
        if v is None:
            packing.append(default)
            continue
        v = np.asarray(v, float).ravel()
        if v.size != 1 or not np.isfinite(v[0]):
            raise MeasurementsError(source, f"dataset {name}: {key} {v.tolist()[:3]} is not "
                                            "one finite number")
        packing.append(float(v[0]))
    scale, offset = packing
    return a if (scale, offset) == (1.0, 0.0) else a * scale + offset


def _numeric(f, name: str, source: str, matlab: bool = False) -> np.ndarray:
    """Dataset ``name`` of the open HDF5 file ``f`` as float64; refused, with its
    name, where it is a group or holds no numbers (strings, compounds). A matrix of a
    MATLAB file (``matlab``) is transposed back to MATLAB's own rows: MATLAB writes
    column-major, so its n x 3 matrix is a (3, n) dataset."""
    import h5py

    d = _dataset(f, name, source)
    stored_as = (_attr_text(d.attrs.get("MATLAB_class"), "MATLAB_class", source)
                 if matlab else None)
    if not isinstance(d, h5py.Dataset):
        if matlab and "MATLAB_sparse" in d.attrs:  # -v7.3's sparse matrix: a group
            raise MeasurementsError(source, f"{name} is a sparse matrix: save full({name})")
        raise MeasurementsError(source, f"{name} is an HDF5 group, not a dataset")
    if stored_as == "char":  # -v7.3 stores text as uint16 codes: read, they were numbers
        raise MeasurementsError(source, f"dataset {name} holds text, not numbers")
    if matlab and d.attrs.get("MATLAB_empty"):  # [] is stored as its dimensions
        return np.zeros((0, 0))
    if d.dtype.kind not in "iuf":
        held = ("text" if d.dtype.kind in "SUO" else "complex numbers (a BRDF is real: keep "
                "the real part)" if d.dtype.kind == "c" else "booleans (a mask?)"
                if d.dtype.kind == "b" else d.dtype)
        raise MeasurementsError(source, f"dataset {name} holds {held}, not numbers")
    if (d.size or 0) > MAX_NUMBERS:  # None: a null dataspace, read below as empty
        # the declared shape, before anything is read: a file of a few KB may declare
        # 10^12 numbers never written (it asked numpy for 7 TiB)
        raise MeasurementsError(source, f"dataset {name} holds {d.size:,} numbers (shape "
                                        f"{d.shape}): more than a sample list read here "
                                        f"({MAX_NUMBERS:,}); bin or thin it first")
    try:
        a = _unpacked(d, np.asarray(d, float), name, source)
        return a.T if matlab and a.ndim == 2 else a
    except MemoryError:
        raise MeasurementsError(source, f"dataset {name} ({d.size:,} numbers) does not fit "
                                        "in memory") from None
    except (TypeError, ValueError, OSError) as e:
        raise MeasurementsError(source, f"dataset {name} cannot be read as numbers "
                                        f"({e})") from None


def _an_angle_unit(unit: str | None) -> bool:
    try:
        return unit is not None and _unit_scale(unit, "") > 0
    except MeasurementsError:
        return False


def _per_steradian(f, name: str, source: str) -> None:
    """Refuses a values dataset whose ``units`` attribute is not a BRDF's (1/sr), as a
    CSV's ``r [%]`` is: one in percent was fitted as 1/sr (kd 40), said only by the
    albedo note."""
    unit = _attr_text(_dataset(f, name, source).attrs.get("units"), "units", source)
    if unit is None or _PER_STERADIAN.fullmatch(f"[{unit.strip()}]"):
        return
    raise MeasurementsError(source, f"dataset {name} has units {unit[:40]!r}: a sample list's "
                                    "values are a BRDF, in 1/sr (a reflectance in % or a "
                                    "radiance is not one); convert them, and set its units "
                                    "to 1/sr or drop the attribute")


def _one_per_sample(f, name: str, source: str, matlab: bool = False) -> np.ndarray:
    """Dataset ``name``, one number per sample: (n,), (n, 1) or (1, n) (a column or a
    row, as MATLAB, R or Fortran write a vector). Any other shape is refused with it: a
    (2, 250) angle array flattened would pair one sample's angle with another's
    values, silently."""
    a = _numeric(f, name, source, matlab)
    if a.ndim == 1 or (a.ndim == 2 and 1 in a.shape):
        return a.ravel()
    raise MeasurementsError(source, f"{_shape_said(name, a, matlab)}: expected "
                                    + ("a vector" if matlab else "(n,)")
                                    + ", one number per sample")


def _shape_said(name: str, values: np.ndarray, matlab: bool) -> str:
    """A dataset's shape as its writer knows it: a MATLAB variable's size as MATLAB
    writes it (3 x 50, not the transposed (50, 3) of its HDF5 storage, which read
    "has shape (50, 3), not (n, 3)" of a 3 x 50 matrix)."""
    if not matlab:
        return f"dataset {name} has shape {values.shape}"
    dims = values.shape if values.ndim == 2 else values.shape[::-1]  # see _numeric
    return f"MATLAB variable {name} is {' x '.join(str(k) for k in dims)}"


def _transposed_hint(name: str, values: np.ndarray, matlab: bool) -> str:
    """What to do with RGB values the other way round, 3 x n: a MATLAB matrix of that
    size, or an n x 3 matrix as a column-major writer (Fortran, R, Julia, MATLAB's own
    h5write) stores it, (3, n). Not guessed: a (3, 3) dataset reads either way."""
    if values.ndim != 2 or values.shape[0] != 3:
        return ""
    if matlab:
        return f": save its transpose ({name}')"
    return ("; (3, n) is how a column-major writer (MATLAB's h5write, R, Julia, "
            "Fortran) stores an n x 3 matrix: write its transpose")


def _hdf5(head: bytes) -> bool:
    """Whether a file's first bytes (at least 2,056 of them) are HDF5's: its
    signature at 0 or after a user block (:data:`HDF5_OFFSETS`)."""
    return any(head[k:k + len(HDF5_SIGNATURE)] == HDF5_SIGNATURE for k in HDF5_OFFSETS)


def _container_reader(path: Path, head: bytes) -> Callable | None:
    """The reader of a file whose first bytes (``head``, at least 2,056 of them) say
    it is a container of named arrays, whatever its name: HDF5 (a MATLAB -v7.3 file
    too), a MATLAB version-5 file, an .npz archive; else None."""
    if _hdf5(head):
        return read_hdf5
    if matlab.is_v5(head):
        return read_mat
    if head.startswith(npz.ZIP_MAGIC) and npz.is_npz(path):
        return read_npz
    return None


def _by_content(path: Path) -> Callable:
    with open(path, "rb") as f:
        head = f.read(4096)
    if (reader := _container_reader(path, head)) is not None:
        return reader
    # binary: the MERL reader says what is wrong with it
    return read_text_samples if _looks_like_text(head) else merl.read


def _looks_like_text(head: bytes) -> bool:
    """Whether a file's first bytes are text (UTF-8, Windows-1252, or UTF-16 with its
    mark): no NUL byte, which every MERL table's header holds."""
    return head.startswith(UTF16_MARKS) or b"\x00" not in head


def read_text_samples(path: str | os.PathLike) -> Measurements:
    """A text sample list of either layout: ASTM where it has a VARS or NUM_POINTS
    line, else CSV (``.txt`` is both)."""
    text = _text(Path(path))  # decoded once, for the choice and the reader
    keys = {re.split(r"\s+", line.strip(), maxsplit=1)[0].upper()
            for line in _lines(text) if line.strip()}
    return (_astm_samples if {"VARS", "NUM_POINTS"} & keys else _csv_samples)(text, str(path))


#: suffix -> reader; a MERL table is read as a table.
READERS: dict[str, Callable] = {
    ".binary": merl.read, ".astm": read_astm, ".csv": read_csv, ".tsv": read_csv,
    ".txt": read_text_samples, ".h5": read_hdf5, ".hdf5": read_hdf5, ".mat": read_mat,
    ".npz": read_npz,
}


def reader_for(path: str | os.PathLike, name: str | None = None) -> Callable:
    """The reader of ``path``: by its suffix (``name``'s, where given), else by its
    first bytes."""
    path = Path(path)
    reader = READERS.get(Path(name or path).suffix.lower())
    if reader is None:
        reader = _by_content(path)
    else:
        with open(path, "rb") as f:  # a file named as another layout: read as what it is
            head = f.read(HDF5_OFFSETS[-1] + len(HDF5_SIGNATURE))
        if (container := _container_reader(path, head)) is not None:
            return container
        if head[:merl.HEADER_BYTES] == np.asarray(merl.SHAPE, "<i4").tobytes():
            # a MERL table named .csv
            return merl.read
    return reader


def read_measured(path: str | os.PathLike,
                  name: str | None = None) -> merl.MerlTable | Measurements:
    """A measured file in any layout (module docstring); ``name`` as in
    :func:`read_table`. Raises MerlFormatError (MeasurementsError is one) with one
    line on what is wrong."""
    path = Path(path)
    if path.is_dir():
        raise MerlFormatError(name or str(path), "is a directory, not a measured table")
    try:
        os.stat(path)
    except OSError as e:  # as the MERL reader says it (a symbolic link loop: its words)
        raise MerlFormatError(name or str(path), f"cannot read: {e.strerror}") from None
    if not path.is_file():
        # a pipe (brdffit fit <(zcat t.binary.gz), /dev/stdin) has no size and is read
        # once: copied first, then read as the file it carries (it read as empty)
        import tempfile

        with tempfile.TemporaryDirectory(prefix="brdffit-stream-") as folder:
            copy = Path(folder) / (Path(name or path).name or "stream")
            _copy_stream(path, copy, name or str(path))
            return read_measured(copy, name or str(path))
    reader = reader_for(path, name)
    try:
        got = reader(path)
    except MerlFormatError as e:
        if name is None:
            raise
        raise type(e)(name, e.problem) from None
    if name is not None:
        got = dataclasses.replace(got, source=name)
    return got


def _copy_stream(path: Path, copy: Path, source: str) -> None:
    """The stream at ``path`` copied to the file ``copy``, up to MAX_STREAM_BYTES."""
    left = MAX_STREAM_BYTES
    with open(path, "rb") as stream, open(copy, "wb") as out:
        while chunk := stream.read(min(2**20, left + 1)):
            if len(chunk) > left:
                raise MerlFormatError(source, f"a stream longer than {MAX_STREAM_BYTES:,} "
                                              "bytes: no measured file is that large (save "
                                              "it to a file to see what it holds)")
            out.write(chunk)
            left -= len(chunk)


def read_table(path: str | os.PathLike, name: str | None = None):
    """A measured file as a MERL table: ``(table, input)``; ``input`` is None for a
    MERL file, else :func:`input_summary` of its samples. ``name``: what the file is
    called where ``path`` is a temporary copy (its suffix chooses the reader, and the
    messages and the table name it)."""
    got = read_measured(path, name)
    if isinstance(got, merl.MerlTable):
        return got, None
    table, binning = got.to_table()
    return table, input_summary(got, binning)


def input_summary(samples: Measurements, binning=None) -> dict:
    """What a fit of samples reports of its input (``FitResult.input``): the format,
    the sample count, the channels, whether they have sigma, and where they were
    binned, the binning (``Binning.summary``) and the line that says it."""
    out = {"format": samples.provenance.get("format"), "samples": samples.n,
           "channels": samples.provenance.get("channels", 3),
           "sigma": samples.sigma is not None}
    if "spectral" in samples.provenance:  # projected to RGB: which light, which observer
        out["spectral"] = samples.provenance["spectral"]
    if samples.provenance.get("decimal_comma"):  # read as 0.25 from 0,25: said, not silent
        out["decimal_comma"] = True
    if binning is not None:
        out.update(binning=binning.summary(), note=binning.describe())
    return out


def table_summary(measured: merl.MerlTable | Measurements) -> dict:
    """What a store keeps of a measured file: a table's ``summary()``; a sample list's
    is that of the table it bins into (what the plots draw), with ``input`` saying what
    the binning did."""
    if isinstance(measured, merl.MerlTable):
        return measured.summary()
    table, binning = measured.to_table()
    return {**table.summary(), "input": input_summary(measured, binning)}
