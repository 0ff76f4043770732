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
- **Excel** workbooks (``.xlsx``, ``.xlsm``): the first sheet that reads as samples,
  read as the CSV it would be saved as (:mod:`brdffit.io.workbook`).
- In every sample layout, one row per (direction pair, channel) too, a "long" layout: a
  ``channel`` column (``r``, ``g``, ``b``, or ``450nm``) or a ``wavelength`` one (nm) beside
  one ``value``, pivoted to one sample per pair (:mod:`brdffit.io.long_layout`).

A file that is not what its suffix says, or whose content no reader recognises, gets
one line naming the file and what was expected. A list of more samples than
``brdffit.io.measurements.MAX_SAMPLES`` is refused before a number is read (an HDF5
file by its datasets' declared shapes: a few MB compressed may declare GBs).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from brdffit.errors import MerlFormatError
from brdffit.io import merl, named_arrays, npz, text_samples, workbook
from brdffit.io.measurements import Measurements, MeasurementsError
from brdffit.io.named_arrays import read_hdf5, read_mat, read_npz
from brdffit.io.text_samples import read_astm, read_csv, read_text_samples, read_xlsx

#: The most bytes read from a stream (a pipe, /dev/stdin), which is copied to a file
#: first: a MERL table is 35 MB, a sample list of ten million rows about 1 GB; an
#: endless one (/dev/zero) was copied until the disk was full.
MAX_STREAM_BYTES = 2 * 2**30


def _container(path: Path, head: bytes) -> Callable | None:
    """The reader of a file whose first bytes (``head``) say it is a container, whatever
    its name: of named arrays (HDF5, MATLAB, .npz) or an Excel workbook; else None."""
    if (reader := named_arrays.container_reader(path, head)) is not None:
        return reader
    if head.startswith(npz.ZIP_MAGIC) and workbook.is_xlsx(path):
        return read_xlsx
    return None


def _by_content(path: Path) -> Callable:
    with open(path, "rb") as f:
        head = f.read(4096)
    if (reader := _container(path, head)) is not None:
        return reader
    # binary: the MERL reader says what is wrong with it
    return read_text_samples if text_samples.looks_like_text(head) else merl.read


#: suffix -> reader; a MERL table is read as a table.
READERS: dict[str, Callable] = {
    ".binary": merl.read, ".astm": read_astm, ".csv": read_csv, ".tsv": read_csv,
    ".txt": read_text_samples, ".h5": read_hdf5, ".hdf5": read_hdf5, ".mat": read_mat,
    ".npz": read_npz, ".xlsx": read_xlsx, ".xlsm": read_xlsx,
}


#: The readers of containers (by their first bytes, :func:`_container`): a file named
#: as one that is text is read as text. Not a .mat: MATLAB's ``save -ascii`` writes
#: text under that name, which its reader names as such.
CONTAINER_READERS = (read_hdf5, read_npz, read_xlsx)


def reader_for(path: str | os.PathLike, name: str | None = None) -> Callable:
    """The reader of ``path``: by its suffix (``name``'s, where given), else by its
    first bytes."""
    path = Path(path)
    reader = READERS.get(Path(name or path).suffix.lower())
    if reader is None:
        reader = _by_content(path)
    else:
        with open(path, "rb") as f:  # a file named as another layout: read as what it is
            head = f.read(named_arrays.HEAD_BYTES)
        if (container := _container(path, head)) is not None:
            return container
        is_merl = head[:merl.HEADER_BYTES] == np.asarray(merl.SHAPE, "<i4").tobytes()
        if reader is read_npz and not is_merl:
            if head and not head.startswith(npz.ZIP_MAGIC) and text_samples.looks_like_text(
                    head):
                return _text_named_npz
            # "a zip archive, not a text sample list", of a zip cut short: an .npz is one
            why = npz.not_npz(path, head)
            return read_npz if why is None else functools.partial(_not_npz, why=why)
        if reader in CONTAINER_READERS and text_samples.looks_like_text(head):
            # a CSV saved as .xlsx: "not a readable Excel workbook (File is not a zip
            # file)"; read as the text it is, as any layout named as another is
            return read_text_samples
        if is_merl:  # a MERL table named .csv
            return merl.read
    return reader


def _not_npz(path: str | os.PathLike, why: str) -> Measurements:
    raise MeasurementsError(str(path), f"{npz.NOT_NPZ}: {why}")


def _text_named_npz(path: str | os.PathLike) -> Measurements:
    """A text file named .npz: the sample list it is (a CSV saved under that name), or
    refused as the .npz it is not: "garbage" was refused as a CSV ("no column for
    theta_i ... (the header has garbage)"), of a file its user took for an .npz."""
    try:
        return read_text_samples(path)
    except MeasurementsError as e:
        raise MeasurementsError(str(path), f"{npz.NOT_NPZ}: text, not a zip archive (nor a "
                                           f"sample list: {e.problem})") from None


def read_measured(path: str | os.PathLike, name: str | None = None,
                  sheet: str | None = None) -> merl.MerlTable | Measurements:
    """A measured file in any layout (module docstring); ``name`` as in
    :func:`read_table`; ``sheet``: an Excel workbook's sheet to read (else its first
    sheet of samples), refused for any other file. Raises MerlFormatError
    (MeasurementsError is one) with one line on what is wrong."""
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
            return read_measured(copy, name or str(path), sheet)
    reader = reader_for(path, name)
    if sheet is not None and reader is not read_xlsx:
        raise MeasurementsError(name or str(path), f"a sheet was named ({sheet!r}), and "
                                                   "this is no Excel workbook: only a "
                                                   "workbook has sheets")
    try:
        got = reader(path) if sheet is None else reader(path, sheet=sheet)
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


def declared_samples(path: str | os.PathLike, name: str | None = None) -> int | None:
    """How many samples a file of named arrays (HDF5, MATLAB, .npz) declares, from its
    datasets' shapes alone (:func:`brdffit.io.named_arrays.declared_samples`): for a
    caller that weighs a file before reading it. None for any other layout."""
    return named_arrays.declared_samples(path, reader_for(path, name))


def read_table(path: str | os.PathLike, name: str | None = None, sheet: str | None = None):
    """A measured file as a MERL table: ``(table, input)``; ``input`` is None for a
    MERL file, else :func:`input_summary` of its samples. ``name``: what the file is
    called where ``path`` is a temporary copy (its suffix chooses the reader, and the
    messages and the table name it); ``sheet`` as in :func:`read_measured`."""
    got = read_measured(path, name, sheet)
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
    if samples.provenance.get("empty_rows"):  # rows of empty cells among the data, skipped
        out["empty_rows"] = samples.provenance["empty_rows"]
    if "half_diff" in samples.provenance:  # directions given by their half/difference angles
        out["half_diff"] = samples.provenance["half_diff"]
    if "long_layout" in samples.provenance:  # one row per (direction, channel), pivoted
        out["long_layout"] = samples.provenance["long_layout"]
    if "sheet" in samples.provenance:  # an Excel workbook's: which sheet, of how many
        out.update(sheet=samples.provenance["sheet"], sheets=samples.provenance["sheets"])
        if samples.provenance.get("sheet_hidden"):  # a hidden sheet's samples: said
            out["sheet_hidden"] = True
        if "sheets_passed" in samples.provenance:  # the sheets before it, and why
            out["sheets_passed"] = samples.provenance["sheets_passed"]
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
