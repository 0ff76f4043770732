"""The library calls a worker runs for the service: thin, picklable, top-level.

They take paths and plain data, not tables (a table is 35 MB; the worker reads
it from the data dir itself), and they return values rather than raise for bad
input: a job's failure is an outcome to store, and exceptions that cross a
process boundary must unpickle (``MerlFormatError``'s two-argument constructor
does not).
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
import traceback

#: Where :func:`report` sends a running task's progress (set by :func:`serve`).
_reporter = None


def report(stage: str, fraction: float) -> None:
    """Tell the server what the task is doing (``stage``) and how far it is
    (``fraction`` of the job, 0 .. 1); a no-op outside a worker."""
    if _reporter is not None:
        _reporter(stage, fraction)


def _read(table_path: str, source: str):
    from brdffit.io import merl

    table = merl.read(table_path)
    # Name it as the uploader did: the name shows in results and plot titles.
    return dataclasses.replace(table, source=source)


def fit_models(table_path: str, source: str, models: list[str], options: dict) -> dict:
    """Fit each model to the table: ``{"ok": True, "results": [FitResult dict, ...]}``
    or ``{"ok": False, "reason": "..."}``."""
    from brdffit import BrdffitError
    from brdffit.fitting.scene import Scene, fit_in_scene
    from brdffit.jsonout import strict
    from brdffit.models import UnknownModelError

    try:
        report("reading the table", 0.0)
        table = _read(table_path, source)
        options = dict(options)
        rule = {"tolerance": options.pop("tolerance", None), "budget": options.pop("budget", None)}
        scene = options.pop("scene", None)
        scene = None if scene is None else Scene.from_dict(scene)
        if models == ["auto"]:
            report("fitting the candidates and choosing (model auto)", 0.0)
            return {"ok": True, "results": _select(table, scene, rule, options)}
        # Strict before it is stored and served: a metric a fit could not measure is null.
        # The fraction counts finished models: a fit does not report its own steps.
        results = []
        for i, m in enumerate(models):
            report(f"fitting {m} ({i + 1} of {len(models)})", i / len(models))
            results.append(strict(fit_in_scene(table, m, scene, **options).to_dict()))
        report("storing the results", 1.0)
        return {"ok": True, "results": results}
    except (BrdffitError, UnknownModelError, ValueError) as e:
        return {"ok": False, "reason": str(e)}
    except Exception as e:  # a bug, not the input's fault: keep the evidence
        return {"ok": False, "reason": f"internal error: {type(e).__name__}: {e}",
                "traceback": traceback.format_exc()}


def _select(table, scene, rule: dict, options: dict) -> list[dict]:
    """``model="auto"``: every candidate's fit, the chosen one carrying the selection
    (ranking, reason) in ``selection``."""
    from brdffit.jsonout import strict
    from brdffit.selection import DEFAULT_TOLERANCE, select

    def progress(i: int, n: int, model: str, row: dict | None) -> None:
        if row is None:  # before candidate i; after it, the fraction counts it done
            report(f"fitting {model} ({i + 1} of {n} candidates, model auto)", i / n)

    tolerance = DEFAULT_TOLERANCE if rule["tolerance"] is None else rule["tolerance"]
    sel = select(table, tolerance=tolerance, budget=rule["budget"], scene=scene,
                 progress=progress, **options)
    return [strict(sel.fits[row["model"]].to_dict())
            for row in sel.ranking if row["model"] in sel.fits]


def render_plot(table_path: str, source: str, result: dict, kind: str,
                exposure_ev: float = 0.0) -> dict:
    """One plot of a finished fit: ``{"ok": True, "png": bytes}`` (``brdffit.view.plots``)
    or ``{"ok": False, "reason": "..."}``."""
    from brdffit.view import plots

    try:
        return {"ok": True, "png": plots.render(kind, _read(table_path, source), result,
                                                exposure_ev)}
    except Exception as e:  # a stored table gone bad, or a plotting bug
        return {"ok": False, "reason": f"{type(e).__name__}: {e}",
                "traceback": traceback.format_exc()}


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
    watch_parent(parent_pid)
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
