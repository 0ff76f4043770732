"""What a batch worker runs: read one table by its path, fit it, return plain records.

These functions run inside Dask worker processes (or in the caller's process for
``workers=0``). They take a *path*, not a table: workers that share storage with
the client read the 35 MB file themselves, and only a few hundred bytes of
results travel back. Every failure becomes a record (a value), never an exception
that would cross the wire: a bad table must not stop a batch, and brdffit's
errors do not all survive pickling.

Compiled fits are cached per worker process by ``brdffit.fitting.pipeline``, so a worker
compiles each (model, options) once and reuses it for every later table.
"""

from __future__ import annotations

import errno
import hashlib
import os
import socket
import threading
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING

from brdffit import __version__, heap
from brdffit.errors import BrdffitError, MerlFormatError
from brdffit.fitting.options import FitOptions  # a batch's options are the library's, key() and all

if TYPE_CHECKING:
    from brdffit.request import FitRequest
from brdffit.io import merl, readers
from brdffit.io.measurements import Measurements


@dataclass
class TableReadRecord:
    """One table as a worker found it. ``sha256`` is None when it could not be read."""

    path: str
    status: str  # "ok" or "failed"
    message: str = ""  # why it failed; empty when ok
    sha256: str | None = None
    size_bytes: int | None = None
    measured_bins: int | None = None
    read_s: float = 0.0
    worker: str = ""
    finished_at: str = ""
    #: a sample list's summary (brdffit.io.readers.input_summary; its fits carry
    #: their own, fuller ``input``); None for a table. ``measured_bins`` counts its
    #: samples.
    input: dict | None = None


@dataclass
class FitRecord:
    """One table x model fit. ``fit`` is ``FitResult.to_dict()`` when ``status == "ok"``."""

    path: str
    model: str
    sha256: str
    options: dict
    status: str  # "ok" or "failed"
    message: str = ""  # why it failed; empty when ok
    fit: dict | None = None
    worker: str = ""
    brdffit_version: str = __version__
    finished_at: str = ""

    @property
    def options_key(self) -> str:
        return FitOptions.key_of(self.options)


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def now() -> str:
    # to the microsecond: an interrupted --refit goes on with the fits made since it
    # began (BatchStore.made_since), which may be the same second
    return datetime.now(UTC).isoformat(timespec="microseconds")


def _describe(e: BaseException) -> str:
    """A one-line message; an unexpected exception keeps its type so a bug is visible."""
    if isinstance(e, (BrdffitError, KeyError)) and str(e):
        return str(e)
    return f"{type(e).__name__}: {e}"


def read_table(path: str) -> tuple[merl.MerlTable | Measurements | None, TableReadRecord]:
    """Read and hash ``path`` from one read of its bytes.

    Hashing the very bytes that are parsed means the recorded sha256 is the
    content that was fitted, even if the file changes during the batch. A
    file of the wrong size is only streamed through the hash, never held in
    memory (a batch may sweep up a 10 GB file by mistake), and ``merl.read``
    says what is wrong with it.
    """
    t0 = time.perf_counter()
    record = TableReadRecord(path=path, status="failed", worker=worker_name())
    h = hashlib.sha256()
    data = None
    try:
        with open(path, "rb") as f:
            record.size_bytes = os.fstat(f.fileno()).st_size
            if record.size_bytes == merl.FILE_BYTES:
                data = f.read()
                h.update(data)
            else:
                while chunk := f.read(1 << 22):
                    h.update(chunk)
    except OSError as e:
        why = e.strerror or str(e)
        if e.errno == errno.ELOOP:  # the link's target exists: it leads back to itself
            why = f"a link to {os.readlink(path)}, which leads back round to itself (a loop)"
        elif os.path.islink(path) and not os.path.exists(path):
            why = f"a link to {os.readlink(path)}, which does not exist"
        record.message = str(MerlFormatError(path, f"cannot read: {why}"))
        record.finished_at = now()
        return None, record
    record.sha256 = h.hexdigest()
    try:
        if data is None:
            # samples in another layout (ASTM, CSV, Excel, HDF5, MATLAB, .npz: fitted at their own
            # directions), or a MERL file of the wrong size, which the reader names
            # the problem of
            table = readers.read_measured(path)
            if isinstance(table, merl.MerlTable):
                raise MerlFormatError(path, "changed size while being read")
            record.input = readers.input_summary(table)
        else:
            table = merl.from_bytes(data, source=path)
    except Exception as e:  # noqa: BLE001 - any failure is this table's, recorded
        record.message = _describe(e)
        table = None
    else:
        record.status = "ok"
        record.measured_bins = (table.n_measured if isinstance(table, merl.MerlTable)
                                else table.n)
    record.read_s = time.perf_counter() - t0
    record.finished_at = now()
    return table, record


def fit_records(table: merl.MerlTable | Measurements, record: TableReadRecord,
                request: FitRequest) -> list[FitRecord]:
    """Fit ``request`` to a table that was read (``brdffit.request.run``): one record
    per model it fits (for auto, each candidate, fitted and ranked as ``brdffit fit
    --model auto`` fits them, the chosen one carrying its ``selection``); a failure is
    recorded, not raised."""
    from brdffit.request import run

    def one(model: str, fit: dict | None = None, failure: str = "") -> FitRecord:
        return FitRecord(path=record.path, model=model, sha256=record.sha256 or "",
                         options=request.fit_record(),
                         status="failed" if fit is None else "ok",
                         message=failure, fit=fit, worker=record.worker, finished_at=now())

    try:
        report = run(table, request, measured_input=record.input)
    except Exception as e:  # noqa: BLE001 - a batch records every fit's failure
        return [one(m, failure=_describe(e)) for m in request.fitted_models]
    return [one(m, fit=report.fits[m].to_dict()) if m in report.fits
            else one(m, failure=report.failed.get(m, "not fitted"))
            for m in request.fitted_models]


def work_items(request: FitRequest, models: list[str]) -> list[list[str]]:
    """The fits of ``request`` that a table still needs (``models``, those left), as
    work items: auto's candidates (when any is left) as one item, fitted together as
    ``brdffit fit --model auto`` fits them (each seeded from the one it contains; all
    again: a seed may be among the done ones); else each model on its own, so that
    an interrupted batch keeps every model it finished."""
    if request.auto:
        group = list(request.fitted_models)
        return [group] if set(group) & set(models) else []
    return [[m] for m in models]


def fit_table(path: str, request: dict, item: list[str], expected_sha256: str | None = None,
              done_models: tuple[str, ...] = ()) -> dict:
    """Read ``path`` (or take it from this worker's :func:`recent_table`) and make the
    work item ``item`` (:func:`work_items`) of ``request`` (``FitRequest.to_dict()``:
    what a worker is sent).

    ``done_models`` are the models the client already holds finished fits for,
    valid only for the content ``expected_sha256``: if the file changed since
    the client hashed it, every model is fitted again.

    Returns ``{"table": TableReadRecord dict, "fits": [FitRecord dict, ...]}``.
    """
    # A batch worker (local or on any Dask cluster) keeps the table-sized blocks its fits
    # free: unmapped and faulted in again on every pass, they cost 51 tables x 6 models
    # on 2 workers ~40% of their time in the kernel (brdffit.heap; once per process).
    heap.keep_freed_memory()
    return fit_read_table(recent_table(path), request, item, expected_sha256, done_models)


#: Tables this worker process read last: path -> (the file's identity when read, what
#: read_table returned). A batch sends one task per (table, model), so a worker meets a
#: table again for its next model: reading, hashing and parsing it again, and with a new
#: table object making again everything the fits share per table (its weights and
#: subsamples, device arrays, start hints, the sphere renders the verdict compares
#: with), cost 0.2-0.3 s a task against a ~0.1 s fit.
_RECENT_TABLES: dict[str, tuple[tuple, tuple]] = {}
_RECENT_KEPT = 2
_RECENT_LOCK = threading.Lock()


def _file_identity(path: str) -> tuple | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def recent_table(path: str) -> tuple[merl.MerlTable | Measurements | None, TableReadRecord]:
    """:func:`read_table`, or the same table this process read last, while the file is
    unchanged (device, inode, size and modification time as when it was read): its
    record (sha256 of the bytes read) is then that read's. A table that failed to read
    is read again."""
    ident = _file_identity(path)
    with _RECENT_LOCK:
        kept = _RECENT_TABLES.get(path)
    if ident is not None and kept is not None and kept[0] == ident:
        return kept[1]
    read = read_table(path)
    if ident is not None and read[0] is not None and _file_identity(path) == ident:
        with _RECENT_LOCK:
            _RECENT_TABLES.pop(path, None)
            _RECENT_TABLES[path] = (ident, read)
            while len(_RECENT_TABLES) > _RECENT_KEPT:
                _RECENT_TABLES.pop(next(iter(_RECENT_TABLES)))
    return read


def fit_read_table(read: tuple[merl.MerlTable | None, TableReadRecord], request: dict,
                   item: list[str], expected_sha256: str | None = None,
                   done_models: tuple[str, ...] = ()) -> dict:
    """:func:`fit_table` for a table :func:`read_table` already read."""
    from brdffit.request import FitRequest

    req = FitRequest.from_dict(request)
    table, record = read
    fits = []
    if table is not None:
        done = set(done_models) if record.sha256 == expected_sha256 else set()
        if req.auto:
            if set(item) - done:
                fits += fit_records(table, record, req)
        else:
            for m in item:
                if m not in done:
                    fits += fit_records(table, record, req.replace(models=(m,)))
    return {"table": asdict(record), "fits": [asdict(f) for f in fits]}
