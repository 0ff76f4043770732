"""The default fits' programs, lowered once and shipped inside the package.

A new process with an empty cache spends ~40% of a first fit before XLA compiles
anything: JAX traces brdffit's Python and lowers it to StableHLO, program by program
(a first ``auto``: 8.5 s of tracing and lowering beside 18 s of compiling, summed over
its threads; bench/results/startup.md). The lowered programs do not depend on the
machine: ``jax.export`` serialises them, and a later JAX reads them back
(its compatibility guarantee). The programs of the default requests (``auto`` and
each of its candidates, the log loss: what ``brdffit warmup`` compiles) are kept
under ``brdffit/programs/``, and :func:`brdffit.executables.jit` compiles from them
instead of tracing, then keeps the compiled executable as before.

A shipped program is used only where it is what tracing would give:

- the **source digest** in ``programs/INDEX`` is the digest of every brdffit module
  that the programs' own modules import, directly or not (:func:`source_files`),
  with the versions of equinox, lineax and optimistix, whose code is traced into
  the programs; any change to either and the whole directory is passed over;
- each file is found by the same key as a compiled executable on disk (the
  function, its static arguments, the shapes and dtypes of its arrays), less the
  machine;
- only on the CPU, the platform they were lowered for.

``python -m brdffit.build_programs build`` (``make programs``) makes them afresh;
its ``check`` fails, naming the command, when they are stale, and the test suite
runs it. A file that does not load is traced as before.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.metadata
import lzma
import pickle
import sys
from pathlib import Path

from brdffit import runtime

PACKAGE = Path(__file__).resolve().parent
DIRECTORY = PACKAGE / "programs"
INDEX = DIRECTORY / "INDEX"
SUFFIX = ".stablehlo.xz"
#: Where the programs' code lives: the modules whose functions are ``executables.jit``
#: programs, and the registry of models (every built-in model's code is traced).
ROOT_MODULES = ("brdffit.fitting.problem", "brdffit.fitting.samples", "brdffit.fitting.sphere",
                "brdffit.fitting.starts", "brdffit.fitting.uncertainty", "brdffit.models",
                "brdffit.executables")
#: Libraries whose code is traced into the programs (JAX's own lowering is what
#: ``jax.export``'s compatibility covers).
TRACED_LIBRARIES = ("equinox", "lineax", "optimistix")
_FORMAT = 1


def _module_file(module: str) -> Path | None:
    parts = module.split(".")[1:]
    base = PACKAGE.joinpath(*parts)
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _imports(path: Path, module: str) -> set[str]:
    """The brdffit modules ``path`` (module ``module``) imports anywhere in its code,
    a function's body included, with every package above each of them."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_bytes())):
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
                parts = name.split(".")
                found.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
    return found


@functools.cache
def source_files() -> tuple[Path, ...]:
    """Every brdffit source file that the programs' code can run: the closure of
    :data:`ROOT_MODULES` under imports (an over-estimate: a module imported for one
    name counts whole)."""
    seen: dict[str, Path] = {}
    todo = [m for root in ROOT_MODULES for m in _parents(root)]
    while todo:
        module = todo.pop()
        if module in seen:
            continue
        path = _module_file(module)
        if path is None:  # a name imported from a module, not a module
            continue
        seen[module] = path
        todo.extend(_imports(path, module) - seen.keys())
    return tuple(sorted(set(seen.values())))


def _parents(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


@functools.cache
def source_digest() -> str:
    """The digest the shipped programs were built at, when they are current."""
    h = hashlib.sha256(f"format {_FORMAT}\n".encode())
    for path in source_files():
        h.update(str(path.relative_to(PACKAGE)).encode())
        h.update(path.read_bytes())
    for dist in TRACED_LIBRARIES:
        try:
            h.update(f"{dist} {importlib.metadata.version(dist)}\n".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{dist} -\n".encode())
    return h.hexdigest()[:24]


def index_digest() -> str | None:
    try:
        return INDEX.read_text().split()[0]
    except (OSError, IndexError):
        return None


@functools.cache
def usable() -> bool:
    """Whether the shipped programs are current and this process runs on the CPU."""
    import jax

    return (jax.default_backend() == "cpu" and index_digest() is not None
            and index_digest() == source_digest())


def lowered(file_name: str, arrays):
    """(the program shipped as ``file_name`` lowered for ``arrays``, its outputs'
    structure as an example value), or None where there is none usable."""
    if recording is not None or not usable():  # building them: every program traced
        return None
    path = DIRECTORY / (file_name + SUFFIX)
    if not path.is_file():
        return None
    import jax
    from jax import export

    try:
        serialized, example = pickle.loads(lzma.decompress(path.read_bytes()))
        program = export.deserialize(bytearray(serialized))
        return jax.jit(program.call).lower(*arrays), example
    except Exception as e:  # noqa: BLE001 - damaged, or from a JAX this one cannot read
        runtime.log.info("brdffit: shipped program %s not used (%s)", file_name, e)
        return None


# -- building them ------------------------------------------------------------------

#: Set by ``brdffit.build_programs``: ``executables.jit`` exports every program it
#: traces into it (file name -> (serialised program, an example of its outputs)).
recording: dict | None = None


def record(file_name: str, flat, arrays, example) -> None:
    """Export the traced function ``flat`` for ``arrays``, while programs are built."""
    if recording is None or file_name in recording:
        return
    import jax
    from jax import export

    try:
        program = export.export(jax.jit(flat), platforms=["cpu"])(*arrays)
        recording[file_name] = (bytes(program.serialize()), example)
    except Exception as e:  # noqa: BLE001 - a program jax.export cannot keep: traced as before
        print(f"  not exported: {file_name} ({type(e).__name__}: {str(e)[:200]})",
              file=sys.stderr)
