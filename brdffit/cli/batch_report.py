"""``brdffit batch-report``: rank the models of a ``brdffit batch`` results file."""

from __future__ import annotations

import sys

from brdffit import extras, jsonout
from brdffit.batch.report import format_ranking, plot_summary, rank
from brdffit.cli.fit import add_option_arguments, rule_from_args
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
    if not args.no_png:
        extras.require("plots", "brdffit batch-report's figure", hint="--no-png prints only")
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
        }, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
    else:
        print(format_ranking(ranking, args.results, args.tolerance))
    if not args.no_png:
        png = args.png or (args.results.removesuffix(".h5") + ".summary.png")
        plot_summary(ranking, png, source=args.results)
        print(f"wrote {png}", file=sys.stderr)
    return 0
