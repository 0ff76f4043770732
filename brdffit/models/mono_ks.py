"""A model's variant with a grey (monochrome) specular scale: ``MonoKs(GGX())``.

Every RGB parameter that colours a specular lobe alone (``ks``; each lobe's scale of
ggx2, ggx3 and ggx4; MaterialX's ``specular_color``) becomes one value shared by R, G and B;
the rest of the model is unchanged. Its name is the base's plus ``_mono``
(``"ggx_mono"``), which ``brdffit.models.get`` resolves.

| name        | range    | meaning                                   |
|-------------|----------|-------------------------------------------|
| ks (ks1...) | [0, inf) | specular scale, one value for R, G and B  |
| others      |          | as in the base model                      |

Why: a dielectric's highlight has the light's colour, so its ``ks`` is grey and
two of the three values a renderer stores and interpolates are redundant
(``brdffit.selection`` reports when a fitted ``ks`` is grey within a tolerance).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .base import AbstractBRDFModel, ParamSpec

SUFFIX = "_mono"


#: The RGB parameters that are a specular lobe's colour and nothing else, beside the
#: scales a model declares of its lobes (``lobe_scales``: ggx2's ``ks1``, ``ks2``, ...):
#: a lobe's ``ks`` (rough_plastic's too, which declares none) and MaterialX's
#: ``specular_color``. A base colour (glTF, principled, standard_surface) is the
#: diffuse's colour too, a sheen's its own layer's, a conductor's ``eta`` and ``k`` its
#: optics: "every RGB parameter but kd" made gltf_pbr_mono a grey material and called
#: gltf_sheen's "ks" not grey.
SPECULAR_COLOURS = ("ks", "specular_color")


def specular_colour_specs(model: AbstractBRDFModel) -> tuple[ParamSpec, ...]:
    """The RGB parameters of ``model`` that colour a specular lobe alone
    (:data:`SPECULAR_COLOURS` and its ``lobe_scales``: a list of names written here
    left ggx3's third and ggx4's fourth lobe coloured in their _mono variants)."""
    names = {*SPECULAR_COLOURS, *model.lobe_scales}
    return tuple(s for s in model.param_specs if s.rgb and s.name in names)


class MonoKs(AbstractBRDFModel):
    base: AbstractBRDFModel

    def __check_init__(self):
        if not specular_colour_specs(self.base):
            raise ValueError(f"{self.base.name} has no specular colour to make grey")

    @property
    def name(self) -> str:
        return self.base.name + SUFFIX

    @property
    def param_specs(self) -> tuple[ParamSpec, ...]:
        grey = {s.name for s in specular_colour_specs(self.base)}
        return tuple(
            dataclasses.replace(s, rgb=False, doc=s.doc.replace("(RGB)", "(grey)"))
            if s.name in grey else s
            for s in self.base.param_specs
        )

    @property
    def physical_specs(self) -> tuple[ParamSpec, ...]:
        grey = {s.name for s in specular_colour_specs(self.base)}
        return tuple(dataclasses.replace(s, rgb=False, doc=s.doc.replace("(RGB)", "(grey)"))
                     if s.name in grey else s for s in self.base.physical_specs)

    @property
    def shape_grid(self):
        return self.base.shape_grid

    def compiled_form(self) -> MonoKs:
        return dataclasses.replace(self, base=self.base.compiled_form())

    def expand(self, params: dict) -> dict:
        """Params of the base model: each grey scale repeated over R, G, B."""
        out = dict(params)
        for s in specular_colour_specs(self.base):
            out[s.name] = jnp.broadcast_to(jnp.asarray(params[s.name]), (3,))
        return out

    def eval_frame(self, params, frame):
        return self.base.eval_frame(self.expand(params), frame)

    def eval_channels(self, params, frame):
        return self.base.eval_channels(self.expand(params), frame)

    def grey_starts(self, base_starts: np.ndarray) -> np.ndarray:
        """The base model's starts (unconstrained, one per row) with each specular
        scale averaged over R, G, B (``brdffit.fitting.starts`` makes the base's)."""
        grey = [s.name for s in specular_colour_specs(self.base)]
        starts = []
        for u in base_starts:
            p = {k: np.asarray(v) for k, v in self.base.constrain(jnp.asarray(u)).items()}
            starts.append(self.unconstrain({**p, **{k: p[k].mean() for k in grey}}))
        return np.stack(starts)
