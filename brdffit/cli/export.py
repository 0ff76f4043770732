"""``brdffit export RESULT --to TARGET``: a fit as a renderer's material.

RESULT is the output of ``brdffit fit --json`` (the result schema, docs/results.md;
``-`` reads standard input), or a batch results file (``brdffit batch``, HDF5) with
``--table NAME`` and optionally ``--model MODEL`` (default: the table's best fit).
The material goes to ``--out DIR``
as the files a renderer loads, or to standard output as one document (the first file:
Mitsuba's for its RGB variants; stderr names the others); the warnings (every clamp and
approximation) and the fidelity go to standard error, or all of it as one JSON
document with ``--json``. See docs/exports.md.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from pathlib import Path

from brdffit import executables
from brdffit.cli import output_folder
from brdffit.cli.fit import say_compiling_once
from brdffit.errors import BrdffitError, ExportError
from brdffit.export import TARGETS, export
from brdffit.fitting.quality import figure_words
from brdffit.fitting.result import FitResult
from brdffit.models.catalogue import UnknownModelError

#: The first bytes of every HDF5 file (a batch results file is one).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: ``--viewer``'s choices: the viewers of the targets that have them (glTF's)
VIEWER_CHOICES = tuple(dict.fromkeys(v for t in TARGETS.values() for v in t.viewers))


def add_arguments(p) -> None:
    p.add_argument("result", help="a fit result JSON file (brdffit fit --json), - for stdin, "
                                  "or a batch results file (brdffit batch --out)")
    p.add_argument("--to", required=True, choices=list(TARGETS), dest="target",
                   help="the renderer: mitsuba (load_dict + scene XML), gltf (glTF 2.0 "
                        "material), materialx (standard_surface node, or a "
                        "generalized_schlick lobe over a diffuse)")
    p.add_argument("--target-model", metavar="MODEL",
                   help="which of the renderer's models the file carries: "
                        + "; ".join(f"{t}: {', '.join(m.SHADED_AS)}" for t, m in TARGETS.items())
                        + " (default: the fit's own model where it is one of them, else the "
                        "first, or the one layered over it that keeps the fit's coat or "
                        "sheen)")
    p.add_argument("--measured", metavar="TABLE",
                   help="the measured .binary table the fidelity is judged against "
                        "(default: the fit's own table file, where it is still there); "
                        "another table than the fit's judges the material and does not "
                        "make it")
    p.add_argument("--out", "-o", metavar="DIR",
                   help="write the material's files into DIR (created if missing)")
    p.add_argument("--json", action="store_true",
                   help="print the whole export (material, warnings, fidelity) as JSON "
                        "(with --out, the files are written too)")
    # default None, not "spec": a --viewer given with another target is refused
    p.add_argument("--viewer", choices=VIEWER_CHOICES, default=None,
                   help="with --to gltf: fit the factors for the spec's definition (default) "
                        "or for the way three.js or Blender (Cycles) shades them (a coat, "
                        "sheen or film fit keeps its layer where the viewer shades it)")
    p.add_argument("--glb", action="store_true",
                   help="with --to gltf --out DIR: one binary .glb instead of the .gltf")
    store = p.add_argument_group("a batch results file (docs/batch.md)")
    store.add_argument("--table", help="the table: its name in the file (brdffit batch-report "
                                       "shows it), its path, or its file name")
    store.add_argument("--model", help="the fitted model (default: the table's best fit)")


def _result_text(source: str) -> str:
    """The fit result's text: UTF-8, with or without the byte-order mark an editor on
    Windows writes (``json`` refuses one); any other bytes are no fit result, said with
    the file's name (the codec's own message named no file)."""
    try:
        if source == "-":
            return sys.stdin.read().removeprefix("\ufeff")
        return Path(source).read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise BrdffitError(f"{source}: not a brdffit fit JSON (byte {e.object[e.start]:#04x} "
                           f"at offset {e.start:,} is not UTF-8 text); give the file brdffit "
                           "fit --json wrote, or a batch's results file (HDF5)") from None


def _read_result(source: str) -> FitResult:
    text = _result_text(source)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise BrdffitError(f"{source}: neither a fit result (JSON, as brdffit fit --json "
                           f"writes; {e}) nor a batch's results file (HDF5)") from None
    except RecursionError:
        raise BrdffitError(f"{source}: not a fit result: JSON nested too deeply") from None
    if isinstance(data, dict) and "results" in data and "schema" not in data:
        raise BrdffitError(f"{source}: holds several fits; export one of them "
                           "(brdffit fit --json writes one result)")
    if not isinstance(data, dict):
        raise BrdffitError(f"{source}: not a fit result")
    try:
        return FitResult.from_dict(data)
    except (TypeError, ValueError) as e:
        raise BrdffitError(f"{source}: not a fit result: {e}") from None


def _table_beside(result: FitResult, source: str) -> FitResult:
    """``result`` with its table's path found beside its JSON file (``source``) where it
    names the table relative to where it was fitted and that is not here: the same fit
    exported from another directory was made without its table (a car paint left
    MaterialX as 88% metal there and as a dielectric beside it, the weighing between
    them needing the table)."""
    table = result.table
    if source == "-" or not table or os.path.isabs(table) or os.path.isfile(table):
        return result
    beside = Path(source).parent / table
    return dataclasses.replace(result, table=str(beside)) if beside.is_file() else result


def _is_store(source: str) -> bool:
    if source == "-":
        return False
    with open(source, "rb") as f:  # a missing file: OSError, a one-line message
        return f.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE


def _say_exporting(target: str) -> None:
    """Said once the fit is read, before the export starts: a Mitsuba export refits the
    fit as the renderer's materials and weighs a metal against a dielectric (~12 s in a
    new process, its programs loaded), and it printed nothing meanwhile."""
    print(f"brdffit: exporting to {target}: the renderer's material made from the fit and "
          "measured against the table (seconds)...", file=sys.stderr, flush=True)


def _export(args):
    if not _is_store(args.result):
        if args.table is not None or args.model is not None:
            raise BrdffitError(f"{args.result}: a fit result holds one fit; --table and "
                               "--model choose a fit of a batch results file (brdffit batch)")
        result = _table_beside(_read_result(args.result), args.result)
        _say_exporting(args.target)
        try:
            return export(result, args.target, table=args.measured,
                          target_model=args.target_model, viewer=args.viewer or "spec")
        except (ExportError, UnknownModelError) as e:  # the fit's: said with its file's name
            raise ExportError(f"{args.result}: {e}") from None
    if args.table is None:
        from brdffit.batch.store import read_attrs, read_index

        read_attrs(args.result)  # refuses an HDF5 file that is not a batch file
        names = sorted(t.name for t in read_index(args.result).values())
        shown = ", ".join(names[:20]) + (f" and {len(names) - 20} more" if len(names) > 20
                                         else "")
        raise BrdffitError(f"{args.result}: a batch results file; choose a table with "
                           f"--table (it holds {shown or 'no tables'})")
    from brdffit.batch.exports import export_from_store

    return export_from_store(args.result, args.table, args.target, args.model,
                             table_file=args.measured, target_model=args.target_model,
                             viewer=args.viewer or "spec")


def _check_viewer(args) -> None:
    """A ``--viewer`` given with a target that has no viewers is refused now, in the
    flags' words: it was refused after the fit was read and "exporting to mitsuba" said,
    by the library's words on the glTF export."""
    if args.viewer is None or TARGETS[args.target].viewers:
        return
    with_viewers = [n for n, t in TARGETS.items() if t.viewers]
    others = [n for n, t in TARGETS.items() if not t.viewers]
    raise BrdffitError(f"--viewer is for --to {' or '.join(with_viewers)} "
                       f"({', '.join(VIEWER_CHOICES)}); {' and '.join(others)} have their "
                       "renderer's own shading")


def _write_stdout(files: dict[str, str]) -> None:
    """The material's document on stdout: the first of its files (the renderer's own:
    Mitsuba's for its RGB variants), alone, so that ``> material.xml`` is one document
    its parser reads (the RGB and spectral scenes printed back to back were "junk after
    document element"); the others are named on stderr, for --out."""
    (first, text), *rest = files.items()
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    if rest:
        print(f"brdffit: standard output holds {first} alone; --out DIR writes "
              f"{', '.join(name for name, _ in rest)} too (docs/exports.md)", file=sys.stderr)


def run(args) -> int:
    if args.glb and (args.target != "gltf" or not args.out):
        raise BrdffitError("--glb writes a binary glTF file: it needs --to gltf and --out DIR")
    _check_viewer(args)
    folder = output_folder(args.out, "--out") if args.out else None  # before the export
    previous, executables.on_compile = executables.on_compile, say_compiling_once()
    try:
        out = _export(args)
    finally:
        executables.on_compile = previous
    written = []
    if folder is not None:
        from brdffit.io.atomic import write_bytes

        for name, data in out.file_bytes(glb=args.glb).items():
            write_bytes(folder / name, data)
            written.append(folder / name)
    if args.json:  # stdout is the JSON alone; the files' names go to stderr
        print(out.to_json(indent=2))
        for path in written:
            print(f"wrote {path}", file=sys.stderr)
        return 0
    for path in written:
        print(path)
    if not args.out:
        _write_stdout(out.files)
    fid = out.fidelity
    how = ("exact" if fid["exact"]
           else f"approximated, log_rmse to the fit {fid['log_rmse_to_fit']:.4g}"
           if fid["log_rmse_to_fit"] else "its own parameters, in a file whose shading each "
           "viewer chooses: see each viewer's figures")
    line = f"{args.target}: {out.source_model} fit as {fid['target_model']} ({how})"
    if fid.get("log_rmse_to_table") is not None:
        colour = fid.get("sphere_colour") or {}
        binned = fid.get("measured_on") == "binned samples"
        line += (f"; to {'the samples binned onto the MERL grid' if binned else 'the table'}: "
                 f"log_rmse {fid['log_rmse_to_table']:.4g} (the fit's "
                 f"{_figure(fid.get('fit_log_rmse'), '.4g')}"
                 f"{', at the samples themselves' if binned else ''}), lit sphere "
                 f"{figure_words(colour)}")
    print(line, file=sys.stderr)
    for viewer, v in (fid.get("viewers") or {}).items():
        if v is None:  # said, so that a silent viewer is not read as a good one
            print(f"  in {viewer}: not modelled (no model here shades this file as "
                  f"{viewer} does; docs/exports.md, Viewers)", file=sys.stderr)
        else:
            colour = v["sphere_colour"] or {}
            ignored = (f" (it ignores {', '.join(v['ignores'])}: shades the rest)"
                       if v.get("ignores") else "")
            print(f"  in {viewer} ({v['model']}): log_rmse to the table "
                  f"{v['log_rmse_to_table']:.4g}, lit sphere {figure_words(colour)}{ignored}",
                  file=sys.stderr)
    for w in out.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def _figure(x, fmt: str) -> str:
    return "n/a" if x is None else format(x, fmt)
