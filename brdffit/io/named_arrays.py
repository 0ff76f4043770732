"""Sample lists held as named arrays: HDF5 (``.h5``, ``.hdf5``), MATLAB ``.mat``
(``-v7.3`` is HDF5; version 5 and ``-v7`` through :mod:`brdffit.io.matlab`) and NumPy
``.npz`` (:mod:`brdffit.io.npz`), their layouts as :mod:`brdffit.io.readers` describes
them.

One reader, :func:`_hdf5_samples`, reads them all: a MATLAB file's variables and an
archive's arrays are first laid out as an in-memory HDF5 file (a MATLAB matrix as
``save -v7.3`` stores it, column-major). A MATLAB or NumPy user is told of variables
and arrays, not datasets. What a file declares is weighed before a number is read
(:func:`declared_samples`): a few MB compressed may declare GBs. A dataset whose values
live in another file (an external link, external storage, a virtual dataset) is
refused: a sample list is read from its own bytes alone.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from brdffit.io import long_layout, matlab, merl, npz, spectra, variables
from brdffit.io.columns import (
    ANGLE_ALIASES,
    ANGLES,
    CHANNEL_WORDS,
    CHANNELS,
    HALF_DIFF,
    IRRADIANCE,
    ONE_CHANNEL,
    PER_STERADIAN,
    POLARISED_WHY,
    RADIANCE_IS,
    SIGMA_IS,
    TWO_LONG,
    UNCERTAINTY,
    XYZ_WHY,
    an_angle_unit,
    angle_name,
    azimuths_within,
    cie_xyz,
    half_diff_as_directions,
    half_diff_name,
    long_column_kind,
    polar_unit_checked,
    stated_unit,
    unit_scale,
)
from brdffit.io.measurements import Measurements, MeasurementsError, too_many_samples

#: HDF5's file signature (its first eight bytes).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: Where HDF5's signature may stand: at 0, or after a user block of 512, 1024 or 2048
#: bytes, as MATLAB's ``save -v7.3`` writes its own 512-byte header first (such a
#: .mat file was read as a MERL table, or called not text).
HDF5_OFFSETS = (0, 512, 1024, 2048)
#: How many of a file's first bytes say whether it is one of the containers read here.
HEAD_BYTES = HDF5_OFFSETS[-1] + len(HDF5_SIGNATURE)
#: The first bytes of a MATLAB -v7.3 .mat file's user block.
MATLAB_73 = b"MATLAB 7.3 MAT-file"
#: The most numbers one HDF5 dataset may hold: 10^8 float64 (800 MB), ten million
#: RGB samples with room to spare.
MAX_NUMBERS = 10**8


def _hdf5_angles(f, source: str) -> dict[str, tuple[str, str | None]]:
    """Canonical angle -> the file's dataset that holds it and the unit its name says:
    ``theta_i``, any name a CSV column may have (``theta_in``, ``Theta_S``, ...), with
    its unit (``theta_i_deg``: a MATLAB ``save`` writes no attribute); two datasets for
    one angle are refused."""
    named: dict[str, tuple[str, str | None]] = {}
    for key in f.keys():
        if (m := angle_name(key)) is not None:
            canonical, unit = ANGLE_ALIASES[f"{m[1]}_{m[2]}"], m[3]
        elif (m := half_diff_name(key)) is not None:  # theta_h, theta_d, phi_d, phi_h
            canonical, unit = m[1], m[2]
        else:
            continue
        if canonical in named:
            raise MeasurementsError(source, f"two datasets give {canonical} "
                                            f"({named[canonical][0]!r} and {key!r})")
        named[canonical] = (key, unit)
    return named


def direction_keys(named: dict) -> tuple[str, ...] | None:
    """Which of ``named``'s angles give the samples' directions: the four angles, or,
    where none of them is named (as a CSV's columns are read), the half and difference
    angles (theta_h, theta_d, phi_d, and phi_h where given); None where neither is
    whole."""
    if all(a in named for a in ANGLES):
        return ANGLES
    if not any(a in named for a in ANGLES) and all(a in named for a in HALF_DIFF[:3]):
        return tuple(a for a in HALF_DIFF if a in named)
    return None


def _written_by_matlab(f, path) -> bool:
    """Whether the open HDF5 file ``f`` is a MATLAB -v7.3 .mat file: its user block
    says so, or its datasets carry MATLAB's ``MATLAB_class`` attribute."""
    if f.userblock_size:
        with open(path, "rb") as raw:
            if raw.read(len(MATLAB_73)) == MATLAB_73:
                return True
    return any(d is not None and "MATLAB_class" in d.attrs
               for d in (_opened(f, name) for name in f.keys()))


def hdf5_unreadable(path: str | os.PathLike, e: OSError) -> str:
    """Why h5py could not open ``path`` (its error ``e``), in words that say what to do:
    another format by its first bytes, a file another program holds open for writing
    (HDF5's lock), a file cut short, or damaged. h5py's own words were "an HDF5 file,
    not HDF5" for the last three: the signature was there, the rest was not read."""
    text = " ".join(str(e).split())
    try:
        with open(path, "rb") as raw:
            head = raw.read(64)
    except OSError:
        head = b""
    kind = merl.other_format(head) or ("a text file" if merl.looks_like_text(head) else None)
    if kind is not None and kind != "an HDF5 file":
        return f"{kind}, not HDF5 (by its first bytes)"
    if isinstance(e, BlockingIOError) or "unable to lock file" in text:
        return ("an HDF5 file another program holds open for writing (HDF5's file lock): "
                "close it there, or set HDF5_USE_FILE_LOCKING=FALSE to read it as it is")
    cut = re.search(r"truncated file: eof = (\d+).*stored_eof = (\d+)", text)
    if cut:
        return (f"a truncated HDF5 file: {int(cut[1]):,} bytes of the {int(cut[2]):,} it "
                "says it holds (a copy cut short, or a writer stopped mid-write): copy or "
                "write it again")
    if kind is None:
        return f"not an HDF5 file, nor one brdffit knows by its first bytes ({text})"
    return f"a damaged HDF5 file, which h5py cannot open ({text})"


def read_hdf5(path: str | os.PathLike) -> Measurements:
    """An HDF5 file of sample datasets (module docstring)."""
    import h5py

    source = str(path)
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise MeasurementsError(source, hdf5_unreadable(path, e)) from None
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
        head = raw.read(HEAD_BYTES)
    if is_hdf5(head):
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
        if npz.zip_members(path) == []:  # np.savez(path) of no arrays: "not an .npz" puzzled
            raise MeasurementsError(str(path), "an empty .npz archive: it holds no arrays "
                                               "(np.savez was given none)")
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
    """Whether the sample reader reads a dataset of this name (an angle, the values,
    their sigma, wavelengths, a long layout's channel): a file of named arrays reads
    only these."""
    key = name.strip().lower()
    return (angle_name(name) is not None or half_diff_name(name) is not None
            or long_column_kind(key) is not None
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
    raw, scales = _raw_angles(f, named, source, matlab, file_format)
    provenance = _stored_provenance(f.attrs.get("provenance"), file_format)
    names = {a: named[a][0] for a in ANGLES if a in named}
    if direction_keys(named) != ANGLES:  # the half and difference angles, as written
        given = [named[a][0] for a in direction_keys(named)]
        raw, scales = half_diff_as_directions(raw, scales, source, names=given)
        provenance["half_diff"] = given
        names = {a: f"{a} (of {', '.join(given)})" for a in ANGLES}
    v = _value_names(f, source)
    long = _long_dataset(f, v, source, len(raw[0]))
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
    if long is not None and (v.keys() & {"rgb", "spectral", *CHANNELS} or "value" not in v):
        given = [v[k] for k in ("value", "rgb", "spectral", *CHANNELS) if k in v]
        raise MeasurementsError(
            source, f"dataset {long[0]!r} says which channel or wavelength each row holds "
                    "(one row per direction and channel, a long layout): each row's value is "
                    "then one dataset, value (also brdf, y), one number per row; the file's "
                    "values: " + (", ".join(given) or "none"))
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
    elif "spectral" in v and long is None:
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
        values, provenance["spectral"] = spectra.projected(spectral, wavelengths, source)
    else:
        raise MeasurementsError(source, "no values: a dataset rgb (n, 3), r, g and b "
                                        "(n,) each, value (n,; also brdf or y), or "
                                        "spectral (n, k) with wavelengths (k,)")
    sigma = _hdf5_sigma(f, v, source, matlab, rgb=values.ndim == 2, n=len(values))
    wavelengths = None
    if long is not None:  # one row per (direction, channel): pivoted first
        raw, values, sigma, wavelengths, provenance["long_layout"] = _pivoted(
            f, long, raw, scales, values, sigma, source, matlab)
    polar_unit_checked(raw, scales, source)
    angles = [a * scale for a, scale in zip(raw, scales, strict=True)]
    provenance.update(azimuths_within(raw, scales))
    if wavelengths is not None:
        if sigma is not None:
            raise MeasurementsError(source, "sigma of spectral samples is not read yet: drop "
                                            "the sigma dataset (or project to RGB with it)")
        values, provenance["spectral"] = spectra.projected(values, wavelengths, source)
    if provenance.get("channels") == 1 and not (
            values.ndim == 1 or np.all(values == values[:, :1])):
        del provenance["channels"]  # said of grey values: these are coloured
    return Measurements.from_angles(*angles, values, sigma, source=source,
                                    provenance=provenance, names=names)


def _raw_angles(f, named: dict, source: str, matlab: bool,
                file_format: str) -> tuple[list[np.ndarray], list[float]]:
    """The angle datasets' numbers as stored (``named``: :func:`_declared_angles`; the
    four angles, or the half and difference angles: :func:`direction_keys`),
    and the radians per unit of each, from its name or its ``units`` attribute (or the
    file's), which must agree where both say it."""
    raw, scales = [], []
    for canonical in direction_keys(named):
        name, in_name = named[canonical]
        own, shared = _dataset(f, name, source).attrs.get("units"), f.attrs.get("units")
        if in_name is not None:
            said = _attr_text(own, "units", source)
            if said is not None and unit_scale(said, source) != unit_scale(in_name,
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
        if own is not None and len(stated) == 2 and not an_angle_unit(stated[1]):
            stated = stated[:1]  # the file's units are its values' (1/sr), not angles'
        scale = unit_scale(stated[0], source)
        if len(stated) == 2 and unit_scale(stated[1], source) != scale:
            # as a CSV's two statements of one column's unit are: which one the
            # numbers are in would be a guess (the dataset's won, unsaid)
            raise MeasurementsError(source, f"dataset {name}: two units (its own 'units' "
                                            f"{stated[0]!r}, the file's {stated[1]!r})")
        raw.append(_one_per_sample(f, name, source, matlab))
        scales.append(scale)
    return raw, scales


#: The datasets of an HDF5 sample list besides its angles: kind -> the names it may have
#: (case does not matter), as a CSV's columns may (``value``, ``brdf``, ``y``).
_VALUE_DATASETS = {"rgb": ("rgb",), "value": ONE_CHANNEL, "spectral": ("spectral",),
                   "sigma": ("sigma",), "wavelengths": ("wavelengths",),
                   **{c: (c, *(w for w, cc in CHANNEL_WORDS.items() if cc == c))
                      for c in CHANNELS},
                   **{f"sigma_{c}": (f"sigma_{c}",) for c in CHANNELS}}
#: The kinds that are a value's standard deviation, as a CSV's sigma columns.
_SIGMAS = ("sigma", *(f"sigma_{c}" for c in CHANNELS))
#: Those that hold one row per sample.
_PER_SAMPLE = ("rgb", "value", "spectral", *_SIGMAS, *CHANNELS)


def _long_dataset(f, v: dict[str, str], source: str, rows: int) -> tuple[str, str] | None:
    """The dataset that says which channel or wavelength each row holds, where the file
    has one row per (direction, channel) (:mod:`brdffit.io.long_layout`), and its kind
    (``"channel"``, ``"wavelength"``); None for a wide file. Such a dataset is named as
    a CSV's column is (:func:`brdffit.io.columns.long_column_kind`), or it is
    ``wavelengths`` beside no ``spectral``. One element so named (a MATLAB workspace's
    ``lambda = 0.1``, an HDF5 group of settings) says nothing of the rows: it is not
    read; nor is one beside values of one row per sample (``rgb``, ``spectral``) that
    does not hold one element per row (``rows``; the RGB's nominal wavelengths, say).
    A polarisation is refused, as are two such datasets (names that differ in
    case too), wavelengths said to be in another unit than nm, and CIE XYZ (``X``,
    ``Y``, ``Z``: Y was read as a grey value and X and Z dropped), as a CSV of the same
    columns is."""
    keys = {k.strip().lower(): k for k in f.keys()}
    if "value" in v and (xyz := cie_xyz(keys)):
        raise MeasurementsError(source, f"datasets {', '.join(keys[n] for n in xyz)}: "
                                        + XYZ_WHY)
    wide = bool(v.keys() & {"rgb", "spectral", *CHANNELS})
    found = []
    for k in f.keys():
        kind = long_column_kind(k.strip().lower())
        elements = None if kind is None else _declared_elements(f, k)
        if (kind is None or elements == 1 or (wide and elements != rows)
                or (k == v.get("wavelengths") and "spectral" in v)):  # a spectrum's grid
            continue
        if kind == "polarisation":
            raise MeasurementsError(
                source, f"dataset {k!r} says which polarisation each row holds: "
                        f"{POLARISED_WHY}, or if every row has the same {k}, drop it")
        found.append((k, kind))
    if len(found) > 1:
        raise MeasurementsError(source, f"datasets {found[0][0]!r} and {found[1][0]!r} "
                                        + TWO_LONG)
    if found and found[0][1] == "wavelength" and (d := _opened(f, found[0][0])) is not None:
        unit = _attr_text(d.attrs.get("units"), "units", source)
        long_layout.refuse_other_units(unit or stated_unit(found[0][0].lower()),
                                       f"dataset {found[0][0]}", source)
    return found[0] if found else None


def _declared_elements(f, name: str) -> int:
    """How many elements object ``name`` of ``f`` declares, from its declaration alone:
    a dataset's size (0 where it is empty or null), a MATLAB struct's, cell's or char
    matrix's from its dimensions (``MATLAB_dims``, as :mod:`brdffit.io.matlab` keeps
    them: a char's characters); 1 for any other group (no column of rows); -1 for what
    cannot be opened here (an external link: refused where it is read)."""
    import h5py

    d = _opened(f, name)  # None for an external link, or a link to nothing
    if d is None:
        return -1
    dims = d.attrs.get("MATLAB_dims")  # a version-5 file's struct, cell or char
    if dims is not None:
        return int(np.prod(dims))
    return int(d.size or 0) if isinstance(d, h5py.Dataset) else 1


def _pivoted(f, long: tuple[str, str], raw: list[np.ndarray], scales: list[float],
             values: np.ndarray, sigma: np.ndarray | None, source: str, matlab: bool):
    """A long layout's rows (:func:`_long_dataset`) pivoted to one per direction pair:
    the angles, values, sigma, wavelengths (None for RGB) and what the pivot did. The
    channel's length is weighed before it is read; each row is checked as a wide list's
    sample is (:func:`brdffit.io.long_layout.pivot`)."""
    name, kind = long
    n = len(values)
    rows = _declared_rows(f, name, source, matlab)
    if rows != n:
        column = (f"; a char row vector is one text: save a column, {name}(:)"
                  if matlab and rows == 1 else "")
        raise MeasurementsError(source, f"dataset {name} holds {rows:,} value(s), not one per "
                                        f"row ({n}): a long layout names each row's {kind}; if "
                                        f"every row has the same one, drop it{column}")
    numbers = np.arange(n)
    if kind == "wavelength":
        keys = _one_per_sample(f, name, source, matlab)
    else:
        kind, keys = long_layout.channel_keys(_texts(f, name, source, matlab), name, source,
                                              numbers, noun="dataset")
    p = long_layout.pivot(raw, scales, keys, kind, name, values, sigma, numbers, source,
                          noun="dataset")
    return p.raw, p.values, p.sigma, p.wavelengths, p.summary


def _declared_rows(f, name: str, source: str, matlab: bool) -> int:
    """How many rows dataset ``name`` gives one element each, from its declared shape
    ((n,), a row or a column; a MATLAB char matrix's rows; 0 where it is empty);
    another shape is refused with it."""
    import h5py

    d = _dataset(f, name, source)
    if not isinstance(d, h5py.Dataset):
        return _declared_elements(f, name)
    shape = _stored_shape(f, name, matlab)
    if matlab and _attr_text(d.attrs.get("MATLAB_class"), "MATLAB_class", source) == "char" \
            and len(shape) == 2:
        return shape[0]  # one text per row of the char matrix
    if d.shape is None or len(shape) <= 1 or 1 in shape:
        return int(d.size or 0)
    raise MeasurementsError(source, f"{_shape_said(name, np.empty(shape), matlab)}: expected "
                                    + ("a vector" if matlab else "(n,)")
                                    + ", one per row")


def _texts(f, name: str, source: str, matlab: bool) -> list[str]:
    """Dataset ``name`` as text, one string per row: strings (h5py's, an .npz's text,
    a MATLAB version-5 char matrix's rows or cell of strings), a MATLAB -v7.3 char
    matrix (stored as UTF-16 codes, one column per row), or numbers (said as written,
    for the refusal of a channel that is a number). Its length is weighed before
    (:func:`_declared_rows`)."""
    import h5py

    d = _dataset(f, name, source)
    if not isinstance(d, h5py.Dataset):
        raise MeasurementsError(source, f"{name} is an HDF5 group, not a dataset"
                                + (f": save it as a char matrix, char({name})" if matlab
                                   else ""))
    cls = _attr_text(d.attrs.get("MATLAB_class"), "MATLAB_class", source) if matlab else None
    if cls == "cell" and h5py.check_string_dtype(d.dtype) is None:
        # -v7.3 stores a cell as references to its elements (a version-5 file's cell of
        # strings is read as text: brdffit.io.matlab)
        raise MeasurementsError(source, f"{name} is a cell array: save it as a char matrix, "
                                        f"char({name})")
    if d.shape is None:
        return []
    if cls == "char" and d.dtype.kind in "iu":
        codes = np.atleast_2d(np.asarray(d))  # (characters, rows), column-major
        return ["".join(map(chr, column)).rstrip("\x00 ") for column in codes.T]
    if d.dtype.kind in "iuf":
        return [f"{x:g}" for x in _one_per_sample(f, name, source, matlab)]
    try:
        return [str(t) for t in np.ravel(d.asstr()[()])]
    except UnicodeDecodeError:
        raise MeasurementsError(source, f"dataset {name} holds text that is not UTF-8") from None
    except (TypeError, ValueError):  # references, numbers of variable length, ...
        raise MeasurementsError(source, f"dataset {name} holds neither text nor numbers "
                                        f"({d.dtype})") from None


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
        if (key not in read and IRRADIANCE.fullmatch(key.strip().lower())
                and not any(str(k).lower().startswith("brdf") for k in read)):
            # the unread datasets are looked at here: an irradiance too (columns.IRRADIANCE)
            raise MeasurementsError(
                source, f"dataset {key!r} holds the light falling on the sample: are the "
                        f"values radiances? {RADIANCE_IS}")
        if key not in read and UNCERTAINTY.fullmatch(key.strip().lower()):
            raise MeasurementsError(
                source, f"dataset {key!r} looks like each value's uncertainty, which is "
                        "read from a dataset sigma ((n, 3) or (n,)) or sigma_r, sigma_g, "
                        f"sigma_b: {SIGMA_IS}")
    given = [v[k] for k in _SIGMAS if k in v]
    if not given:
        return None
    if given == [v.get("sigma")]:
        sigma = _numeric(f, v["sigma"], source, matlab)
        if sigma.size == 0 and n > 0:  # MATLAB's sigma = [], an empty array: none given
            return None
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
    if direction_keys(named) is None:
        # a file that says what it is (a batch's results), or a MATLAB struct of them
        kind = _attr_text(f.attrs.get("format"), "format", source)
        structs = [k for k in f.keys() if isinstance(d := _opened(f, k), h5py.Group)
                   and _attr_text(d.attrs.get("MATLAB_class"), "MATLAB_class", source)
                   == "struct"]
        half = [a for a in HALF_DIFF[:3] if a in named]
        raise MeasurementsError(
            source, f"no dataset {', '.join(missing)} (the file has "
                    f"{', '.join(f.keys()) or 'none'})"
            + (f": a {kind} file, not a sample list" if isinstance(kind, str) else "")
            + (f"; or theta_h, theta_d and phi_d (the half and difference angles): it has "
               f"{', '.join(half)} of them" if half else "")
            + (f"; {structs[0]} is a MATLAB struct: save its fields as variables, "
               f"save('file.mat', '-struct', '{structs[0]}')" if structs else ""))
    if (why := too_many_samples(_declared_samples(
            f, [named[a][0] for a in direction_keys(named)]))):
        raise MeasurementsError(source, f"its datasets declare {why}")
    return named


def declared_samples(path: str | os.PathLike, reader: Callable) -> int | None:
    """How many samples an HDF5 sample list declares (its datasets' rows, read from
    their shapes: no number is read), for a caller that weighs a file before reading
    it (the service, what it would store; ``reader``: the file's, as
    ``brdffit.io.readers.reader_for`` chose it); None for a file no reader here reads,
    or one without the four angles (its reader says what is wrong with it)."""
    import h5py

    if reader not in (read_hdf5, read_mat, read_npz):
        return None
    # reader_for gives read_mat to a version-5 file alone (a -v7.3 one is read_hdf5's)
    declared = {read_mat: matlab.as_hdf5, read_npz: npz.as_hdf5}.get(reader)
    try:
        with (declared(path, str(path), max_numbers=MAX_NUMBERS, wanted=_read_here,
                       values=False) if declared else h5py.File(path, "r")) as f:
            named = _hdf5_angles(f, str(path))
            if (keys := direction_keys(named)) is None:
                return None
            return _declared_samples(f, [named[a][0] for a in keys])
    except (OSError, MeasurementsError):
        return None


#: The formats a sample list brdffit stored (brdffit.io.writers) was read from: every
#: format brdffit reads samples in (an Excel sheet or a MATLAB file uploaded to the
#: service, stored as HDF5, read back as "hdf5": its sheet and layout were lost).
_STORED_FORMATS = ("astm", "csv", "hdf5", "mat", "npz", "xlsx")


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
    if isinstance(said, dict) and said.get("format") in _STORED_FORMATS and _shaped(said):
        return {**said, "stored_as": file_format}
    return {"format": file_format}


def _is(value, kind) -> bool:
    """``isinstance``, where a bool is no int (True is one to Python, not to a JSON key)."""
    return isinstance(value, kind) and (kind is bool) == isinstance(value, bool)


def _shaped(said: dict) -> bool:
    """Whether every key of ``said`` that brdffit reads back has the type brdffit writes
    (a lab's JSON that names ``format`` "csv" and ``sheets`` "3" is not brdffit's: the
    CLI's first line compared "3" with 1, a traceback)."""
    def texts(d, *keys):
        return isinstance(d, dict) and all(_is(d.get(k), str) for k in keys)

    checks = {
        "sheet": lambda v: _is(v, str),
        "sheets": lambda v: _is(v, int) and v >= 1,
        "sheets_passed": lambda v: isinstance(v, list) and all(texts(p, "sheet", "why")
                                                                for p in v),
        "long_layout": lambda v: texts(v, "column", "per_sample") and _is(v.get("rows"), int),
        "decimal_comma": lambda v: _is(v, bool),
        "channels": lambda v: _is(v, int),
        "spectral": lambda v: isinstance(v, dict),
        "azimuths_within_deg": lambda v: _is(v, int | float),
    }
    if ("sheet" in said) != ("sheets" in said):
        return False
    return all(check(said[key]) for key, check in checks.items() if key in said)


def _attr_text(value, what: str, source: str) -> str | None:
    """An HDF5 attribute's text (bytes decoded as UTF-8); None where it is absent. A
    one-element array of text (as some writers store a string) is that text: it read
    as the unit "[b'degrees']"."""
    if value is None:
        return None
    if isinstance(value, np.ndarray) and value.size == 1 and value.dtype.kind in "SUO":
        value = value.ravel()[0]
    if isinstance(value, str):
        try:
            value.encode()
        except UnicodeEncodeError:
            # h5py gives a variable-length string's bytes that are no UTF-8 as lone
            # surrogates (b'\xff' as '\udcff'): its bytes again, refused as such below
            value = value.encode(errors="surrogateescape")
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
        if key == "scale_factor" and v[0] == 0:  # every value 0: "brightest 0" said later
            raise MeasurementsError(source, f"dataset {name}: scale_factor 0 makes every "
                                            "value 0 (CF packing: value * scale_factor + "
                                            "add_offset)")
        packing.append(float(v[0]))
    scale, offset = packing
    # CF's marks of a value not measured, compared as stored (before the packing):
    # 999 rows were fitted as data (kd 3.1 for 0.2), and -9999 refused as "negative".
    # Refused by name, as a CSV's "n/a" cell is: which samples to leave out is the
    # measurer's to say
    for key in ("_FillValue", "missing_value"):
        v = d.attrs.get(key)
        if v is None:
            continue
        try:
            marks = np.asarray(v, float).ravel()
        except (TypeError, ValueError):
            raise MeasurementsError(source, f"dataset {name}: {key} {v!r} is not a number"
                                    ) from None
        for mark in marks[np.isfinite(marks)]:
            n = int(np.count_nonzero(a == mark))
            if n:
                raise MeasurementsError(
                    source, f"dataset {name}: {n:,} value{'s are' if n != 1 else ' is'} its "
                            f"{key} ({mark:g}), the mark of a value not measured: leave "
                            "those samples out of the file before fitting")
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
    if d.shape is None:  # HDF5's null dataspace (h5py.Empty): h5py refuses to read it
        raise MeasurementsError(source, f"dataset {name} is empty (an HDF5 null dataspace): "
                                        "it holds no values")
    if h5py.check_vlen_dtype(d.dtype) is not None and h5py.check_string_dtype(d.dtype) is None:
        raise MeasurementsError(source, f"dataset {name} holds a variable-length array per "
                                        "row (a ragged list): write it as one (n,) or (n, 3) "
                                        "array of numbers")
    if (held := variables.not_numbers(d.dtype)) is not None:
        raise MeasurementsError(source, f"dataset {name} holds {held}, not numbers")
    if (d.size or 0) > MAX_NUMBERS:
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
    except MeasurementsError:
        raise
    except (TypeError, ValueError, OSError) as e:
        raise MeasurementsError(source, f"dataset {name} cannot be read as numbers "
                                        f"({e})") from None


def _per_steradian(f, name: str, source: str) -> None:
    """Refuses a values dataset whose ``units`` attribute is not a BRDF's (1/sr), as a
    CSV's ``r [%]`` is: one in percent was fitted as 1/sr (kd 40), said only by the
    albedo note."""
    unit = _attr_text(_dataset(f, name, source).attrs.get("units"), "units", source)
    if unit is None or PER_STERADIAN.fullmatch(f"[{unit.strip()}]"):
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


def is_hdf5(head: bytes) -> bool:
    """Whether a file's first bytes (at least :data:`HEAD_BYTES` of them) are HDF5's: its
    signature at 0 or after a user block (:data:`HDF5_OFFSETS`)."""
    return any(head[k:k + len(HDF5_SIGNATURE)] == HDF5_SIGNATURE for k in HDF5_OFFSETS)


def container_reader(path: Path, head: bytes) -> Callable | None:
    """The reader of a file whose first bytes (``head``, at least :data:`HEAD_BYTES`) say
    it is a container of named arrays, whatever its name: HDF5 (a MATLAB -v7.3 file
    too), a MATLAB version-5 file, an .npz archive; else None."""
    if is_hdf5(head):
        return read_hdf5
    if matlab.is_v5(head):
        return read_mat
    if head.startswith(npz.ZIP_MAGIC) and npz.is_npz(path):
        return read_npz
    return None
