"""The exceptions brdffit raises on bad input. Shells turn them into messages."""

from __future__ import annotations


class BrdffitError(Exception):
    """Base of every error that is the input's fault, not a bug."""


class MerlFormatError(BrdffitError, ValueError):
    """A file or buffer that is not a valid MERL ``.binary`` table."""

    def __init__(self, source: str, problem: str):
        self.source = source
        self.problem = problem
        super().__init__(f"{source}: {problem}")

    def __reduce__(self):
        # Exceptions pickle as cls(*args); args holds only the message here, so
        # say how to rebuild it (worker processes send these back to the parent).
        return (type(self), (self.source, self.problem))


class FitInputError(BrdffitError, ValueError):
    """Fit options or a table that a fit cannot work with (explained in the message)."""


class ResultFormatError(BrdffitError, ValueError):
    """A fit result (a ``fit.json``, a results file's fit) that is not one: another
    schema version, unknown or missing keys, values of the wrong type."""


class ExportError(BrdffitError, ValueError):
    """An export that cannot be made: unknown target, or a fit with nothing to export
    (``brdffit.export``; here, below it, so that its conversions raise it too)."""

