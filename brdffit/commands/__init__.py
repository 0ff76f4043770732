"""One module per ``brdffit`` subcommand, each with ``add_arguments(parser)`` and
``run(args)``; a command ``batch-report`` lives in ``batch_report.py``.

:data:`COMMANDS` lists them for ``brdffit --help`` without importing them: a
command's module, and JAX, Dask or uvicorn behind it, is imported only when that
command is asked for.
"""

from __future__ import annotations

import importlib
from types import ModuleType

#: command -> its one-line summary, in the order ``brdffit --help`` lists them
COMMANDS = {
    "batch": "fit many tables x models into one HDF5 file (resumable, Dask)",
    "batch-report": "rank the models of a batch results file",
    "fit": "fit a model to a MERL .binary table",
    "models": "list the models with their parameters and ranges",
    "serve": "run the REST API (fits in worker processes)",
}


def load(command: str) -> ModuleType:
    """The module of ``command`` (imported now, with whatever it needs)."""
    return importlib.import_module(f"{__name__}.{command.replace('-', '_')}")
