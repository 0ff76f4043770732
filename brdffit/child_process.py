"""Processes a command starts beside itself (``brdffit serve``'s warm-up): they
must not outlive it.

uvicorn re-raises the SIGTERM that stopped it, so a ``finally`` in the parent does
not always run, and nothing runs after a SIGKILL. Linux's parent-death signal
(``prctl(PR_SET_PDEATHSIG)``), set in the child before it runs, ends the child
whenever its parent ends. Elsewhere the parent's own cleanup is all there is.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys


def _prepare(nice: int) -> None:
    if nice:
        os.nice(nice)
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # not Linux


def start(argv: list[str], *, nice: int = 0, **popen) -> subprocess.Popen:
    """``python -m brdffit.cli ARGV`` as a child that ends with this process."""
    return subprocess.Popen([sys.executable, "-m", "brdffit.cli", *argv],
                            preexec_fn=lambda: _prepare(nice), **popen)


def stop(proc: subprocess.Popen | None) -> None:
    """Terminate ``proc`` if it still runs, and reap it."""
    if proc is not None and proc.poll() is None:
        proc.terminate()
        proc.wait()
