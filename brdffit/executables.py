"""Compiled fits kept on disk, so that a new process runs them without tracing.

JAX's persistent compilation cache (``brdffit.runtime``) saves the *compilation* of a
function, but a new process still traces it and lowers it to find the cache entry:
for a default fit that is ~1 s of a 2 s command. :func:`jit` keeps the compiled
executable itself (``jax.experimental.serialize_executable``) under
``cache_dir()/executables/<fingerprint>/``, found again from the arguments' shapes
alone; loading one takes milliseconds to ~0.1 s. Where none is kept yet, a program
the package ships already lowered (``brdffit.exported``: the default fits') is
compiled from that, without tracing.

:func:`jit` is a drop-in ``equinox.filter_jit``: arrays are traced, every other
argument is static. The key of an executable on disk is everything its code depends
on:

- the **fingerprint**: the bytes of every brdffit source file, the versions of jax,
  jaxlib, equinox, lineax and optimistix, the backend and device kind, the CPU's
  feature flags and ``XLA_FLAGS``; a new brdffit or jax gets a new directory, and
  directories unused for :data:`KEEP_DAYS` are removed;
- the function's name, the structure and static values of its arguments (a model's
  static fields, a solver's tolerances) and the shape and dtype of every array.

Only brdffit's own functions, with arguments built from brdffit's own classes,
optimistix/lineax/equinox and Python's plain values, are kept on disk: a plugin
model's code is not in the fingerprint, so its fits are compiled as usual
(``equinox.filter_jit``), in memory.
A file that cannot be read or loaded is compiled again and replaced; a cache that
cannot be written costs speed only. ``BRDFFIT_CACHE_DIR=`` (empty) switches it off.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import os
import pickle
import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from brdffit import exported, runtime

#: Fingerprint directories not used for this long are removed (old brdffit or jax).
KEEP_DAYS = 7
#: Modules whose classes may appear in a key on disk: their code is fixed by the
#: fingerprint (brdffit) or by the recorded package versions.
_KEYED_MODULES = ("brdffit.", "optimistix.", "lineax.", "equinox.", "jax.", "builtins",
                  "collections", "numpy")
_FORMAT = 1  # of the files written here


class _SharedLock:
    """Many holders of the shared side (compiling), or one of the exclusive side
    (loading from disk): see ``call`` in :func:`jit`."""

    def __init__(self):
        self._cond = threading.Condition()
        self._shared = 0
        self._exclusive = False

    @contextlib.contextmanager
    def shared(self):
        with self._cond:
            self._cond.wait_for(lambda: not self._exclusive)
            self._shared += 1
        try:
            yield
        finally:
            with self._cond:
                self._shared -= 1
                self._cond.notify_all()

    @contextlib.contextmanager
    def exclusive(self):
        with self._cond:
            self._cond.wait_for(lambda: not self._exclusive and not self._shared)
            self._exclusive = True
        try:
            yield
        finally:
            with self._cond:
                self._exclusive = False
                self._cond.notify_all()


_ready = _SharedLock()
#: One lock per program (function and argument key): a second caller waits for the
#: first one's compile instead of repeating it.
_key_locks: dict = {}
_key_locks_lock = threading.Lock()


_jax_cache_off = {"count": 0, "saved": None}
_jax_cache_off_lock = threading.Lock()


@contextlib.contextmanager
def _without_jax_cache():
    """JAX's persistent compilation cache neither read nor written by the compiles in
    this block (and, meanwhile, by any other thread's: that costs those speed only).

    ``jax.config.enable_compilation_cache(False)`` is not enough: JAX decides once
    per process, at its first compile, whether the cache is used, and later
    switches are not read. Once a process had compiled anything with the cache
    on, a program compiled to be kept on disk came from JAX's cache, and was kept
    without its machine code: every later process found it broken ("function ...
    not found"), compiled it again, and kept it broken again. JAX's own record of
    that decision is set aside while such compiles run; where this JAX version
    keeps it elsewhere, the config switch is all there is."""
    from jax._src import compilation_cache as jax_cache
    from jax._src import config as jax_config

    if not all(hasattr(jax_cache, a) for a in ("_cache_checked", "_cache_used",
                                               "_cache_initialized_mutex")):
        with jax_config.enable_compilation_cache(False):
            yield
        return
    with _jax_cache_off_lock:
        if _jax_cache_off["count"] == 0:
            with jax_cache._cache_initialized_mutex:
                _jax_cache_off["saved"] = (jax_cache._cache_checked, jax_cache._cache_used)
                jax_cache._cache_checked, jax_cache._cache_used = True, False
        _jax_cache_off["count"] += 1
    try:
        with jax_config.enable_compilation_cache(False):
            yield
    finally:
        with _jax_cache_off_lock:
            _jax_cache_off["count"] -= 1
            if _jax_cache_off["count"] == 0:
                with jax_cache._cache_initialized_mutex:
                    jax_cache._cache_checked, jax_cache._cache_used = _jax_cache_off["saved"]


class Event(NamedTuple):
    """One program that :func:`jit` made ready: compiled (``how`` = "compiled", its
    tracing and lowering in ``lower_s``, XLA's compilation in ``compile_s``) or
    loaded from disk ("loaded", the load and first run in ``compile_s``). A compiled
    program's ``lowering`` says where its StableHLO came from: "traced" from brdffit's
    Python, or "shipped" (read from the package's lowered programs,
    ``brdffit.exported``: ``lower_s`` is then reading and lowering that file)."""

    name: str
    how: str
    lower_s: float
    compile_s: float
    lowering: str = "traced"


#: Every program made ready in this process, in order: what a cold start spends
#: (``bench/startup.py``, ``brdffit warmup``). A few dozen entries per process.
events: list[Event] = []

#: Called with a program's name, and whether the program will be kept on disk for
#: the next process, just before :func:`jit` compiles it (not when it is loaded from
#: disk), from whichever thread compiles: a shell can say that a first use is
#: compiling (``brdffit fit``) instead of seeming to hang for seconds. Not kept: the
#: cache is off, or the program holds a plugin model (whose code the fingerprint does
#: not cover). The library says nothing (None).
on_compile: Callable[[str, bool], None] | None = None


@functools.cache
def _fingerprint() -> str:
    import jax

    h = hashlib.sha256(f"format {_FORMAT}\n".encode())
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")) + sorted(package.rglob("*.json")):
        h.update(str(path.relative_to(package)).encode())
        h.update(path.read_bytes())
    for dist in ("jax", "jaxlib", "equinox", "lineax", "optimistix"):
        try:
            h.update(f"{dist} {importlib.metadata.version(dist)}\n".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{dist} -\n".encode())
    device = jax.devices()[0]
    h.update(f"{device.platform} {device.device_kind} {device.client.platform_version}\n".encode())
    h.update(os.environ.get("XLA_FLAGS", "").encode())
    h.update(_cpu_flags().encode())
    return h.hexdigest()[:24]


def _cpu_flags() -> str:
    # XLA compiles for the host's instruction set: an executable from another CPU
    # (a shared home directory) could use instructions this one lacks.
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    return line
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine()


def _directory() -> Path | None:
    base = runtime.cache_dir()
    return None if base is None else _directory_in(base)


def programs_kept() -> tuple[bool, bool]:
    """Whether the cache keeps programs of this brdffit, and of another (what the
    command line's compile notice says): each has its directory (one per fingerprint,
    which every brdffit source file, the JAX versions, XLA_FLAGS and the CPU make).
    Every edit of brdffit's code or upgrade of JAX starts an empty one and compiles
    again (a default ggx fit: 6 programs, ~3 s of compiling); that was said as "first
    use of these options on this machine" after the same fit had run a minute before."""
    # the directory this process keeps its programs in (cached, and made where missing,
    # by the compile anyway)
    current = _directory()
    if current is None:
        return False, False

    def holds_programs(folder) -> bool:
        try:
            return any(f.suffix == ".xla" for f in folder.iterdir())
        except OSError:  # removed meanwhile (stale), or unreadable: no programs of use
            return False

    try:
        others = [d for d in current.parent.iterdir() if d != current and d.is_dir()]
    except OSError:
        others = []
    return holds_programs(current), any(map(holds_programs, others))


@functools.cache
def _directory_in(base: str) -> Path | None:
    root = Path(base) / "executables"
    path = root / _fingerprint()
    try:
        path.mkdir(parents=True, exist_ok=True)
        os.utime(path)
    except OSError as e:
        runtime.log.info("brdffit: compiled fits not kept on disk (%s)", e)
        return None
    _remove_stale(root, path)
    return path


def _remove_stale(root: Path, current: Path) -> None:
    cutoff = time.time() - KEEP_DAYS * 86400
    for d in root.iterdir():
        try:
            if d != current and d.is_dir() and d.stat().st_mtime < cutoff:
                for f in d.iterdir():
                    f.unlink()
                d.rmdir()
        except OSError:
            pass  # another process's, or in use: left for next time


def _type_is_keyed(cls) -> bool:
    """Whether a class (or function) is code the key can vouch for."""
    return (getattr(cls, "__module__", "") or "").startswith(_KEYED_MODULES)


def _treedef_is_keyed(treedef) -> bool:
    node = treedef.node_data()
    if node is not None and not _type_is_keyed(node[0]):
        return False
    return all(_treedef_is_keyed(c) for c in treedef.children())


_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")


def _static_text(value) -> str | None:
    """A process-independent text of a static leaf, or None when it has none."""
    if callable(value) and hasattr(value, "__qualname__"):
        return f"{value.__module__}.{value.__qualname__}" if _type_is_keyed(value) else None
    if not _type_is_keyed(type(value)):
        return None
    return _ADDRESS.sub("", repr(value))


class _Entry:
    """One compiled program and the structure of what it returns."""

    __slots__ = ("call", "out_def")

    def __init__(self, call, out_def):
        self.call, self.out_def = call, out_def


#: XLA options for brdffit's programs on the CPU. XLA's newer fusion emitters
#: (the default since jax 0.5 or so) take ~1.7x the CPU time to compile our
#: programs and run them no faster: measured on every built-in model, a cold
#: ``auto`` compiled 45.7 s of programs with them and 25.7 s without, and the warm
#: programs ran within this machine's noise of each other (bench/results/startup.md,
#: docs/fitting.md). An XLA that no longer knows an option compiles without it.
CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
_options_refused: set[str] = set()


@functools.cache
def _native_kernels_ready() -> None:
    """Give JAX's CPU LAPACK kernels their LAPACK routines, as lowering a linear
    algebra op does on first use. A program loaded from disk skips lowering: where it
    calls LAPACK (the QR solves of optimistix's Levenberg-Marquardt and dogleg) its
    first run crashed the process (a segmentation fault). JAX's own loader of
    exported programs does the same (``jax._src.export``)."""
    import jax
    import jax.numpy as jnp

    try:
        try:
            from jax._src.lax.linalg import initialize_lapack
        except ImportError:  # a JAX that moved it: lowering a QR initialises them too
            jax.jit(jnp.linalg.qr).lower(jnp.zeros((2, 2)))
        else:
            initialize_lapack()
    except Exception as e:  # noqa: BLE001 - a JAX that changed more: loads go on, logged
        runtime.log.warning("brdffit: JAX's LAPACK kernels not made ready (%s); a stored "
                            "program that calls LAPACK may fail", e)


def calls_lapack(payload: bytes) -> bool:
    """Whether a serialised executable calls JAX's CPU LAPACK kernels: it names
    them (``lapack_dgeqrf_ffi``, ...: a routine's name starts with its precision,
    s, d, c or z; the payload's debug information also holds the names of the
    Python functions that traced it). Only such a program needs
    :func:`_native_kernels_ready` before it runs, which imports SciPy's LAPACK
    (0.13-0.18 s of every new process that loads a fit, measured on a 2-core Xeon;
    brdffit's own lm solver calls none). A false positive costs that time, nothing else."""
    return _LAPACK_TARGET.search(payload) is not None


_LAPACK_TARGET = re.compile(rb"lapack_[sdcz][a-z]")


def _compile(lowered):
    """``lowered`` compiled with :data:`CPU_COMPILER_OPTIONS` on the CPU (without,
    where this XLA refuses one of them), as XLA's default elsewhere."""
    import jax

    options = {k: v for k, v in CPU_COMPILER_OPTIONS.items() if k not in _options_refused}
    if not options or jax.default_backend() != "cpu":
        return lowered.compile()
    try:
        return lowered.compile(compiler_options=options)
    except Exception as e:  # noqa: BLE001 - an option this XLA has dropped or renamed
        runtime.log.info("brdffit: XLA refused compiler options %s (%s); compiling "
                         "without them", options, e)
        _options_refused.update(options)
        return lowered.compile()


#: How long a process waits for another one's compile of the same program before it
#: compiles the program itself (the other may be stopped, not dead: a dead one's lock
#: is released by the kernel). The longest single compile measured is ~4 s.
COMPILE_WAIT_S = 300.0


@contextlib.contextmanager
def _compiling_elsewhere_waited(path: Path | None):
    """Held while this process compiles the program to be kept at ``path``: another
    process that wants it meanwhile waits here, then finds the file and loads it,
    instead of compiling the same program at the same time (an exclusive ``flock``
    on ``<path>.lock``; the kernel releases it when its holder dies). Where locking
    is not possible (no cache, no ``fcntl``, a file system without locks) or the
    wait runs past :data:`COMPILE_WAIT_S`, this process compiles it too."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        fcntl = None
    if path is None or fcntl is None:
        yield
        return
    try:
        fd = os.open(path.with_suffix(".lock"), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:  # a read-only cache: nothing will be stored either
        yield
        return
    try:
        deadline = time.monotonic() + COMPILE_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:  # another process compiles it now
                if time.monotonic() > deadline:
                    runtime.log.info("brdffit: waited %.0f s for another process's compile "
                                     "of %s; compiling it here", COMPILE_WAIT_S, path.name)
                    break
                time.sleep(0.05)
            except OSError:  # no locks on this file system
                break
        yield  # closing the descriptor releases the lock
    finally:
        os.close(fd)


def _example(out_def):
    """A picklable value of the structure ``out_def`` (its leaves zeros): what a
    program returns, kept beside it on disk."""
    import jax

    return jax.tree_util.tree_unflatten(out_def, [0] * out_def.num_leaves)


def _compiled_form(x):
    if type(x) is tuple:  # several models (auto's candidates measured in one pass)
        return tuple(map(_compiled_form, x))
    form = getattr(x, "compiled_form", None)
    return form() if callable(form) else x


def _compiled_forms(args: tuple, kwargs: dict) -> tuple[tuple, dict]:
    """The arguments with each one that names a compiled form (a ``compiled_form()``
    method: brdffit's models) replaced by it: models that differ only in data give
    one model of them all, and one program serves them
    (``brdffit.models.base.share_programs``)."""
    return (tuple(_compiled_form(a) for a in args),
            {k: _compiled_form(v) for k, v in kwargs.items()})


def jit(fn: Callable | None = None, *, compiled_forms: bool = True) -> Callable:
    """``fn`` compiled like ``equinox.filter_jit``, its executables kept on disk.

    Its arguments are taken in their compiled forms (:func:`_compiled_forms`: one
    program for the lobe models of one family), unless ``compiled_forms=False``
    (``@jit(compiled_forms=False)``): a program that times a model as a renderer runs
    it must have that model's own code."""
    if fn is None:
        return functools.partial(jit, compiled_forms=compiled_forms)
    import equinox as eqx
    import jax

    plain = eqx.filter_jit(fn)
    entries: dict = {}
    name = f"{fn.__module__}.{fn.__qualname__}"
    own_code = fn.__module__.startswith("brdffit.")  # the fingerprint covers its code

    def split(args, kwargs):
        if compiled_forms:
            args, kwargs = _compiled_forms(args, kwargs)
        leaves, treedef = jax.tree_util.tree_flatten((args, kwargs))
        dynamic = [i for i, x in enumerate(leaves) if eqx.is_array(x)]
        key = (treedef, tuple(
            (x.shape, x.dtype, getattr(x, "weak_type", False)) if eqx.is_array(x) else x
            for x in leaves), jax.config.jax_enable_x64)
        return leaves, treedef, dynamic, key

    def compile_entry(leaves, treedef, dynamic, to_store: bool,
                      file_name: str | None) -> _Entry:
        out_defs = []

        def flat(*arrays):
            full = list(leaves)
            for i, a in zip(dynamic, arrays):
                full[i] = a
            args, kwargs = jax.tree_util.tree_unflatten(treedef, full)
            out_leaves, out_def = jax.tree_util.tree_flatten(fn(*args, **kwargs))
            out_defs.append(out_def)
            return out_leaves

        arrays = [leaves[i] for i in dynamic]
        t0 = time.perf_counter()
        shipped = None if file_name is None else exported.lowered(file_name, arrays)
        if shipped is not None:
            lowered, example = shipped
            out_def, lowering = jax.tree_util.tree_structure(example), "shipped"
        else:
            lowered = jax.jit(flat).lower(*arrays)
            out_def, lowering = out_defs[0], "traced"
            if exported.recording is not None and file_name is not None:
                exported.record(file_name, flat, arrays, _example(out_def))
        t1 = time.perf_counter()
        # An executable that JAX's own cache loaded serialises without its machine
        # code (its fused kernels are then "not found" when run): the one kept on
        # disk is compiled afresh, once per fingerprint.
        with _without_jax_cache() if to_store else contextlib.nullcontext():
            compiled = _compile(lowered)
        events.append(Event(name, "compiled", t1 - t0, time.perf_counter() - t1, lowering))
        return _Entry(compiled, out_def)

    def program_name(leaves, treedef) -> str | None:
        """The program's file name (no suffix), the same on every machine: its
        function and digest of its key; None where the key cannot vouch for its code."""
        if not own_code or not _treedef_is_keyed(treedef):
            return None
        parts = [name, _ADDRESS.sub("", str(treedef)), str(jax.config.jax_enable_x64)]
        for x in leaves:
            if eqx.is_array(x):
                parts.append(f"{x.dtype}{list(x.shape)}{'w' if getattr(x, 'weak_type', 0) else ''}")
            else:
                text = _static_text(x)
                if text is None:
                    return None
                parts.append(text)
        digest = hashlib.sha256("\n".join(parts).encode()).hexdigest()[:32]
        return f"{fn.__name__}-{digest}"

    def disk_path(file_name: str | None) -> Path | None:
        directory = _directory()
        return None if directory is None or file_name is None else directory / f"{file_name}.xla"

    def load(path: Path) -> _Entry | None:
        from jax.experimental import serialize_executable

        t0 = time.perf_counter()
        try:
            with open(path, "rb") as f:
                payload, in_tree, out_tree, out_example = pickle.load(f)
            if calls_lapack(payload):
                _native_kernels_ready()
            call = serialize_executable.deserialize_and_load(payload, in_tree, out_tree)
            runtime.log.debug("brdffit: loaded compiled %s in %.3f s", name,
                              time.perf_counter() - t0)
            return _Entry(call, jax.tree_util.tree_structure(out_example))
        except Exception as e:  # noqa: BLE001 - damaged, truncated or from an older jax
            runtime.log.info("brdffit: compiled %s not loaded from %s (%s)", name, path, e)
            return None

    def store(path: Path, entry: _Entry) -> None:
        from jax.experimental import serialize_executable

        try:
            payload, in_tree, out_tree = serialize_executable.serialize(entry.call)
            example = _example(entry.out_def)
            tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
            with open(tmp, "wb") as f:
                pickle.dump((payload, in_tree, out_tree, example), f,
                            protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except Exception as e:  # noqa: BLE001 - not serialisable, or no space: speed only
            runtime.log.info("brdffit: compiled %s not kept (%s)", name, e)

    def loaded_and_run(path: Path, arrays):
        """The executable kept at ``path`` and its outputs on ``arrays``, or None when
        it is missing, does not load or does not run (its file is then removed)."""
        t0 = time.perf_counter()
        if not path.exists():
            return None
        entry = load(path)
        if entry is None:  # damaged (written whole, then spoilt): read once, not again
            with contextlib.suppress(OSError):  # a read-only cache: compiled in memory
                path.unlink(missing_ok=True)
            return None
        try:
            out = jax.block_until_ready(entry.call(*arrays))
            events.append(Event(name, "loaded", 0.0, time.perf_counter() - t0))
            return entry, out
        except Exception as e:  # noqa: BLE001 - a file that loads but cannot run
            runtime.log.info("brdffit: compiled %s in %s does not run (%s); compiling again",
                             name, path, e)
            with contextlib.suppress(OSError):
                path.unlink(missing_ok=True)
            return None

    def make_ready(leaves, treedef, dynamic, key, arrays, run: bool):
        """(entry, its outputs on ``arrays`` or None): the program compiled, or loaded
        from disk (and run once, to check it), and kept; compiled, it is run only
        when ``run`` says so."""
        # Programs compile side by side (auto's candidates, a fit's report made
        # ready while its solve compiles: XLA compiles outside the GIL), but a
        # program read from disk is loaded and first run alone: when threads
        # loaded and ran deserialised executables while others compiled or
        # loaded, one crashed in its first run (a segmentation fault in
        # block_until_ready, once in a test run).
        with _key_locks_lock:
            key_lock = _key_locks.setdefault((name, key), threading.Lock())
        with key_lock:  # one thread makes a program ready; the others wait for it
            entry = entries.get(key)
            if entry is not None:
                return entry, None
            file_name = program_name(leaves, treedef)
            path = disk_path(file_name)
            found = loaded(path, key, arrays)
            if found is not None:
                return found
            # one process compiles a program, the others wait for its file and load
            # it: a batch's Dask workers, a service's worker processes, the tests'
            # servers and CLIs all start at once on the same empty cache
            with _compiling_elsewhere_waited(path):
                found = loaded(path, key, arrays)
                if found is not None:
                    return found
                if on_compile is not None:
                    on_compile(name, path is not None)
                with _ready.shared():
                    entry = compile_entry(leaves, treedef, dynamic, path is not None,
                                          file_name)
                    out = jax.block_until_ready(entry.call(*arrays)) if run else None
                if path is not None:
                    store(path, entry)
            entries[key] = entry
            return entry, out

    def loaded(path: Path | None, key, arrays):
        """(entry, its outputs) from the file at ``path``, kept in ``entries``; None
        where there is no usable file."""
        if path is None or not path.exists():
            return None
        with _ready.exclusive():
            found = loaded_and_run(path, arrays)
        if found is not None:  # already run once, to check it
            entries[key] = found[0]
        return found

    def ready(*args, **kwargs) -> None:
        """Make the program for these arguments ready, as a call would, without
        running it where it is compiled: a caller that knows the shapes of a later
        call compiles it beside other work (a fit's solve, beside its scoring)."""
        leaves, treedef, dynamic, key = split(args, kwargs)
        try:
            if entries.get(key) is not None:
                return
        except TypeError:  # an unhashable static argument: nothing to keep
            return
        make_ready(leaves, treedef, dynamic, key, [leaves[i] for i in dynamic], run=False)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        leaves, treedef, dynamic, key = split(args, kwargs)
        arrays = [leaves[i] for i in dynamic]
        if any(isinstance(a, jax.core.Tracer) for a in arrays):
            return plain(*args, **kwargs)  # called inside another traced function
        try:
            entry = entries.get(key)
        except TypeError:  # an unhashable static argument: no caching of ours
            return plain(*args, **kwargs)
        out = None
        if entry is None:
            entry, out = make_ready(leaves, treedef, dynamic, key, arrays, run=True)
        if out is None:
            out = entry.call(*arrays)
        return jax.tree_util.tree_unflatten(entry.out_def, out)

    call.ready = ready
    call.compiled_forms = compiled_forms
    return call
