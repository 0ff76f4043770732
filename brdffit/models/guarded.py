"""Guarded elementwise maths for the BRDF models.

Every division, square root, logarithm and power that can meet a zero or an
infinity on the closed hemisphere goes through one of these. They use the
"double where" pattern: the unsafe branch is evaluated on a substituted safe
input, so that neither the value nor the gradient of the *unselected* branch can
produce a NaN (``jnp.where`` alone still back-propagates NaNs from the branch it
discards).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

#: Smallest denominator / radicand we let through. Far below anything a MERL bin
#: centre produces (cos >= ~1e-4) but large enough that 1/TINY is finite in float32.
TINY = 1e-30


def safe_sqrt(x: Float[Array, ...]) -> Float[Array, ...]:
    """sqrt(max(x, 0)) with a zero (not infinite) gradient at x <= 0."""
    positive = x > TINY
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def safe_div(num: Float[Array, ...], den: Float[Array, ...], floor: float = TINY):
    """num / den with |den| floored at ``floor`` (sign kept, den >= 0 in our uses)."""
    ok = den > floor
    return num / jnp.where(ok, den, floor)


def safe_pow(base: Float[Array, ...], exponent) -> Float[Array, ...]:
    """max(base, 0) ** exponent for exponent > 0, with finite gradients in both.

    ``0 ** n`` is 0 and its derivative in ``n`` (``x**n log x``) is taken as 0,
    the limit, instead of ``0 * -inf``.
    """
    positive = base > TINY
    log_base = jnp.log(jnp.where(positive, base, 1.0))
    return jnp.where(positive, jnp.exp(exponent * log_base), 0.0)


def safe_normalize(v: Float[Array, "... 3"], xp=jnp) -> Float[Array, "... 3"]:
    """v / |v|; the zero vector (wi = -wo, both grazing) maps to the normal +z.
    ``xp``: ``jax.numpy``, or ``numpy`` for arrays made once, without compiling."""
    sq = xp.sum(v * v, axis=-1, keepdims=True)
    ok = sq > TINY
    unit = v / xp.sqrt(xp.where(ok, sq, 1.0))
    # unit's dtype, not v's: numpy float64 directions under JAX's float32 are float32
    # here, and asking JAX for float64 there warns from this line
    return xp.where(ok, unit, xp.array([0.0, 0.0, 1.0], dtype=unit.dtype))


def sin_from_cos(c: Float[Array, ...]) -> Float[Array, ...]:
    """sin(theta) from cos(theta) for theta in [0, pi/2]: finite gradient at c = 1."""
    return safe_sqrt(1.0 - c * c)
