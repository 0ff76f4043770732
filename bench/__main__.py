"""`make bench`: the speed-vs-error report, then startup, batch and selection benchmarks.
(``python -m bench.service_start --baseline CHECKOUT`` compares two checkouts' service
start, and is run by hand.)

    python -m bench [--quick]

Each part writes its own files under bench/results/.
"""

from __future__ import annotations

import importlib
import sys


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    quick = "--quick" in argv
    from bench import speed

    rc = speed.main(["--quick"] if quick else [])
    for name in ("bench.startup", "bench.batch_bench", "bench.selection_bench"):
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError:
            continue
        rc |= int(module.main([]) or 0)
    return rc


if __name__ == "__main__":
    sys.exit(main())
