"""Sample lists written as text: ASTM E1392 (``.astm``) and CSV / TSV (``.csv``,
``.tsv``, ``.txt``), their layouts as :mod:`brdffit.io.readers` describes them.

Text as labs and spreadsheets write it: UTF-8, Windows-1252 in comments and headers,
UTF-16 with its mark; a decimal comma under semicolons or tabs; quoted cells, a row of
units under the header, Excel's ``sep=`` line and its empty trailing cells. What is
read as numbers is only the columns a fit reads; every row that is not numbers there
is refused with its line number.
"""

from __future__ import annotations

import contextlib
import csv
import os
import re
from pathlib import Path

import numpy as np

from brdffit.io import long_layout, merl, spectra, workbook
from brdffit.io.columns import (
    ANGLE_ALIASES,
    ANGLES,
    CHANNELS,
    HALF_DIFF,
    IRRADIANCE,
    ONE_CHANNEL,
    POLARISED_WHY,
    RADIANCE,
    RADIANCE_IS,
    SIGMA_IS,
    TWO_LONG,
    UNCERTAINTY,
    XYZ_WHY,
    angle_name,
    azimuths_within,
    cie_xyz,
    half_diff_as_directions,
    half_diff_name,
    long_column_kind,
    polar_unit_checked,
    stated_unit,
    unit_scale,
    value_name,
)
from brdffit.io.measurements import Measurements, MeasurementsError, too_many_samples

#: UTF-16's byte-order marks (little- and big-endian), as Excel's "Unicode text" starts.
UTF16_MARKS = (b"\xff\xfe", b"\xfe\xff")

#: The most columns a header may name: a spectral list of one column per nanometre from
#: 300 to 2,500 nm has 2,200. A 40 MB header of 20 million took 41 s to refuse, column
#: by column, in the service's own process.
MAX_COLUMNS = 10_000


def _columns(names: list[str], source: str, default_unit: str | None) -> dict:
    """Which column holds what: ``{"theta_i": (index, scale), ..., "values": [idx...],
    "sigma": [idx...] or None}``; refuses duplicated, missing or unit-less columns."""
    seen: dict[str, int] = {}
    for k, raw in enumerate(names):
        name = value_name(raw.strip().lower())
        if not name and k == 0 and len(names) > 1:
            continue  # a row index, as pandas' to_csv and R's write.csv write it: not read
        if not name:
            raise MeasurementsError(source, f"column {k + 1} of the header has no name")
        if name in seen:
            raise MeasurementsError(source, f"column {raw.strip()[:80]!r} appears twice in "
                                            "the header")
        seen[name] = k
    long = _long_column(names, seen, source)
    _unread_uncertainty(seen, names, source)
    _unread_irradiance(seen, names, source)
    out: dict = {}
    out.update(_named_angles(seen, names, default_unit, source, _direction_angle))
    if any(a in out for a in ANGLES):
        out["names"] = {a: names[out[a][0]].strip()[:40] for a in ANGLES if a in out}
    missing = [a for a in ANGLES if a not in out]
    # the half and difference angles, where no direction's angle is named
    half = _half_diff_columns(seen, names, default_unit, source) if not out else {}
    if set(HALF_DIFF[:3]) <= set(half):
        out["half_diff"] = half
        out["half_diff_names"] = [names[k].strip()[:40] for k, _ in half.values()]
        out["names"] = {a: f"{a} (of {', '.join(out['half_diff_names'])})" for a in ANGLES}
        missing = []
    if missing:
        # in-plane data often leaves the azimuths out, and which side a signed theta is
        # on differs between instruments: asked for, not guessed
        in_plane = ("; in-plane samples still need them: phi_i 0 and phi_o 180 on the "
                    "side opposite the light (the specular side), 0 on the light's side"
                    if set(missing) <= {"phi_i", "phi_o"} else "")
        if half:  # some of the half and difference angles, not all three
            in_plane = (f"; or theta_h, theta_d and phi_d (the half and difference angles): "
                        f"the file has {', '.join(sorted(half))} of them")
        listed = ", ".join(n.strip() for n in names)
        listed = listed if len(listed) <= 200 else f"{listed[:200]}... ({len(names)} columns)"
        raise MeasurementsError(source, f"no column for {', '.join(missing)} (the header has "
                                        f"{listed}){in_plane}")
    rgb = [seen.get(c) for c in CHANNELS]
    one = [seen[c] for c in ONE_CHANNEL if c in seen]
    spectral = sorted((lam, k) for name, k in seen.items()
                      if (lam := spectra.wavelength_of(name)) is not None)
    if long is not None:
        if len(one) != 1 or any(k is not None for k in rgb) or spectral:
            given = [names[k].strip() for k in (*one, *(k for k in rgb if k is not None),
                                                *(k for _, k in spectral))]
            raise MeasurementsError(
                source, f"column {long[2]!r} says which channel or wavelength each row holds "
                        "(one row per direction and channel, a long layout): each row's value "
                        "is then one column, value (also brdf, y); the file's value columns: "
                        + (", ".join(given[:6]) or "none"))
        out["values"] = one
        out["sigma"] = _sigma_columns(seen, source, rgb=False)
        out["long"] = long
    elif spectral and (all(k is not None for k in rgb) or one):
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
        if xyz := cie_xyz(seen):
            # CIE XYZ: y is its luminance, but x and z were dropped unsaid and a coloured
            # material fitted grey
            said = ", ".join(names[seen[n]].strip() for n in xyz)
            raise MeasurementsError(source, f"columns {said}: " + XYZ_WHY)
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


def _long_column(names: list[str], seen: dict[str, int],
                 source: str) -> tuple[int, str, str] | None:
    """The column that says which channel or wavelength a row holds, where the file has
    one row per (direction, channel) (:mod:`brdffit.io.long_layout`): its index, its kind
    (``"channel"``: its cells name r, g, b or wavelengths; ``"wavelength"``: nm) and its
    name, known by a word of it (:func:`brdffit.io.columns.long_column_kind`); None for a
    wide file. A polarisation column is refused, as are two such columns and wavelengths
    said to be in another unit than nm."""
    found = []
    for name, k in seen.items():
        kind = long_column_kind(name)
        if kind is None:
            continue
        said = names[k].strip()[:40]
        if kind == "polarisation":
            raise MeasurementsError(
                source, f"column {said!r} says which polarisation each row holds: "
                        f"{POLARISED_WHY}, or if every row has the same {said}, drop the "
                        "column")
        if kind == "wavelength":
            long_layout.refuse_other_units(stated_unit(name), f"column {said!r}", source)
        found.append((k, kind, said))
    if len(found) > 1:
        raise MeasurementsError(source, f"columns {found[0][2]!r} and {found[1][2]!r} "
                                        + TWO_LONG)
    return found[0] if found else None


def _other_units(seen: dict[str, int]) -> str:
    """Value columns named with a unit that is not a BRDF's (``r [%]``): said, so that a
    reflectance in percent is not taken for a file without values."""
    other = [n for n in seen
             if (m := re.fullmatch(r"(\w+)\s*[\[(].*[\])]", n))
             and value_name(m[1]) in (*CHANNELS, *ONE_CHANNEL)]
    # in watts or candelas: radiances, which are told what a BRDF is below
    by_power = [n for n in other
                if re.search(rf"[\[(]\s*(?:{_POWER_UNIT})", n, re.IGNORECASE)]
    other = [n for n in other if n not in by_power]
    said = (f"; {', '.join(repr(n) for n in other)}: a unit that is not 1/sr (a BRDF's; "
            "a reflectance in % or a radiance is not one)" if other else "")
    if any(re.search(rf"[\[(]\s*(?:{_DIMENSIONLESS})\s*[\])]", n, re.IGNORECASE) for n in other):
        said += ("; a reflectance factor (BRF) is pi times the BRDF: divide the values by "
                 "pi and give them in 1/sr")
    radiances = [n for n in seen if RADIANCE.fullmatch(n)] + by_power
    if radiances:
        said += f"; {', '.join(repr(n) for n in radiances)}: a radiance, not a BRDF: {RADIANCE_IS}"
    return said


def _unread_irradiance(seen: dict[str, int], names: list[str], source: str) -> None:
    """Refuses a column of :data:`IRRADIANCE` (the light on the sample): the values
    beside it are radiances, which were fitted as a BRDF with the irradiance unsaid.
    Beside values named a BRDF (``brdf``, ``brdf_r``) it is the lab's record, not read."""
    # the header's own words: BRDF R is read as r, and still names a BRDF
    if any(names[k].strip().lower().startswith("brdf") or "brdf" in name
           for name, k in seen.items()):
        return
    for name, k in seen.items():
        if IRRADIANCE.fullmatch(name):
            raise MeasurementsError(
                source, f"column {names[k].strip()[:40]!r} holds the light falling on the "
                        f"sample: are the values radiances? {RADIANCE_IS}")


def _unread_uncertainty(seen: dict[str, int], names: list[str], source: str) -> None:
    """Refuses a column of :data:`UNCERTAINTY` that is not a sigma column read here,
    saying what to name it."""
    for name, k in seen.items():
        if (name in ("sigma", *(f"sigma_{c}" for c in CHANNELS), *CHANNELS, *ONE_CHANNEL)
                or not UNCERTAINTY.fullmatch(name)):
            continue  # read as sigma or as values, or no uncertainty
        said = names[k].strip()[:40]
        raise MeasurementsError(
            source, f"column {said!r} looks like each value's uncertainty, which is read "
                    f"from columns sigma_r, sigma_g, sigma_b (or one sigma): {SIGMA_IS}")


def _direction_angle(name: str) -> tuple[str, str | None] | None:
    m = angle_name(name)
    return None if m is None else (ANGLE_ALIASES[f"{m[1]}_{m[2]}"], m[3])


def _half_diff_angle(name: str) -> tuple[str, str | None] | None:
    m = half_diff_name(name)
    return None if m is None else (m[1], m[2])


def _named_angles(seen: dict[str, int], names: list[str], default_unit: str | None,
                  source: str, read) -> dict[str, tuple[int, float]]:
    """The angle columns ``read`` knows (a lower-case name -> the angle it gives and the
    unit its name says, or None) -> (index, radians per unit), refused where one has no
    unit or two give one angle."""
    found: dict[str, tuple[int, float]] = {}
    for name, k in seen.items():
        if (known := read(name)) is None:
            continue
        angle, unit = known
        if angle in found:
            raise MeasurementsError(source, f"two columns give {angle} "
                                            f"({names[found[angle][0]].strip()!r} and "
                                            f"{names[k].strip()!r})")
        unit = unit or default_unit
        if unit is None:
            raise MeasurementsError(
                source, f"column {names[k].strip()!r} has no unit: name it {angle}_deg or "
                        f"{angle}_rad, or put '# angles: degrees' (or radians) before the "
                        "header")
        found[angle] = (k, unit_scale(unit, source))
    return found


def _half_diff_columns(seen: dict[str, int], names: list[str], default_unit: str | None,
                       source: str) -> dict[str, tuple[int, float]]:
    """The half and difference angles' columns (``theta_h``, ``theta_d``, ``phi_d``,
    optional ``phi_h``: :data:`~brdffit.io.columns.HALF_DIFF`), in that order; empty
    where there are none."""
    found = _named_angles(seen, names, default_unit, source, _half_diff_angle)
    return {h: found[h] for h in HALF_DIFF if h in found}


def angle_columns(cols: dict) -> list[int]:
    """The columns that hold a sample's directions: its four angles, or its half and
    difference angles."""
    if "half_diff" in cols:
        return [k for k, _ in cols["half_diff"].values()]
    return [cols[a][0] for a in ANGLES]


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
               provenance: dict, lines: list[tuple[int, str]] | None = None,
               delimiter: str | None = None) -> Measurements:
    """The samples of the data rows (``rows`` as numbers, ``row_numbers`` their lines);
    ``lines`` and ``delimiter``: the rows as text, where a long layout's channel column
    is read from its cells."""
    if "half_diff" in cols:  # the directions, in radians, of the half and difference angles
        half = cols["half_diff"].values()  # in HALF_DIFF's order
        raw, scales = half_diff_as_directions([rows[:, k] for k, _ in half],
                                              [scale for _, scale in half], source,
                                              row_numbers, cols["half_diff_names"])
        provenance["half_diff"] = cols["half_diff_names"]
    else:
        raw = [rows[:, cols[a][0]] for a in ANGLES]
        scales = [cols[a][1] for a in ANGLES]
    values = rows[:, cols["values"]]
    sigma = None if cols["sigma"] is None else rows[:, cols["sigma"]]
    wavelengths = cols.get("wavelengths")
    if "long" in cols and len(rows):  # one row per (direction, channel): pivoted first
        k, kind, name = cols["long"]
        kind, keys = (("wavelength", rows[:, k]) if kind == "wavelength" else
                      long_layout.channel_keys([_cells(line, delimiter, source, number)[k]
                                                for number, line in lines],
                                               name, source, row_numbers))
        p = long_layout.pivot(raw, scales, keys, kind, name, values[:, 0],
                              None if sigma is None else sigma[:, 0], row_numbers, source,
                              names=cols["names"])
        raw, values, sigma, row_numbers = p.raw, p.values, p.sigma, p.rows
        wavelengths, provenance["long_layout"] = p.wavelengths, p.summary
    polar_unit_checked(raw, scales, source)
    provenance.update(azimuths_within(raw, scales))
    angles = [a * scale for a, scale in zip(raw, scales, strict=True)]
    if wavelengths is not None:
        if sigma is not None:
            raise MeasurementsError(source, "sigma of spectral samples is not read yet: drop "
                                            "the sigma column (or project to RGB with it)")
        values, provenance["spectral"] = spectra.projected(values, wavelengths, source,
                                                           row_numbers)
    return Measurements.from_angles(*angles, values[:, 0] if values.shape[1] == 1 else values,
                                    sigma, source=source, provenance=provenance,
                                    rows=row_numbers, names=cols["names"])


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
    if delimiter == "," and "." not in line and len(line.split(",")) > width:
        # 0,25,30,... : a comma-decimal locale's numbers, split by commas as well
        return (" (decimal commas in a comma-separated file? Separate the cells by ';' or "
                "tabs, or write the numbers with decimal points)")
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
        hint = " (decompress it first)" if kind == "a gzip archive" else ""
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
        if (data or re.match(r"^[-+.\d]", stripped) or _a_number(stripped)
                or _channel_first(header, stripped)):
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
    text_column = cols["long"][0] if cols.get("long", (0, ""))[1] == "channel" else None
    rows, numbers = _numbers(data, "," if commas else None, len(names), source,
                             used=[k for k in range(len(names)) if k != text_column])
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
                       "header": header}, data, "," if commas else None)


def _channel_first(header: dict[str, str], line: str) -> bool:
    """Whether ``line`` is an ASTM data row that starts with its channel: VARS names a
    channel column first (a long layout), and the line's first cell names one (``r``,
    ``450nm``). Its rows were read as header keys ("no data")."""
    names = [n for n in re.split(r"[,\s]+", header.get("VARS", "")) if n]
    if not names or long_column_kind(names[0].lower()) != "channel":
        return False
    cell = re.split(r"[,\s]+", line, maxsplit=1)[0].lower()
    return cell in long_layout.RGB_CELLS or spectra.wavelength_of(cell) is not None


def _degrees_in_astm(rows: np.ndarray, cols: dict, names: list[str], source: str) -> None:
    """Refuses an ASTM file whose angles are degrees (the standard's are radians), said
    as that, with the file's own column names: it read "phi_o is beyond +-720 degrees"
    of a file whose phi_s held 295, or "theta_i is below the horizon" of 30."""
    if "half_diff" in cols:  # theta_h and theta_d are its polar angles
        index = {a: k for a, (k, _) in cols["half_diff"].items()}
        polar, azimuth = ("theta_h", "theta_d"), ("phi_d", "phi_h")
    else:
        index = {a: cols[a][0] for a in ANGLES}
        polar, azimuth = ("theta_i", "theta_o"), ("phi_i", "phi_o")
    theta = [rows[:, index[a]] for a in polar]
    phi = [rows[:, index[a]] for a in azimuth if a in index]
    if not rows.size or not all(np.all(np.isfinite(a)) for a in (*theta, *phi)):
        return
    top = max(float(np.max(np.abs(a))) for a in theta)
    if top <= 2 * np.pi or top > 90.0 + 1e-3:
        # radians (a polar angle past the horizon in radians is refused as such, row by
        # row), or angles of neither unit
        return
    shown = ", ".join(names[k] for k in index.values())
    raise MeasurementsError(source, f"an ASTM E1392 file's angles are radians, and {shown} "
                                    f"hold polar angles up to {top:.4g}: degrees? Convert "
                                    "them to radians (or write the list as a CSV, whose "
                                    "columns name their unit: theta_i_deg, ...)")


#: A unit of power or luminous intensity (``W/(m2 sr)``, ``mW m-2``, ``cd/m2``, ``nits``):
#: a radiance's, not a BRDF's (read case-insensitively).
_POWER_UNIT = r"[mµuk]?w\b.*|cd\s*/.*|nits?\b"

#: A dimensionless value's unit (a reflectance factor, BRF: pi times a BRDF), as a units
#: row or a column's brackets write it.
_DIMENSIONLESS = r"1|brf|rf|reflectance(?:\s+factor)?|unitless|dimensionless"
#: What a units row under the header may hold, cell by cell.
_UNIT_CELL = re.compile(rf"(deg|degrees?|rad|radians?|°|1\s*/\s*sr|sr\s*\^?\s*-\s*1|%|nm|-|"
                        # a reflectance factor's: read as units, so that the values are
                        # refused as not a BRDF's (the angles' units row was not read, and
                        # the message said the angles had none)
                        rf"{_DIMENSIONLESS}|"
                        # arbitrary units: read as a row of units, so that the values'
                        # columns are refused as not a BRDF's, not the angles' as unitless
                        r"a\.?\s*u\.?|arb\.?(\s*units?)?|"
                        # a radiance's or an irradiance's (W/(m2 sr), W m-2, cd/m2, lx):
                        # read as units, so that the values are refused as radiances
                        rf"{_POWER_UNIT}|lx|lux|)",
                        re.IGNORECASE)


def _names_a_unit(name: str) -> bool:
    """Whether a column's name already carries its unit (``theta_i_deg``, ``r [1/sr]``)."""
    name = name.strip().lower()
    return bool(re.search(r"[\[(/]|_(deg|rad|degrees|radians)$", name))


def _unbracketed(cell: str) -> str:
    """``[deg]`` or ``(1/sr)`` as ``deg`` or ``1/sr``; ``W/(m2 sr)`` as it is."""
    cell = cell.strip()
    while len(cell) >= 2 and (cell[0], cell[-1]) in (("[", "]"), ("(", ")")):
        cell = cell[1:-1].strip()
    return cell


def _units_row(row: tuple[int, str] | None, delimiter: str | None, width: int,
               source: str) -> list[str] | None:
    """The cells of a row of units under the header (``deg,deg,deg,deg,1/sr,1/sr,
    1/sr``), brackets dropped; None where the row is not one (a data row)."""
    if row is None:
        return None
    cells = [_unbracketed(c) for c in _cells(row[1], delimiter, source, row[0])]
    if len(cells) != width or not any(cells) or not all(_UNIT_CELL.fullmatch(c) for c in cells):
        return None
    if all(_a_number(c) for c in cells if c):  # a data row of ones ("1" is a unit too)
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


def _same_units(names: list[str], units: list[str], stated: str | None, source: str) -> None:
    """Refuses two statements of one angle column's unit that disagree: its name's, the
    units row's cell under it, and a ``# angles:`` line (``stated``). Which one the
    numbers are in would be a guess."""
    def words(unit: str | None) -> str | None:
        unit = (unit or "").strip().lower().replace("°", "deg")
        return ("degrees" if unit.startswith("deg") else "radians" if unit.startswith("rad")
                else None)

    for name, cell in zip(names, units, strict=True):
        m = angle_name(name)
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


def read_xlsx(path: str | os.PathLike, sheet: str | None = None) -> Measurements:
    """An Excel workbook's first sheet of samples, or the one named ``sheet``, read as the
    CSV it would be saved as (:mod:`brdffit.io.workbook`). A sheet before it that names
    no angle columns (notes, a chart's data) is passed over, and the result says why; a
    sheet that names them is the samples' sheet, and its refusal is the workbook's;
    where no sheet names them, the refusal gives each sheet's reason. A sheet named is
    read or refused: a workbook of two sheets of samples fitted the first, and the
    second could not be reached."""
    source = str(path)
    passed: list[dict] = []
    with contextlib.closing(workbook.sheet_texts(path, source, sheet)) as sheets:
        for name, text, count, hidden in sheets:
            try:
                m = _csv_samples(text, source, delimiter="\t", file_format="xlsx")
            except MeasurementsError as e:
                why = _sheet_problem(path, name, e.problem)
                if _names_angles(text) or sheet is not None:
                    # the samples' own sheet: its refusal is the file's (a row of "n/a" in
                    # it passed it over, and a later sheet's samples were fitted)
                    raise MeasurementsError(source, _of_sheet(name, why, count)) from None
                passed.append({"sheet": name, "why": why})
                continue
            m.provenance.update(sheet=name, sheets=count)
            if hidden:  # no visible sheet holds samples, or this one was named
                m.provenance["sheet_hidden"] = True
            if passed:
                m.provenance["sheets_passed"] = passed
            return m
    if not passed:
        raise MeasurementsError(source, "an Excel workbook whose sheets hold no cells")
    first, others = passed[0], passed[1:]
    problem = _of_sheet(first["sheet"], first["why"], count)
    if others:
        problem += "; " + "; ".join(f"sheet {o['sheet']!r}: {o['why']}" for o in others[:3])
        if len(others) > 3:
            problem += f"; and {len(others) - 3} more sheets that hold no samples"
    raise MeasurementsError(source, problem)


def _of_sheet(name: str, why: str, count: int) -> str:
    """``why``, naming the sheet where the workbook has more than one."""
    return why if count == 1 else f"sheet {name!r}: {why}"


#: A sheet's first lines searched for a header of samples (a title, notes and a units
#: row may stand above it).
HEADER_LINES = 20


def _names_angles(text: str) -> bool:
    """Whether one of a sheet's first lines (tab-separated cells) names two of the
    angle columns: a sheet of samples, whose refusal is the workbook's, where a sheet
    of notes or of a chart's data is passed over."""
    lines = [line for line in text.splitlines() if line.strip()][:HEADER_LINES]
    for line in lines:
        found = {ANGLE_ALIASES[f"{m[1]}_{m[2]}"] for cell in line.split("\t")
                 if (m := angle_name(cell.strip('" '))) is not None}
        found |= {m[1] for cell in line.split("\t")
                  if (m := half_diff_name(cell.strip('" '))) is not None}
        if len(found) >= 2:
            return True
    return False


def _sheet_problem(path, sheet: str, problem: str) -> str:
    """Why ``sheet`` holds no samples: the CSV reader's ``problem``, with the cause where
    it is a formula whose value was never computed."""
    problem = problem.replace("the file holds", "the sheet holds")  # a sheet's, not the file's
    if (cell := workbook.uncomputed_formula(path, sheet)) is None:
        return problem
    return (f"{problem}; cell {cell} holds a formula whose value was never computed (the "
            "workbook was written by a program, not saved by a spreadsheet): open it in "
            "Excel or LibreOffice and save it")


def _csv_samples(text: str, source: str, delimiter: str | None = None,
                 file_format: str = "csv") -> Measurements:
    """A CSV's samples; ``delimiter``: its cells' (None: Excel's ``sep=`` line, else
    guessed from the header). Given as a tab (a sheet's cells), a line keeps its
    leading tabs: its first cells may be empty (a row index's header)."""
    unit = unit_line = None
    lines: list[tuple[int, str]] = []
    comments: list[tuple[int, str]] = []  # those before the header
    for number, line in enumerate(_lines(text)):
        stripped = line.strip(" \r\n") if delimiter == "\t" else line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if not lines:
                comments.append((number, stripped))
            m = re.fullmatch(r"#\s*angles\s*[:=]\s*(\w+)", stripped, re.IGNORECASE)
            if m:
                # refused before any row is read, even where every column has its own
                scale = unit_scale(m[1], source)
                if unit is not None and scale != unit_scale(unit, source):
                    raise MeasurementsError(
                        source, f"two angle units: {unit!r} (line {unit_line + 1}) and "
                                f"{m[1]!r} (line {number + 1}); keep the one the angles are in")
                unit, unit_line = m[1], number
            continue
        lines.append((number, stripped))
    if not lines:
        raise MeasurementsError(source, "no header and no data: the file is empty")
    if delimiter is not None:
        pass
    elif m := re.fullmatch(r"sep=(.)", lines[0][1]):  # Excel's line naming the delimiter
        delimiter, lines = m[1], lines[1:]
        if not lines:
            raise MeasurementsError(source, "no header and no data after its 'sep=' line")
    else:
        delimiter = _delimiter(lines[0][1])
    split_at = None if delimiter == " " else delimiter  # blanks: any run of them
    names = _cells(lines[0][1], split_at, source, lines[0][0])
    while len(names) > 1 and not names[-1].strip():
        names.pop()  # unnamed columns at the end, as Excel leaves them: empty cells
    if len(names) > MAX_COLUMNS:  # before any work per column (~1 s per 500,000)
        raise MeasurementsError(source, f"the header names {len(names):,} columns; a sample "
                                        "list has its angles and values (one per channel "
                                        f"or wavelength): at most {MAX_COLUMNS:,} are read")
    # rows of empty cells (",,,,,,", a spreadsheet's formatted but empty rows) are
    # skipped as blank lines are; those between rows of data are counted, and said (a
    # row whose cells were all cleared was left out unsaid)
    filled = [bool(line[1].strip(f"{delimiter} \t")) for line in lines[1:]]
    last = max((k for k, f in enumerate(filled) if f), default=-1)
    empty_between = sum(1 for k, f in enumerate(filled[:last]) if not f)
    lines = [lines[0], *(line for line, f in zip(lines[1:], filled, strict=True) if f)]
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
    used = sorted(set(angle_columns(cols)) | set(cols["values"]) | set(cols["sigma"] or ())
                  | ({cols["long"][0]} if cols.get("long", (0, ""))[1] == "wavelength" else set()))
    comma = _decimal_comma(lines[1:], delimiter, used, source)
    rows, numbers = _numbers(lines[1:], split_at, len(names), source, comma=comma, used=used)
    return _from_rows(rows, numbers, cols, source,
                      {"format": file_format, "columns": [n.strip() for n in names],
                       "angle_unit": unit or "per column",
                       **({"decimal_comma": True} if comma else {}),
                       **({"empty_rows": empty_between} if empty_between else {})},
                      lines[1:], split_at)


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


def looks_like_text(head: bytes) -> bool:
    """Whether a file's first bytes are text (UTF-8, Windows-1252, or UTF-16 with its
    mark): no NUL byte, which every MERL table's header holds."""
    return head.startswith(UTF16_MARKS) or b"\x00" not in head


def read_text_samples(path: str | os.PathLike) -> Measurements:
    """A text sample list of either layout: ASTM where it has a VARS or NUM_POINTS
    line, else CSV (``.txt`` is both)."""
    text = _text(Path(path))  # decoded once, for the choice and the reader
    if text.lstrip("\ufeff \t\r\n")[:1] in ("{", "["):
        # a fit's JSON given as the measured table (`export --measured fit.json`) read
        # as a CSV: "column 'null]' appears twice in the header"
        raise MeasurementsError(str(path), "a JSON document, not a measured table or a "
                                           "sample list (a fit's result? give the file it "
                                           "was fitted to)")
    keys = {re.split(r"\s+", line.strip(), maxsplit=1)[0].upper()
            for line in _lines(text) if line.strip()}
    return (_astm_samples if {"VARS", "NUM_POINTS"} & keys else _csv_samples)(text, str(path))
