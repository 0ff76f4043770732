"""Preloaded into the local Dask worker processes of a batch (``brdffit batch --workers
N``): ``distributed`` calls :func:`dask_setup` in each worker as it starts.

A Ctrl-C at a terminal signals the whole process group, and local workers are in
the batch's group: each died of its own ``KeyboardInterrupt`` in the middle of a
fit, printing a 30-line traceback under the batch's one-line message. The batch
process owns its workers and stops them itself when it is interrupted (it cancels
their tasks and closes the cluster), so a worker ignores SIGINT.
"""

from __future__ import annotations

import signal
import threading


def dask_setup(worker) -> None:
    # Runs in the worker process's main thread (its event loop), where signal
    # handlers can be set; elsewhere there is nothing to undo.
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
