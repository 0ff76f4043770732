"""Preloaded into the local Dask worker processes of a batch (``brdffit batch --workers
N``): ``distributed`` calls :func:`dask_setup` in each worker as it starts.

- **Ctrl-C.** A Ctrl-C at a terminal signals the whole process group, and local
  workers are in the batch's group: each died of its own ``KeyboardInterrupt`` in
  the middle of a fit, printing a 30-line traceback under the batch's one-line
  message. The batch process owns its workers and stops them itself when it is
  interrupted (it cancels their tasks and closes the cluster), so a worker ignores
  SIGINT. Its scheduler lives in the batch process, so when the batch stops, a
  worker's next heartbeat can find the scheduler gone before the worker is told to
  close, and ``distributed`` logs that as an error with a traceback
  (:class:`HeartbeatToStoppedBatch` drops exactly that record, nothing else: a local
  worker loses its scheduler only when the batch that owns both ends).
- **Cores.** XLA sizes its CPU thread pools by the cores a process may run on, when
  JAX first runs (after this, in the worker's first task). Worker ``i`` of ``N``
  (``BRDFFIT_LOCAL_WORKERS``) is given cores ``i, i + N, ...`` of the batch's own
  (one core each on a machine with no more cores than workers): the workers do not
  fight over cores, as with single-threaded XLA flags, but their programs are those
  every other brdffit process compiles and keeps (the flags are part of their
  fingerprint), and each worker still uses every core of its share.
"""

from __future__ import annotations

import logging
import os
import signal
import threading

from brdffit.batch.cluster import LOCAL_WORKERS_ENV, SINGLE_THREADED_XLA


def dask_setup(worker) -> None:
    # Runs in the worker process's main thread (its event loop), where signal
    # handlers can be set; elsewhere there is nothing to undo.
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.getLogger("distributed.worker").addFilter(HeartbeatToStoppedBatch())
    take_cores(worker.name)


class HeartbeatToStoppedBatch(logging.Filter):
    """Drops ``distributed``'s "Failed to communicate with scheduler during heartbeat"
    record in a local worker: its scheduler is the batch process's, gone only when the
    batch is (which says so itself). Every other worker record passes."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(
            "Failed to communicate with scheduler during heartbeat")


def core_share(index: int, workers: int, cores: list[int]) -> list[int]:
    """The cores of worker ``index`` of ``workers`` among ``cores``: every
    ``workers``-th from its own, or one core where the workers outnumber them."""
    if workers <= len(cores):
        return cores[index % workers::workers]
    return [cores[index % len(cores)]]


def take_cores(name, environ=os.environ) -> None:
    """Keep this process to its share of the cores (:func:`core_share`), where it is
    one of several local workers (``LocalCluster`` names them 0, 1, ...)."""
    try:
        workers = int(environ.get(LOCAL_WORKERS_ENV, "0"))
    except ValueError:
        return
    if workers < 2 or not isinstance(name, int) or name < 0:
        return
    if not hasattr(os, "sched_setaffinity"):  # macOS: no affinity, the flags instead
        os.environ.setdefault("XLA_FLAGS", SINGLE_THREADED_XLA)
        return
    os.sched_setaffinity(0, core_share(name, workers, sorted(os.sched_getaffinity(0))))
