"""Process-wide JAX settings, applied once, before brdffit's first JAX code runs.

:func:`configure` is called at the top of the modules that compute with JAX
(``brdffit.models``, which ``fitting``, ``loss``, ``initialisation``, ``selection``,
``render`` and ``plots`` import first), not by ``import brdffit``: a process that
only reads tables or talks to the service (``brdffit.client``) never imports JAX.

- float64 on: a MERL table spans ~6 decades and a near-mirror lobe's parameters
  are resolved only in double precision (float32 is opt-in per fit, where the
  stability suite shows it is safe).
- a persistent compilation cache, so a second process reuses the compiled fits
  of the first (``BRDFFIT_JAX_CACHE`` to move it, empty to switch it off).
"""

from __future__ import annotations

import os

_configured = False


def cache_dir() -> str | None:
    """brdffit's on-disk cache (JAX's compiled code, the bin grid), or None if off."""
    path = os.environ.get(
        "BRDFFIT_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "brdffit", "jax")
    )
    return path or None


def configure() -> None:
    global _configured
    if _configured:
        return
    _configured = True
    import jax

    jax.config.update("jax_enable_x64", True)
    cache = cache_dir()
    if cache:
        try:
            os.makedirs(cache, exist_ok=True)
            jax.config.update("jax_compilation_cache_dir", cache)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        except OSError:
            pass  # read-only home: run without the cache rather than fail
