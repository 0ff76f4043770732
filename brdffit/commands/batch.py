"""``brdffit batch`` (fit many tables x models into HDF5) and ``brdffit batch-report``."""

from __future__ import annotations

import os
import sys

from .. import jsonout
from ..batch import run_batch
from ..batch_progress import format_duration
from ..batch_report import format_ranking, plot_summary, rank
from ..options import FitOptions
from .fit import add_fit_options, add_option_arguments, options_from_args

EXIT_FAILED_TABLES = 1  # the batch ran, but some tables or fits failed


def register(sub) -> None:
    p = sub.add_parser(
        "batch", help="fit many tables x models into one HDF5 file (resumable, Dask)",
        description="Fit every table of INPUTS with every model into an HDF5 file. Run it "
                    "again with the same arguments to resume: finished fits are skipped.",
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="table files, directories (every *.binary below) or glob patterns")
    p.add_argument("--models", required=True, type=_models,
                   help="comma-separated model names, e.g. ggx,beckmann,lambert; 'auto' "
                        "for the selection's candidates (batch-report shows the choice)")
    p.add_argument("--out", required=True, help="results file (.h5), created or resumed")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=_default_workers(),
                       help="local worker processes (default: the CPU count, "
                            f"{_default_workers()} here); 0 fits in this process")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="run on this existing Dask cluster instead of local workers")
    add_fit_options(p)
    p.add_argument("--refit", action="store_true",
                   help="fit again what the file already holds (e.g. after a model changed)")
    p.add_argument("--checkpoint", type=float, default=10.0, metavar="SECONDS",
                   help="longest time between rewrites of the .h5 (every result is "
                        "journaled at once regardless; default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(run=run)

    r = sub.add_parser("batch-report", help="rank the models of a batch results file")
    r.add_argument("results", help="an .h5 file written by `brdffit batch`")
    r.add_argument("--png", help="summary figure (default: RESULTS without .h5 + .summary.png)")
    r.add_argument("--no-png", action="store_true", help="print only")
    r.add_argument("--json", action="store_true", help="print the ranking as JSON")
    add_option_arguments(r, ["tolerance"])  # the 'auto' column, as `fit --model auto`
    r.set_defaults(run=run_report)


def _default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def _models(text: str) -> list[str]:
    return [m.strip() for m in text.split(",") if m.strip()]


def run(args) -> int:
    options = options_from_args(args)
    s = run_batch(args.inputs, args.models, args.out, options=options, workers=args.workers,
                  scheduler=args.scheduler, refit=args.refit, progress=not args.quiet,
                  checkpoint_s=args.checkpoint)
    if s.recovered:
        print(f"recovered {s.recovered} results journaled by an interrupted run", file=sys.stderr)
    print(f"{s.out}: {s.fits} fits on {s.tables - s.skipped} tables in "
          f"{format_duration(s.elapsed_s)}; {s.skipped} tables were already done")
    if s.ok:
        return 0
    for path, message in s.failed_tables:
        print(f"failed: {message}" if message.startswith(path) else f"failed: {path}: {message}",
              file=sys.stderr)
    for path, model, message in s.failed_fits:
        print(f"failed: {path} [{model}]: {message}", file=sys.stderr)
    print(f"brdffit: {s.n_failed_tables} of {s.tables} tables failed "
          f"({len(s.failed_fits)} failed fits); the rest are in {s.out}", file=sys.stderr)
    return EXIT_FAILED_TABLES


def run_report(args) -> int:
    FitOptions(tolerance=args.tolerance)  # the range every shell checks
    ranking = rank(args.results)
    if args.json:
        # A model with no successful fit has mean and median NaN: null in JSON.
        jsonout.dump({
            "attrs": ranking.attrs,
            "tables": [{"name": t.name, "path": t.path, "status": t.status, "best": t.best,
                        "auto": t.chosen(args.tolerance)[0],
                        "auto_reason": t.chosen(args.tolerance)[1],
                        "log_rmse": t.errors, "message": t.message,
                        "failed_models": t.failed_models} for t in ranking.tables],
            "models": [vars(s) for s in ranking.summary],
        }, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
    else:
        print(format_ranking(ranking, args.results, args.tolerance))
    if not args.no_png:
        png = args.png or (args.results.removesuffix(".h5") + ".summary.png")
        plot_summary(ranking, png)
        print(f"wrote {png}", file=sys.stderr)
    return 0
