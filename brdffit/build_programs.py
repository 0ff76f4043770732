"""Build and check the lowered programs shipped in the package (``brdffit.exported``).

    python -m brdffit.build_programs build   # `make programs`: lower them afresh
    python -m brdffit.build_programs check   # exit 1, naming the command, when stale

``build`` runs the default requests (``brdffit warmup``'s: ``auto`` and each of its
candidates, the log loss) with brdffit's cache off, so that every program is traced,
and ``executables.jit`` exports each one it traces (``exported.recording``). The index
lists the source files the programs' digest covers: the closure under imports of
the modules their code lives in (:func:`source_files`, found by parsing the sources
here, at build time: ``ast.parse`` on a server's threads at once can fail in CPython
3.11, "AST constructor recursion depth mismatch"). A module of its own, on the
shells' floor: it imports the command line, which the programs' code does not.
"""

from __future__ import annotations

import argparse
import ast
import functools
import lzma
import os
import pickle
import sys
import time

from brdffit import exported

#: Where the programs' code lives: the modules whose functions are ``executables.jit``
#: programs, and the registry of models (every built-in model's code is traced); and
#: auto's flow, which decides which of them a first auto runs (its one pass over the
#: table is one program per set of candidates it measures: when that set changed, the
#: shipped programs lacked the new one and stayed "current").
ROOT_MODULES = ("brdffit.fitting.problem", "brdffit.fitting.samples", "brdffit.fitting.sphere",
                "brdffit.fitting.starts", "brdffit.fitting.uncertainty", "brdffit.models",
                "brdffit.executables", "brdffit.selection")


def _module_file(module: str) -> str | None:
    """``module``'s source file relative to the package, or None (a name, not a module)."""
    parts = module.split(".")[1:]
    base = exported.PACKAGE.joinpath(*parts)
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return str(path.relative_to(exported.PACKAGE))
    return None


def _imports(source: str, module: str) -> set[str]:
    """The brdffit modules the file ``source`` (module ``module``) imports anywhere in
    its code, a function's body included, with every package above each of them."""
    package = module if source.endswith("__init__.py") else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse((exported.PACKAGE / source).read_bytes())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")
                up = up[:len(up) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        for name in names:
            if name == "brdffit" or name.startswith("brdffit."):
                found.update(_parents(name))
    return found


def _parents(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


@functools.cache
def source_files() -> tuple[str, ...]:
    """Every brdffit source file (relative to the package) that the programs' code
    can run: the closure of :data:`ROOT_MODULES` under imports (an over-estimate: a
    module imported for one name counts whole)."""
    seen: dict[str, str] = {}
    todo = [m for root in ROOT_MODULES for m in _parents(root)]
    while todo:
        module = todo.pop()
        if module in seen:
            continue
        source = _module_file(module)
        if source is None:
            continue
        seen[module] = source
        todo.extend(_imports(source, module) - seen.keys())
    return tuple(sorted(set(seen.values())))


def build() -> int:
    """Lower the programs of the default requests and write them under
    ``exported.DIRECTORY`` (the previous ones removed)."""
    from brdffit.cli import warmup

    os.environ["BRDFFIT_CACHE_DIR"] = ""  # trace every program: none from a cache
    _without_source_locations()
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
    files = source_files()
    exported.INDEX.write_text("".join([
        f"{exported.digest_of(files)}\n",
        f"# {len(programs)} programs lowered by `python -m brdffit.build_programs build` "
        f"from the default requests ({', '.join(args.models)}; loss log), current while\n",
        "# these sources and the traced libraries' versions are as they were:\n",
        *(f"source {f}\n" for f in files)]))
    exported.usable.cache_clear()
    print(f"brdffit.build_programs: {len(programs)} programs, {total / 1e6:.2f} MB, in "
          f"{time.perf_counter() - t0:.0f} s -> {exported.DIRECTORY}", file=sys.stderr)
    return 0


def _without_source_locations() -> None:
    """Lower every file's code without its file name and line numbers in the programs'
    locations, as JAX leaves out its own: a program then changes where its computation
    does, not where a line above it moved (a comment made 26 of 57 files differ), and
    no checkout's or virtual environment's path is shipped (optimistix's and equinox's
    lines were there too). JAX has no public switch for this; where its internal one
    is missing, the programs keep their locations (bigger diffs only)."""
    try:
        from jax._src import source_info_util
    except ImportError:
        return
    register = getattr(source_info_util, "register_exclusion", None)
    if register is not None:
        register(os.path.abspath(os.sep))  # every path: no file is the "user's"


def check() -> int:
    """0 where the shipped programs are current, else 1 and what to run."""
    index = exported.read_index()
    files = source_files()
    want = exported.digest_of(files)
    if index is not None and index == (want, files):
        return 0
    have = None if index is None else index[0]
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
