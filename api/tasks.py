"""The library calls a worker runs for the service: thin, picklable, top-level.

They take paths and plain data, not tables (a table is 35 MB; the worker reads
it from the data dir itself), and they return values rather than raise for bad
input: a job's failure is an outcome to store, and exceptions that cross a
process boundary must unpickle (``MerlFormatError``'s two-argument constructor
does not).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import threading
import time
import traceback

from brdffit.outcome import Outcome

#: Where :func:`report` sends a running task's progress (set by :func:`serve`).
_reporter = None

#: JAX's events for making a program (tracing, lowering, XLA's compile). A job that
#: spent more than COMPILING_SHARE of its time on them is no measure of the machine's
#: speed, as the cost estimate counts it (``api.estimate``: a worker whose cache is
#: empty compiles once, then never again): its worker time is stored, not learnt from. (Not the
#: time less its compiling: the fits compile on several threads at once, and the
#: summed events outran the job's wall time on a cold ggx job.)
COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration",
                  "/jax/core/compile/jaxpr_to_mlir_module_duration",
                  "/jax/core/compile/backend_compile_duration")
COMPILING_SHARE = 0.05
_compiling_s = [0.0]  # summed by the listener _count_compiling registers


@functools.cache  # one listener per process
def _count_compiling() -> None:
    from jax import monitoring

    def heard(event: str, duration: float, **_kwargs) -> None:
        if event in COMPILE_EVENTS:
            _compiling_s[0] += duration

    monitoring.register_event_duration_secs_listener(heard)


def report(stage: str, fraction: float) -> None:
    """Tell the server what the task is doing (``stage``) and how far it is
    (``fraction`` of the job, 0 .. 1); a no-op outside a worker."""
    if _reporter is not None:
        _reporter(stage, fraction)


def _read(table_path: str, source: str):
    """The stored table or sample list (``api.services.tables``), named as the
    uploader named it: the name shows in results and plot titles."""
    from brdffit.io import readers

    # by content: a stored sample list is HDF5 whatever its stored name says
    return dataclasses.replace(readers.read_measured(table_path), source=source)


def fit_models(table_path: str, source: str, request: dict,
               measured_input: dict | None = None) -> Outcome:
    """The fits a job asks for (``brdffit.request.run``): an :class:`Outcome` whose
    value is the list of every fit made (``FitResult`` dicts; for ``auto`` every
    candidate's, the chosen one carrying its ``selection``), its notes the models
    that could not be fitted beside ones that could. ``measured_input``: the table
    was binned from uploaded samples (its summary's ``input``); every fit carries it."""
    from api.estimate import counts_the_work
    from brdffit.jsonout import strict
    from brdffit.request import FitRequest, run

    _count_compiling()
    try:
        t0, compiling0 = time.perf_counter(), _compiling_s[0]
        request = FitRequest.from_dict(request)
        report("reading the table", 0.0)
        table = _read(table_path, source)

        def progress(i: int, n: int, model: str, row: dict | None) -> None:
            if row is None:  # before model i; after it, the fraction counts it done
                what = "candidates, model auto" if request.auto else "models"
                report(f"fitting {model} ({i + 1} of {n} {what})", i / n)

        fitted = run(table, request, progress=progress, measured_input=measured_input)
        report("storing the results", 1.0)
        wall = time.perf_counter() - t0
        compiled = _compiling_s[0] - compiling0 > COMPILING_SHARE * wall
        # a sample list's bins, beyond a table's polish size or not, only loosen the count
        counted = counts_the_work(request, fitted.fits.values(),
                                  getattr(table, "n_measured", 0))
        # Strict before it is stored and served: a metric a fit could not measure is null.
        return Outcome.success([strict(r.to_dict()) for r in fitted.fits.values()],
                               notes=[f"{m} could not be fitted: {why}"
                                      for m, why in fitted.failed.items()],
                               seconds=wall, measures_machine=counted and not compiled)
    except Exception as e:  # noqa: BLE001 - a failure is the job's outcome, not a crash
        return Outcome.failure(e)


def render_plot(table_path: str, source: str, result: dict, kind: str,
                exposure_ev: float = 0.0) -> Outcome:
    """One plot of a finished fit: an :class:`Outcome` whose value is the PNG's bytes
    (``brdffit.view.plots``)."""
    from brdffit.view import plots

    try:
        if kind == "samples":  # a sample list's, drawn at each sample (the route checked)
            from brdffit.view import sample_plot

            return Outcome.success(sample_plot.samples(_read(table_path, source), result))
        if kind == "ranking":  # auto's candidates: the selection carries them (the route checked)
            return Outcome.success(plots.ranking(result["selection"]))
        from brdffit.io.merl import MerlTable

        measured = _read(table_path, source)
        if isinstance(measured, MerlTable):
            return Outcome.success(plots.render(kind, measured, result, exposure_ev))
        from brdffit.fitting.samples import binned

        # a sample list: its report draws its samples, the other plots its binned table
        return Outcome.success(plots.render(kind, binned(measured)[0], result, exposure_ev,
                                            measured=measured))
    except Exception as e:  # noqa: BLE001 - a stored table gone bad, or a plotting bug
        return Outcome.failure(e)


def export_fit(result: dict, target: str, table_path: str | None = None,
               target_model: str | None = None, viewer: str = "spec") -> Outcome:
    """A finished fit as a renderer's material (``brdffit.export.export``): an
    :class:`Outcome` whose value is the export's dict; a fit that cannot be exported
    so is a failure that is not ``internal``."""
    from brdffit import jsonout
    from brdffit.export import export
    from brdffit.fitting.result import FitResult

    try:
        fitted = FitResult.from_dict(result)
        table = None
        if table_path is not None:
            import dataclasses

            from brdffit.io import readers

            # the job's own table, stored under its hash: named as the fit knows it
            stored = readers.read_table(table_path)[0]
            table = dataclasses.replace(stored, source=fitted.table or stored.source)
        out = export(fitted, target, table=table, target_model=target_model, viewer=viewer)
        return Outcome.success(jsonout.strict(out.to_dict()))
    except Exception as e:  # noqa: BLE001 - an ExportError is the request's, else a bug
        return Outcome.failure(e)


def write_material(name: str, path: str) -> Outcome:
    """The shipped material ``name`` rebuilt from its network (``data_synth.nbrdf``:
    JAX, ~200 MB) and written to ``path`` as a MERL table, here in a worker: in the
    server's own process, one request took it from 120 to 420 MB and six 2 GB."""
    try:
        from brdffit.io import merl
        from data_synth import nbrdf

        with open(path, "wb") as f:
            f.write(merl.to_bytes(nbrdf.make_table(name)))
        return Outcome.success(None)
    except Exception as e:  # noqa: BLE001 - a disk full, or a bug: the route's 500
        return Outcome.failure(e)


def warm_up() -> int:
    """Import the library (JAX, matplotlib) before the first job needs it."""
    import brdffit.fitting.pipeline  # noqa: F401  (import brdffit alone is lazy)
    import brdffit.view.plots  # noqa: F401

    return os.getpid()


def serve(conn, parent_pid: int) -> None:
    """A worker process's life (``api.runner.ProcessRunner``): take ``(fn, args)``
    from the pipe, answer ``("value", v)`` or ``("error", text)``, with
    ``("progress", stage, fraction)`` messages on the way; ``None`` ends it."""
    global _reporter
    from brdffit import heap

    watch_parent(parent_pid)
    heap.keep_freed_memory()  # while a job runs: its table-sized arrays reuse the heap
    warm_up()
    _reporter = lambda stage, fraction: conn.send(("progress", stage, float(fraction)))  # noqa: E731
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError, KeyboardInterrupt):  # the server is gone
            return
        if task is None:
            return
        fn, args = task
        try:
            answer = ("value", fn(*args))
        except Exception as e:  # tasks return failures as values; this is a bug
            answer = ("error", f"{type(e).__name__}: {e}\n{traceback.format_exc()}")
        heap.give_memory_back()  # an idle worker does not hold its last job's peak
        try:
            conn.send(answer)
        except (EOFError, OSError):
            return


def watch_parent(parent_pid: int) -> None:
    """Exit when the server is gone.

    A server killed with SIGKILL cannot stop its workers; without this they
    would finish (and compete with) fits nobody will collect.
    """

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
