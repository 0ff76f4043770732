"""Where the service keeps things: table files and a SQLite database of jobs.

Layout of the data dir::

    brdffit.sqlite3          tables and jobs (WAL mode)
    tables/<sha256>.binary   uploaded tables, named by their content
    plots/<job>/<model>/<kind>.png   rendered plots, a cache
    tmp/                     uploads in flight (emptied at start)

A job's life: ``queued`` -> ``running`` -> ``done`` | ``failed``. Every change is
one SQL statement, so a process killed at any instant leaves each job in one
well-defined state, and :meth:`Store.recover` settles the ``running`` ones at the
next start. WAL with ``synchronous=NORMAL`` survives a killed process (what a
restart mid-job means here); only a power cut may lose the last commits.

Each call opens its own connection: calls come from the threadpool and the
queue's thread hops, and SQLite connections do not cross threads.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import sqlite3
import time
import uuid
from collections.abc import Iterator
from contextlib import closing, contextmanager
from dataclasses import dataclass
from pathlib import Path

from brdffit import jsonout
from brdffit.errors import BrdffitError

STATUSES = ("queued", "running", "done", "failed", "cancelled")
#: Statuses a job leaves no more.
FINISHED = ("done", "failed", "cancelled")

#: ``PRAGMA user_version`` of the layout below. 0: the first layout (no
#: ``cancelled``, no progress); 1: no ``run_s``; 2: ``run_s`` only where it measures the
#: machine (no ``run_measures``); :meth:`Store._migrate` brings it up to date.
SCHEMA_VERSION = 3

_SCHEMA = """
CREATE TABLE IF NOT EXISTS tables (
    id          TEXT PRIMARY KEY,          -- sha256 of the file
    size        INTEGER NOT NULL,
    name        TEXT NOT NULL,             -- the uploader's file name
    summary     TEXT NOT NULL,             -- JSON, MerlTable.summary()
    created_at  REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS jobs (
    seq         INTEGER PRIMARY KEY AUTOINCREMENT,  -- queue order
    id          TEXT NOT NULL UNIQUE,
    table_id    TEXT NOT NULL REFERENCES tables(id),
    models      TEXT NOT NULL,             -- JSON list of model names
    options     TEXT NOT NULL,             -- JSON object: the request, FitRequest.to_dict()
                                           -- (rows before brdffit.request/1: flat options)
    status      TEXT NOT NULL
                CHECK (status IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    reason      TEXT,                      -- why it failed
    note        TEXT,                      -- what happened on the way (re-runs)
    results     TEXT,                      -- JSON list of FitResult dicts, one per model
    attempts    INTEGER NOT NULL DEFAULT 0,
    created_at  REAL NOT NULL,
    started_at  REAL,
    finished_at REAL,
    stage       TEXT,                      -- what a running job is doing
    fraction    REAL,                      -- how much of it is done, 0 .. 1
    run_s       REAL,                      -- seconds its worker spent on it (done jobs)
    run_measures INTEGER                   -- 1: run_s measures the machine (Store.recent_runs)
);
CREATE INDEX IF NOT EXISTS jobs_by_status ON jobs (status, seq);
CREATE INDEX IF NOT EXISTS jobs_by_table ON jobs (table_id, seq);
CREATE TABLE IF NOT EXISTS probe (
    id          INTEGER PRIMARY KEY CHECK (id = 1),
    at          REAL NOT NULL              -- the last write /healthz made to see it can
);
"""

#: The columns version 0 had, in order (the jobs table is rebuilt to widen its CHECK).
_V0_JOB_COLUMNS = ("seq, id, table_id, models, options, status, reason, note, results, "
                   "attempts, created_at, started_at, finished_at")

#: What to do about a database the service refuses to open (docs/service.md).
REPAIR = ("stop the service, then restore a backup of {path} (docs/service.md, "
          "'Backup and repair') or rebuild it from the table files with "
          "`python -m api.repair rebuild --data-dir {data_dir}`")


class DatabaseRefused(BrdffitError):
    """The job database is damaged, emptied or missing beside existing tables: the
    service does not start on it (starting empty would silently drop every job)."""


class DataDirInUse(BrdffitError):
    """Another server holds the data directory (:class:`ServerLock`)."""


class ServerLock:
    """An exclusive lock on a data directory, held by the server that serves it, from
    before it settles the jobs a stopped server left (:meth:`Store.recover`) until it
    has put its own back. A second ``brdffit serve`` on the same directory, by mistake,
    re-queued the first's running job as a stopped server's (spending an attempt, and
    failing it at the last one), emptied its uploads in progress and, stopping, re-queued
    them again; it now stops, saying which server holds the directory. The lock is the
    kernel's (``flock``): a killed server's is released with its process."""

    NAME = "server.lock"

    def __init__(self, data_dir: str | os.PathLike):
        self.data_dir = Path(data_dir)
        self._fd: int | None = None

    def acquire(self) -> ServerLock:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.data_dir / self.NAME, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 64).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise DataDirInUse(
                f"{self.data_dir} is served by another brdffit server (pid {holder}): stop "
                "it first, or give this one another data directory (--data-dir, "
                "BRDFFIT_DATA_DIR); two servers on one directory take each other's running "
                "jobs for a stopped server's") from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # the lock goes with the descriptor
            self._fd = None

    def __enter__(self) -> ServerLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


@dataclass(frozen=True)
class TableRecord:
    id: str
    size: int
    name: str
    summary: dict
    created_at: float


@dataclass(frozen=True)
class JobRecord:
    id: str
    table_id: str
    models: list[str]
    request: dict  # brdffit.request.FitRequest.to_dict()
    status: str
    reason: str | None
    note: str | None
    results: list[dict] | None
    attempts: int
    created_at: float
    started_at: float | None
    finished_at: float | None
    stage: str | None = None
    fraction: float | None = None
    run_s: float | None = None  # seconds its worker spent on it (Store.finish)


@dataclass(frozen=True)
class Page:
    """One page of a listing, newest first; ``next_cursor`` continues it (None: the end)."""

    items: list
    total: int
    next_cursor: str | None


def _table(row: sqlite3.Row) -> TableRecord:
    return TableRecord(row["id"], row["size"], row["name"], json.loads(row["summary"]),
                       row["created_at"])


def _request(models: list[str], stored: dict) -> dict:
    """A job's request as ``FitRequest.to_dict()`` has it; a job stored before that
    form held ``models`` and flat options, rearranged here as they are read."""
    if "schema" in stored or "models" in stored:  # flat options never held `models`
        return stored
    from brdffit.request import legacy_request

    return legacy_request(models, stored)


def _job(row: sqlite3.Row) -> JobRecord:
    return JobRecord(
        id=row["id"], table_id=row["table_id"], models=json.loads(row["models"]),
        request=_request(json.loads(row["models"]), json.loads(row["options"])),
        status=row["status"], reason=row["reason"],
        note=row["note"], results=json.loads(row["results"]) if row["results"] else None,
        attempts=row["attempts"], created_at=row["created_at"], started_at=row["started_at"],
        finished_at=row["finished_at"], stage=row["stage"], fraction=row["fraction"],
        run_s=row["run_s"],
    )


def _add_note(old: str | None, new: str) -> str:
    return new if not old else f"{old}; {new}"


def _create(con: sqlite3.Connection) -> None:
    # One statement at a time: executescript() would commit the open transaction.
    for statement in _SCHEMA.split(";"):
        if statement.strip():
            con.execute(statement)


class Store:
    """Tables and jobs under one data dir (see the module docstring)."""

    def __init__(self, data_dir: str | os.PathLike, database: str | os.PathLike | None = None,
                 *, check: bool = True):
        self.data_dir = Path(data_dir)
        self.tables_dir = self.data_dir / "tables"
        self.plots_dir = self.data_dir / "plots"
        self.tmp_dir = self.data_dir / "tmp"
        for d in (self.tables_dir, self.plots_dir, self.tmp_dir):
            d.mkdir(parents=True, exist_ok=True)
        self.database = Path(database) if database else self.data_dir / "brdffit.sqlite3"
        if check:
            self.check()
        with self._connect() as con:
            con.execute("PRAGMA journal_mode=WAL")
            self._migrate(con)

    def _refuse(self, problem: str) -> DatabaseRefused:
        what = REPAIR.format(path=self.database, data_dir=self.data_dir)
        return DatabaseRefused(f"job database {self.database}: {problem}; not starting on it "
                               f"(that would drop every job). To go on: {what}")

    def check(self) -> None:
        """Refuse a database that is not one this service can trust (raises
        :class:`DatabaseRefused` saying what is wrong and what to do).

        SQLite opens an empty file, or no file, as a fresh database: a truncated
        file, or one deleted beside the uploaded tables, would start an empty
        service and every job would be gone without a word.
        """
        tables_on_disk = any(self.tables_dir.glob("*.binary"))
        if not self.database.exists():
            if tables_on_disk:
                raise self._refuse(f"missing, but {self.tables_dir} holds uploaded tables")
            return
        if self.database.stat().st_size == 0:
            raise self._refuse("the file is empty (0 bytes): truncated")
        try:
            with self._connect() as con:
                found = [r[0] for r in con.execute("PRAGMA quick_check")]
                version = con.execute("PRAGMA user_version").fetchone()[0]
                names = {r[0] for r in con.execute("SELECT name FROM sqlite_master")}
        except sqlite3.DatabaseError as e:
            raise self._refuse(f"unreadable ({e})") from None
        if found != ["ok"]:
            raise self._refuse("damaged: " + "; ".join(" ".join(f.split()) for f in found[:5]))
        if version > SCHEMA_VERSION:
            raise self._refuse(f"written by a newer brdffit (layout {version}, this one "
                               f"knows up to {SCHEMA_VERSION})")
        if not {"tables", "jobs"} <= names and (names or tables_on_disk):
            raise self._refuse("not a brdffit job database (no tables and jobs)")

    def _migrate(self, con: sqlite3.Connection) -> None:
        """Bring the layout to :data:`SCHEMA_VERSION`, in one transaction."""
        version = con.execute("PRAGMA user_version").fetchone()[0]
        has_jobs = con.execute(
            "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'jobs'").fetchone()
        con.execute("BEGIN IMMEDIATE")
        try:
            if has_jobs and version == 0:
                # Version 0's CHECK has no 'cancelled': SQLite changes a CHECK only by
                # copying the table (https://sqlite.org/lang_altertable.html#otheralter).
                con.execute("ALTER TABLE jobs RENAME TO jobs_v0")
                con.execute("DROP INDEX IF EXISTS jobs_by_status")
                _create(con)
                con.execute(f"INSERT INTO jobs ({_V0_JOB_COLUMNS}) "
                            f"SELECT {_V0_JOB_COLUMNS} FROM jobs_v0")
                con.execute("DROP TABLE jobs_v0")
            else:
                _create(con)
                columns = {r["name"] for r in con.execute("PRAGMA table_info(jobs)")}
                if "run_s" not in columns:  # version 1
                    con.execute("ALTER TABLE jobs ADD COLUMN run_s REAL")
                if "run_measures" not in columns:  # version 2 stored run_s only where it did
                    con.execute("ALTER TABLE jobs ADD COLUMN run_measures INTEGER")
                    con.execute("UPDATE jobs SET run_measures = 1 WHERE run_s IS NOT NULL")
            con.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            con.execute("COMMIT")
        except BaseException:
            con.execute("ROLLBACK")
            raise

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        con = sqlite3.connect(self.database, timeout=30.0, isolation_level=None)
        try:
            con.row_factory = sqlite3.Row
            con.execute("PRAGMA synchronous=NORMAL")
            con.execute("PRAGMA foreign_keys=ON")
            yield con
        finally:
            con.close()

    # -- tables ---------------------------------------------------------------------

    def table_path(self, table_id: str) -> Path:
        return self.tables_dir / f"{table_id}.binary"

    def clear_tmp(self) -> None:
        """Drop uploads that a killed server left half-written."""
        shutil.rmtree(self.tmp_dir, ignore_errors=True)
        self.tmp_dir.mkdir(parents=True, exist_ok=True)

    def add_table(self, table_id: str, tmp_file: Path, size: int, name: str,
                  summary: dict) -> tuple[TableRecord, bool]:
        """Move a validated upload into place; returns (record, newly created).

        The file is renamed before the row is written, so a row always has its
        file. A re-upload (or two racing uploads) of the same bytes keeps the
        first row: the id is the content.
        """
        final = self.table_path(table_id)
        if final.exists():
            tmp_file.unlink(missing_ok=True)
        else:
            os.replace(tmp_file, final)
        return self.register_table(table_id, size, name, summary)

    def register_table(self, table_id: str, size: int, name: str,
                       summary: dict) -> tuple[TableRecord, bool]:
        """The row of a table file already in place (``add_table``, ``api.repair``)."""
        with self._connect() as con:
            cur = con.execute(
                "INSERT OR IGNORE INTO tables (id, size, name, summary, created_at) "
                "VALUES (?, ?, ?, ?, ?)",
                (table_id, size, name, jsonout.dumps(summary), time.time()),
            )
            created = cur.rowcount == 1
            row = con.execute("SELECT * FROM tables WHERE id = ?", (table_id,)).fetchone()
        return _table(row), created

    def get_table(self, table_id: str) -> TableRecord | None:
        with self._connect() as con:
            row = con.execute("SELECT * FROM tables WHERE id = ?", (table_id,)).fetchone()
        return _table(row) if row else None

    # -- jobs -----------------------------------------------------------------------

    def create_job(self, table_id: str, request: dict) -> JobRecord:
        """A queued job of ``request`` (``FitRequest.to_dict()``) on the table ``table_id``;
        its ``models`` are kept beside it, for listings filtered by model."""
        job_id = uuid.uuid4().hex
        models = list(request["models"])
        with self._connect() as con:
            con.execute(
                "INSERT INTO jobs (id, table_id, models, options, status, created_at) "
                "VALUES (?, ?, ?, ?, 'queued', ?)",
                (job_id, table_id, jsonout.dumps(models), jsonout.dumps(request), time.time()),
            )
            row = con.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return _job(row)

    def get_job(self, job_id: str) -> JobRecord | None:
        with self._connect() as con:
            row = con.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return _job(row) if row else None

    def claim_next(self) -> JobRecord | None:
        """The oldest queued job, now marked running (one atomic statement)."""
        with self._connect() as con:
            rows = con.execute(
                "UPDATE jobs SET status = 'running', attempts = attempts + 1, started_at = ?, "
                "stage = 'starting', fraction = 0 "
                "WHERE seq = (SELECT seq FROM jobs WHERE status = 'queued' ORDER BY seq LIMIT 1) "
                "RETURNING *",
                (time.time(),),
            ).fetchall()  # fetch all: the statement (and its commit) completes
        return _job(rows[0]) if rows else None

    def finish(self, job_id: str, results: list[dict], notes=(),
               run_s: float | None = None, measures_machine: bool = False) -> None:
        """The job is done with ``results``; ``notes`` (what happened on the way, e.g.
        a model that could not be fitted beside others) go to its note; ``run_s``: the
        seconds its worker spent on it; ``measures_machine``: they measure its machine
        (:meth:`recent_runs`: no compiling, no work the estimate does not count)."""
        with self._connect() as con:
            row = con.execute("SELECT note FROM jobs WHERE id = ?", (job_id,)).fetchone()
            note = row["note"] if row else None
            for text in notes:
                note = _add_note(note, text)
            con.execute(
                "UPDATE jobs SET status = 'done', results = ?, reason = NULL, note = ?, "
                "finished_at = ?, run_s = ?, run_measures = ? WHERE id = ? "
                "AND status = 'running'",
                (jsonout.dumps(results), note, time.time(), run_s,
                 int(bool(measures_machine and run_s is not None)), job_id),
            )

    def recent_runs(self, limit: int) -> list[tuple[dict, int, float]]:
        """The ``limit`` latest done jobs whose worker time measures the machine (stored
        so by :meth:`finish`), newest first: each
        job's request (``FitRequest.to_dict()``), its table's measured bins and the
        seconds its worker spent on it (the cost estimate's measure of the machine)."""
        with self._connect() as con:
            rows = con.execute(
                "SELECT jobs.models, jobs.options, jobs.run_s, tables.summary FROM jobs "
                "JOIN tables ON tables.id = jobs.table_id "
                "WHERE jobs.status = 'done' AND jobs.run_s IS NOT NULL AND jobs.run_measures = 1 "
                "ORDER BY jobs.finished_at DESC LIMIT ?", (limit,)).fetchall()
        out = []
        for row in rows:
            bins = json.loads(row["summary"]).get("measured_bins")
            if isinstance(bins, int) and bins > 0:
                out.append((_request(json.loads(row["models"]), json.loads(row["options"])),
                            bins, row["run_s"]))
        return out

    def fail(self, job_id: str, reason: str) -> None:
        with self._connect() as con:
            con.execute(
                "UPDATE jobs SET status = 'failed', reason = ?, finished_at = ? "
                "WHERE id = ? AND status = 'running'",
                (reason, time.time(), job_id),
            )

    def retry_or_fail(self, job_id: str, what: str, max_attempts: int) -> str:
        """A run was interrupted (``what`` happened): queue it again while it has
        attempts left, else fail it. Returns the new status."""
        with self._connect() as con:
            row = con.execute("SELECT attempts, note FROM jobs WHERE id = ? AND status = 'running'",
                              (job_id,)).fetchone()
            if row is None:
                return "gone"
            if row["attempts"] < max_attempts:
                note = _add_note(
                    row["note"], f"attempt {row['attempts']} interrupted ({what}); re-queued"
                )
                con.execute("UPDATE jobs SET status = 'queued', note = ? WHERE id = ?",
                            (note, job_id))
                return "queued"
            reason = (f"interrupted {row['attempts']} time(s), the last by: {what}; "
                      f"not retried (BRDFFIT_MAX_ATTEMPTS={max_attempts})")
            con.execute("UPDATE jobs SET status = 'failed', reason = ?, finished_at = ? "
                        "WHERE id = ?", (reason, time.time(), job_id))
            return "failed"

    def recover(self, max_attempts: int) -> tuple[list[str], list[str]]:
        """At start: settle the jobs that were running when the last server died.

        Returns (re-queued ids, failed ids). Queued jobs need nothing: they run.
        """
        requeued, failed = [], []
        with self._connect() as con:
            ids = [r["id"] for r in con.execute("SELECT id FROM jobs WHERE status = 'running'")]
        for job_id in ids:
            status = self.retry_or_fail(job_id, "the server stopped while it ran", max_attempts)
            (requeued if status == "queued" else failed).append(job_id)
        return requeued, failed

    def release_running(self) -> int:
        """At a clean shutdown: running jobs go back to the queue, the attempt not
        counted (the server chose to stop; the job did nothing wrong)."""
        with self._connect() as con:
            cur = con.execute(
                "UPDATE jobs SET status = 'queued', attempts = MAX(attempts - 1, 0), "
                "note = CASE WHEN note IS NULL THEN 'server shut down while it ran; re-queued' "
                "ELSE note || '; server shut down while it ran; re-queued' END "
                "WHERE status = 'running'"
            )
            return cur.rowcount

    def set_progress(self, job_id: str, stage: str, fraction: float) -> None:
        with self._connect() as con:
            con.execute("UPDATE jobs SET stage = ?, fraction = ? "
                        "WHERE id = ? AND status = 'running'", (stage, fraction, job_id))

    def cancel_queued(self, job_id: str) -> bool:
        """Cancel a job that has not started; False if it is not queued (any more)."""
        with self._connect() as con:
            cur = con.execute(
                "UPDATE jobs SET status = 'cancelled', reason = 'cancelled before it started', "
                "finished_at = ?, stage = NULL WHERE id = ? AND status = 'queued'",
                (time.time(), job_id))
            return cur.rowcount == 1

    def cancelled(self, job_id: str, reason: str) -> None:
        """A running job was stopped on request."""
        with self._connect() as con:
            con.execute("UPDATE jobs SET status = 'cancelled', reason = ?, finished_at = ? "
                        "WHERE id = ? AND status = 'running'", (reason, time.time(), job_id))

    def list_jobs(self, *, limit: int, cursor: int | None = None, status: str | None = None,
                  table_id: str | None = None, model: str | None = None) -> Page:
        """Jobs, newest first, ``limit`` at a time; ``cursor``: the last page's
        ``next_cursor``. Keyset paging: a page stays right while jobs are added."""
        where, args = [], []
        if status is not None:
            where.append("status = ?")
            args.append(status)
        if table_id is not None:
            where.append("table_id = ?")
            args.append(table_id)
        if model is not None:
            where.append("EXISTS (SELECT 1 FROM json_each(jobs.models) WHERE value = ?)")
            args.append(model)
        return self._page("jobs", "seq", where, args, limit, cursor, _job)

    def list_tables(self, *, limit: int, cursor: int | None = None,
                    name: str | None = None) -> Page:
        """Tables, newest first; ``name``: the ones whose name contains it."""
        where, args = [], []
        if name is not None:
            where.append("instr(lower(name), lower(?)) > 0")
            args.append(name)
        return self._page("tables", "rowid", where, args, limit, cursor, _table)

    def _page(self, table: str, key: str, where: list[str], args: list, limit: int,
              cursor: int | None, make) -> Page:
        clause = " AND ".join(where) or "1"
        with self._connect() as con:
            total = con.execute(f"SELECT COUNT(*) FROM {table} WHERE {clause}", args).fetchone()[0]
            if cursor is not None:
                clause += f" AND {key} < ?"
                args = [*args, cursor]
            rows = con.execute(f"SELECT {key} AS page_key, * FROM {table} WHERE {clause} "
                               f"ORDER BY {key} DESC LIMIT ?", [*args, limit + 1]).fetchall()
        more = len(rows) > limit
        rows = rows[:limit]
        return Page([make(r) for r in rows], total,
                    str(rows[-1]["page_key"]) if more else None)

    def delete_job(self, job_id: str) -> str | None:
        """Delete a finished job and its plots. Returns None when deleted, else the
        status that stops it (``queued``/``running``: cancel it first; ``gone``)."""
        with self._connect() as con:
            row = con.execute("SELECT status FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is None:
                return "gone"
            cur = con.execute("DELETE FROM jobs WHERE id = ? AND status IN "
                              "('done', 'failed', 'cancelled')", (job_id,))
            if cur.rowcount != 1:
                # read again: a DELETE beside this one may have taken it since (this one
                # answered 409 "cancelled; cancel it first" for a job already gone)
                now = con.execute("SELECT status FROM jobs WHERE id = ?", (job_id,)).fetchone()
                return "gone" if now is None else now["status"]
        shutil.rmtree(self.plots_dir / job_id, ignore_errors=True)
        return None

    def delete_table(self, table_id: str, *, with_fits: bool) -> tuple[str | None, int]:
        """Delete a table (row, then file). Returns (None, fits deleted) or (why not, count):
        ``gone``; ``fits`` (jobs use it and ``with_fits`` is False); ``active``
        (queued or running jobs use it)."""
        with self._connect() as con:
            con.execute("BEGIN IMMEDIATE")
            try:
                if con.execute("SELECT 1 FROM tables WHERE id = ?", (table_id,)).fetchone() is None:
                    con.execute("ROLLBACK")
                    return "gone", 0
                jobs = con.execute("SELECT id, status FROM jobs WHERE table_id = ?",
                                   (table_id,)).fetchall()
                active = [j for j in jobs if j["status"] not in FINISHED]
                if active or (jobs and not with_fits):
                    con.execute("ROLLBACK")
                    return ("active" if active else "fits"), len(active or jobs)
                con.execute("DELETE FROM jobs WHERE table_id = ?", (table_id,))
                con.execute("DELETE FROM tables WHERE id = ?", (table_id,))
                con.execute("COMMIT")
            except BaseException:
                if con.in_transaction:
                    con.execute("ROLLBACK")
                raise
        # The row first: a row never points at a missing file (a file without a row
        # is only disk space, and the next upload of the same bytes reuses it).
        self.table_path(table_id).unlink(missing_ok=True)
        for job in jobs:
            shutil.rmtree(self.plots_dir / job["id"], ignore_errors=True)
        return None, len(jobs)

    def probe(self) -> None:
        """One real write (raises if the database cannot take one): what /healthz
        and a dispatcher waiting out a storage failure ask."""
        with self._connect() as con:
            con.execute("INSERT OR REPLACE INTO probe (id, at) VALUES (1, ?)", (time.time(),))

    def backup(self, destination: str | os.PathLike) -> None:
        """A consistent copy of the database while the service runs (SQLite's
        online backup); the table files are plain files beside it."""
        with self._connect() as con, closing(sqlite3.connect(destination)) as out:
            con.backup(out)

    def counts(self) -> dict[str, int]:
        with self._connect() as con:
            rows = con.execute("SELECT status, COUNT(*) AS n FROM jobs GROUP BY status").fetchall()
        return {s: 0 for s in STATUSES} | {r["status"]: r["n"] for r in rows}

    # -- plots ----------------------------------------------------------------------

    def export_path(self, job_id: str, model: str, target: str, target_model: str | None,
                    viewer: str) -> Path:
        """Where a made export is kept (beside the job's plots, removed with them): one
        file per target, renderer's model and viewer asked for, and per version of
        brdffit that made it (a newer one makes it again: its schema or its fit may
        differ)."""
        from brdffit import __version__

        name = f"export-{target}-{target_model or '-'}-{viewer}-{__version__}.json"
        return self.plots_dir / job_id / model / name

    def plot_path(self, job_id: str, model: str, kind: str, exposure_ev: float = 0.0) -> Path:
        """Where a rendered plot is kept; one file per exposure asked for."""
        name = kind if exposure_ev == 0 else f"{kind}@{exposure_ev:+g}EV"
        return self.plots_dir / job_id / model / f"{name}.png"
