"""``brdffit batch``: fit many tables x models into one HDF5 file (``brdffit.batch.job``)."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading

from brdffit.batch.job import DIR_SUFFIXES, run_batch, stop_requested
from brdffit.batch.progress import format_duration
from brdffit.cli import EXIT_INTERRUPTED, name_list
from brdffit.cli.fit import add_fit_options, add_request_arguments, request_from_args

EXIT_FAILED_TABLES = 1  # the batch ran, but some tables or fits failed


def add_arguments(p) -> None:
    p.description = ("Fit every table of INPUTS with every model into an HDF5 file. Run it "
                     "again with the same arguments to resume: finished fits are skipped.")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="table or sample files, directories (every "
                        f"{', '.join('*' + s for s in DIR_SUFFIXES)} below) or glob patterns")
    p.add_argument("--models", required=True, type=name_list("--models"),
                   help="comma-separated model names, e.g. ggx,beckmann,lambert; 'auto' "
                        "for the selection's candidates (batch-report shows the choice; "
                        "--candidates names them)")
    p.add_argument("--out", required=True, help="results file (.h5), created or resumed")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=_default_workers(),
                       help="local worker processes (default: the CPU count, "
                            f"{_default_workers()} here); 0 fits in this process")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="run on this existing Dask cluster instead of local workers")
    add_fit_options(p)
    add_request_arguments(p, "--models")
    p.add_argument("--refit", action="store_true",
                   help="fit again what the file already holds (e.g. after a model changed)")
    p.add_argument("--checkpoint", type=float, default=10.0, metavar="SECONDS",
                   help="longest time between rewrites of the .h5 (every result is "
                        "journaled at once regardless; default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def _default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def workers_note(workers: int, cores: int) -> str | None:
    """A line for stderr when ``--workers`` asks for more local workers than cores:
    each worker fits on a core of its own where it can have one, so the extra ones
    only share cores with the others (more memory and start-up, no more fits)."""
    if workers <= cores:
        return None
    return (f"brdffit: {workers} workers on {cores} cores: the extra workers share cores "
            f"with the others (more memory, no more cores; --workers {cores} uses them all)")


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def summary_line(s) -> str:
    """The run's last line: ``out.h5: 4 fits on 2 tables in 3s; 1 table was already
    done``."""
    # a table some of whose fits were in the file is neither done nor new: its kept fits
    # are said (it read "none was done before" after a resume that kept them)
    done = [f"{_count(s.skipped, 'table')} {'was' if s.skipped == 1 else 'were'} already done"
            ] if s.skipped else []
    if s.kept:
        done.append(f"{_count(s.kept, 'fit')}{' of the others' if s.skipped else ''} kept "
                    "from before")
    # fits in the file made again were done before, and are gone: one fit per model is
    # kept (it read "none was done before" where a run with other options replaced them)
    replaced = ((s.replaced_options, "made with other options, replaced"),
                (s.replaced_changed, "of tables whose file changed since, replaced"))
    done += [f"{_count(n, 'fit')} {why}" for n, why in replaced if n]
    if s.refitted:  # it read "none was done before" where --refit replaced them
        done.append(f"{_count(s.refitted, 'stored fit')} made again (--refit)")
    if s.resumed_refit:
        done.append(f"going on with the --refit begun {s.resumed_refit}")
    if s.moved:
        done.append(f"{_count(s.moved, 'table')} found at a new path, "
                    f"{'its' if s.moved == 1 else 'their'} fits kept")
    done = ", ".join(done) or "none was done before"
    return (f"{s.out}: {_count(s.fits, 'fit')} on {_count(s.tables - s.skipped, 'table')} in "
            f"{format_duration(s.elapsed_s)}; {done}")


def _interrupt(signum, frame):
    # SIGTERM (kill, a scheduler's job stop) ends a batch as Ctrl-C does: its work on
    # the cluster is cancelled and what finished is checkpointed, rather than the
    # process vanishing with its tasks left running. The flag stops the batch at its
    # next result should this exception be lost (raised inside a weakref callback).
    stop_requested.set()
    raise KeyboardInterrupt


def _quiet_lost_interrupt(unraisable) -> None:
    # A KeyboardInterrupt raised where Python cannot raise it (a weakref callback, a
    # __del__) is printed as "Exception ignored in ..." and dropped; the batch stops
    # at its next result anyway (stop_requested), so the user sees one line.
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and stop_requested.is_set():
        return
    sys.__unraisablehook__(unraisable)


#: The loggers whose messages of a cancelled call :class:`_LostSyncCancel` drops.
_CANCEL_LOGGERS = ("tornado.application", "distributed.scheduler")


class _LostSyncCancel(logging.Filter):
    """Drops, once an interrupt stopped the batch, the error tornado logs where Dask's
    client cancels a call that had not started yet: distributed's ``sync`` (2026.8)
    schedules ``cancel`` on the interrupt, and where the interrupt came before the call's
    coroutine ran, ``cancel`` reads its future before it exists (a NameError, with its
    traceback on stderr, seen in a fresh clone's test run). The call was to be cancelled
    anyway: the user is told one line (the batch's), not an upstream traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        # and the scheduler's "Couldn't gather keys: {...: 'forgotten'}", logged where the
        # interrupt cancelled a fit whose result was being gathered (a test's flake: the
        # user saw it above the batch's one line)
        return not (stop_requested.is_set()
                    and ("sync.<locals>.cancel" in record.getMessage()
                         or "Couldn't gather keys" in record.getMessage()))


def run(args) -> int:
    request = request_from_args(args, models=args.models)  # refused before any file
    note = None if args.scheduler else workers_note(args.workers, _default_workers())
    if note:
        print(note, file=sys.stderr)
    main_thread = threading.current_thread() is threading.main_thread()
    stop_requested.clear()
    previous = ({sig: signal.signal(sig, _interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
                if main_thread else None)
    previous_hook, sys.unraisablehook = sys.unraisablehook, _quiet_lost_interrupt
    lost_cancel = _LostSyncCancel()
    for name in _CANCEL_LOGGERS:
        logging.getLogger(name).addFilter(lost_cancel)
    try:
        s = run_batch(args.inputs, request, args.out,
                      workers=args.workers, scheduler=args.scheduler, refit=args.refit,
                      progress=not args.quiet, checkpoint_s=args.checkpoint)
    except KeyboardInterrupt:
        # One line: run_batch has cancelled the batch's tasks and checkpointed.
        print(f"brdffit: interrupted; the finished fits are in {args.out}, run the same "
              "command again to go on", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        # this run's: a signal during a complete run's teardown left it set, and an
        # in-process caller's next batch stopped at its first result
        stop_requested.clear()
        sys.unraisablehook = previous_hook
        for name in _CANCEL_LOGGERS:
            logging.getLogger(name).removeFilter(lost_cancel)
        if main_thread:  # an in-process caller (a test) keeps its own handlers
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    if s.recovered_fits:  # fits, as the summary counts them (table records were counted too)
        print(f"recovered {_count(s.recovered_fits, 'fit')} journaled by an interrupted run",
              file=sys.stderr)
    if s.damaged:
        print(f"fitted again: {_count(s.damaged, 'fit')} whose stored result did not read back "
              "(a damaged file)", file=sys.stderr)
    for path in s.passed_over:
        print(f"passed over: {path} (another batch's results file, not a table)",
              file=sys.stderr)
    for path, group in s.renamed:  # the file's own name is another table's group
        print(f"stored as group {group!r}: {path} (another table has its name)",
              file=sys.stderr)
    print(summary_line(s))
    if s.ok:
        return 0
    for path, message in s.failed_tables:
        print(f"failed: {message}" if message.startswith(path) else f"failed: {path}: {message}",
              file=sys.stderr)
    for path, model, message in s.failed_fits:
        print(f"failed: {path} [{model}]: {message}", file=sys.stderr)
    print(f"brdffit: {s.n_failed_tables} of {s.tables} tables failed "
          f"({len(s.failed_fits)} failed fits); the rest are in {s.out}", file=sys.stderr)
    return EXIT_FAILED_TABLES
