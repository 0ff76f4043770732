"""``brdffit fit TABLE``: fit one table and print the result (or JSON)."""

from __future__ import annotations

import json
import sys

from .. import merl
from ..fitting import PRECISIONS, SOLVERS, FitResult, fit
from ..sampling import DEFAULT_SAMPLES


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a model to a MERL .binary table")
    p.add_argument("table", help="path to a MERL .binary file")
    p.add_argument("--model", default="ggx", help="model name (see `brdffit models`)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--solver", choices=SOLVERS, default="lm")
    p.add_argument("--samples", type=_samples, default=DEFAULT_SAMPLES,
                   help=f"bins the solver sees (default {DEFAULT_SAMPLES}; 'all' for every bin)")
    p.add_argument("--precision", choices=list(PRECISIONS), default="float64")
    p.add_argument("--starts", type=int, default=2, help="solver starts (best kept)")
    p.add_argument("--max-steps", type=int, default=256)
    p.add_argument("--plots", metavar="DIR",
                   help="also write the plots (slices, error_map, spheres, polar) as DIR/*.png")
    p.set_defaults(run=run)


def _samples(text: str) -> int | None:
    if text == "all":
        return None
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"--samples wants an integer or 'all', got {text!r}") from None


def format_result(r: FitResult) -> str:
    """A human-readable summary of a fit."""
    lines = [f"{r.table}: {r.model} fit, {r.result} after {r.steps} steps in {r.time_s:.2f} s"
             + ("" if r.converged else "  (NOT converged)")]
    for name, v in r.params.items():
        val = ", ".join(f"{x:.5g}" for x in v) if isinstance(v, list) else f"{v:.5g}"
        lines.append(f"  {name:<6} = {val}")
    e = r.error
    lines.append(f"  log_rmse = {e['log_rmse']:.4g} (full table)   rmse_cos = {e['rmse_cos']:.4g} 1/sr")
    s = r.samples
    d = s["dropped"]
    lines.append(
        f"  bins: {s['used']:,} fitted of {s['usable']:,} usable; dropped {d['unmeasured']:,} "
        f"unmeasured, {d['nonfinite']:,} non-finite, {d['below_horizon']:,} below the horizon"
    )
    return "\n".join(lines)


def run(args) -> int:
    table = merl.read(args.table)
    result = fit(table, args.model, solver=args.solver, samples=args.samples,
                 precision=args.precision, starts=args.starts, max_steps=args.max_steps)
    if args.json:
        json.dump(result.to_dict(), sys.stdout)
        sys.stdout.write("\n")
    else:
        print(format_result(result))
    if args.plots:
        from .. import plots  # matplotlib only when asked for

        for path in plots.save_all(table, result, args.plots):
            # stderr: with --json, stdout stays one JSON object
            print(f"wrote {path}", file=sys.stderr)
    # A fit that ran is a result, converged or not: `converged` says which.
    return 0
