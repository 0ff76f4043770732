"""Shading-frame quantities shared by every model (docs/models.md, "Directions").

Local frame with the normal on +z; ``wi`` and ``wo`` point away from the surface.
Directions below the horizon are clamped to it: the models are defined for
cos_i, cos_o >= 0 only, and a fit never feeds them anything else.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float

from .guarded import safe_normalize


class Frame(NamedTuple):
    """What the models need of a (wi, wo) pair, shaped like the batch.

    Only scalars: a fit precomputes the frame of every bin once (it depends on
    the geometry alone) and the models never touch the direction vectors.
    """

    cos_i: Float[Array, ...]
    cos_o: Float[Array, ...]
    cos_h: Float[Array, ...]
    cos_d: Float[Array, ...]
    #: sin^2 from the tangent-plane components, not 1 - cos^2: exact near the
    #: normal, where a sharp lobe lives and 1 - cos^2 cancels (badly in float32).
    sin2_i: Float[Array, ...]
    sin2_o: Float[Array, ...]
    sin2_h: Float[Array, ...]
    #: wi_xy . wo_xy = sin_i sin_o cos(phi_i - phi_o)
    dot_xy: Float[Array, ...]


def shading_frame(wi: Float[Array, "... 3"], wo: Float[Array, "... 3"], xp=jnp) -> Frame:
    """The frame of each (wi, wo) pair; ``xp``: ``jax.numpy``, or ``numpy`` for the
    frames of the bin grid, made once per process without a compiled program."""
    h = safe_normalize(wi + wo, xp)
    cos_i = xp.clip(wi[..., 2], 0.0, 1.0)
    cos_o = xp.clip(wo[..., 2], 0.0, 1.0)
    cos_h = xp.clip(h[..., 2], 0.0, 1.0)
    cos_d = xp.clip(xp.sum(wi * h, axis=-1), 0.0, 1.0)
    sin2_i = xp.clip(wi[..., 0] ** 2 + wi[..., 1] ** 2, 0.0, 1.0)
    sin2_o = xp.clip(wo[..., 0] ** 2 + wo[..., 1] ** 2, 0.0, 1.0)
    sin2_h = xp.clip(h[..., 0] ** 2 + h[..., 1] ** 2, 0.0, 1.0)
    dot_xy = wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]
    return Frame(cos_i, cos_o, cos_h, cos_d, sin2_i, sin2_o, sin2_h, dot_xy)
