"""``python -m brdffit.cli``: the same as the ``brdffit`` command."""

import sys

from brdffit.cli import main

sys.exit(main())
