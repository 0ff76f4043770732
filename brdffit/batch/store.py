"""Where a batch keeps its results: an HDF5 file, made crash-safe by a journal.

Layout of ``results.h5`` (``format = "brdffit-batch"``, ``format_version = 1``;
docs/batch.md describes every field)::

    /                          attrs: format, format_version, brdffit_version, created,
                                      updated, models, options, engine, n_tables,
                                      n_tables_failed, n_fits, n_fits_failed
    /inputs                    the table paths of the latest run, in order (strings)
    /tables/<name>             one group per table file; attrs: path, sha256, size_bytes,
                                      measured_bins, status, message, read_s, worker,
                                      finished_at
    /tables/<name>/<model>     one group per fitted model; attrs: status, message, sha256,
                                      options, solver, samples, precision, starts,
                                      max_steps, seed, result, converged, steps, time_s,
                                      starts_used, samples_used, samples_usable,
                                      samples_measured, dropped_unmeasured,
                                      dropped_nonfinite, dropped_below_horizon, worker,
                                      brdffit_version, finished_at, fit_json (the
                                      whole result in the result schema, JSON)
    /tables/<name>/<model>/params/<param>   float64, shape (3,) (RGB) or () (docs/models.md names)
    /tables/<name>/<model>/error/<metric>   float64, shape (): FitResult.error
    /index                     compound, one row per record written, in order (kind
                               "table" or "fit"): kind, name, path, model, sha256, options,
                               status, message, result, converged, steps, log_rmse,
                               measured_bins; a later row supersedes an earlier one

``/index`` repeats what resume and the ranking need, so that they read one
dataset instead of walking every group (h5py spends milliseconds per group);
the groups are the full record, and what a reader should use.

Crash safety. One writer (the batch's client process) and two files:

- ``results.h5.journal``: append-only JSON lines, one per finished table or
  fit, written and fsynced as each table's results arrive. It is the
  authoritative progress; a line torn by a kill is dropped on the next start.
- ``results.h5``: updated by *checkpoints*: copy the current file, add the
  records not yet in it, fsync, and rename over the old one. A rename is
  atomic, so a reader or a SIGKILL at any moment finds the previous complete
  file or the next one, never a half-written one. After a checkpoint the
  journal is emptied; after a clean finish it is removed.

The journal is also the lock: a second batch on the same file is refused.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import glob
import json
import os
import shutil
from dataclasses import asdict, dataclass, field
from datetime import datetime

import h5py
import numpy as np

from brdffit import __version__, jsonout
from brdffit.batch.tasks import FitOptions, FitRecord, TableReadRecord, now
from brdffit.errors import BrdffitError
from brdffit.io.named_arrays import HDF5_SIGNATURE, hdf5_unreadable

FORMAT = "brdffit-batch"
FORMAT_VERSION = 1


class BatchFileError(BrdffitError, ValueError):
    """A results file that is not a brdffit batch file, or is in use by another batch."""


@dataclass
class FitEntry:
    """What the index holds of one fit: enough to resume and to rank."""

    sha256: str
    options: str  # FitOptions.key()
    status: str
    message: str = ""
    result: str = ""
    converged: bool = False
    steps: int = -1
    log_rmse: float = float("nan")


@dataclass
class TableEntry:
    """What the index holds of one table, with its current fits by model."""

    name: str  # its group under /tables
    path: str
    sha256: str | None
    status: str
    message: str = ""
    measured_bins: int = -1
    fits: dict[str, FitEntry] = field(default_factory=dict)


#: Columns of ``/index``, one row per record a checkpoint wrote (kind "table" or
#: "fit"), in order. Rows are only ever appended: a dataset rewritten at every
#: checkpoint leaves its old space behind in HDF5, and the file grew
#: quadratically when the index was a snapshot (54 MB after 300 checkpoints).
_INDEX_COLUMNS = (("kind", str), ("name", str), ("path", str), ("model", str),
                  ("sha256", str), ("options", str), ("status", str), ("message", str),
                  ("result", str), ("converged", "?"), ("steps", "<i8"),
                  ("log_rmse", "<f8"), ("measured_bins", "<i8"))
_INDEX_DTYPE = np.dtype([(n, h5py.string_dtype() if k is str else k) for n, k in _INDEX_COLUMNS])


def _index_row(r: dict, name: str) -> dict:
    """The index row of a journal record (``TableReadRecord`` or ``FitRecord`` as a dict)."""
    row = {"kind": r["kind"], "name": name, "path": r["path"], "model": r.get("model", ""),
           "sha256": r["sha256"] or "", "options": "", "status": r["status"],
           "message": r["message"], "result": "", "converged": False, "steps": -1,
           "log_rmse": float("nan"), "measured_bins": _int(r.get("measured_bins"))}
    if r["kind"] == "fit":
        fit = r["fit"] or {}
        row.update(options=FitOptions.key_of(r["options"]),
                   result=fit.get("result", ""), converged=bool(fit.get("converged", False)),
                   steps=int(fit.get("steps", -1)),
                   log_rmse=_float(fit.get("error", {}).get("log_rmse")))
    return row


def _apply_row(tables: dict[str, TableEntry], row: dict) -> None:
    """Fold one index row into the state: later rows supersede earlier ones."""
    path = row["path"]
    if row["kind"] == "table":
        old = tables.get(path)
        if old is None:
            # a group keeps one table: its name under another path is that table moved
            # (BatchStore.record_move), and its fits go with it
            moved = next((p for p, e in tables.items() if e.name == row["name"]), None)
            old = tables.pop(moved) if moved is not None else None
        t = TableEntry(row["name"], path, row["sha256"] or None, row["status"], row["message"],
                       row["measured_bins"])
        if old is not None:
            # Fits of other content describe a table that no longer exists.
            keep_all = t.sha256 is None  # unreadable now: nothing to compare
            t.fits = {m: f for m, f in old.fits.items() if keep_all or f.sha256 == t.sha256}
        tables[path] = t
    else:
        t = tables.setdefault(path, TableEntry(row["name"], path, row["sha256"], "ok"))
        t.fits[row["model"]] = FitEntry(
            row["sha256"], row["options"], row["status"], row["message"], row["result"],
            bool(row["converged"]), int(row["steps"]), float(row["log_rmse"]))


class BatchStore:
    """The single writer of a batch's results; use as a context manager.

    ``add`` journals a table's records at once; ``checkpoint`` folds them into
    the HDF5 file. Resume asks ``done_models``.
    """

    def __init__(self, path: str | os.PathLike):
        # the link's target: a symbolic link named as --out was replaced by a file of
        # its own (the target kept its old results), and two spellings of one file took
        # two locks
        self.path = os.path.realpath(os.fspath(path))
        self.journal_path = self.path + ".journal"
        self._tmp_prefix = os.path.join(os.path.dirname(self.path),
                                        f".{os.path.basename(self.path)}.tmp-")
        self._tables: dict[str, TableEntry] = {}
        self._names: dict[str, str] = {}  # table path -> group name in the file
        self._taken: set[str] = set()
        self._pending: list[dict] = []  # journaled, not yet in the HDF5 file
        self._journal_fd: int | None = None
        self.recovered = 0  # records replayed from a previous run's journal
        self.recovered_fits = 0  # of them, fits (the others are their tables' records)
        self.damaged: list[tuple[str, str]] = []  # (table path, model) fitted again

    # -- opening, closing ------------------------------------------------------------

    def __enter__(self) -> BatchStore:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:
        directory = os.path.dirname(self.path)
        if not os.path.isdir(directory):
            raise BatchFileError(f"{self.path}: directory {directory} does not exist")
        if os.path.isdir(self.path):
            raise BatchFileError(f"{self.path}: a directory; the results file is a .h5 "
                                 "file in it, e.g. --out DIR/results.h5")
        if self.path.endswith(".journal"):
            raise BatchFileError(f"{self.path}: a .journal name is another results file's "
                                 "journal; name the results file .h5")
        if is_hdf5(self.journal_path):
            raise BatchFileError(
                f"{self.path}: {self.journal_path} is an HDF5 file, not this file's journal "
                "(a results file written under that name?): move it away or rename it")
        try:
            self._journal_fd = _lock(self.journal_path, self.path)
        except OSError as e:
            raise BatchFileError(f"{self.path}: cannot write in {directory} ({e.strerror}): "
                                 "the results file and its journal go there") from None
        try:
            if os.path.isfile(self.path) and os.path.getsize(self.path) == 0:
                os.unlink(self.path)  # made by `touch` for the batch to fill: a new file
            if os.path.exists(self.path):
                self._tables = read_index(self.path)
                for t in self._tables.values():
                    self._names[t.path] = t.name
                    self._taken.add(t.name)
                self.damaged = _unreadable_fits(self.path, self._tables)
            for stale in glob.glob(glob.escape(self._tmp_prefix) + "*"):
                os.unlink(stale)  # a checkpoint a kill interrupted; we hold the lock
            self._replay_journal()
        except BaseException:
            if os.fstat(self._journal_fd).st_size == 0:
                # ours, under the lock, and nothing in it: a refused --out leaves nothing
                os.unlink(self.journal_path)
            os.close(self._journal_fd)
            self._journal_fd = None
            raise

    def close(self) -> None:
        if self._journal_fd is None:
            return
        if not self._pending:
            # Everything is in the HDF5 file. Unlink while still locked: a batch
            # waiting on the old journal sees it gone and takes a fresh one.
            os.unlink(self.journal_path)
        os.close(self._journal_fd)
        self._journal_fd = None

    # -- resume ----------------------------------------------------------------------

    def as_known(self, paths: list[str]) -> list[str]:
        """``paths`` with each file once: a path that reaches a file a previous run
        recorded under another path (a folder given once through a symbolic link, once
        not) is replaced by the recorded one, so that resume finds its fits and the
        table keeps one entry; two spellings of one file in ``paths`` are one table, the
        first. A recorded path that reaches another file now (a link since moved) is
        another table."""
        recorded: dict[str, str] = {}
        for known in self._tables:
            recorded.setdefault(os.path.realpath(known), known)
        out: dict[str, None] = {}
        taken: set[str] = set()
        for p in paths:
            real = os.path.realpath(p)
            if real in taken:
                continue
            taken.add(real)
            out.setdefault(p if p in self._tables else recorded.get(real, p))
        return list(out)

    def known_sha256(self, path: str) -> str | None:
        """The content hash a previous run read at ``path`` (None if never read)."""
        t = self._tables.get(path)
        return t.sha256 if t and t.status == "ok" else None

    def done_models(self, path: str, sha256: str, key: str) -> set[str]:
        """Models with a successful fit of this exact content under the fit key ``key``
        (``FitRequest.fit_key()``: the options and the scene)."""
        t = self._tables.get(path)
        if t is None or t.sha256 != sha256:
            return set()
        return {m for m, f in t.fits.items()
                if f.sha256 == sha256 and f.options == key and f.status == "ok"}

    def replaced(self, path: str, sha256: str, key: str, models) -> tuple[int, int]:
        """Of ``models``' successful fits stored for ``path``, those a run that fits
        content ``sha256`` under fit key ``key`` makes again: ``(made with other
        options, made of other content)``."""
        t = self._tables.get(path)
        if t is None:
            return 0, 0
        stored = [t.fits[m] for m in models if m in t.fits and t.fits[m].status == "ok"]
        other_content = sum(f.sha256 != sha256 for f in stored)
        other_options = sum(f.sha256 == sha256 and f.options != key for f in stored)
        return other_options, other_content

    def stored_ok(self, path: str, models) -> set[str]:
        """Of ``models``, those with a successful fit stored for ``path`` (any options)."""
        t = self._tables.get(path)
        return set() if t is None else {m for m in models
                                        if m in t.fits and t.fits[m].status == "ok"}

    def vanished(self) -> dict[str, str]:
        """sha256 -> recorded path, of the tables read before whose file is gone from
        its path (moved, renamed, or deleted)."""
        return {t.sha256: p for p, t in self._tables.items()
                if t.status == "ok" and t.sha256 and not os.path.lexists(p)}

    def record_move(self, old: str, new: str) -> None:
        """The table recorded at ``old`` is now at ``new`` (the same content: its
        sha256): its group, its fits and the group's ``path`` go with it, so that a
        folder moved or renamed is resumed, not fitted again as new tables (``mat~2``)."""
        t = self._tables[old]
        with _reading(self.path) as f:
            attrs = {k: _plain(v) for k, v in f["tables"][t.name].attrs.items()}
        self._names[new] = t.name
        record = asdict(TableReadRecord(
            path=new, sha256=t.sha256, status="ok", message="",
            size_bytes=_int(attrs.get("size_bytes")), measured_bins=t.measured_bins,
            read_s=float(attrs.get("read_s", 0.0)), worker=f"moved from {old}",
            finished_at=now()))
        self._apply({"kind": "table", **record})
        _write_all(self._journal_fd, (jsonout.dumps({"kind": "table", **record},
                                                    separators=(",", ":")) + "\n").encode())
        os.fsync(self._journal_fd)

    def made_since(self, path: str, since: str) -> set[str]:
        """Models of the table at ``path`` whose stored fit was made at or after
        ``since`` (``now()``'s ISO time): what an interrupted ``--refit`` already made."""
        t = self._tables.get(path)
        if t is None or not os.path.exists(self.path):
            return set()
        with _reading(self.path) as f:
            g = f["tables"].get(t.name)
            if g is None:
                return set()
            start = _time(since)
            return {m for m in g if m in t.fits and start is not None
                    and (made := _time(_plain(g[m].attrs.get("finished_at", "")))) is not None
                    and made >= start}

    def counts(self) -> dict[str, int]:
        tables = self._tables.values()
        fits = [f for t in tables for f in t.fits.values()]
        return {
            "n_tables": len(self._tables),
            "n_tables_failed": sum(t.status != "ok" for t in tables),
            "n_fits": len(fits),
            "n_fits_failed": sum(f.status != "ok" for f in fits),
        }

    def reserve_names(self, paths: list[str]) -> list[tuple[str, str]]:
        """Fix the group names of new tables in this order (results arrive in any order);
        returns ``(path, name)`` of each new one named ``stem~N``, its file's name being
        another table's group already."""
        renamed = []
        for p in paths:
            new = p not in self._names
            name = self._group_name(p)
            if new and "~" in name and not os.path.basename(p).startswith(name):
                renamed.append((p, name))
        return renamed

    # -- recording ---------------------------------------------------------------------

    def add(self, table: TableReadRecord, fits: list[FitRecord]) -> None:
        """Apply one table's results, and journal them (fsynced before returning)."""
        records = [{"kind": "table", **asdict(table)}]
        records += [{"kind": "fit", **asdict(f)} for f in fits]
        # Strict JSON: a metric a fit could not measure is null here, NaN again in HDF5.
        data = "".join(jsonout.dumps(r, separators=(",", ":")) + "\n" for r in records).encode()
        # Applied before they are journaled: a Ctrl-C that lands between the fsync and
        # the apply would leave records in the journal only, and the checkpoint that
        # follows an interrupt empties the journal, losing them. Applied first, the
        # checkpoint writes them whatever point the interrupt reached.
        for r in records:
            self._apply(r)
        _write_all(self._journal_fd, data)
        os.fsync(self._journal_fd)

    def _apply(self, r: dict) -> None:
        _apply_row(self._tables, _index_row(r, self._group_name(r["path"])))
        self._pending.append(r)

    # -- the HDF5 file -------------------------------------------------------------------

    def checkpoint(self, attrs: dict | None = None, inputs: list[str] | None = None) -> None:
        """Fold the journaled records into the HDF5 file, atomically (copy, add, rename).

        ``attrs`` become file attributes (lists and dicts as JSON); ``inputs``
        replaces the ``/inputs`` dataset (a dataset: attributes are limited to
        64 KiB, and a batch may name thousands of tables).
        """
        tmp = f"{self._tmp_prefix}{os.getpid()}"
        existed = os.path.exists(self.path)
        try:
            if existed:
                shutil.copyfile(self.path, tmp)
                f = h5py.File(tmp, "r+")
            else:
                # Free-space tracking lets a refitted model's group reuse the
                # space of the group it replaces.
                f = h5py.File(tmp, "w", libver=("v110", "latest"), fs_strategy="fsm",
                              fs_persist=True)
                f.attrs["format"] = FORMAT
                f.attrs["format_version"] = FORMAT_VERSION
                f.attrs["created"] = now()
                f.create_group("tables")
                f.create_dataset("index", shape=(0,), maxshape=(None,), chunks=(256,),
                                 dtype=_INDEX_DTYPE)
            with f:
                for r in self._pending:
                    if r["kind"] == "table":
                        self._write_table(f["tables"], r)
                    else:
                        self._write_fit(f["tables"], r)
                self._append_index(f["index"])
                if inputs is not None:
                    if "inputs" in f:
                        del f["inputs"]
                    f.create_dataset("inputs", data=list(inputs), dtype=h5py.string_dtype())
                for k, v in (attrs or {}).items():
                    if v is None:  # a mark that no longer holds (refit_pending)
                        if k in f.attrs:
                            del f.attrs[k]
                    else:
                        f.attrs[k] = v if isinstance(v, (str, int, float)) else jsonout.dumps(v)
                f.attrs["brdffit_version"] = __version__
                f.attrs["updated"] = now()
                for k, v in self.counts().items():
                    f.attrs[k] = v
            _fsync_path(tmp)
            os.replace(tmp, self.path)
            _fsync_path(os.path.dirname(self.path))
        except BaseException as e:
            with contextlib.suppress(OSError):  # the folder may refuse this too
                os.unlink(tmp)
            if _write_failed(e):  # the file as it was is whole; the journal holds the rest
                full = getattr(e, "errno", None) in _FULL or getattr(e, "errno", None) is None
                raise BatchFileError(
                    f"{self.path}: could not write the results file ("
                    f"{os.strerror(e.errno) if getattr(e, 'errno', None) else 'a write failed'}"
                    f"{'; a full disk?' if full else ''}); this run's finished fits are kept "
                    f"in {self.journal_path}: "
                    f"{'free some space' if full else 'make the folder writable'} and run "
                    "the batch again, which folds them in") from None
            if (existed and isinstance(e, (OSError, KeyError, ValueError, TypeError,
                                           AttributeError, RuntimeError))
                    and getattr(e, "errno", None) is None):  # h5py's, not the disk's
                # the results are safe in the journal; the file they go into is damaged
                raise BatchFileError(
                    f"{self.path}: a damaged batch results file ({type(e).__name__}: "
                    f"{' '.join(str(e).split())}); this run's results are kept in "
                    f"{self.journal_path}: move the damaged file away and run again (they "
                    "go into a new file)") from None
            raise
        # Only now is the journal redundant; a kill before this line replays
        # records that are already in the file, which rewrites them unchanged.
        self._pending.clear()
        os.ftruncate(self._journal_fd, 0)

    def _group_name(self, path: str) -> str:
        if path not in self._names:
            stem = os.path.basename(path)
            stem = stem[: -len(".binary")] if stem.endswith(".binary") and len(stem) > 7 else stem
            # "." and ".." are HDF5's paths to a group itself and its parent: "..binary" put
            # its table's attributes on /tables and its fits beside the tables
            stem = "_" * len(stem) if not stem.strip(".") else stem
            name, i = stem, 1
            while name in self._taken:
                i += 1
                name = f"{stem}~{i}"
            self._names[path] = name
            self._taken.add(name)
        return self._names[path]

    def _append_index(self, index: h5py.Dataset) -> None:
        rows = [_index_row(r, self._group_name(r["path"])) for r in self._pending]
        if not rows:
            return
        n = index.shape[0]
        index.resize((n + len(rows),))
        index[n:] = np.array([tuple(row[c] for c, _ in _INDEX_COLUMNS) for row in rows],
                             dtype=_INDEX_DTYPE)

    def _write_table(self, tables: h5py.Group, r: dict) -> None:
        g = tables.require_group(self._group_name(r["path"]))
        if r["sha256"] is not None:
            for model in list(g):
                if g[model].attrs.get("sha256") != r["sha256"]:
                    del g[model]
        g.attrs.update({
            "path": r["path"],
            "sha256": r["sha256"] or "",
            "size_bytes": _int(r["size_bytes"]),
            "measured_bins": _int(r["measured_bins"]),
            "status": r["status"],
            "message": r["message"],
            "read_s": float(r["read_s"]),
            "worker": r["worker"],
            "finished_at": r["finished_at"],
        })

    def _write_fit(self, tables: h5py.Group, r: dict) -> None:
        t = tables.require_group(self._group_name(r["path"]))
        if r["model"] in t:
            del t[r["model"]]
        g = t.create_group(r["model"])
        o = r["options"]
        g.attrs.update({
            "status": r["status"],
            "message": r["message"],
            "sha256": r["sha256"],
            "options": FitOptions.key_of(o),
            "solver": o["solver"],
            "samples": _int(o["samples"], none=0),
            "precision": o["precision"],
            "starts": o["starts"],
            "max_steps": o["max_steps"],
            "seed": o["seed"],
            "worker": r["worker"],
            "brdffit_version": r["brdffit_version"],
            "finished_at": r["finished_at"],
        })
        fit = r["fit"]
        if fit is None:
            g.attrs.update({"result": "", "converged": False, "steps": -1, "time_s": float("nan")})
            return
        s = fit["samples"]
        g.attrs["fit_json"] = jsonout.dumps(fit)  # the whole result, in the result schema
        g.attrs.update({
            "result": fit["result"],
            "converged": bool(fit["converged"]),
            "steps": int(fit["steps"]),
            "time_s": float(fit["time_s"]),
            "starts_used": int(fit["starts"]),
            "samples_used": int(s["used"]),
            "samples_usable": int(s["usable"]),
            "samples_measured": int(s["measured"]),
            "dropped_unmeasured": int(s["dropped"]["unmeasured"]),
            "dropped_nonfinite": int(s["dropped"]["nonfinite"]),
            "dropped_below_horizon": int(s["dropped"]["below_horizon"]),
        })
        params = g.create_group("params")
        for name, v in fit["params"].items():
            params[name] = np.asarray(v, dtype=np.float64)
        error = g.create_group("error")
        for name, v in fit["error"].items():
            error[name] = np.float64(_float(v))

    def _replay_journal(self) -> None:
        os.lseek(self._journal_fd, 0, os.SEEK_SET)
        chunks = []
        while chunk := os.read(self._journal_fd, 1 << 20):
            chunks.append(chunk)
        data = b"".join(chunks)
        complete = data.rfind(b"\n") + 1
        if complete < len(data):  # a line torn by a kill: the next append must not join it
            os.ftruncate(self._journal_fd, complete)
        for line in data[:complete].splitlines():
            try:
                r = json.loads(line)
            except ValueError:
                continue  # a torn line from an older kill that a crash left mid-file
            self._apply(r)
            self.recovered += 1
            if r.get("kind") == "fit":
                self.recovered_fits += 1


def _open(path: str) -> h5py.File:
    if os.path.isdir(path):
        raise BatchFileError(f"{path}: a directory, not a batch results file")
    if not os.path.exists(path):
        raise BatchFileError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise BatchFileError(f"{path}: {hdf5_unreadable(path, e)}; a batch results file is "
                             "the HDF5 file `brdffit batch --out` writes") from None
    if f.attrs.get("format") != FORMAT:
        f.close()
        raise BatchFileError(f"{path}: an HDF5 file, but not a brdffit batch results file")
    stated = f.attrs.get("format_version", 0)
    try:
        version = int(stated)
    except (TypeError, ValueError):
        f.close()
        raise BatchFileError(f"{path}: a damaged batch results file (format_version "
                             f"{_plain(stated)!r}, not a number)") from None
    if version > FORMAT_VERSION:
        f.close()  # the version is read before: a closed file's attributes are gone
        raise BatchFileError(f"{path}: written by a newer brdffit (format version "
                             f"{version}; this one reads up to {FORMAT_VERSION})")
    return f


@contextlib.contextmanager
def _reading(path: str):
    """The batch file at ``path``, open for reading; what goes wrong inside (a damaged
    file: a checksum, an address past its end, an attribute that is not what was
    written) is one :class:`BatchFileError` naming the file, not h5py's traceback."""
    with _open(path) as f:
        try:
            yield f
        except BatchFileError:
            raise
        except (OSError, KeyError, IndexError, ValueError, TypeError, AttributeError,
                RuntimeError) as e:  # IndexError: a table's group made a dataset
            raise BatchFileError(f"{path}: a damaged batch results file ({type(e).__name__}: "
                                 f"{' '.join(str(e).split())})") from None


def _unreadable_fits(path: str, tables: dict[str, TableEntry]) -> list[tuple[str, str]]:
    """The fits the index calls done whose stored result does not read back (a disk
    error, a bit flipped): marked ``damaged`` in ``tables``, so that a resume fits them
    again instead of keeping a result nobody can read. One attribute read per fit."""
    damaged = []
    with _reading(path) as f:
        groups = f.get("tables")
        for t in tables.values():
            for model, entry in t.fits.items():
                if entry.status != "ok":
                    continue
                try:
                    json.loads(_plain(groups[t.name][model].attrs["fit_json"]))
                except (KeyError, TypeError, ValueError, OSError, RuntimeError):
                    entry.status = "damaged"
                    damaged.append((t.path, model))
    return damaged


def read_attrs(path: str | os.PathLike) -> dict:
    """The file-level attributes of a batch file, as plain Python values."""
    with _reading(os.fspath(path)) as f:
        return {k: _plain(v) for k, v in f.attrs.items()}


def read_index(path: str | os.PathLike) -> dict[str, TableEntry]:
    """Every table of a batch file, by path, with its current fits: the ``/index``
    replayed (two reads of one dataset, fast at any size)."""
    with _reading(os.fspath(path)) as f:
        rows = f["index"][()]
    tables: dict[str, TableEntry] = {}
    names = rows.dtype.names
    for values in rows.tolist():
        _apply_row(tables, {k: _plain(v) for k, v in zip(names, values, strict=True)})
    return tables


def read_results(path: str | os.PathLike) -> dict:
    """A batch file as plain data: ``{"attrs": {...}, "inputs": [...], "tables": [...]}``.

    Each table is a dict of its attrs plus ``name`` and ``fits`` (model -> dict
    of that group's attrs plus ``params`` and ``error`` dicts; RGB params as
    lists of 3 floats, as in :class:`brdffit.FitResult`). A fit that ran also has
    ``fit``: its whole result in the result schema (``FitResult.to_dict()``,
    docs/results.md), the JSON ``brdffit fit --json`` prints.
    """
    with _reading(os.fspath(path)) as f:
        out = {"attrs": {k: _json_safe(v) for k, v in f.attrs.items()}, "tables": [],
               "inputs": [_plain(s) for s in f["inputs"][()]] if "inputs" in f else []}
        for name, g in f["tables"].items():
            table = {"name": name, **{k: _json_safe(v) for k, v in g.attrs.items()},
                     "fits": {}}
            for model, m in g.items():
                fit = {k: _json_safe(v) for k, v in m.attrs.items()}
                if "fit_json" in fit:  # FitResult.to_dict(), as the CLI and the API give it
                    fit["fit"] = json.loads(fit.pop("fit_json"))
                params, error = m.get("params", {}), m.get("error", {})
                fit["params"] = {k: _json_safe(d[()]) for k, d in params.items()}
                # NaN in HDF5 is a metric not measured: None, as in the fit's own JSON
                fit["error"] = {k: _json_safe(float(d[()])) for k, d in error.items()}
                table["fits"][model] = fit
            out["tables"].append(table)
    return out


def read_looks(path: str | os.PathLike) -> dict[tuple[str, str], dict]:
    """(table name, model) -> the fit's ``quality`` block (its verdict, reason and
    ``next``; empty for a fit stored before results had one), for every fit that ran."""
    out = {}
    with _reading(os.fspath(path)) as f:
        for name, g in f["tables"].items():
            for model, m in g.items():
                if "fit_json" in m.attrs:
                    out[name, model] = json.loads(_plain(m.attrs["fit_json"])).get("quality") or {}
    return out


def read_fit(path: str | os.PathLike, table: str, model: str | None = None) -> dict:
    """One fit of a batch file, in the result schema (``FitResult.to_dict()``).

    ``table``: its group name (``brdffit batch-report`` shows it), the path it was
    read from, or that path's file name (with or without ``.binary``); ``model``: the
    fitted model, or None (or ``"auto"``) for the table's best fit (auto's choice where
    the batch fitted auto, else the lowest ``log_rmse``:
    ``brdffit.selection.chosen_result``). Raises
    :class:`BatchFileError` naming what the file holds when there is no such table,
    no such model, or the fit failed.
    """
    path = os.fspath(path)
    with _reading(path) as f:
        groups = f["tables"]
        name = _find_table(path, groups, table)
        g = groups[name]
        if _plain(g.attrs.get("status", "ok")) != "ok":  # read or refused: no fit ran
            raise BatchFileError(f"{path}: table {name!r} was not fitted: "
                                 f"{_plain(g.attrs.get('message', '')) or 'it failed to read'}")
        fits = {m: {k: _plain(v) for k, v in g[m].attrs.items()} for m in g}
        if model == "auto" and "auto" not in fits:
            model = None  # auto's choice, as the service's ?model=auto of an auto job
        if model is None:
            ok = {m: a for m, a in fits.items() if a.get("status") == "ok" and "fit_json" in a}
            if not ok:
                raise BatchFileError(f"{path}: table {name!r} has no successful fit"
                                     f"{_failed(fits)}")
            from brdffit.selection import chosen_result  # the library's one rule

            model = chosen_result([json.loads(a["fit_json"]) for a in ok.values()])["model"]
        if model not in fits:
            raise BatchFileError(
                f"{path}: table {name!r} has no {model} fit; it has "
                f"{', '.join(sorted(fits)) or 'none'}")
        a = fits[model]
        if a.get("status") != "ok" or "fit_json" not in a:
            raise BatchFileError(f"{path}: the {model} fit of table {name!r} failed: "
                                 f"{a.get('message') or 'no result stored'}")
        return json.loads(a["fit_json"])


def table_name(path: str | os.PathLike, table: str) -> str:
    """The group name of ``table`` in the batch file (see :func:`read_fit`): unique in
    the file where two tables' files share a name (``mat``, ``mat~2``)."""
    path = os.fspath(path)
    with _reading(path) as f:
        return _find_table(path, f["tables"], table)


def _find_table(path: str, groups: h5py.Group, table: str) -> str:
    """The group name of ``table`` (see :func:`read_fit`)."""
    if table in groups:
        return table
    stem = table.removesuffix(".binary")
    # the path as the batch was given it (relative to here) reaches the stored absolute one
    spelled = {table, os.path.abspath(table), os.path.realpath(table)}
    found = []
    for name, g in groups.items():
        source = _plain(g.attrs.get("path", ""))
        base = os.path.basename(source)
        if source in spelled or table == base or stem == base.removesuffix(".binary"):
            found.append(name)
    if len(found) == 1:
        return found[0]
    if found:
        raise BatchFileError(f"{path}: {table!r} names several tables: {', '.join(found)}; "
                             "give one of these names")
    names = sorted(groups)
    shown = ", ".join(names[:20]) + (f" and {len(names) - 20} more" if len(names) > 20 else "")
    raise BatchFileError(f"{path}: no table {table!r}; the file holds "
                         f"{shown or 'no tables'}")


def _failed(fits: dict) -> str:
    failed = [f"{m} ({a.get('message') or a.get('status')})" for m, a in fits.items()]
    return f"; its fits: {', '.join(failed)}" if failed else ""


#: Errors of a disk without room.
_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
#: Errors of a folder or disk that refuses the write (made read-only during the batch,
#: an immutable folder, a disk gone): a bare "operation not permitted" said nothing of
#: the finished fits kept in the journal.
_REFUSED = (errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO)


def _write_failed(e: BaseException) -> bool:
    """Whether writing the results file failed on the disk: its own error (no room, or
    a folder that refuses the write), or HDF5's, which carries no errno ("can't close
    file (file write failed: time = ..., buf = 0x55a8...)", which was the whole
    message)."""
    if getattr(e, "errno", None) in _FULL + _REFUSED:
        return True
    return isinstance(e, OSError) and "write failed" in str(e)


def is_hdf5(path: str) -> bool:
    """Whether ``path`` is a file that starts with HDF5's signature."""
    try:
        with open(path, "rb") as f:
            return f.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
    except OSError:
        return False


def _plain(v):
    """h5py values as plain Python (numpy scalars, arrays, bytes)."""
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def _time(text) -> datetime | None:
    """An ISO time written by ``now()`` (to the second in files written before
    2026-12-06), or None where it does not read as one."""
    try:
        return datetime.fromisoformat(text)
    except (TypeError, ValueError):
        return None


def _json_safe(v):
    """:func:`_plain`, with a float that is not finite (NaN: not measured, a failed
    fit's time) as None: what :func:`read_results` returns is strict JSON."""
    v = _plain(v)
    if isinstance(v, float):
        return v if np.isfinite(v) else None
    if isinstance(v, list):
        return [_json_safe(x) for x in v]
    return v


def _int(v, none: int = -1) -> int:
    return none if v is None else int(v)


def _float(v) -> float:
    """A metric from a journal record: null there (strict JSON) is NaN in HDF5."""
    return float("nan") if v is None else float(v)


def _lock(journal_path: str, results_path: str) -> int:
    """Open and exclusively lock the journal; refuse when another batch holds it."""
    for _ in range(10):
        fd = os.open(journal_path, os.O_RDWR | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise BatchFileError(
                f"{results_path}: another batch is writing it (it holds {journal_path})"
            ) from None
        try:
            current = os.stat(journal_path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            current = False
        if current:
            return fd
        os.close(fd)  # the previous holder removed it as we opened it: take the new one
    raise BatchFileError(f"{results_path}: could not lock {journal_path}")


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _fsync_path(path: str) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
