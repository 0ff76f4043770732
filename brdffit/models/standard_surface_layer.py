"""What MaterialX's layered standard_surface models share (``standard_surface_coat``,
``standard_surface_sheen``): a layer of the node over (or within) the rest of it, whose
parameters follow the node's own.

A fit of one starts from the ``standard_surface`` fit with the layer off (``parent``,
``embed_parent``), beside starts that put each of the layer's start values
(``layer_starts``) over every broad base of ``standard_surface``'s starts
(specular_roughness 0.2 and up), the base's unconstrained values first, then the
layer's, in the model's parameter order.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from .base import ParamSpec
from .standard_surface import StandardSurface

#: The base's least specular_roughness among a layered model's starts.
BROAD_BASE = 0.2

BASE = StandardSurface()


class StandardSurfaceLayer(StandardSurface):
    """A layer of the ``standard_surface`` node over the full node (metalness fitted:
    the ``dielectric`` field stays False) (module docstring)."""

    #: The layer's parameters, after the node's own.
    layer_specs: ClassVar[tuple[ParamSpec, ...]] = ()
    #: The layer's parameter values a fit starts from, one dict per start.
    layer_starts: ClassVar[tuple[dict[str, float], ...]] = ()

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        return (*BASE.param_specs, *self.layer_specs)

    @property
    def parent(self) -> str | None:
        return "standard_surface"

    @property
    def shape_grid(self) -> tuple[dict[str, float], ...]:
        return tuple({**shape, **layer} for shape in BASE.shape_grid
                     if shape["specular_roughness"] >= BROAD_BASE
                     for layer in self.layer_starts)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """``standard_surface``'s starts on every broad base, each with each of
        ``layer_starts``."""
        base_starts = BASE.start_candidates(table, usable, kd)
        broad = [u for shape, u in zip(BASE.shape_grid, base_starts, strict=True)
                 if shape["specular_roughness"] >= BROAD_BASE]
        layers = [np.concatenate([s.unconstrain(np.broadcast_to(start[s.name], (s.size,)))
                                  for s in self.layer_specs]) for start in self.layer_starts]
        return np.stack([np.concatenate([u, layer]) for u in broad for layer in layers])
