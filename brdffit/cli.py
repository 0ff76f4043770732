"""The ``brdffit`` command line: a thin shell over the library.

Each subcommand lives in its own module under ``brdffit.commands`` with a
``register(subparsers)`` function; this module finds them, parses, and turns
brdffit's input errors into one-line messages and exit codes (never a traceback).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import commands
from .errors import BrdffitError

EXIT_INPUT = 2  # bad input: malformed table, unknown model, bad option
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="brdffit", description="Fit analytic BRDF models to measured MERL tables."
    )
    parser.add_argument("--version", action="version", version=f"brdffit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda i: i.name):
        importlib.import_module(f"{commands.__name__}.{info.name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except BrdffitError as e:
        print(f"brdffit: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except (ValueError, OSError) as e:  # bad option values, unreadable paths
        print(f"brdffit: error: {e}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("brdffit: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
