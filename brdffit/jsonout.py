"""Strict JSON: the one way brdffit writes JSON (the CLI, the service, batch files).

JSON (RFC 8259) has no NaN or Infinity. Python's ``json`` writes them anyway unless
told not to, and strict readers (``JSON.parse``, jq, serde, Go) then refuse the
whole document. brdffit's rule: a float that is not finite (a metric a failed fit
could not measure) is written as ``null`` under its own key, so a reader still sees
which value is missing. Every writer calls :func:`dumps` or :func:`dump`, which also
pass ``allow_nan=False``: a non-finite value that slips past :func:`strict` raises
instead of producing a file no strict parser reads.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def strict(value: Any) -> Any:
    """``value`` with every non-finite float (Python or numpy) replaced by None, in
    dicts, lists and tuples at any depth; numpy scalars become Python ones."""
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    if isinstance(value, dict):
        return {k: strict(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict(v) for v in value]
    return value


def dumps(value: Any, **kw) -> str:
    """``json.dumps`` of :func:`strict` ``(value)``, refusing NaN and Infinity."""
    return json.dumps(strict(value), allow_nan=False, **kw)


def dump(value: Any, fp, **kw) -> None:
    """``json.dump`` of :func:`strict` ``(value)`` to ``fp``, refusing NaN and Infinity."""
    json.dump(strict(value), fp, allow_nan=False, **kw)
