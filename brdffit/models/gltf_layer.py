"""What glTF's layered models share (``gltf_clearcoat``, ``gltf_sheen``,
``gltf_iridescence`` and their three.js and Blender twins, ``gltf_threejs_*``,
``gltf_blender_*``): a layer over the core material (``gltf_pbr``, or the viewer's
``gltf_threejs``, ``gltf_blender``: ``base_model``), whose parameters follow the base's.

A fit of one starts from the ``gltf_pbr`` fit with the layer off (``parent``,
``embed_parent``), beside starts that put each of the layer's start values
(``layer_starts``) over every broad base of ``gltf_pbr``'s starts (roughness 0.2 and
up: a coat sharper than its base, or a fabric's body), the base's unconstrained values
first, then the layer's, in the model's parameter order.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel
from .frame import Frame
from .gltf_blender import GltfBlender
from .gltf_pbr import GltfPBR
from .gltf_threejs import GltfThreejs

#: The base's least roughness among a layered model's starts.
BROAD_BASE = 0.2

BASE = GltfPBR()
#: The same base as three.js shades it: under a layer's three.js twin
#: (``gltf_threejs_clearcoat``, ``gltf_threejs_sheen``).
THREEJS_BASE = GltfThreejs()
#: ... and as Blender's Cycles shades it (under ``gltf_blender_clearcoat``).
BLENDER_BASE = GltfBlender()


class GltfLayer(AbstractBRDFModel):
    parent: ClassVar[str] = "gltf_pbr"
    #: The model that shades the base under the layer (``parent``'s).
    base_model: ClassVar[AbstractBRDFModel] = BASE
    #: The layer's parameter values a fit starts from, one dict per start.
    layer_starts: ClassVar[tuple[dict[str, float], ...]] = ()

    @property
    def shape_grid(self) -> tuple[dict[str, float], ...]:
        return tuple({**shape, **layer} for shape in BASE.shape_grid
                     if shape["roughness"] >= BROAD_BASE for layer in self.layer_starts)

    def eval_frame(self, params, frame: Frame):
        return jnp.moveaxis(self.eval_channels(params, frame), 0, -1)

    def start_candidates(self, table, usable: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """``gltf_pbr``'s starts on every broad base, each with each of
        ``layer_starts``."""
        base_starts = BASE.start_candidates(table, usable, kd)
        broad = [u for shape, u in zip(BASE.shape_grid, base_starts, strict=True)
                 if shape["roughness"] >= BROAD_BASE]
        specs = self.param_specs[len(BASE.param_specs):]
        layers = [np.concatenate([s.unconstrain(np.broadcast_to(start[s.name], (s.size,)))
                                  for s in specs]) for start in self.layer_starts]
        return np.stack([np.concatenate([u, layer]) for u in broad for layer in layers])
