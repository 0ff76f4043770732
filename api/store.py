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

import json
import os
import shutil
import sqlite3
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from brdffit import jsonout

STATUSES = ("queued", "running", "done", "failed")

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
    options     TEXT NOT NULL,             -- JSON object, fit() keywords
    status      TEXT NOT NULL CHECK (status IN ('queued', 'running', 'done', 'failed')),
    reason      TEXT,                      -- why it failed
    note        TEXT,                      -- what happened on the way (re-runs)
    results     TEXT,                      -- JSON list of FitResult dicts, one per model
    attempts    INTEGER NOT NULL DEFAULT 0,
    created_at  REAL NOT NULL,
    started_at  REAL,
    finished_at REAL
);
CREATE INDEX IF NOT EXISTS jobs_by_status ON jobs (status, seq);
"""


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
    options: dict
    status: str
    reason: str | None
    note: str | None
    results: list[dict] | None
    attempts: int
    created_at: float
    started_at: float | None
    finished_at: float | None


def _table(row: sqlite3.Row) -> TableRecord:
    return TableRecord(row["id"], row["size"], row["name"], json.loads(row["summary"]),
                       row["created_at"])


def _job(row: sqlite3.Row) -> JobRecord:
    return JobRecord(
        id=row["id"], table_id=row["table_id"], models=json.loads(row["models"]),
        options=json.loads(row["options"]), status=row["status"], reason=row["reason"],
        note=row["note"], results=json.loads(row["results"]) if row["results"] else None,
        attempts=row["attempts"], created_at=row["created_at"], started_at=row["started_at"],
        finished_at=row["finished_at"],
    )


def _add_note(old: str | None, new: str) -> str:
    return new if not old else f"{old}; {new}"


class Store:
    """Tables and jobs under one data dir (see the module docstring)."""

    def __init__(self, data_dir: str | os.PathLike, database: str | os.PathLike | None = None):
        self.data_dir = Path(data_dir)
        self.tables_dir = self.data_dir / "tables"
        self.plots_dir = self.data_dir / "plots"
        self.tmp_dir = self.data_dir / "tmp"
        for d in (self.tables_dir, self.plots_dir, self.tmp_dir):
            d.mkdir(parents=True, exist_ok=True)
        self.database = Path(database) if database else self.data_dir / "brdffit.sqlite3"
        with self._connect() as con:
            con.execute("PRAGMA journal_mode=WAL")
            con.executescript(_SCHEMA)

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

    def create_job(self, table_id: str, models: list[str], options: dict) -> JobRecord:
        job_id = uuid.uuid4().hex
        with self._connect() as con:
            con.execute(
                "INSERT INTO jobs (id, table_id, models, options, status, created_at) "
                "VALUES (?, ?, ?, ?, 'queued', ?)",
                (job_id, table_id, jsonout.dumps(models), jsonout.dumps(options), time.time()),
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
                "UPDATE jobs SET status = 'running', attempts = attempts + 1, started_at = ? "
                "WHERE seq = (SELECT seq FROM jobs WHERE status = 'queued' ORDER BY seq LIMIT 1) "
                "RETURNING *",
                (time.time(),),
            ).fetchall()  # fetch all: the statement (and its commit) completes
        return _job(rows[0]) if rows else None

    def finish(self, job_id: str, results: list[dict]) -> None:
        with self._connect() as con:
            con.execute(
                "UPDATE jobs SET status = 'done', results = ?, reason = NULL, finished_at = ? "
                "WHERE id = ? AND status = 'running'",
                (jsonout.dumps(results), time.time(), job_id),
            )

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

    def counts(self) -> dict[str, int]:
        with self._connect() as con:
            rows = con.execute("SELECT status, COUNT(*) AS n FROM jobs GROUP BY status").fetchall()
        return {s: 0 for s in STATUSES} | {r["status"]: r["n"] for r in rows}

    # -- plots ----------------------------------------------------------------------

    def plot_path(self, job_id: str, model: str, kind: str) -> Path:
        return self.plots_dir / job_id / model / f"{kind}.png"
