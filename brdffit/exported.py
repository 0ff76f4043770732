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
  that the programs' own modules import, directly or not (listed in the index), with
  the versions of equinox, lineax and optimistix, whose code is traced into the
  programs; any change to either and the whole directory is passed over;
- each file is found by the same key as a compiled executable on disk (the
  function, its static arguments, the shapes and dtypes of its arrays), less the
  machine;
- only on the CPU, the platform they were lowered for.

``python -m brdffit.build_programs build`` (``make programs``) makes them afresh;
its ``check`` fails, naming the command, when they are stale, and the test suite
runs it. A file that does not load is traced as before.
"""

from __future__ import annotations

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
#: Libraries whose code is traced into the programs (JAX's own lowering is what
#: ``jax.export``'s compatibility covers).
TRACED_LIBRARIES = ("equinox", "lineax", "optimistix")
_FORMAT = 1


def digest_of(files) -> str:
    """The digest of the brdffit source ``files`` (paths relative to the package)
    and of the :data:`TRACED_LIBRARIES`' installed versions."""
    h = hashlib.sha256(f"format {_FORMAT}\n".encode())
    for name in sorted(files):
        h.update(name.encode())
        h.update((PACKAGE / name).read_bytes())
    for dist in TRACED_LIBRARIES:
        try:
            h.update(f"{dist} {importlib.metadata.version(dist)}\n".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{dist} -\n".encode())
    return h.hexdigest()[:24]


def read_index() -> tuple[str, tuple[str, ...]] | None:
    """(the digest the programs were built at, the source files it covers), or None
    where there is no index. The files are listed at build time
    (``brdffit.build_programs``: the modules the programs' code imports): a change to
    what they import changes one of them, so the list is current while the digest is."""
    try:
        lines = INDEX.read_text().splitlines()
    except OSError:
        return None
    files = tuple(ln.split(" ", 1)[1] for ln in lines[1:] if ln.startswith("source "))
    return (lines[0].strip(), files) if lines and files else None


@functools.cache
def usable() -> bool:
    """Whether the shipped programs are current and this process runs on the CPU."""
    import jax

    index = read_index()
    if index is None or jax.default_backend() != "cpu":
        return False
    try:
        return digest_of(index[1]) == index[0]
    except OSError:  # a listed file gone: sources changed since
        return False


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
