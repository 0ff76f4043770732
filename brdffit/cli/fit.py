"""``brdffit fit TABLE``: fit one table and print the result (or JSON)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import threading

from brdffit import executables, extras, jsonout, runtime
from brdffit.cli import name_list, output_folder
from brdffit.fitting import options
from brdffit.fitting.options import FIT_KEYWORDS, FitOptions, SelectionRule
from brdffit.fitting.quality import describe
from brdffit.fitting.result import FitResult, error_measures_nothing
from brdffit.fitting.scene import PRESETS as SCENE_PRESETS
from brdffit.fitting.scene import Scene
from brdffit.io import readers
from brdffit.io.measurements import Measurements
from brdffit.io.merl import SHAPE as GRID
from brdffit.request import FitReport, FitRequest, split_names
from brdffit.request import run as fit_request
from brdffit.selection import format_selection


def add_option_arguments(p, names, of: type = FitOptions) -> None:
    """A ``--flag`` for each of the fields ``names`` of
    ``brdffit.fitting.options.FitOptions`` (or ``SelectionRule``).

    Type, choices, default and help come from the field, so the command line
    cannot drift from the library; ranges are checked where every shell checks
    them, when the :class:`FitOptions` is built (:func:`options_from_args`). A
    rule's flags are left out of the parsed arguments unless given: a rule is
    only part of a request that asks for one (:func:`request_from_args`).
    """
    rule = of is SelectionRule
    for name in names:
        default, opt = options.spec(name, of)
        flag = f"--{name.replace('_', '-')}"
        unset = {"default": argparse.SUPPRESS} if rule else {"default": default}
        if opt.kind is bool:  # a flag: --physical turns it on
            p.add_argument(flag, action="store_true", **unset,
                           help=f"{opt.doc} (default off)".replace("%", "%%"))
            continue
        if opt.kind is tuple:  # names, comma-separated
            p.add_argument(flag, type=name_list(flag), **unset,
                           help=f"{opt.doc}, comma-separated (default "
                           f"{','.join(default)})".replace("%", "%%"))
            continue
        shown = opt.cli_none if default is None and opt.cli_none else default
        valid = "" if opt.choices else opt.describe_range(opt.cli_none or "absent") + "; "
        help_text = f"{opt.doc} ({valid}default {'none' if shown is None else shown})"
        kw = {**unset, "help": help_text.replace("%", "%%")}
        if opt.choices is not None:
            kw["choices"] = opt.choices
        else:
            kw["type"] = _value_parser(name, opt)
        p.add_argument(flag, **kw)


def _value_parser(name: str, opt: options.Option):
    def parse(text: str):
        if opt.cli_none is not None and text == opt.cli_none:
            return None
        try:
            return opt.kind(text)
        except ValueError:
            wanted = {int: "an integer", float: "a number", str: "a string"}[opt.kind]
            alt = f" or {opt.cli_none!r}" if opt.cli_none else ""
            raise argparse.ArgumentTypeError(
                f"--{name.replace('_', '-')} wants {wanted}{alt}, got {text!r}") from None

    parse.__name__ = name  # argparse names the option by it in its messages
    return parse


def add_fit_options(p) -> None:
    """The options of ``brdffit.fit`` (shared by ``fit`` and ``batch``)."""
    add_option_arguments(p, FIT_KEYWORDS)


def options_from_args(args) -> FitOptions:
    """The :class:`FitOptions` of parsed arguments (the fields the parser has);
    raises ``FitInputError`` for a value out of range."""
    return FitOptions(**{n: getattr(args, n) for n in options.names() if hasattr(args, n)})


def rule_from_args(args) -> SelectionRule | None:
    """The :class:`SelectionRule` of the rule's flags given (None where none was)."""
    given = {n: getattr(args, n) for n in options.names(SelectionRule) if hasattr(args, n)}
    return SelectionRule.from_dict(given) if given else None


#: The layout each reader of ``brdffit.io.readers.READERS`` reads, in words, by the
#: reader's name; a reader added there without words here is still listed, by its
#: suffixes (:func:`formats_help`).
READER_WORDS = {
    "read": "a MERL table", "read_astm": "ASTM E1392", "read_csv": "CSV/TSV with a header",
    "read_text_samples": "ASTM or CSV by its content", "read_hdf5": "HDF5",
    "read_mat": "MATLAB", "read_npz": "NumPy", "read_xlsx": "Excel",
}


def formats_help() -> str:
    """Every layout the readers take, with its suffixes, from the readers' registry:
    the help listed ASTM, CSV/TSV and HDF5 by hand, and not the .mat, .npz and .xlsx
    readers added since."""
    by_reader: dict = {}
    for suffix, reader in readers.READERS.items():
        by_reader.setdefault(reader, []).append(suffix)
    return ", ".join(f"{READER_WORDS[r.__name__]} ({', '.join(s)})" if r.__name__ in READER_WORDS
                     else ", ".join(s) for r, s in by_reader.items())


def add_arguments(p) -> None:
    p.add_argument("table", help=f"the measured file, by its suffix: {formats_help()}; "
                   "another suffix is read by its content (docs/measurements.md; samples "
                   "are fitted at their own directions); '-' reads it from standard input")
    p.add_argument("--sheet", metavar="NAME",
                   help="an Excel workbook's sheet of samples to fit (default: its first "
                        "sheet that holds samples)")
    default_model = options.DEFAULT_MODEL
    p.add_argument("--model", default=default_model,
                   help="model name (see `brdffit models`), a comma-separated list of them "
                   "(each is fitted, the best log_rmse is the result), or 'auto' to choose "
                   f"one (docs/selection.md) (default {default_model})")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_fit_options(p)
    p.add_argument("--plots", metavar="DIR",
                   help="also write the plots (report, slices, error_map, spheres, polar; ranking "
                        "with auto; spheres_judged, the spheres at the exposure the verdict "
                        "judged, where that is 2 stops or more from spheres.png's; "
                        "samples, each sample fitted against measured, for a sample list) "
                        "as DIR/*.png")
    add_request_arguments(p, "--model")


def add_request_arguments(p, model_flag: str) -> None:
    """The selection rule's and the scene's flags, which ``fit`` and ``batch`` share
    (the fit options are :func:`add_fit_options`')."""
    auto = p.add_argument_group(f"{model_flag} auto: the selection rule (docs/selection.md)")
    add_option_arguments(auto, options.names(SelectionRule), of=SelectionRule)
    scene = p.add_argument_group("scene: only the directions a scene uses count")
    scene.add_argument("--scene", metavar="FILE", help="scene description: .json, .npy, .csv")
    scene.add_argument("--scene-preset", choices=list(SCENE_PRESETS))
    scene.add_argument("--max-theta", type=float, metavar="DEG",
                       help="largest incidence and view angle (degrees)")
    scene.add_argument("--max-theta-i", type=float, metavar="DEG", help="largest incidence angle")
    scene.add_argument("--max-theta-o", type=float, metavar="DEG", help="largest view angle")


#: Bins of the MERL grid.
N_BINS = GRID[0] * GRID[1] * GRID[2]


def format_result(r: FitResult) -> str:
    """A human-readable summary of a fit: parameters with their standard errors and
    undetermined flags (docs/results.md), every metric, the bins used."""
    bounded = ", physically bounded" if r.physical is not None else ""
    lines = [f"{r.table}: {r.model} fit ({r.loss} loss{bounded}), {r.result} after {r.steps} "
             f"steps in {r.time_s:.2f} s" + ("" if r.converged else "  (NOT converged)")]
    u = r.uncertainty or {}
    se, flag = u.get("std_error", {}), u.get("undetermined", {})
    at_bound = u.get("at_bound", {})
    for name, v in r.params.items():
        vals = v if isinstance(v, list) else [v]
        errs = se.get(name, [None] * len(vals))
        errs = errs if isinstance(errs, list) else [errs]
        bounds = at_bound.get(name, [False] * len(vals))
        bounds = bounds if isinstance(bounds, list) else [bounds]
        keys = [name] if not isinstance(v, list) else [f"{name}[{i}]" for i in range(len(vals))]
        absent = [error_measures_nothing(u.get("why", {}).get(k)) for k in keys]
        shown = ", ".join(_with_error(x, None if a else e, b)
                          for x, e, b, a in zip(vals, errs, bounds, absent, strict=True))
        flags = flag.get(name, False)
        mark = "  UNDETERMINED" if any(flags if isinstance(flags, list) else [flags]) else ""
        lines.append(f"  {name:<6} = {shown}{mark}")
    for entry, why in u.get("why", {}).items():
        lines.append(f"    {entry}: {why}")
    for entry, others in u.get("strongly_correlated", {}).items():
        lines.append(f"    {entry} correlates (|r| > 0.95) with {', '.join(others)}")
    for layer, seen in (u.get("layers") or {}).items():
        lines.append(f"  layer {layer}: {seen['status']} ({seen['why']})")
    e = r.error
    on_samples = (r.input or {}).get("fitted_at") == "samples"
    whole = "every sample" if on_samples else "full table"
    on = "scene" if r.scene is not None else whole
    held = (r.quality or {}).get("basis") == "held_out"
    psnr = _g(e.get("psnr_db"), ".1f")
    lines.append(f"  error ({on}): log_rmse {e['log_rmse']:.4g}   cube_root_rmse "
                 f"{_g(e.get('cube_root_rmse'))}   rmse_cos {e['rmse_cos']:.4g} 1/sr   "
                 f"rel_peak_error {_g(e.get('rel_peak_error'))}   "
                 f"{'held-out' if held else 'sphere'} PSNR {psnr}{'' if psnr == 'n/a' else ' dB'}")
    if "held_out_log_rmse" in e:
        used, of = r.input.get("used"), r.input.get("samples")
        # the folds split the solver's samples: said where they are fewer than every sample
        # (at 200,000 a held-out 0.00749 read below the in-sample 0.00781 unexplained)
        over = (f", over the solver's {used:,} samples" if isinstance(used, int)
                and isinstance(of, int) and used < of else "")
        lines.append(f"  held-out error ({r.input['held_out']['folds']}-fold{over}): log_rmse "
                     f"{e['held_out_log_rmse']:.4g}   cube_root_rmse "
                     f"{_g(e.get('held_out_cube_root_rmse'))}   rmse_cos "
                     f"{_g(e.get('held_out_rmse_cos'))} 1/sr")
    lines += describe_physical(r.physical)
    lines += describe(r.quality)
    if r.full_table_error is not None:
        lines.append(f"  log_rmse = {r.full_table_error['log_rmse']:.4g} ({whole})   "
                     f"scene {r.scene['description']}")
    s = r.samples
    d = s["dropped"]
    if on_samples:
        lines += describe_coverage(r.input)
        lines.append(f"  samples: {s['used']:,} fitted of {s['usable']:,} usable; dropped "
                     f"{d['below_horizon']:,} on the horizon")
    else:
        # a scene's bins are the usable ones: those it leaves out are the rest of the grid
        outside = N_BINS - s["usable"] - sum(d.values())
        lines.append(
            f"  bins: {s['used']:,} fitted of {s['usable']:,} usable; dropped "
            f"{d['unmeasured']:,} unmeasured, {d['nonfinite']:,} non-finite, "
            f"{d['below_horizon']:,} below the horizon"
            + (f", {outside:,} outside the scene" if r.scene is not None and outside > 0 else ""))
    lines += [f"  note: {n}" for n in r.notes]  # where the fit did other than asked
    return "\n".join(lines)


def describe_physical(p: dict | None) -> list[str]:
    """What a physically bounded fit's bounds did (its ``physical`` block, docs/results.md),
    for a person: the bounded fit's log_rmse against the unconstrained one's, the largest
    albedo, and the bounds that decided it. --physical printed nothing of them (the cost
    was in --json alone)."""
    if p is None:
        return []
    head = "  physical bounds (directional albedo <= 1, reflectances <= 1): "
    after = max(p["albedo_max_after"])
    if not p["active"] and p["scale"] == 1.0 and p["relative_cost"] in (0.0, None):
        return [f"{head}none active, the unconstrained fit meets them (log_rmse "
                f"{_g(p['log_rmse'])}, largest albedo {after:.4g} at "
                f"{p['albedo_max_after_theta_deg']:g} deg)"]
    cost = p["relative_cost"]
    # a ratio beyond +100%: on a table the model made, the unconstrained fit's ~1e-8
    # read "+7.5e+07%"
    cost = ("n/a" if cost is None else f"{100 * cost:+.2g}%" if cost < 1
            else f"{1 + cost:.3g}x")
    unconstrained = ("" if p.get("unconstrained_result") in (None, "successful")
                     else f", its solve {p['unconstrained_result']}")
    return [f"{head}log_rmse {_g(p['log_rmse'])} against the unconstrained fit's "
            f"{_g(p['unconstrained_log_rmse'])} ({cost}){unconstrained}; largest albedo "
            f"{after:.4g} at {p['albedo_max_after_theta_deg']:g} deg (unconstrained "
            f"{max(p['albedo_max_before']):.4g} at {p['albedo_max_before_theta_deg']:g} deg)",
            "    active: " + ("; ".join(p["active"]) or "none")]


#: From this far (theta_h, degrees) between the mirror and its nearest sample, a seen
#: peak is said to be the fitted one: a MERL metal's lobe is 1-2 degrees wide.
MIRROR_GAP_DEG = 1.0


def describe_coverage(measured_input: dict) -> list[str]:
    """Where a sample fit's samples lie, and what they leave undetermined, for a person."""
    c = measured_input.get("coverage")
    if not c:
        return []
    regions = c["regions"]
    peak = {True: "seen", False: "NOT seen (no sample within half its height)",
            None: "no lobe fitted"}[c["peak_seen"]]
    if c["peak_seen"] and c.get("min_theta_h_deg", 0.0) >= MIRROR_GAP_DEG:
        # "seen" is of the fitted lobe: a broad dim one fitted where a sharp peak fell
        # between the samples is seen too (chrome's 200 samples: alpha 0.15 for 0.007)
        peak += (f" (the fitted one; the nearest sample is {c['min_theta_h_deg']:.1f} deg from "
                 "a mirror configuration: a narrower highlight would go unseen)")
    lines = [f"  coverage: {regions['held']} of {regions['of']} (theta_h, theta_d) regions of "
             f"{regions['deg']} deg; theta_i {c['theta_i_deg'][0]:.0f}-{c['theta_i_deg'][1]:.0f} "
             f"deg, theta_o {c['theta_o_deg'][0]:.0f}-{c['theta_o_deg'][1]:.0f} deg"
             f"{', in-plane' if c['in_plane'] else ''}; specular peak {peak}"]
    loose = {k: v for k, v in (measured_input.get("identifiability") or {}).items()
             if v != "determined"}
    if loose:
        lines.append("  not determined by these samples: "
                     + "; ".join(f"{k} ({why})" for k, why in loose.items()))
    return lines


def _g(x, fmt: str = ".4g") -> str:
    # a figure not measured: None from a stored result, NaN from a fresh one (it
    # printed "sphere PSNR nan dB")
    return "n/a" if x is None or not math.isfinite(x) else format(x, fmt)


def _with_error(x: float, se: float | None, at_bound: bool) -> str:
    if at_bound:
        return f"{x:.5g} (at bound)"
    return f"{x:.5g}" if se is None else f"{x:.5g} ± {se:.2g}"


def request_from_args(args, models=None) -> FitRequest:
    """The :class:`~brdffit.request.FitRequest` of parsed ``brdffit fit`` (or ``batch``,
    whose ``models`` are given) arguments; raises ``FitInputError`` (or ``SceneError``)
    for what the library refuses."""
    scene = Scene.from_options(args.scene, preset=args.scene_preset, max_theta=args.max_theta,
                               max_theta_i=args.max_theta_i, max_theta_o=args.max_theta_o)
    # --model takes a list too (ggx,beckmann): each is fitted, the best is the result
    return FitRequest(models=split_names(str(args.model), "--model") if models is None else models,
                      options=options_from_args(args), scene=scene, rule=rule_from_args(args))


def run(args) -> int:
    request = request_from_args(args)  # refused before the table is read
    if args.plots:
        extras.require("plots", "brdffit fit --plots")  # before the fit, not after
    # '-' as brdffit export takes it (it was "-: cannot read: No such file")
    measured = readers.read_measured("/dev/stdin" if args.table == "-" else args.table,
                                     sheet=getattr(args, "sheet", None))
    if args.plots:  # made once the input is read: a refused file leaves no empty folder
        output_folder(args.plots, "--plots")
    table = measured
    if isinstance(measured, Measurements):  # said before the fit: what it will see
        from brdffit.fitting.samples import binned

        comma = ", decimal commas" if measured.provenance.get("decimal_comma") else ""
        if half := measured.provenance.get("half_diff"):
            comma += f", directions from their half and difference angles ({', '.join(half)})"
        if empty := measured.provenance.get("empty_rows"):
            comma += f", {empty:,} row{'s' if empty != 1 else ''} of empty cells skipped"
        if long := measured.provenance.get("long_layout"):
            comma += (f", pivoted from {long['rows']:,} rows, one per sample and "
                      f"{long['column']}: {long['per_sample']} per sample")
        if measured.provenance.get("sheets", 1) > 1:  # which sheet of a workbook, and why
            comma += (f", {'hidden ' if measured.provenance.get('sheet_hidden') else ''}"
                      f"sheet {measured.provenance['sheet']!r} of {measured.provenance['sheets']}")
            comma += "".join(f"; sheet {p['sheet']!r} passed over: {p['why']}"
                             for p in measured.provenance.get("sheets_passed", ()))
        print(f"brdffit: {measured.n} sample{'s' if measured.n != 1 else ''} "
              f"({measured.provenance.get('format')}{comma}), to be fitted at their own "
              "directions, with a held-out error", file=sys.stderr)
        table = binned(measured)[0]  # what the plots draw: the samples in their bins
    # for this fit only: a caller of main() in its own process keeps its own hook
    previous, executables.on_compile = executables.on_compile, say_compiling_once()
    try:
        report = fit_request(measured, request,
                             progress=print_progress if request.auto else None)
    finally:
        executables.on_compile = previous
    # auto: the ranking and its reason, then the chosen fit in full, as one fit prints
    # (its standard errors, every error figure, the bins or the samples' coverage, notes)
    text = ("\n".join([format_selection(cli_words(report.selection), chosen_params=False), "",
                       format_result(report.chosen_fit)]) if report.selection is not None
            else format_result(report.chosen_fit) if len(report.ranking) == 1
            else format_models(report))
    return write_report(args, table, report, text,
                        measured if isinstance(measured, Measurements) else None)


#: The library's keywords in auto's reason (``brdffit.selection``) -> this command's
#: flags: "mono_ks=True fits it" told a command-line user a Python keyword.
FLAG_WORDS = {"mono_ks=True": "--mono-ks"}


def cli_words(selection):
    """``selection`` with its reason in the command line's words (:data:`FLAG_WORDS`);
    --json keeps the library's, as the service and Python callers read them."""
    reason = selection.reason
    for keyword, flag in FLAG_WORDS.items():
        reason = reason.replace(keyword, flag)
    return dataclasses.replace(selection, reason=reason)


def format_models(report: FitReport) -> str:
    """``--model a,b,...``: one line per model, the reason for the best, then the best
    fit in full (:func:`format_result`)."""
    held = any(row.get("log_rmse_basis") == "held_out" for row in report.ranking)
    lines = [f"{'model':<14}{'k':>3} {'held-out' if held else 'log_rmse':>10} {'looks':>8}  solve"]
    for row in report.ranking:
        if row["status"] == "failed":
            lines.append(f"{row['model']:<14}{row['n_params']:>3}  failed: {row['message']}")
            continue
        lines.append(f"{row['model']:<14}{row['n_params']:>3} {row['log_rmse']:>10.4g} "
                     f"{row.get('verdict') or '-':>8}  {row['result']}")
    return "\n".join([*lines, report.reason, "", format_result(report.chosen_fit)])


def say_compiling_once():
    """``executables.on_compile`` for one command: the first compile says, on stderr,
    why this run takes seconds (a first use of these options on this machine, or a
    brdffit or JAX other than the one whose programs the cache keeps), and whether the
    next run will load what it compiles. A program that is not kept (a
    plugin model's, or any with the cache off) is compiled in every run, which its
    own line says, once."""
    lock = threading.Lock()
    said: set[bool] = set()  # whether a kept / a not-kept compile was announced

    def say(name: str, kept: bool) -> None:
        with lock:
            if kept in said:
                return
            said.add(kept)
        if kept:
            kept_here, kept_before = executables.programs_kept()
            if kept_before and not kept_here:
                _say_between_progress(f"brdffit: compiling (seconds; brdffit or JAX changed "
                                      f"since the programs kept in {runtime.cache_dir()} "
                                      "were compiled; kept there for the next run)")
                return
            first = ("since brdffit or JAX last changed" if kept_before
                     else "on this machine")
            _say_between_progress(f"brdffit: first use of these options {first}: "
                                  f"compiling (seconds; kept in {runtime.cache_dir()} for the "
                                  f"next run)")
            return
        why = ("BRDFFIT_CACHE_DIR is empty" if runtime.cache_dir() is None
               else "a plugin model's programs are compiled in every run")
        _say_between_progress(f"brdffit: compiling (seconds; not kept: {why})")

    return say


#: ``--model auto``'s progress line while its candidate is being fitted (printed without
#: its end, which the candidate's figures complete), or None: a line said meanwhile (the
#: compile notice) goes on a line of its own, and the progress line is restated after it
#: (it read "fitting gltf_pbr ...brdffit: first use ..." then " log_rmse ..." alone).
_open_progress: list[str] = []


def _say_between_progress(line: str) -> None:
    if _open_progress:
        print(file=sys.stderr)
    print(line, file=sys.stderr, flush=True)
    if _open_progress:
        print(_open_progress[0], end="", file=sys.stderr, flush=True)


def print_progress(i: int, n: int, model: str, row: dict | None) -> None:
    """``--model auto``'s progress, one line per candidate on stderr (stdout stays the
    result, one JSON object with --json)."""
    _open_progress.clear()
    if row is None:
        _open_progress.append(f"auto: [{i + 1}/{n}] fitting {model} ...")
        print(_open_progress[0], end="", file=sys.stderr, flush=True)
    elif row["status"] == "failed":
        print(f" failed: {row.get('message', row.get('result'))}", file=sys.stderr, flush=True)
    else:
        note = "" if row["converged"] else f", {row['result']}"
        # a sample list's candidates are ranked by their held-out error: said so (it
        # read "log_rmse 0.2485" beside the result's in-sample 0.2434)
        basis = "held-out log_rmse" if row.get("log_rmse_basis") == "held_out" else "log_rmse"
        print(f" {basis} {row['log_rmse']:.4g} in {row['fit_time_s']:.1f} s{note}",
              file=sys.stderr, flush=True)


def write_report(args, table, report: FitReport, as_text: str,
                 samples: Measurements | None = None) -> int:
    """Print JSON (the chosen fit in the result schema; auto's carries its
    ``selection``) or text, write the plots if asked (and for a sample list,
    ``samples``, each sample's: ``samples.png``)."""
    if args.json:
        jsonout.dump(report.chosen_fit.to_dict(), sys.stdout)  # a metric not measured is null
        sys.stdout.write("\n")
    else:
        print(as_text)
    if args.plots:
        from brdffit.view import plots  # matplotlib only when asked for

        paths = plots.save_report(table, report, args.plots, measured=samples)
        if samples is not None:  # each sample, of which the others show few
            from brdffit.view import sample_plot

            paths.append(sample_plot.save(samples, report.chosen_fit, args.plots))
        for path in paths:
            # stderr: with --json, stdout stays one JSON object
            print(f"wrote {path}", file=sys.stderr)
    # A fit that ran is a result, converged or not: `converged` says which.
    return 0
