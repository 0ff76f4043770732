"""Fit one request to many tables into one HDF5 file: ``run_batch(inputs, request, out)``.

The shape of a batch:

1. inputs (files, directories, glob patterns) become a sorted list of table
   paths (:func:`find_tables`);
2. tables already fitted with the same content (sha256), model, options and scene are
   skipped (resume: :class:`brdffit.batch.store.BatchStore`);
3. one work item per table and model left goes to Dask workers, local processes
   by default or an existing cluster (``scheduler="tcp://HOST:PORT"``); a worker
   reads the table from its path and fits the model
   (:func:`brdffit.batch.tasks.fit_table`);
4. results return to this process, the only writer, which journals each fit as
   it arrives and checkpoints the HDF5 file atomically. An interrupted batch
   cancels what it left on the cluster.

A bad table is a failed record, not an exception: the batch fits all the rest
and :attr:`BatchSummary.ok` is False. ``workers=0`` runs everything in this
process without Dask (debugging, or a machine where Dask cannot start workers).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import glob
import hashlib
import json
import math
import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

from brdffit import jsonout
from brdffit.batch.cluster import CONNECT_TIMEOUT_S, DaskRunner, connect, require_dask
from brdffit.batch.progress import ProgressLine
from brdffit.batch.store import FORMAT, BatchStore, is_hdf5
from brdffit.batch.tasks import (
    FitRecord,
    TableReadRecord,
    fit_read_table,
    fit_table,
    now,
    read_table,
    work_items,
    worker_name,
)
from brdffit.errors import BrdffitError, FitInputError

if TYPE_CHECKING:
    from brdffit.request import FitRequest

__all__ = ["BatchInputError", "BatchSummary", "DaskRunner", "find_tables", "request_of",
           "run_batch"]

TABLE_SUFFIX = ".binary"
#: What a directory given to a batch yields: MERL tables and sample lists by suffix
#: (brdffit.io.readers; ``.txt``, which notes share, only when named).
DIR_SUFFIXES = (TABLE_SUFFIX, ".astm", ".csv", ".tsv", ".h5", ".hdf5", ".mat", ".npz",
                ".xlsx")


#: Set by the shell's SIGINT/SIGTERM handler (``brdffit batch``) with the
#: KeyboardInterrupt it raises: the batch stops at its next result even where that
#: exception was lost. Python prints and ignores one raised inside a weakref callback
#: or a ``__del__``, and the batch then ran to its end and exited 0 after a Ctrl-C.
stop_requested = threading.Event()


class BatchInputError(BrdffitError, ValueError):
    """Batch arguments that name nothing to fit (no such file, empty glob, no models)."""


@dataclass
class BatchSummary:
    """What one ``run_batch`` call did. Failures are this run's (path, message)."""

    out: str
    tables: int = 0
    skipped: int = 0  # tables whose every fit was already in the file
    kept: int = 0  # fits of the other tables already in the file, not made again
    # fits in the file to be made again, of tables hashed before the run (--refit hashes
    # none: it makes every fit again, as asked): made with other options, or of a table
    # whose file changed since
    replaced_options: int = 0
    replaced_changed: int = 0
    refitted: int = 0  # stored successful fits made again because --refit asked
    resumed_refit: str | None = None  # when the interrupted --refit this run goes on with began
    moved: int = 0  # tables found at a new path (same content): their fits went with them
    # other batches' results files in a folder fitted: passed over (they are no tables)
    passed_over: list[str] = field(default_factory=list)
    # (path, group) of each new table whose group is not its file's name: another
    # table of the same name has that group (a/mat.binary and b/mat.binary: mat, mat~2)
    renamed: list[tuple[str, str]] = field(default_factory=list)
    fits: int = 0  # fits made in this run, failed ones included
    failed_tables: list[tuple[str, str]] = field(default_factory=list)
    failed_fits: list[tuple[str, str, str]] = field(default_factory=list)  # path, model, message
    recovered: int = 0  # journal records of an interrupted run folded into the file
    recovered_fits: int = 0  # of them, fits (each fit's table has a record too)
    damaged: int = 0  # fits whose stored result did not read back: fitted again
    elapsed_s: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.failed_tables and not self.failed_fits

    @property
    def n_failed_tables(self) -> int:
        """Tables with a failure: unreadable, malformed, or any of their fits failed."""
        return len({p for p, _ in self.failed_tables} | {p for p, _, _ in self.failed_fits})


@dataclass(frozen=True)
class _Task:
    path: str
    expected_sha256: str | None
    done_models: tuple[str, ...]


def find_tables(inputs: Iterable[str], exclude: Iterable[str] = (),
                passed_over: list[str] | None = None) -> list[str]:
    """Absolute paths of the tables that ``inputs`` name, in order, without repeats.

    A file is taken whatever its name (a bad one fails as a table, later); a
    directory gives every measured file below it by its suffix (:data:`DIR_SUFFIXES`:
    MERL tables and sample lists, a lab's mixed folder); a pattern (``*``, ``?``,
    ``[``) is expanded like a shell glob, ``**`` included. An input that names nothing
    is an error: it is far more often a typo than an intent. ``exclude``: paths never
    taken (the batch's own results file, an HDF5 file in the folder it fits).
    ``passed_over``: given, a folder's HDF5 files that are another batch's results
    (``brdffit-batch``) are appended to it rather than taken (each failed as a table on
    every run, and the batch always exited 1); named alone, such a file is taken.
    """
    found: dict[str, None] = {}
    # the results file and its journal (a quoted 'g/*' with --out g/r.h5 took the results
    # file in as a table on every run after the first, failed, and a crash's journal too)
    skip = {os.path.abspath(os.fspath(p)) + end for p in exclude for end in ("", ".journal")}

    skipped: list[str] = []
    hidden: list[str] = []

    def add_dir(d: str) -> int:
        # glob passes over a folder it cannot read without a word: its files were left
        # out of the batch unsaid (and a folder named itself "held no measured file")
        unreadable: list[OSError] = []
        for _ in os.walk(d, onerror=unreadable.append):
            pass
        if unreadable:
            e = unreadable[0]
            more = f" (and {len(unreadable) - 1} more)" if len(unreadable) > 1 else ""
            raise BatchInputError(f"{e.filename}: cannot be read ({e.strerror}){more}: its "
                                  "files would be left out of the batch; make it readable, "
                                  "or name the folders to fit")
        # one walk; hidden files and folders (an editor's, a sync tool's) are left out,
        # as a shell's * leaves them, and said where they are all the folder holds
        # ("holds no measured file" was untrue)
        every = sorted(f for suffix in DIR_SUFFIXES for f in glob.glob(
            os.path.join(glob.escape(d), "**", "*" + suffix), recursive=True,
            include_hidden=True))
        files = []
        for f in every:
            is_hidden = any(part.startswith(".") for part in
                            os.path.relpath(f, d).split(os.sep))
            (hidden if is_hidden else files).append(f)
        n = 0
        for f in files:
            if os.path.abspath(f) in skip:
                skipped.append(f)
            # a link to nothing is taken too: it fails as a table, named with its
            # reason, rather than vanishing from the batch unsaid
            elif passed_over is not None and is_batch_results(f):
                passed_over.append(os.path.abspath(f))
            elif os.path.isfile(f) or not os.path.exists(f):
                found.setdefault(os.path.abspath(f))
                n += 1
        return n

    for text in inputs:
        if os.path.isdir(text):
            skipped.clear()
            hidden.clear()
            before = len(passed_over or ())
            if not add_dir(text):
                parts = [f"{', '.join(skipped)}, the batch's own results file (--out)"
                         ] if skipped else []
                if passed_over is not None and len(passed_over) > before:
                    parts.append(f"{_hidden_words(passed_over[before:])}, another batch's "
                                 "results")
                if hidden:
                    parts.append(f"{_hidden_words(hidden)}, hidden (a name or folder "
                                 "starting with '.'): name them to fit them")
                but = f" but {'; '.join(parts)}" if parts else ""
                raise BatchInputError(f"{text}: directory holds no measured file{but} "
                                      f"({', '.join('*' + s for s in DIR_SUFFIXES)})")
        elif os.path.lexists(text):
            if os.path.abspath(text) in skip:
                raise BatchInputError(f"{text}: the batch's own results file (--out), not a "
                                      "table")
            found.setdefault(os.path.abspath(text))
        elif glob.has_magic(text):
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise BatchInputError(f"{text}: no file matches")
            for m in matches:
                if os.path.isdir(m):
                    add_dir(m)
                elif os.path.abspath(m) not in skip:
                    found.setdefault(os.path.abspath(m))
            if not any(os.path.abspath(m) not in skip for m in matches):
                raise BatchInputError(f"{text}: matches the batch's own results file (--out) "
                                      "alone")
        else:
            raise BatchInputError(f"{text}: no such file or directory")
    if not found:
        raise BatchInputError("no tables to fit")
    _check_names_storable(found)
    return list(found)


def is_batch_results(path: str) -> bool:
    """Whether ``path`` is an HDF5 file that a batch wrote (its ``format`` attribute)."""
    if not path.endswith((".h5", ".hdf5")) or not is_hdf5(path):
        return False
    try:
        import h5py

        with h5py.File(path, "r") as f:
            return f.attrs.get("format") in (FORMAT, FORMAT.encode())
    except (OSError, ValueError):
        return False


def _hidden_words(hidden: list[str]) -> str:
    return ", ".join(hidden[:3]) + (f" and {len(hidden) - 3} more" if len(hidden) > 3 else "")


def _check_names_storable(paths) -> None:
    """Refuses paths whose names are not valid UTF-8 (bytes a filesystem keeps and
    Python reads as surrogates): the results file stores every path as UTF-8 text, and
    h5py failed on the first checkpoint with "'utf-8' codec can't encode characters",
    naming no file, after the batch had run. Named here, before any work."""
    bad = []
    for p in paths:
        try:
            p.encode("utf-8")
        except UnicodeEncodeError:
            bad.append(p.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace"))
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        raise BatchInputError(f"{shown}: a file name that is not valid UTF-8 (the results "
                              "file stores names as UTF-8): rename it, or leave it out")


def request_of(request) -> FitRequest:
    """A batch's :class:`~brdffit.request.FitRequest`: ``request`` itself, or model
    names (a list, or ``"ggx,lambert"``; ``"auto"`` for the selection's candidates)
    with the library's default options. An unknown name is an input error."""
    from brdffit.request import FitRequest

    if isinstance(request, FitRequest):
        return request
    try:
        return FitRequest.of(list(request) if not isinstance(request, str) else request)
    except FitInputError as e:
        raise BatchInputError(str(e)) from None


def file_sha256(path: str) -> str | None:
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            while chunk := f.read(1 << 22):
                h.update(chunk)
    except OSError:
        return None  # the worker will read it too, and record why it cannot
    return h.hexdigest()


def _moved(paths: list[str], store: BatchStore) -> int:
    """How many of ``paths`` are tables the file recorded at a path now gone, found
    at a new one (by their sha256); each move is recorded (:meth:`BatchStore.record_move`): a
    folder moved or renamed is resumed, its tables keep their groups. New files are
    hashed only when some recorded file is gone."""
    gone = store.vanished()
    new = [p for p in paths if store.known_sha256(p) is None]
    if not gone or not new:
        return 0
    with ThreadPoolExecutor(max_workers=4) as pool:
        hashes = list(pool.map(file_sha256, new))
    moved = 0
    for p, sha in zip(new, hashes, strict=True):
        old = gone.pop(sha, None)
        if old is not None:
            store.record_move(old, p)
            moved += 1
    return moved


def _plan(paths: list[str], request: FitRequest, store: BatchStore, refit: bool,
          summary: BatchSummary, refit_since: str | None = None) -> list[_Task]:
    """Tasks for the tables with fits left to make; ``summary`` counts the tables
    complete and the stored fits that will be made again (and why). ``refit``: every
    fit is made again, but those made since ``refit_since`` (an interrupted --refit
    of the same request, gone on with)."""
    model_names, key = list(request.fitted_models), request.fit_key()
    # Only tables a previous run read need hashing here; new ones are hashed by
    # their worker from the bytes it fits. hashlib releases the GIL: threads help.
    known = [p for p in paths if (not refit or refit_since) and store.known_sha256(p)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        current = dict(zip(known, pool.map(file_sha256, known), strict=True))
    tasks = []
    for p in paths:
        sha = current.get(p)
        done = store.done_models(p, sha, key) if sha else set()
        if refit:
            done &= store.made_since(p, refit_since) if refit_since else set()
            summary.refitted += len(store.stored_ok(p, model_names) - done)
        if done >= set(model_names):
            summary.skipped += 1
            continue
        # auto's candidates are fitted together: where one is left, all are made again
        left = {m for item in work_items(request, [m for m in model_names if m not in done])
                for m in item}
        tasks.append(_Task(p, sha, tuple(sorted(done))))
        summary.kept += len(done - left)
        if sha is not None and not refit:  # its fits of other options or content go once read
            options, changed = store.replaced(p, sha, key, model_names)
            summary.replaced_options += options
            summary.replaced_changed += changed
    return tasks


def _refit_mark(store: BatchStore, attrs: dict, refit: bool,
                summary: BatchSummary) -> str | None:
    """For ``--refit``: sets ``attrs["refit_pending"]`` (the request and when its refit
    began, kept in the file until the refit finishes) and returns when an interrupted
    refit of the same request began, which this run goes on with (None: none)."""
    if not refit:
        return None
    mark = {"models": attrs["models"], "options": attrs["options"], "since": now()}
    pending = None
    if os.path.exists(store.path):
        from brdffit.batch.store import read_attrs

        try:
            pending = json.loads(read_attrs(store.path).get("refit_pending") or "null")
        except ValueError:
            pending = None
    since = None
    if (isinstance(pending, dict) and pending.get("models") == mark["models"]
            and pending.get("options") == mark["options"]
            and isinstance(pending.get("since"), str)):
        since = mark["since"] = pending["since"]
        summary.resumed_refit = since
    attrs["refit_pending"] = mark
    return since


def _models_left(task: _Task, sha256: str | None, model_names: list[str]) -> list[str]:
    """The models still to fit on a table read with content ``sha256``: the plan's
    finished models hold only for the content it hashed."""
    done = set(task.done_models) if sha256 == task.expected_sha256 else set()
    return [m for m in model_names if m not in done]


def _run_in_process(tasks: list[_Task], request: FitRequest) -> Iterator[dict]:
    """One table after another in this process, the next one read (and hashed: ~60
    ms for 35 MB) in a thread while this one is fitted: file reading and hashing
    release the GIL. Each fit is yielded, and so journaled, as it ends: an
    interrupted run keeps the finished models of the table it was fitting."""
    wire = request.to_dict()
    with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="brdffit-read") as pool:
        ahead = pool.submit(read_table, tasks[0].path) if tasks else None
        for i, t in enumerate(tasks):
            read = ahead.result()
            ahead = pool.submit(read_table, tasks[i + 1].path) if i + 1 < len(tasks) else None
            todo = (_models_left(t, read[1].sha256, list(request.fitted_models))
                    if read[0] is not None else [])
            if not todo:  # unreadable: one record, no fits
                yield {**fit_read_table(read, wire, []), "table_done": True}
            items = work_items(request, todo)
            for j, item in enumerate(items):
                yield {**fit_read_table(read, wire, item), "table_done": j == len(items) - 1}


def _run_on_dask(client, tasks: list[_Task], request: FitRequest,
                 timeout_s: float | None) -> Iterator[dict]:
    """One Dask task per (table, model) (auto's candidates: one task for them all,
    :func:`~brdffit.batch.tasks.work_items`), each result yielded as it arrives.

    Per model rather than per table, so that an interrupted batch loses at most
    the fits in flight (the finished models of a table are journaled), and a
    cancelled batch leaves each worker at most one fit to finish: a running task
    cannot be stopped, and a whole table's models ran on for minutes after the
    client had gone. A table's tasks are sent to one worker first, which keeps the
    table it read for the next model's task.

    Each task reads the table itself, so a file rewritten during the batch can give
    its models different content. The store keeps one content per table (the last
    read), and dropped the fits of the other without a word: where a table's fits
    disagree, the file is hashed again and every model not fitted to what it holds
    now is fitted again (:data:`CONTENT_ROUNDS` times at most, then failed, saying why).
    """
    from distributed import as_completed

    futures = {}  # future -> (task, its models)
    left: dict[str, int] = {}  # table path -> its fits not yet returned
    tables_read: dict[str, dict] = {}  # table path -> a worker's record of reading it
    # table path -> model -> the content (sha256) its fit read; the plan's finished
    # models count as fits of the content it hashed
    fitted = {t.path: dict.fromkeys(t.done_models, t.expected_sha256) for t in tasks}
    rounds: dict[str, int] = {}  # table path -> times its models were refitted for a change

    wire, model_names = request.to_dict(), list(request.fitted_models)
    options = request.fit_record()

    # Each table's tasks go to one worker first (round robin over the tables): it reads
    # the table once and fits its models from that one read (brdffit.batch.tasks.
    # recent_table); a worker left idle may still take them (work stealing).
    homes = list(client.scheduler_info().get("workers", {}))
    home_of = {t.path: homes[i % len(homes)] for i, t in enumerate(tasks)} if homes else {}

    def submit(t: _Task, item: list[str]):
        home = home_of.get(t.path)  # none where no worker had joined yet
        where = {} if home is None else {"workers": [home], "allow_other_workers": True}
        fut = client.submit(fit_table, t.path, wire, item, None, (), pure=False, **where)
        futures[fut] = (t, item)
        left[t.path] = left.get(t.path, 0) + 1
        return fut

    for t in tasks:
        for item in work_items(request, _models_left(t, t.expected_sha256, model_names)):
            submit(t, item)
    pending = as_completed(list(futures), loop=client.loop, timeout=timeout_s)
    try:
        for fut in pending:
            t, item = futures.pop(fut)
            try:
                result = fut.result()
            except Exception as exc:  # noqa: BLE001 - the task failed, not the batch
                # fit_table returns failures as records, so this is a worker that
                # died on the fit (after Dask's retries) or a lost cluster.
                why = f"worker failed on this table: {type(exc).__name__}: {exc}"
                read = tables_read.get(t.path)
                if read is not None:  # another fit read it: this model's fit failed
                    result = {"table": read, "fits": [asdict(FitRecord(
                        path=t.path, model=model, sha256=read["sha256"], options=options,
                        status="failed", message=why, worker=worker_name(), finished_at=now(),
                    )) for model in item]}
                else:
                    result = {"table": asdict(TableReadRecord(
                        path=t.path, status="failed", worker=worker_name(), finished_at=now(),
                        message=why)), "fits": []}
            fut.release()
            sha = result["table"]["sha256"]
            if result["table"]["status"] == "ok":
                tables_read[t.path] = result["table"]
            if sha is not None:
                fitted[t.path].update(dict.fromkeys(item, sha))
                if len(set(fitted[t.path].values())) > 1:
                    # The file changed since the plan hashed it, or between two of its
                    # tasks' reads: what it holds now decides which fits stand.
                    result = _refit_changed(
                        t, result, fitted[t.path], rounds, futures,
                        lambda again, t=t: pending.add(submit(t, again)), request)
            left[t.path] -= 1
            if result is None:
                continue  # a fit of content gone: fitted again, or failed, above
            yield {**result, "table_done": left[t.path] == 0}
    finally:
        # Interrupted (Ctrl-C, SIGTERM, an error): nothing of this batch stays on
        # the cluster but the fits already running.
        client.cancel(list(futures))


#: How many times a table's models are fitted again for a file rewritten during the
#: batch, before they are failed: a file written to all the time is not a measurement.
CONTENT_ROUNDS = 3


def _refit_changed(t: _Task, result: dict, fitted: dict[str, str | None],
                   rounds: dict[str, int], futures: dict, resubmit, request) -> dict | None:
    """Sends again the models of ``t`` whose fits read other content than its file
    holds now (those still running are checked as they return). Returns ``result``
    to store, or None where it is itself a fit of content gone: stored, its table's
    record would drop the fits of what the file holds now. Past :data:`CONTENT_ROUNDS`
    the models are not sent again but failed, saying why."""
    now_sha = file_sha256(t.path)
    running = {m for fut_t, fut_item in futures.values() if fut_t.path == t.path
               for m in fut_item}
    stale = [m for m, sha in fitted.items() if sha != now_sha and m not in running]
    gone = result["table"]["sha256"] != now_sha
    if not stale:
        return None if gone else result
    rounds[t.path] = rounds.get(t.path, 0) + 1
    if rounds[t.path] > CONTENT_ROUNDS:
        why = (f"the file changed while the batch fitted it ({CONTENT_ROUNDS} times "
               "over): run the batch again once it is written")
        fits = [f for f in result["fits"] if f["model"] not in stale]
        fits += [asdict(FitRecord(path=t.path, model=m, sha256=now_sha,
                                  options=request.fit_record(), status="failed",
                                  message=why, worker=worker_name(), finished_at=now()))
                 for m in stale]
        for m in stale:
            fitted[m] = now_sha  # failed, for what the file holds now: not sent again
        return {**result, "table": {**result["table"], "sha256": now_sha}, "fits": fits}
    for again in work_items(request, stale):
        for m in again:
            fitted.pop(m, None)  # running again: decided when it returns
        resubmit(again)
    return None if gone else result


class _Complete:
    """Whether the run is complete: every result stored. From then on a Ctrl-C or
    SIGTERM is no interrupt: it may cut short what is left (the local cluster takes 2-3
    s to shut down after the last result), and the run ends as finished. A signal in
    that window made a complete batch an interrupted one (exit 130, no summary, its
    --refit mark kept). As a context manager, drops such a KeyboardInterrupt."""

    complete = False

    def __enter__(self) -> _Complete:
        return self

    def __exit__(self, kind, value, tb) -> bool:
        return self.complete and kind is not None and issubclass(kind, KeyboardInterrupt)


#: A scheduler not reached after this long is said to be waited for (:func:`_reached`).
SAY_WAITING_AFTER_S = 2.0


@contextlib.contextmanager
def _reached(scheduler: str, progress: bool | ProgressLine) -> Iterator:
    """``connect(scheduler=...)``, saying on stderr what the batch waits for where the
    address took the connection and its answer takes more than
    :data:`SAY_WAITING_AFTER_S`: such an address is waited for up to the connect timeout
    (30 s), and the terminal stayed blank meanwhile. A quick connect or refusal says
    nothing, nor does an address where nothing listens (refused after 5 s): the line
    said "waiting up to 30 s for its answer" there too, of an answer never waited for."""
    line = progress if isinstance(progress, ProgressLine) else ProgressLine(
        0, enabled=bool(progress))
    listening, settled = threading.Event(), threading.Event()

    def say_when_waiting() -> None:
        if settled.wait(SAY_WAITING_AFTER_S):
            return
        listening.wait()  # set on settling too
        if not settled.is_set():
            line.say(f"reaching the Dask scheduler at {scheduler} (waiting up to "
                     f"{CONNECT_TIMEOUT_S:g} s for its answer)")

    waiter = threading.Thread(target=say_when_waiting, name="dask-waiting", daemon=True)
    with contextlib.ExitStack() as stack:
        waiter.start()
        try:
            client = stack.enter_context(connect(scheduler=scheduler,
                                                 timeout_s=CONNECT_TIMEOUT_S,
                                                 listening=listening))
        finally:
            settled.set()
            listening.set()
        yield client


def run_batch(
    inputs: Iterable[str],
    request: FitRequest | Iterable[str] | str,
    out: str | os.PathLike,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    refit: bool = False,
    progress: bool | ProgressLine = True,
    checkpoint_s: float = 10.0,
    on_result: Callable[[TableReadRecord, list[FitRecord]], None] | None = None,
    timeout_s: float | None = None,
) -> BatchSummary:
    """Fit ``request`` to every table of ``inputs``, every model's fit into ``out``.

    Args:
        inputs: table files, directories, glob patterns (:func:`find_tables`).
        request: a :class:`~brdffit.request.FitRequest`, as ``brdffit fit`` runs one:
            each of its models is fitted and stored, or for auto each candidate
            (fitted together, as ``brdffit fit --model auto`` fits them;
            ``batch-report`` shows the choice). Its options and scene apply to every
            fit; a finished fit is resumed where its table, model, options and scene
            match. Model names alone are a request with the default options.
        out: the HDF5 results file; created, or resumed when it exists.
        workers: local Dask worker processes; 0 fits in this process.
        scheduler: ``tcp://HOST:PORT`` of an existing Dask cluster (``workers`` ignored).
        refit: fit again even what the file already holds.
        progress: draw a progress line on stderr (or pass a
            :class:`~brdffit.batch.progress.ProgressLine`).
        checkpoint_s: at most this long between rewrites of ``out``; every
            result is journaled at once whatever this is.
        on_result: called with each result's records as they are journaled: a
            table's record with one fit (or none, for a table that failed).
        timeout_s: give up (``TimeoutError``) when a Dask batch has not finished
            after this long; what finished is kept. None waits for ever.
    """
    t0 = time.monotonic()
    request = request_of(request)
    model_names = list(request.fitted_models)
    if not scheduler and (not isinstance(workers, int) or workers < 0):
        raise BatchInputError(f"workers must be an integer >= 0, got {workers!r}")
    if not (isinstance(checkpoint_s, int | float) and math.isfinite(checkpoint_s)
            and checkpoint_s >= 0):  # 0: after every result
        raise BatchInputError(f"checkpoint must be a number of seconds >= 0, got "
                              f"{checkpoint_s!r}")
    if scheduler or workers:
        require_dask()  # before the results file is created
    passed_over: list[str] = []
    paths = find_tables(inputs, exclude=[out], passed_over=passed_over)
    summary = BatchSummary(out=os.path.abspath(os.fspath(out)), tables=len(paths),
                           passed_over=passed_over)
    attrs = {
        "models": list(model_names),
        "options": request.fit_key(),
        "request": jsonout.dumps(request.to_dict(), sort_keys=True),
        "engine": scheduler or ("in-process" if workers == 0 else f"local:{workers}"),
    }

    # an existing cluster is reached before the results file is touched: an address
    # that is wrong or down is refused with nothing written (it rewrote a resumed
    # file's models and options to the refused run's)
    done = _Complete()
    with done, (_reached(scheduler, progress) if scheduler else contextlib.nullcontext()
                ) as remote, BatchStore(out) as store:
        summary.recovered = store.recovered
        summary.recovered_fits = store.recovered_fits
        summary.damaged = len(store.damaged)
        paths = store.as_known(paths)
        summary.tables = len(paths)
        summary.moved = _moved(paths, store)
        # group names follow the input order, not finish order
        summary.renamed = store.reserve_names(paths)
        refit_since = _refit_mark(store, attrs, refit, summary)
        store.checkpoint(attrs, inputs=paths)  # the file exists, readable, from the start
        tasks = _plan(paths, request, store, refit, summary, refit_since)
        bar = progress if isinstance(progress, ProgressLine) else ProgressLine(
            len(tasks), skipped=summary.skipped, enabled=bool(progress))
        bar.draw(force=True)
        next_checkpoint = time.monotonic() + checkpoint_s

        failing: dict[str, bool] = {}  # table path -> a failure so far, until it is done

        def take(results: Iterator[dict]) -> None:
            nonlocal next_checkpoint
            for r in results:
                table = TableReadRecord(**r["table"])
                fits = [FitRecord(**f) for f in r["fits"]]
                store.add(table, fits)
                summary.fits += len(fits)
                # Results come one fit at a time: a table counts (and fails) once.
                failed = table.status != "ok" or any(f.status != "ok" for f in fits)
                if table.status != "ok" and not failing.get(table.path):
                    summary.failed_tables.append((table.path, table.message))
                failing[table.path] = failing.get(table.path, False) or failed
                summary.failed_fits += [(f.path, f.model, f.message)
                                        for f in fits if f.status != "ok"]
                if r.get("table_done", True):
                    bar.update(fits=len(fits), failed=failing.pop(table.path))
                else:
                    bar.update(fits=len(fits), failed=False, tables=0)
                if on_result is not None:
                    on_result(table, fits)
                if time.monotonic() >= next_checkpoint:
                    started = time.monotonic()
                    store.checkpoint(attrs)
                    # A checkpoint copies the whole file: on a large one, space
                    # them so that they take at most ~10 % of the batch.
                    took = time.monotonic() - started
                    next_checkpoint = time.monotonic() + max(checkpoint_s, 10 * took)
                # after the result is stored: a finished fit is never dropped
                if stop_requested.is_set():
                    raise KeyboardInterrupt  # the signal's own exception was lost

        try:
            with bar.ticking():
                if tasks and workers == 0 and not scheduler:
                    take(_run_in_process(tasks, request))
                elif tasks:
                    # closing(): on an interrupt the generator cancels its futures
                    # while the client is still connected, not whenever it is collected.
                    with done, (contextlib.nullcontext(remote) if remote is not None
                                else connect(workers, scheduler)) as client, \
                            contextlib.closing(_run_on_dask(client, tasks, request,
                                                            timeout_s)) as results:
                        take(results)
                        done.complete = True  # what follows is the cluster's shutdown
            done.complete = True
        finally:
            with done:
                bar.finish()
            if done.complete and refit:
                attrs["refit_pending"] = None  # done: a later --refit starts afresh
            # Interrupted or not, what was journaled goes into the file now; if
            # this process is killed instead, the next run replays the journal.
            try:
                store.checkpoint(attrs)
            except KeyboardInterrupt:
                if not done.complete:
                    raise
                store.checkpoint(attrs)  # a complete run's file gets every result
    summary.elapsed_s = time.monotonic() - t0
    return summary
