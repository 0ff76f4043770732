"""Arrays every process computes the same way (the MERL grid's directions and weights,
the sphere integrals' quadrature), kept in brdffit's cache directory as ``.npz``.

A new process's first fit computed them again: the grid ~0.3 s, the two sphere
integrals behind every fit's look ~1.1 s of a ~2 s first fit with warm compiled
programs. Read from the file, each takes milliseconds. A file is written beside the
work that asked for it, from a thread the interpreter waits for at exit, through a
temporary name, so that a reader never sees half of one; a damaged file or one of
another layout is computed again and replaced. Without a cache directory
(``BRDFFIT_CACHE_DIR`` empty) nothing is kept. The name carries a version its caller
bumps when the computation changes.
"""

from __future__ import annotations

import os
import threading
import zipfile
from collections.abc import Callable

import numpy as np

from brdffit import runtime

_writers: list[threading.Thread] = []


def load_or_compute(name: str, keys: tuple[str, ...],
                    compute: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays ``keys`` kept as ``<cache>/<name>.npz``, else ``compute()``'s (and
    kept for the next process); read-only either way, one copy shared by the process."""
    directory = runtime.cache_dir()
    path = os.path.join(directory, f"{name}.npz") if directory else None
    if path and os.path.exists(path):
        try:
            with np.load(path) as z:
                if set(z.files) == set(keys):
                    return _frozen({k: z[k] for k in keys})
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            pass  # damaged: computed again below, and replaced
    arrays = _frozen(compute())
    if path:
        # not a daemon: the interpreter finishes the file before it exits
        writer = threading.Thread(target=_store, args=(arrays, directory, path, name),
                                  name=f"brdffit-store-{name}")
        writer.start()
        _writers.append(writer)
    return arrays


def _frozen(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    for a in arrays.values():
        a.setflags(write=False)
    return arrays


def wait_until_stored() -> None:
    """Wait for every file :func:`load_or_compute` is writing."""
    while _writers:
        _writers.pop().join()


def _store(arrays: dict, directory: str, path: str, name: str) -> None:
    try:
        tmp = f"{path}.{os.getpid()}.{threading.get_ident()}.tmp.npz"
        os.makedirs(directory, exist_ok=True)
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
        runtime.log.info("brdffit: cached %s in %s", name, path)
    except OSError as e:
        runtime.log.info("brdffit: %s not cached (%s)", name, e)  # costs speed only
