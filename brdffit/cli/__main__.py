"""``python -m brdffit.cli``: the same as the ``brdffit`` command."""

from brdffit.cli import console

console()
