"""``brdffit export RESULT.json --to TARGET``: a fit as a renderer's material.

RESULT.json is the output of ``brdffit fit --json`` (the result schema,
docs/results.md; ``-`` reads standard input). The material goes to ``--out DIR``
as the files a renderer loads, or to standard output; the warnings (every clamp and
approximation) and the fidelity go to standard error, or all of it as one JSON
document with ``--json``. See docs/exports.md.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from brdffit.errors import BrdffitError
from brdffit.export import TARGETS, export
from brdffit.fitting.result import FitResult


def add_arguments(p) -> None:
    p.add_argument("result", help="a fit result JSON file (brdffit fit --json), or - for stdin")
    p.add_argument("--to", required=True, choices=list(TARGETS), dest="target",
                   help="the renderer: mitsuba (load_dict + scene XML), gltf (glTF 2.0 "
                        "material), materialx (gltf_pbr node)")
    p.add_argument("--out", "-o", metavar="DIR",
                   help="write the material's files into DIR (created if missing)")
    p.add_argument("--json", action="store_true",
                   help="print the whole export (material, warnings, fidelity) as JSON")


def _read_result(source: str) -> FitResult:
    text = sys.stdin.read() if source == "-" else Path(source).read_text()
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise BrdffitError(f"{source}: not JSON ({e})") from None
    if isinstance(data, dict) and "results" in data and "schema" not in data:
        raise BrdffitError(f"{source}: holds several fits; export one of them "
                           "(brdffit fit --json writes one result)")
    if not isinstance(data, dict):
        raise BrdffitError(f"{source}: not a fit result")
    try:
        return FitResult.from_dict(data)
    except (TypeError, ValueError) as e:
        raise BrdffitError(f"{source}: not a fit result: {e}") from None


def run(args) -> int:
    result = _read_result(args.result)
    out = export(result, args.target)
    if args.json:
        print(out.to_json(indent=2))
        return 0
    if args.out:
        folder = Path(args.out)
        folder.mkdir(parents=True, exist_ok=True)
        for name, text in out.files.items():
            (folder / name).write_text(text)
            print(folder / name)
    else:
        for text in out.files.values():
            sys.stdout.write(text if text.endswith("\n") else text + "\n")
    fid = out.fidelity
    how = ("exact" if fid["exact"]
           else f"approximated, log_rmse to the fit {fid['log_rmse_to_fit']:.4g}")
    print(f"{args.target}: {out.source_model} fit as {fid['target_model']} ({how})",
          file=sys.stderr)
    for w in out.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0
