"""Run the project's command lines as real subprocesses."""

from __future__ import annotations

import os
import subprocess
import sys


def run(*args: str, timeout: float = 300, cwd=None, stdin=None) -> subprocess.CompletedProcess:
    """``python -m <args>`` with this interpreter; stdout/stderr captured as text;
    ``stdin``: an open file for its standard input."""
    env = dict(os.environ)
    return subprocess.run(
        [sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout,
        env=env, cwd=cwd, stdin=stdin,
    )
