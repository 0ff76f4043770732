"""``brdffit batch-report``: rank the models of a ``brdffit batch`` results file."""

from __future__ import annotations

import sys

from brdffit import extras, jsonout
from brdffit.batch.report import format_ranking, plot_summary, rank
from brdffit.cli.fit import add_option_arguments, rule_from_args
from brdffit.errors import BrdffitError
from brdffit.fitting.options import SelectionRule


def add_arguments(p) -> None:
    p.add_argument("results", help="an .h5 file written by `brdffit batch`")
    p.add_argument("--png", help="summary figure (default: RESULTS without .h5 + .summary.png)")
    p.add_argument("--no-png", action="store_true", help="print only")
    p.add_argument("--json", action="store_true", help="print the ranking as JSON")
    # the 'auto' column, as `fit --model auto` chooses
    add_option_arguments(p, ["tolerance"], of=SelectionRule)


def run(args) -> int:
    args.tolerance = (rule_from_args(args) or SelectionRule()).tolerance  # checked as anywhere
    png = None
    if not args.no_png:
        extras.require("plots", "brdffit batch-report's figure", hint="--no-png prints only")
        png = _png_path(args.png or (args.results.removesuffix(".h5") + ".summary.png"))
    ranking = rank(args.results)
    if args.json:
        # A model with no successful fit has mean and median NaN: null in JSON.
        jsonout.dump({
            "attrs": ranking.attrs,
            "tables": [{"name": t.name, "path": t.path, "status": t.status, "best": t.best,
                        "auto": t.chosen(args.tolerance)[0],
                        "auto_reason": t.chosen(args.tolerance)[1],
                        "log_rmse": t.errors, "message": t.message,
                        "failed_models": t.failed_models,
                        # how the best fit looks, and what to try next where it is not good
                        "looks": {k: (t.looks.get(t.best) or {}).get(k)
                                  for k in ("verdict", "reason", "next")}}
                       for t in ranking.tables],
            "models": [vars(s) for s in ranking.summary],
            # options whose values differ among the fits ranked side by side (absent: none)
            **({"mixed_options": ranking.mixed_options} if ranking.mixed_options else {}),
        }, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
    else:
        print(format_ranking(ranking, args.results, args.tolerance))
    if png is not None:
        try:
            plot_summary(ranking, png, source=args.results)
        except OSError as e:
            raise BrdffitError(f"--png {png}: cannot write it ({e.strerror or e})") from None
        print(f"wrote {png}", file=sys.stderr)
    return 0


def _png_path(path: str) -> str:
    """``--png``'s file, refused before the report is printed: a folder, another suffix
    (matplotlib wrote ``summary`` as ``summary.png`` and said it wrote ``summary``) or a
    folder that does not exist."""
    import os

    if os.path.isdir(path):
        raise BrdffitError(f"--png {path}: a folder; name the figure's file (FILE.png)")
    if not path.lower().endswith(".png"):
        raise BrdffitError(f"--png {path}: the figure is a PNG; name it FILE.png")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise BrdffitError(f"--png {path}: the folder {folder} does not exist")
    return path
