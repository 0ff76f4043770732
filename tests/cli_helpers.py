"""Run the project's command lines: as real subprocesses (:func:`run`), or through
their ``main(argv)`` in this process (:func:`run_main`)."""

from __future__ import annotations

import contextlib
import io
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


def run_main(module: str, *args: str) -> subprocess.CompletedProcess:
    """What :func:`run` gives for ``python -m <module> <args>``, from the command's own
    ``main(argv)`` in this process: its exit code, and what it printed on stdout and
    stderr. The words, exit codes and files of a command are its ``main``'s; a new
    process adds ~1.5 s of imports and program loading per call, which the tests of
    the entry point itself (a real process, ``python -m``, a closed pipe, the compile
    notice of a new process) still pay, through :func:`run`."""
    if module == "brdffit.cli":
        from brdffit.cli import main
    elif module == "data_synth":
        from data_synth.__main__ import main
    else:
        raise ValueError(f"no in-process main for {module}")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as e:  # argparse's usage errors, as the interpreter reports them
            if isinstance(e.code, str):
                print(e.code, file=sys.stderr)
            code = 1 if isinstance(e.code, str) else (e.code or 0)
    return subprocess.CompletedProcess([module, *args], code, out.getvalue(), err.getvalue())
