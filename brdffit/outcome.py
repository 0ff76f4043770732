"""What crosses a process boundary when work ends: one :class:`Outcome` shape.

A worker (the service's worker process, a Dask worker of a batch) returns a
value rather than raising: a bad table must not stop a batch or crash a
worker, and brdffit's exceptions do not all survive pickling
(``MerlFormatError``'s two-argument constructor). Every such boundary uses this
type, so the side that reads it asks one question (``ok``) and finds the reason
in one place.

Plain data only (``to_dict``/``from_dict``), so it pickles, travels through Dask
and a pipe, and is stored as JSON.
"""

from __future__ import annotations

import traceback as tb
from dataclasses import asdict, dataclass, field

from brdffit.errors import BrdffitError


@dataclass(frozen=True)
class Outcome:
    """``ok`` with a ``value``, or not ok with a ``reason`` a person can read.

    ``error_type`` names the exception behind a failure; ``internal`` marks a bug
    rather than bad input (its ``traceback`` is kept for the log, never shown to
    the user as the reason); ``notes`` says what happened on the way (a model of
    several that could not be fitted); ``seconds`` how long the work took where it
    ran, and ``measures_machine`` whether the service's cost estimate may learn its
    workers' speed from that (no compiling in it, nothing the estimate leaves out).
    """

    ok: bool
    value: object = None
    reason: str = ""
    error_type: str | None = None
    internal: bool = False
    traceback: str | None = None
    notes: tuple[str, ...] = field(default=())
    seconds: float | None = None
    measures_machine: bool = False

    @classmethod
    def success(cls, value, notes=(), seconds: float | None = None,
                measures_machine: bool = False) -> Outcome:
        return cls(ok=True, value=value, notes=tuple(notes), seconds=seconds,
                   measures_machine=measures_machine)

    @classmethod
    def failure(cls, error: BaseException) -> Outcome:
        """The failure ``error`` is: the input's (a brdffit error, a ``ValueError``,
        an unreadable file) keeps its message; anything else is a bug and keeps its
        traceback."""
        internal = not isinstance(error, (BrdffitError, ValueError, KeyError, OSError))
        reason = str(error) if not internal and str(error) else (
            f"{'internal error: ' if internal else ''}{type(error).__name__}: {error}")
        return cls(ok=False, reason=reason, error_type=type(error).__name__, internal=internal,
                   traceback=tb.format_exc() if internal else None)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["notes"] = list(self.notes)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Outcome:
        return cls(**{**d, "notes": tuple(d.get("notes", ()))})
