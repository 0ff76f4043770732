"""The optional parts of brdffit and what each needs installed.

``pip install brdffit`` is the library (JAX, optimistix, numpy, h5py); the
service, the Dask batch runner, the plots and the HTTP client are extras
(``pyproject.toml``). Code that needs an extra calls :func:`require` before
importing it, so a missing extra is one line naming what to install rather
than a ``ModuleNotFoundError`` traceback from deep inside.
"""

from __future__ import annotations

import importlib.util

from brdffit.errors import BrdffitError

#: extra -> the modules it provides (the import names of pyproject.toml's
#: optional-dependencies; tests/test_light_imports.py checks the two agree)
MODULES = {
    "service": ("fastapi", "uvicorn", "multipart", "pydantic_settings", "httpx", "matplotlib"),
    "batch": ("dask", "distributed"),
    "plots": ("matplotlib",),
    "client": ("httpx",),
}


class MissingExtraError(BrdffitError, ImportError):
    """What ``who`` needs is not installed: ``pip install 'brdffit[extra]'``."""

    def __init__(self, who: str, extra: str, missing: tuple[str, ...] = (), hint: str = ""):
        self.who = who
        self.extra = extra
        self.missing = missing
        message = f"{who} needs the {extra} extra: pip install 'brdffit[{extra}]'"
        super().__init__(message + (f" ({hint})" if hint else ""))

    def __reduce__(self):  # pickles across worker processes like MerlFormatError
        return (type(self), (self.who, self.extra, self.missing))


def missing(extra: str) -> tuple[str, ...]:
    """The modules of ``extra`` that cannot be imported here."""
    return tuple(m for m in MODULES[extra] if importlib.util.find_spec(m) is None)


def require(extra: str, who: str, hint: str = "") -> None:
    """Raise :class:`MissingExtraError` unless ``extra`` is installed; ``who`` is
    what needs it, as the user asked for it (``"brdffit serve"``)."""
    gone = missing(extra)
    if gone:
        raise MissingExtraError(who, extra, gone, hint)
