"""Tables in the service's store: validated once, stored by content, shared by the
upload route (``/v1/tables``) and the shipped materials (``/v1/materials``)."""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from pathlib import Path

from api.store import Store, TableRecord
from brdffit import heap
from brdffit.io import readers
from brdffit.io.measurements import Measurements
from brdffit.io.writers import hdf5_bytes, write_hdf5


class StoredTooLarge(Exception):
    """A sample list whose stored layout (brdffit's HDF5, float64, uncompressed) would
    be over the upload cap: the routes answer 413 with this message."""


def _stored_fits(name: str, samples: int, sigma: bool, cap: int | None) -> None:
    """Refuses a sample list of ``samples`` rows whose stored HDF5 would be over
    ``cap`` bytes: the cap holds for what is kept, not only for the body (a 597 KB
    gzip-compressed upload was stored as 224 MB)."""
    stored = hdf5_bytes(samples, sigma)
    if cap is not None and stored > cap:
        raise StoredTooLarge(
            f"{name}: {samples:,} samples are stored as {stored:,} bytes (brdffit's HDF5 "
            f"layout, float64, uncompressed), over the server's cap of {cap:,} bytes "
            f"(BRDFFIT_MAX_UPLOAD_BYTES): upload at most {cap // hdf5_bytes(1, sigma):,} "
            "samples (thin the list, or bin it onto the MERL grid)")


def sheet_id(digest: str, sheet: str) -> str:
    """The id of a workbook's sheet named on upload: the sha256 of the file's sha256 (hex)
    and the sheet's name, so that each sheet of one file is a table of its own, and the
    same file and sheet always get the same id (without a sheet, the id is the file's)."""
    return hashlib.sha256(f"{digest}\x00sheet\x00{sheet}".encode()).hexdigest()


#: One file read and validated at a time in this process (the front), an upload's or a
#: material's: a sample list's parse holds ~12x its size (three 26 MB CSVs at once took
#: it from 72 MB to 823 MB). A MERL table's takes ~50 ms; a long list's, seconds, which
#: the others wait for (in their own threads, not the event loop's).
_VALIDATING = threading.Lock()


def validate_and_store(store: Store, tmp: Path, digest: str, size: int,
                       name: str, cap: int | None = None,
                       sheet: str | None = None) -> tuple[TableRecord, bool]:
    """Store the table file ``tmp`` (its ``sha256`` and ``size`` already known) under
    ``name``: ``(record, created)``, ``created`` False where the same bytes were stored
    before. A file of samples (ASTM, CSV, Excel, HDF5, MATLAB, .npz;
    ``brdffit.io.readers``, chosen by ``name``'s suffix or the content) is stored as
    brdffit's HDF5 sample list (read back by its content whatever the stored file is
    called), which the jobs fit at its own directions; its summary is the summary of
    the table it bins into (what the plots draw), with ``input`` saying what the
    binning did. The id stays the upload's sha256 (:func:`sheet_id` where ``sheet``
    names an Excel workbook's sheet to read, as ``brdffit fit --sheet``: refused, as
    the reader refuses it, for any other file). Raises ``MerlFormatError`` naming
    ``name`` (not the temp file) for a file no reader takes, and
    :class:`StoredTooLarge` where the stored sample list would be over ``cap`` bytes (an
    HDF5 upload's declared rows are weighed before any is read; a text file's once
    read)."""
    if sheet is not None:
        digest = sheet_id(digest, sheet)
    record = store.get_table(digest)
    # known bytes, already validated, unless the stored file is gone (deleted by hand, a
    # lost disk): then this upload puts it back (it answered 200 and every fit failed
    # "cannot read", with no way to repair it)
    if record is not None and store.table_path(digest).is_file():
        tmp.unlink(missing_ok=True)
        return record, False
    declared = readers.declared_samples(tmp, name)
    if declared is not None:  # at least the angles and rgb: refused without reading
        _stored_fits(name, declared, False, cap)
    with _VALIDATING:
        summary = _validated(tmp, name, cap, sheet)
    return store.add_table(digest, tmp, size, name, summary)


def _validated(tmp: Path, name: str, cap: int | None, sheet: str | None) -> dict:
    """The summary of the measured file ``tmp`` (:func:`validate_and_store`), a sample
    list rewritten in place as brdffit's HDF5."""
    try:
        measured = readers.read_measured(tmp, name=name, sheet=sheet)  # errors name it
        if isinstance(measured, Measurements):
            _stored_fits(name, measured.n, measured.sigma is not None, cap)
            # one layout for the jobs to read, sigma and all; the size stays the upload's,
            # as the id does (the stored file's made a 32 KB CSV read 36 KB, and 32 KB in
            # a batch)
            write_hdf5(measured, tmp)
        summary = readers.table_summary(measured)
        del measured
    finally:
        # the front does not sit on a parse's peak (it stayed 300+ MB above its start
        # after three large CSVs: brdffit.heap)
        heap.give_memory_back()
    return summary



def nbrdf():
    """``data_synth.nbrdf`` where this installation has it, else None."""
    try:
        from data_synth import nbrdf as module
    except ImportError:  # an installation of brdffit and api alone
        return None
    return module


def material_names() -> list[str] | None:
    """The shipped real materials, or None where this installation has none."""
    module = nbrdf()
    return None if module is None else list(module.material_names())


def material_file(store: Store) -> Path:
    """A new empty file in the store's temporary folder for a material's table, to be
    written by a worker (``api.tasks.write_material``) and stored by
    :func:`store_material_file`."""
    fd, tmp = tempfile.mkstemp(prefix="material-", suffix=".binary", dir=store.tmp_dir)
    os.close(fd)
    return Path(tmp)


def store_material_file(store: Store, name: str, path: Path) -> tuple[TableRecord, bool]:
    """Store the shipped material ``name``'s table written at ``path`` as an upload of
    its bytes would be (numpy alone: no JAX in the server's process); the caller removes
    ``path`` where it is not stored."""
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return validate_and_store(store, path, digest, path.stat().st_size, f"{name}.binary")
