"""How brdffit runs JAX, without changing the caller's JAX.

- **float64, scoped.** A MERL table spans ~6 decades and a near-mirror lobe's
  parameters are resolved only in double precision, so brdffit's own entry
  points (``fit``, ``select``, the renders, the plots, the synthetic tables) run
  their JAX work inside :func:`float64`: ``jax.enable_x64`` for that call only.
  Importing brdffit, or fitting with it, leaves ``jax_enable_x64`` as the caller
  set it. Evaluating a model directly (``model(params, wi, wo)``) computes in the
  caller's precision; wrap it in ``with brdffit.runtime.float64():`` for double.
- **One cache directory**, created on first use, never on import:
  ``$BRDFFIT_CACHE_DIR`` or ``$XDG_CACHE_HOME/brdffit`` (``~/.cache/brdffit``); an
  empty ``BRDFFIT_CACHE_DIR`` switches caching off. It holds the MERL bin grid
  (``merl-grid-v2.npz``, ~140 MB, ~20x faster than recomputing it in a new
  process), under ``executables/`` the compiled fits themselves
  (``brdffit.executables``: a second process runs them without tracing), and under
  ``jax/`` JAX's persistent compilation cache, for everything else. The compilation cache is only
  switched on where the caller has not chosen one of their own. Both are logged
  (logger ``brdffit``, level INFO) when first used.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
from collections.abc import Callable, Iterator
from typing import TypeVar

log = logging.getLogger("brdffit")
F = TypeVar("F", bound=Callable)

_compilation_cache_checked = False


def cache_dir() -> str | None:
    """brdffit's cache directory (not created here), or None when switched off."""
    path = os.environ.get("BRDFFIT_CACHE_DIR")
    if path is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        path = os.path.join(base, "brdffit")
    return path or None


def use_compilation_cache() -> None:
    """Point JAX's persistent compilation cache at ``cache_dir()/jax``, once per
    process, unless caching is off or the caller already set a cache directory."""
    global _compilation_cache_checked
    if _compilation_cache_checked:
        return
    _compilation_cache_checked = True
    import jax

    directory = cache_dir()
    if directory is None or jax.config.jax_compilation_cache_dir:
        return
    path = os.path.join(directory, "jax")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as e:  # a read-only home costs compile time, not a failure
        log.info("brdffit: no compilation cache (%s)", e)
        return
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    log.info("brdffit: JAX compilation cache in %s", path)


@contextlib.contextmanager
def float64() -> Iterator[None]:
    """JAX in double precision for the enclosed code (this thread only)."""
    import jax

    use_compilation_cache()
    with jax.enable_x64(True):
        yield


def in_float64(fn: F) -> F:
    """``fn`` run inside :func:`float64`: the decorator of brdffit's JAX entry points."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with float64():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity: a container's or a batch
    scheduler's share, not the machine's count)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1
