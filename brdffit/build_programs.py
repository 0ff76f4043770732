"""Build and check the lowered programs shipped in the package (``brdffit.exported``).

    python -m brdffit.build_programs build   # `make programs`: lower them afresh
    python -m brdffit.build_programs check   # exit 1, naming the command, when stale

``build`` runs the default requests (``brdffit warmup``'s: ``auto`` and each of its
candidates, the log loss) with brdffit's cache off, so that every program is traced,
and ``executables.jit`` exports each one it traces (``exported.recording``). A
module of its own: the shipped programs' digest covers what their code imports
(``exported.source_files``), and this tool imports the command line, which theirs
does not.
"""

from __future__ import annotations

import argparse
import lzma
import os
import pickle
import sys
import time

from brdffit import exported


def build() -> int:
    """Lower the programs of the default requests and write them under
    ``exported.DIRECTORY`` (the previous ones removed)."""
    from brdffit.cli import warmup

    os.environ["BRDFFIT_CACHE_DIR"] = ""  # trace every program: none from a cache
    parser = argparse.ArgumentParser()
    warmup.add_arguments(parser)
    args = parser.parse_args([])  # the default requests: auto and its candidates
    exported.recording = {}
    t0 = time.perf_counter()
    try:
        warmup.run(args)
        programs = exported.recording
    finally:
        exported.recording = None
    exported.DIRECTORY.mkdir(exist_ok=True)
    for old in exported.DIRECTORY.glob("*" + exported.SUFFIX):
        old.unlink()
    total = 0
    for file_name, (serialized, example) in sorted(programs.items()):
        data = lzma.compress(pickle.dumps((serialized, example), protocol=4), preset=9)
        (exported.DIRECTORY / (file_name + exported.SUFFIX)).write_bytes(data)
        total += len(data)
    exported.INDEX.write_text(
        f"{exported.source_digest()}\n# {len(programs)} programs lowered by `python -m "
        f"brdffit.build_programs build` from the default requests ({', '.join(args.models)}; "
        "loss log)\n")
    exported.usable.cache_clear()
    print(f"brdffit.build_programs: {len(programs)} programs, {total / 1e6:.2f} MB, in "
          f"{time.perf_counter() - t0:.0f} s -> {exported.DIRECTORY}", file=sys.stderr)
    return 0


def check() -> int:
    """0 where the shipped programs are current, else 1 and what to run."""
    have, want = exported.index_digest(), exported.source_digest()
    if have == want:
        return 0
    print(f"brdffit/programs are stale (built at {have}, the sources are at {want}): "
          "run `make programs` and commit brdffit/programs", file=sys.stderr)
    return 1


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["build"]:
        return build()
    if argv == ["check"]:
        return check()
    print("usage: python -m brdffit.build_programs build|check", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
