"""Shared fixtures. float64 is on for every test (brdffit's JAX modules switch it on)."""

from __future__ import annotations

import os

# Tests keep JAX's persistent compile cache inside the checkout unless told otherwise.
os.environ.setdefault(
    "BRDFFIT_JAX_CACHE", os.path.join(os.path.dirname(__file__), "..", ".venv", "jax-cache")
)

import jax  # noqa: E402

import brdffit.fitting  # noqa: E402,F401

assert jax.config.jax_enable_x64, "brdffit.fitting must switch float64 on at import"
