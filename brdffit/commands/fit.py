"""``brdffit fit TABLE``: fit one table and print the result (or JSON)."""

from __future__ import annotations

import sys

from .. import jsonout, merl
from ..fitting import DEFAULT_STARTS, PRECISIONS, SOLVERS, FitResult
from ..sampling import DEFAULT_SAMPLES
from ..scene import PRESETS as SCENE_PRESETS
from ..scene import Scene, fit_in_scene
from ..selection import DEFAULT_CANDIDATES, DEFAULT_TOLERANCE, format_selection, select


def add_fit_options(p) -> None:
    """The options of ``brdffit.fit`` (shared by ``fit`` and ``batch``)."""
    p.add_argument("--solver", choices=SOLVERS, default="lm")
    p.add_argument("--samples", type=_samples, default=DEFAULT_SAMPLES,
                   help=f"bins the solver sees (default {DEFAULT_SAMPLES}; 'all' for every bin)")
    p.add_argument("--precision", choices=list(PRECISIONS), default="float64")
    p.add_argument("--starts", type=int, default=DEFAULT_STARTS,
                   help="solver starts refined (best kept)")
    p.add_argument("--max-steps", type=int, default=256)


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a model to a MERL .binary table")
    p.add_argument("table", help="path to a MERL .binary file")
    p.add_argument("--model", default="ggx",
                   help="model name (see `brdffit models`), or 'auto' to choose one")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_fit_options(p)
    p.add_argument("--plots", metavar="DIR",
                   help="also write the plots (slices, error_map, spheres, polar) as DIR/*.png")
    auto = p.add_argument_group("--model auto (docs/selection.md)")
    auto.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE,
                      help="choose the cheapest model within this log_rmse of the best, in "
                           f"quadrature (default {DEFAULT_TOLERANCE})")
    auto.add_argument("--budget", type=float,
                      help="choose the cheapest model with log_rmse under this budget")
    auto.add_argument("--candidates", type=lambda t: [c for c in t.split(",") if c],
                      default=list(DEFAULT_CANDIDATES),
                      help=f"comma-separated models (default {','.join(DEFAULT_CANDIDATES)})")
    auto.add_argument("--mono-ks", action="store_true",
                      help="refit the chosen model with a grey ks when its ks is grey")
    scene = p.add_argument_group("scene: only the directions a scene uses count")
    scene.add_argument("--scene", metavar="FILE", help="scene description: .json, .npy, .csv")
    scene.add_argument("--scene-preset", choices=list(SCENE_PRESETS))
    scene.add_argument("--max-theta", type=float, metavar="DEG",
                       help="largest incidence and view angle (degrees)")
    scene.add_argument("--max-theta-i", type=float, metavar="DEG", help="largest incidence angle")
    scene.add_argument("--max-theta-o", type=float, metavar="DEG", help="largest view angle")
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
    on = "scene" if "scene" in r.extra else "full table"
    lines.append(f"  log_rmse = {e['log_rmse']:.4g} ({on})   rmse_cos = {e['rmse_cos']:.4g} 1/sr")
    if "full_table_error" in r.extra:
        lines.append(f"  log_rmse = {r.extra['full_table_error']['log_rmse']:.4g} (full table)   "
                     f"scene {r.extra['scene']['description']}")
    s = r.samples
    d = s["dropped"]
    lines.append(
        f"  bins: {s['used']:,} fitted of {s['usable']:,} usable; dropped {d['unmeasured']:,} "
        f"unmeasured, {d['nonfinite']:,} non-finite, {d['below_horizon']:,} below the horizon"
    )
    return "\n".join(lines)


def run(args) -> int:
    table = merl.read(args.table)
    scene = Scene.from_options(args.scene, preset=args.scene_preset, max_theta=args.max_theta,
                               max_theta_i=args.max_theta_i, max_theta_o=args.max_theta_o)
    options = dict(solver=args.solver, samples=args.samples, precision=args.precision,
                   starts=args.starts, max_steps=args.max_steps)
    if args.model == "auto":
        return _run_auto(args, table, scene, options)
    result = fit_in_scene(table, args.model, scene, **options)
    return _report(args, table, result, result.to_dict(), format_result(result))


def _run_auto(args, table, scene, options) -> int:
    selection = select(table, args.candidates, tolerance=args.tolerance, budget=args.budget,
                       scene=scene, mono_ks=args.mono_ks, **options)
    return _report(args, table, selection.result, selection.to_dict(),
                   format_selection(selection))


def _report(args, table, result, as_dict: dict, as_text: str) -> int:
    """Print JSON or text, write the plots of ``result`` if asked."""
    if args.json:
        jsonout.dump(as_dict, sys.stdout)  # a metric a fit could not measure is null
        sys.stdout.write("\n")
    else:
        print(as_text)
    if args.plots:
        from .. import plots  # matplotlib only when asked for

        for path in plots.save_all(table, result, args.plots):
            # stderr: with --json, stdout stays one JSON object
            print(f"wrote {path}", file=sys.stderr)
    # A fit that ran is a result, converged or not: `converged` says which.
    return 0
