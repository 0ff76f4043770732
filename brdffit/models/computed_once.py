"""Subexpressions that XLA must compute once: :func:`computed_once`.

XLA's fusion copies an elementwise expression it takes for cheap into every fused
loop that reads it, and computes it again there, element by element. For most of a
model that is what makes it fast; for a costly piece read in many places it is not: the
thin film's cosines (``gltf_iridescence``) were computed dozens of times a sample, once
per base under the film, per order of its spectrum and per parameter's pass of the
solver's Jacobian, and a conductor's Fresnel (``rough_conductor``, MaterialX's metal in
``standard_surface``) once per tangent. ``jax.lax.optimization_barrier`` does not stop
it (XLA's CPU pipeline removes barriers before it fuses); a conditional does: its
results are stored, and whatever reads them reads memory.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def computed_once(fn, operands, data):
    """``fn(operands)``, each element computed once and stored (module docstring).

    The conditional's two branches are both ``fn``. Its predicate reads ``data``, an
    array of the frame (the same for every start of a fit, and never constant in a
    compiled fit), so that where the starts are vectorised (``jax.vmap``: start
    scoring) it stays a conditional; a predicate that varied per start would run both
    branches, and a constant one is folded away, the branch inlined (the same values,
    fused as before). A NaN in ``data`` takes the other branch: the same ``fn``."""
    return jax.lax.cond(jnp.all(data == data), fn, fn, operands)
