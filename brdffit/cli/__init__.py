"""The ``brdffit`` command line: a thin shell over the library.

Each subcommand lives in its own module of this package with
``add_arguments(parser)`` and ``run(args)`` (``batch-report`` in
``batch_report.py``); this module builds the parser,
parses, and turns brdffit's input errors into one-line messages and exit codes
(never a traceback). Only the module of the command being run is imported, so
``brdffit --help`` and ``brdffit models`` do not wait for what ``fit`` needs.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Collection
from types import ModuleType

from brdffit.errors import BrdffitError

#: command -> its one-line summary, in the order ``brdffit --help`` lists them; a
#: command's module, and JAX, Dask or uvicorn behind it, is imported only when
#: that command is asked for
COMMANDS = {
    "batch": "fit many tables x models into one HDF5 file (resumable, Dask)",
    "batch-report": "rank the models of a batch results file",
    "export": "write a fit as a Mitsuba 3, glTF 2.0 or MaterialX material",
    "fit": "fit a model to a measured file (MERL .binary table, ASTM, CSV, HDF5, MATLAB "
           ".mat, NumPy .npz or Excel .xlsx samples)",
    "models": "list the models with their parameters and ranges",
    "serve": "run the REST API (fits in worker processes)",
    "warmup": "compile the default models' fits into the cache, before a first user waits",
}

EXIT_INPUT = 2  # bad input: malformed table, unknown model, bad option
EXIT_INTERRUPTED = 130
#: what a shell reports for a process ended by SIGPIPE: the reader went away
EXIT_BROKEN_PIPE = 141


def output_folder(path: str, flag: str):
    """The folder ``path`` a command will write into (``--plots``, ``--out``), made
    now, before the work: a path under a regular file, or one this user may not
    write, is refused in one line naming the flag, not after a fit of minutes."""
    import os
    from pathlib import Path

    folder = Path(path)
    if folder.exists() and not folder.is_dir():  # mkdir said "File exists"
        raise BrdffitError(f"{flag} {path}: a file, not a folder: name a folder to write into")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise BrdffitError(f"{flag} {path}: cannot make the folder ({e.strerror})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise BrdffitError(f"{flag} {path}: the folder is not writable")
    return folder


def name_list(flag: str):
    """An argparse ``type`` for ``flag``'s comma-separated names
    (``brdffit.request.split_names``): an empty item is refused with the reason, not
    argparse's "invalid value"."""
    def parse(text: str) -> list[str]:
        from brdffit.request import split_names

        try:
            return split_names(text, flag)
        except BrdffitError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    parse.__name__ = flag.lstrip("-")  # argparse names the option by it in its messages
    return parse


def build_parser(full: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The ``brdffit`` parser with the arguments of the commands ``full`` (every
    command when None); the others are listed with their summary only."""
    from brdffit import __version__

    parser = argparse.ArgumentParser(
        prog="brdffit", description="Fit analytic BRDF models to measured MERL tables."
    )
    parser.add_argument("--version", action="version", version=f"brdffit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, summary in COMMANDS.items():
        p = sub.add_parser(name, help=summary, description=summary[0].upper() + summary[1:] + ".")
        if full is None or name in full:
            module = load(name)
            module.add_arguments(p)
            p.set_defaults(run=module.run)
    return parser


def load(command: str) -> ModuleType:
    """The module of ``command`` (imported now, with whatever it needs)."""
    return importlib.import_module(f"{__name__}.{command.replace('-', '_')}")


def _command(argv: list[str]) -> str | None:
    """The subcommand ``argv`` names: its first word that is not an option (the
    top-level options take no value)."""
    return next((a for a in argv if not a.startswith("-")), None)


def _start_early(command: str | None) -> None:
    """Begin what ``command`` will need and what waits on nothing: ``fit``'s bin grid
    (numpy; computed, ~0.3 s, where the cache is empty) is made on a thread while
    this one imports JAX for the fit."""
    if command == "fit":
        import threading

        from brdffit.io import grid

        threading.Thread(target=grid.bin_grid, name="brdffit-grid", daemon=True).start()


def one_line(text: str) -> str:
    """``text`` with its control characters escaped (``\\n``, ``\\x00``): an error is
    one line, also where it quotes a file name or a cell that holds a line break."""
    return "".join(c if c.isprintable() or c == "\t" else repr(c)[1:-1] for c in text)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        _start_early(_command(argv))
        parser = build_parser(full={_command(argv)})
        args = parser.parse_args(argv)
        return int(args.run(args) or 0)
    except BrdffitError as e:  # includes a missing extra (brdffit.extras)
        print(f"brdffit: error: {one_line(str(e))}", file=sys.stderr)
        return EXIT_INPUT
    except BrokenPipeError:
        # the reader stopped reading (`brdffit export --json | head`): as any Unix tool,
        # stop quietly; the rest of the output goes nowhere instead of failing again
        # when the interpreter flushes stdout at exit
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except OSError as e:  # unreadable paths, a full disk
        print(f"brdffit: error: {one_line(_os_error_words(e))}", file=sys.stderr)
        return EXIT_INPUT
    except ValueError as e:  # bad option values
        print(f"brdffit: error: {one_line(str(e))}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("brdffit: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED




def _os_error_words(e: OSError) -> str:
    """An OSError as a person reads it: the path and what is wrong, not Python's
    ``[Errno 21] Is a directory: '.part-nns7hir4' -> 'ok_ggx.xml'`` (where a file is
    written through a temporary and renamed, the path meant is the target)."""
    if e.strerror is None:
        return str(e)
    path = e.filename2 if e.filename2 is not None else e.filename
    what = e.strerror[:1].lower() + e.strerror[1:]
    return f"{os.fsdecode(path)}: {what}" if path is not None else what


def console() -> None:
    """The ``brdffit`` command: :func:`main`, then a fast exit.

    Once a command has finished and flushed its output, tearing the interpreter
    down (JAX's compiled executables, device buffers, thread pools) takes ~0.3 s
    of a ~1.5 s command and does nothing a user needs: every file is closed by
    then (commands use context managers), so the process ends with ``os._exit``.
    In-process callers (tests, notebooks) use :func:`main`, which returns."""
    import logging
    import os

    code = main()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (`| head`): nothing left to say
            pass
    os._exit(code)
