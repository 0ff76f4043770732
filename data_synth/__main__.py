"""python -m data_synth: write a synthetic MERL table and its truth sidecar."""

from __future__ import annotations

import argparse
import sys

from brdffit import models
from brdffit.io import merl
from data_synth.synth import PRESETS, make_preset, make_table, write_table


def _parse_param(text: str) -> tuple[str, object]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"--param wants NAME=VALUE[,VALUE,VALUE], got {text!r}")
    name, value = text.split("=", 1)
    try:
        numbers = [float(v) for v in value.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--param {name}: {value!r} is not a number list"
        ) from None
    return name.strip(), numbers[0] if len(numbers) == 1 else numbers


def nbrdf_main(argv: list[str]) -> int:
    """``python -m data_synth nbrdf NAME -o OUT``: a real material's table."""
    from data_synth import nbrdf

    ap = argparse.ArgumentParser(
        prog="python -m data_synth nbrdf",
        description="Write the MERL .binary table of a real material, rebuilt from its "
        "published neural BRDF (data_synth/nbrdf/README.md).",
    )
    ap.add_argument("name", nargs="?", help="material name, e.g. chrome, gold-metallic-paint")
    ap.add_argument("-o", "--out", help="output .binary path (default NAME.binary)")
    ap.add_argument("--list", action="store_true", help="print the material names and exit")
    args = ap.parse_args(argv)
    if args.list:
        print("\n".join(nbrdf.material_names()))
        return 0
    if not args.name:
        ap.error("give a material NAME (or --list)")
    out = args.out or f"{args.name}.binary"
    try:
        table = nbrdf.make_table(args.name)
        merl.write(out, table)
    except (ValueError, OSError) as e:
        print(f"data_synth: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({table.n_measured:,} measured bins, real material {args.name})")
    return 0


def samples_main(argv: list[str]) -> int:
    """``python -m data_synth samples OUT``: a sparse sample list, any layout by suffix."""
    import json

    from brdffit.errors import BrdffitError
    from brdffit.io.writers import WRITERS, write_samples
    from data_synth import sparse

    ap = argparse.ArgumentParser(
        prog="python -m data_synth samples",
        description="Write a sparse list of BRDF samples, as a gonioreflectometer measures "
        f"them, in the layout OUT's suffix names ({', '.join(WRITERS)}), and OUT.json with "
        "the truth.")
    ap.add_argument("out", help="output path: .csv, .tsv, .astm, .h5")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--model", choices=models.names(), default="ggx")
    src.add_argument("--material", help="a shipped real material (python -m data_synth "
                                        "nbrdf --list)")
    ap.add_argument("--param", action="append", type=_parse_param, default=[],
                    metavar="NAME=V[,V,V]", help="model parameter (repeatable)")
    ap.add_argument("--layout", choices=sparse.LAYOUTS, default="cornell")
    ap.add_argument("-n", type=int, default=2000, help="samples (default 2000)")
    ap.add_argument("--noise", type=float, default=0.0, help="multiplicative noise std")
    ap.add_argument("--sigma", action="store_true",
                    help="record noise * value as each sample's sigma (not in .astm)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    try:
        if args.material:
            meas = sparse.sample_material(args.material, args.layout, args.n, noise=args.noise,
                                          sigma=args.sigma, seed=args.seed)
            truth = {"material": args.material}
        else:
            meas, params = sparse.sample_model(args.model, dict(args.param), args.layout,
                                               args.n, noise=args.noise, sigma=args.sigma,
                                               seed=args.seed)
            truth = {"model": args.model, "params": params}
        write_samples(meas, args.out)
        sidecar = f"{args.out}.json"
        with open(sidecar, "w") as f:
            json.dump({**truth, "layout": args.layout, "n": meas.n, "noise": args.noise,
                       "seed": args.seed}, f, indent=1)
    except (ValueError, OSError, BrdffitError) as e:
        print(f"data_synth: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({meas.n:,} samples, {args.layout}) and {sidecar}")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["nbrdf"]:
        return nbrdf_main(argv[1:])
    if argv[:1] == ["samples"]:
        return samples_main(argv[1:])
    ap = argparse.ArgumentParser(
        prog="python -m data_synth",
        description="Write a synthetic MERL .binary table (and OUT.json with the true params). "
        "`python -m data_synth nbrdf NAME -o OUT` writes a real material instead; "
        "`python -m data_synth samples OUT.csv` a sparse sample list.",
    )
    ap.add_argument("out", help="output .binary path")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--model", choices=models.names(), default="ggx")
    src.add_argument("--preset", choices=list(PRESETS), help="a named hard case")
    ap.add_argument(
        "--param",
        action="append",
        type=_parse_param,
        default=[],
        metavar="NAME=V[,V,V]",
        help="model parameter (repeatable); others default (a preset's own, with --preset)",
    )
    # None, not 0: with --preset, an option not given keeps the preset's own value
    ap.add_argument("--noise", type=float,
                    help="multiplicative noise std (e.g. 0.05; default 0, or the preset's)")
    ap.add_argument("--missing", type=float,
                    help="fraction of bins to drop (default 0, or the preset's)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    try:
        if args.preset:
            table, truth = make_preset(args.preset, seed=args.seed, noise=args.noise,
                                       missing=args.missing, params=dict(args.param))
        else:
            table, truth = make_table(
                args.model,
                dict(args.param),
                noise=args.noise or 0.0,
                missing=args.missing or 0.0,
                seed=args.seed,
                source=args.out,
            )
        sidecar = write_table(args.out, table, truth)
    except (ValueError, OSError) as e:
        print(f"data_synth: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({table.n_measured:,} measured bins) and {sidecar}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
