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

import hashlib
import os
import socket
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime

from brdffit import __version__
from brdffit.errors import BrdffitError, MerlFormatError
from brdffit.fitting.options import FitOptions  # a batch's options are the library's, key() and all
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
    return datetime.now(UTC).isoformat(timespec="seconds")


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
        record.message = str(MerlFormatError(path, f"cannot read: {e.strerror or e}"))
        record.finished_at = now()
        return None, record
    record.sha256 = h.hexdigest()
    try:
        if data is None:
            # samples in another layout (ASTM, CSV, HDF5: fitted at their own
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


def fit_records(table: merl.MerlTable | Measurements, record: TableReadRecord, models: list[str],
                options: FitOptions, auto: bool = False) -> list[FitRecord]:
    """Fit ``models`` to a table that was read (``brdffit.request.run``), one record
    per model; a failure is recorded, not raised. ``auto``: ``models`` are auto's
    candidates, fitted and ranked as ``brdffit fit --model auto`` fits them (each
    seeded from the model it contains, refitted when it did not converge), the
    chosen one carrying its ``selection``."""
    from brdffit.request import FitRequest, run

    def one(model: str, fit: dict | None = None, failure: str = "") -> FitRecord:
        return FitRecord(path=record.path, model=model, sha256=record.sha256 or "",
                         options=options.fit_keywords(), status="failed" if fit is None else "ok",
                         message=failure, fit=fit, worker=record.worker, finished_at=now())

    def records(request: FitRequest) -> list[FitRecord]:
        try:
            report = run(table, request, measured_input=record.input)
        except Exception as e:  # noqa: BLE001 - a batch records every fit's failure
            return [one(m, failure=_describe(e)) for m in request.fitted_models]
        return [one(m, fit=report.fits[m].to_dict()) if m in report.fits
                else one(m, failure=report.failed.get(m, "not fitted"))
                for m in request.fitted_models]

    if auto:
        return records(FitRequest(models=("auto",), options=options.replace(model="auto"),
                                  candidates=tuple(models)))
    return [r for m in models for r in records(FitRequest(models=(m,), options=options))]


def fit_table(path: str, models: list[str], options: dict, expected_sha256: str | None = None,
              done_models: tuple[str, ...] = (), auto: tuple[str, ...] = ()) -> dict:
    """Read ``path`` and fit every model of ``models`` not already done.

    ``done_models`` are the models the client already holds finished fits for,
    valid only for the content ``expected_sha256``: if the file changed since
    the client hashed it, every model is fitted again. ``auto``: auto's
    candidates among ``models``, fitted together as ``model="auto"`` fits them
    (all again when any is missing: each is seeded from another's fit).

    Returns ``{"table": TableReadRecord dict, "fits": [FitRecord dict, ...]}``.
    """
    return fit_read_table(read_table(path), models, options, expected_sha256, done_models,
                          auto)


def fit_read_table(read: tuple[merl.MerlTable | None, TableReadRecord], models: list[str],
                   options: dict, expected_sha256: str | None = None,
                   done_models: tuple[str, ...] = (), auto: tuple[str, ...] = ()) -> dict:
    """:func:`fit_table` for a table :func:`read_table` already read."""
    opts = FitOptions.from_dict(options)
    table, record = read
    fits = []
    if table is not None:
        done = set(done_models) if record.sha256 == expected_sha256 else set()
        if auto and not set(auto) <= done:
            fits += fit_records(table, record, list(auto), opts, auto=True)
            done |= set(auto)
        fits += fit_records(table, record, [m for m in models if m not in done], opts)
    return {"table": asdict(record), "fits": [asdict(f) for f in fits]}
