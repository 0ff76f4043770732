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
- **CSV / TSV** (``.csv``, ``.tsv``, ``.txt``): a header row naming the columns;
  ``theta_i``, ``phi_i``, ``theta_o``, ``phi_o`` (``theta_r``/``theta_s``/``theta_v`` and
  their ``phi`` read as ``_o``), each with its unit, ``theta_i_deg`` or
  ``theta_i_rad``, or one line ``# angles: degrees`` (or radians) before the header;
  the values ``r, g, b`` or one channel ``value`` (also ``brdf``, ``y``), or spectral
  columns named by their wavelength (``450nm``; projected to RGB under D65,
  :mod:`brdffit.io.spectra`); optional ``sigma_r, sigma_g, sigma_b`` or ``sigma``.
  Lines starting with ``#`` are comments.
- **HDF5** (``.h5``, ``.hdf5``): datasets ``theta_i``, ``phi_i``, ``theta_o``, ``phi_o``
  (1-d, an attribute ``units`` of ``degrees`` or ``radians``, on each or on the file),
  ``rgb`` (n, 3), ``value`` (n,) or ``spectral`` (n, k) with ``wavelengths`` (k,, nm),
  optional ``sigma`` (n, 3) or (n,).

A file that is not what its suffix says, or whose content no reader recognises, gets
one line naming the file and what was expected.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from brdffit.errors import MerlFormatError
from brdffit.io import merl, spectra
from brdffit.io.measurements import Measurements, MeasurementsError

#: HDF5's file signature (its first eight bytes).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
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
_PER_STERADIAN = re.compile(r"\s*[\[(]\s*(?:1\s*/\s*sr|sr\s*\^?\s*-\s*1|sr⁻¹)\s*[\])]$")
#: Spelled-out channel names, as some instruments' exports write them.
_CHANNEL_WORDS = {"red": "r", "green": "g", "blue": "b"}


def _value_name(name: str) -> str:
    """A lower-case column name without a per-steradian unit, its channel spelled
    as brdffit's (``Red [1/sr]`` is ``r``)."""
    name = _PER_STERADIAN.sub("", name)
    return _CHANNEL_WORDS.get(name, name)


def _unit_suffixed(name: str) -> str:
    """An angle column's name with its unit written as a suffix: ``theta_i [deg]``,
    ``theta_i (deg)``, ``theta_i (°)``, ``theta_i deg`` and ``theta_i/rad`` are read as
    ``theta_i_deg`` and ``theta_i_rad``, as lab software and spreadsheets write them."""
    name = name.replace("°", "deg").replace("º", "deg")
    m = re.fullmatch(r"(.*?)\s*(?:\[\s*(\w+)\s*\]|\(\s*(\w+)\s*\)|/\s*(\w+)|\s+(\w+))",
                     name)
    if m is None:
        return name
    unit = next(u for u in m.groups()[1:] if u is not None)
    return f"{m[1]}_{unit}"


def _columns(names: list[str], source: str, default_unit: str | None) -> dict:
    """Which column holds what: ``{"theta_i": (index, scale), ..., "values": [idx...],
    "sigma": [idx...] or None}``; refuses duplicated, missing or unit-less columns."""
    seen: dict[str, int] = {}
    for k, raw in enumerate(names):
        name = _value_name(raw.strip().lower())
        if not name:
            raise MeasurementsError(source, f"column {k + 1} of the header has no name")
        if name in seen:
            raise MeasurementsError(source, f"column {raw.strip()!r} appears twice in the header")
        seen[name] = k
    out: dict = {}
    for name, k in seen.items():
        m = re.fullmatch(r"(theta|phi)_([a-z]+?)(?:_(deg|rad|degrees|radians))?",
                         _unit_suffixed(name))
        if m is None or f"{m[1]}_{m[2]}" not in ANGLE_ALIASES:
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
    missing = [a for a in ANGLES if a not in out]
    if missing:
        # in-plane data often leaves the azimuths out, and which side a signed theta is
        # on differs between instruments: asked for, not guessed
        in_plane = ("; in-plane samples still need them: phi_i 0 and phi_o 180 on the "
                    "side opposite the light (the specular side), 0 on the light's side"
                    if set(missing) <= {"phi_i", "phi_o"} else "")
        raise MeasurementsError(source, f"no column for {', '.join(missing)} (the header has "
                                        f"{', '.join(n.strip() for n in names)}){in_plane}")
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


def _other_units(seen: dict[str, int]) -> str:
    """Value columns named with a unit that is not a BRDF's (``r [%]``): said, so that a
    reflectance in percent is not taken for a file without values."""
    other = [n for n in seen
             if (m := re.fullmatch(r"(\w+)\s*[\[(].*[\])]", n))
             and _value_name(m[1]) in (*CHANNELS, *ONE_CHANNEL)]
    return (f"; {', '.join(repr(n) for n in other)}: a unit that is not 1/sr (a BRDF's; "
            "a reflectance in % or a radiance is not one)" if other else "")


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
    angles = [rows[:, cols[a][0]] * cols[a][1] for a in ANGLES]
    values = rows[:, cols["values"]]
    if "wavelengths" in cols:
        values, provenance["spectral"] = _projected(values, cols["wavelengths"], source,
                                                    row_numbers)
    sigma = None if cols["sigma"] is None else rows[:, cols["sigma"]]
    return Measurements.from_angles(*angles, values[:, 0] if values.shape[1] == 1 else values,
                                    sigma, source=source, provenance=provenance,
                                    rows=row_numbers)


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


def _decimal_comma(lines: list[tuple[int, str]], delimiter: str | None) -> bool:
    """Whether the numbers are written with a decimal comma, as spreadsheets in many
    locales export them (``0,25;0;45;180;0,0937``): cells split by a semicolon or a
    tab, commas in them, and no point anywhere (a point beside a comma could be a
    thousands separator: such a file is refused, row by row, not guessed at)."""
    if delimiter not in (";", "\t"):
        return False
    text = [line for _, line in lines]
    return any("," in t for t in text) and not any("." in t for t in text)


def _numbers(lines: list[tuple[int, str]], delimiter: str | None, width: int,
             source: str, comma: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The data lines as floats (rows, width), and their line numbers (0-based);
    ``comma``: a decimal comma (:func:`_decimal_comma`)."""
    out = np.empty((len(lines), width))
    # split as CSV is: a quoted cell ("55", as spreadsheets and pandas' QUOTE_ALL write
    # it) is the number inside the quotes
    rows = (csv.reader((line for _, line in lines), delimiter=delimiter) if delimiter
            else (line.split() for _, line in lines))
    for j, ((number, line), cells) in enumerate(zip(lines, rows, strict=True)):
        if len(cells) != width:
            raise MeasurementsError(source, f"row {number + 1} has {len(cells)} values, the "
                                            f"header names {width} columns")
        try:
            # Python's float() also reads 1_0 as 10: no data file means that
            if "_" in line:
                raise ValueError
            out[j] = [float(c.replace(",", ".") if comma else c) for c in cells]
        except ValueError:
            raise MeasurementsError(source, f"row {number + 1} is not all numbers: "
                                            f"{line.strip()[:80]!r}") from None
    return out, np.array([n for n, _ in lines])


def _text(path: Path) -> str:
    """The file as text: UTF-8, or Windows-1252 (Latin-1) where only its comments and
    its header lines hold other characters (``# measured at 25°C``, ``theta_i (°)``,
    ``SAMPLE_NAME Müller``, as Windows lab software writes them); its rows of numbers
    are ASCII either way."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        pass
    refused = MeasurementsError(str(path), "not a text file (not UTF-8): a sample list is "
                                           "text (ASTM, CSV) or HDF5")
    if b"\x00" in data:
        raise refused  # binary
    text = data.decode("cp1252", errors="replace")
    if any(not line.isascii() and re.match(r"\s*[-+.\d]", line) for line in text.splitlines()):
        raise refused  # in a row of numbers: not text of a kind read here
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
    path = Path(path)
    source = str(path)
    header: dict[str, str] = {}
    data: list[tuple[int, str]] = []
    for number, line in enumerate(_text(path).splitlines()):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if data or re.match(r"^[-+.\d]", stripped) or _a_number(stripped):
            data.append((number, stripped))
            continue
        key, value = (re.split(r"\s+", stripped, maxsplit=1) + [""])[:2]  # a tab too
        header[key.upper()] = value.strip()
    if "VARS" not in header:
        raise MeasurementsError(source, "no VARS line: an ASTM E1392 file names its columns "
                                        "(VARS theta_i,phi_i,theta_s,phi_s,R,G,B)")
    names = [n for n in re.split(r"[,\s]+", header["VARS"]) if n]
    cols = _columns(names, source, default_unit="radians")
    # rows split by commas, as the standard's examples; by blanks where a file has none
    commas = not data or "," in data[0][1]
    rows, numbers = _numbers(data, "," if commas else None, len(names), source)
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


#: What a units row under the header may hold, cell by cell.
_UNIT_CELL = re.compile(r"(deg|degrees?|rad|radians?|°|1\s*/\s*sr|sr\s*\^?\s*-\s*1|%|)",
                        re.IGNORECASE)


def _names_a_unit(name: str) -> bool:
    """Whether a column's name already carries its unit (``theta_i_deg``, ``r [1/sr]``)."""
    name = name.strip().lower()
    return bool(re.search(r"[\[(/]|_(deg|rad|degrees|radians)$", name))


def _units_row(line: str, delimiter: str, width: int) -> list[str] | None:
    """The cells of a row of units under the header (``deg,deg,deg,deg,1/sr,1/sr,
    1/sr``), brackets dropped; None where the row is not one (a data row)."""
    if not line:
        return None
    cells = (next(csv.reader(io.StringIO(line), delimiter=delimiter)) if delimiter != " "
             else line.split())
    cells = [c.strip().strip("[]()").strip() for c in cells]
    if len(cells) != width or not any(cells) or not all(_UNIT_CELL.fullmatch(c) for c in cells):
        return None
    return cells


def read_csv(path: str | os.PathLike) -> Measurements:
    """A CSV or TSV file with a header row (module docstring)."""
    path = Path(path)
    source = str(path)
    text = _text(path)
    unit = unit_line = None
    lines = []
    for number, line in enumerate(text.splitlines()):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
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
    try:
        dialect = csv.Sniffer().sniff(lines[0][1], delimiters=",;\t ")
        delimiter = dialect.delimiter
    except csv.Error:
        delimiter = ","
    names = next(csv.reader(io.StringIO(lines[0][1]), delimiter=delimiter))
    if delimiter == " ":
        names = [n for n in names if n]
    units = _units_row(lines[1][1] if len(lines) > 1 else "", delimiter, len(names))
    if units is not None:  # a second header line of units, as instruments export them
        names = [f"{n.strip()} [{u}]" if u and not _names_a_unit(n) else n
                 for n, u in zip(names, units, strict=True)]
        lines = [lines[0], *lines[2:]]
    cols = _columns(names, source, default_unit=unit)
    comma = _decimal_comma(lines[1:], delimiter)
    rows, numbers = _numbers(lines[1:], None if delimiter == " " else delimiter, len(names),
                             source, comma=comma)
    return _from_rows(rows, numbers, cols, source,
                      {"format": "csv", "columns": [n.strip() for n in names],
                       "angle_unit": unit or "per column",
                       **({"decimal_comma": True} if comma else {})})


def _hdf5_angles(f, source: str) -> dict[str, str]:
    """Canonical angle -> the file's dataset that holds it: ``theta_i``, or any name a
    CSV column may have (``theta_in``, ``Theta_S``, ...); two datasets for one angle
    are refused."""
    named: dict[str, str] = {}
    for key in f.keys():
        canonical = ANGLE_ALIASES.get(key.strip().lower())
        if canonical is None:
            continue
        if canonical in named:
            raise MeasurementsError(source, f"two datasets give {canonical} ({named[canonical]!r}"
                                            f" and {key!r})")
        named[canonical] = key
    return named


def read_hdf5(path: str | os.PathLike) -> Measurements:
    """An HDF5 file of sample datasets (module docstring)."""
    import h5py

    source = str(path)
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise MeasurementsError(source, f"not a readable HDF5 file ({e})") from None
    with f:
        named = _hdf5_angles(f, source)
        missing = [a for a in ANGLES if a not in named]
        if missing:
            kind = f.attrs.get("format")  # a file that says what it is (a batch's results)
            kind = kind.decode() if isinstance(kind, bytes) else kind
            raise MeasurementsError(source, f"no dataset {', '.join(missing)} (the file has "
                                            f"{', '.join(f.keys()) or 'none'})"
                                    + (f": a {kind} file, not a sample list"
                                       if isinstance(kind, str) else ""))
        angles = []
        for canonical in ANGLES:
            name = named[canonical]
            unit = f[name].attrs.get("units", f.attrs.get("units"))
            if unit is None:
                raise MeasurementsError(source, f"dataset {name} has no 'units' attribute "
                                                "(degrees or radians), nor has the file")
            unit = unit.decode() if isinstance(unit, bytes) else str(unit)
            angles.append(_one_per_sample(f, name, source) * _unit_scale(unit, source))
        provenance: dict = {"format": "hdf5"}
        stored = f.attrs.get("provenance")
        if stored is not None:  # a list brdffit wrote (brdffit.io.writers): what it was
            try:
                provenance = {**json.loads(stored), "stored_as": "hdf5"}
            except (TypeError, ValueError):
                pass  # not ours after all: an HDF5 file like any other
        kinds = [k for k in ("rgb", "value", "spectral") if k in f]
        if len(kinds) > 1:
            raise MeasurementsError(source, f"datasets {' and '.join(kinds)}: values of more "
                                            "than one kind, keep one")
        if "rgb" in f:
            values = _numeric(f, "rgb", source)
            if values.ndim != 2 or values.shape[1] != 3:
                raise MeasurementsError(source, f"dataset rgb has shape {values.shape}, "
                                                "not (n, 3)")
        elif "value" in f:
            values = _one_per_sample(f, "value", source)
        elif "spectral" in f:
            if "wavelengths" not in f:
                raise MeasurementsError(source, "dataset spectral needs a dataset wavelengths "
                                                "(nm)")
            if "sigma" in f:
                raise MeasurementsError(source, "sigma of spectral samples is not read yet")
            spectral = _numeric(f, "spectral", source)
            wavelengths = _numeric(f, "wavelengths", source)
            if (spectral.ndim != 2 or wavelengths.ndim != 1
                    or spectral.shape[1] != wavelengths.size):
                raise MeasurementsError(
                    source, f"dataset spectral has shape {spectral.shape} and wavelengths "
                            f"{wavelengths.shape}: expected (n, k) and (k,)")
            values, provenance["spectral"] = _projected(spectral, wavelengths, source)
        else:
            raise MeasurementsError(source, "no values: a dataset rgb (n, 3), value (n,), or "
                                            "spectral (n, k) with wavelengths (k,)")
        sigma = _numeric(f, "sigma", source) if "sigma" in f else None
    return Measurements.from_angles(*angles, values, sigma, source=source,
                                    provenance=provenance)


def _numeric(f, name: str, source: str) -> np.ndarray:
    """Dataset ``name`` of the open HDF5 file ``f`` as float64; refused, with its
    name, where it is a group or holds no numbers (strings, compounds)."""
    import h5py

    d = f[name]
    if not isinstance(d, h5py.Dataset):
        raise MeasurementsError(source, f"{name} is an HDF5 group, not a dataset")
    if d.dtype.kind not in "iuf":
        raise MeasurementsError(source, f"dataset {name} holds {d.dtype}, not numbers")
    try:
        return np.asarray(d, float)
    except (TypeError, ValueError, OSError) as e:
        raise MeasurementsError(source, f"dataset {name} cannot be read as numbers "
                                        f"({e})") from None


def _one_per_sample(f, name: str, source: str) -> np.ndarray:
    """Dataset ``name``, one number per sample: (n,), or (n, 1). Any other shape is
    refused with it: a (2, 250) angle array flattened would pair one sample's angle
    with another's values, silently."""
    a = _numeric(f, name, source)
    if a.ndim == 1 or (a.ndim == 2 and a.shape[1] == 1):
        return a.ravel()
    raise MeasurementsError(source, f"dataset {name} has shape {a.shape}: expected (n,), one "
                                    "number per sample")


#: suffix -> reader; a MERL table is read as a table.
READERS: dict[str, Callable] = {
    ".binary": merl.read, ".astm": read_astm, ".csv": read_csv, ".tsv": read_csv,
    ".txt": read_csv, ".h5": read_hdf5, ".hdf5": read_hdf5,
}


def _by_content(path: Path) -> Callable:
    with open(path, "rb") as f:
        head = f.read(4096)
    if head.startswith(HDF5_SIGNATURE):
        return read_hdf5
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError:
        return merl.read  # binary: the MERL reader says what is wrong with it
    keys = {line.split(" ", 1)[0].upper() for line in text.splitlines() if line.strip()}
    return read_astm if {"VARS", "NUM_POINTS"} & keys else read_csv


def reader_for(path: str | os.PathLike, name: str | None = None) -> Callable:
    """The reader of ``path``: by its suffix (``name``'s, where given), else by its
    first bytes."""
    path = Path(path)
    reader = READERS.get(Path(name or path).suffix.lower())
    if reader is None:
        reader = _by_content(path)
    elif reader is merl.read:
        with open(path, "rb") as f:  # a sample list named .binary: read as what it is
            head = f.read(8)
        if head.startswith(HDF5_SIGNATURE):
            return read_hdf5
    return reader


def read_measured(path: str | os.PathLike,
                  name: str | None = None) -> merl.MerlTable | Measurements:
    """A measured file in any layout (module docstring); ``name`` as in
    :func:`read_table`. Raises MerlFormatError (MeasurementsError is one) with one
    line on what is wrong."""
    path = Path(path)
    if path.is_dir():
        raise MerlFormatError(name or str(path), "is a directory, not a measured table")
    if not path.exists():  # as the MERL reader says it
        raise MerlFormatError(name or str(path), "cannot read: No such file or directory")
    if not path.is_file():
        # a pipe (brdffit fit <(zcat t.binary.gz), /dev/stdin) has no size and is read
        # once: copied whole first, then read as the file it carries (it read as empty)
        import shutil
        import tempfile

        with tempfile.TemporaryDirectory(prefix="brdffit-stream-") as folder:
            copy = Path(folder) / (Path(name or path).name or "stream")
            with open(path, "rb") as stream, open(copy, "wb") as out:
                shutil.copyfileobj(stream, out)
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
