"""The model objects by name: the built-in models, then those other packages add.

A new built-in model is one module plus one line in ``BUILTIN`` (and the
catalogue snapshot rewritten, see :mod:`brdffit.models.catalogue`); a model
from another package is declared under the ``brdffit.models`` entry-point group
or passed to :func:`register` (docs/adding-a-model.md).
"""

from __future__ import annotations

from brdffit.models import catalogue
from brdffit.models.base import AbstractBRDFModel, share_programs
from brdffit.models.beckmann import Beckmann
from brdffit.models.blinn_phong import BlinnPhong
from brdffit.models.catalogue import MONO_SUFFIX, UnknownModelError, check_name
from brdffit.models.generalized_schlick import GeneralizedSchlick
from brdffit.models.ggx import GGX
from brdffit.models.ggx2 import GGX2
from brdffit.models.ggx3 import GGX3
from brdffit.models.ggx4 import GGX4
from brdffit.models.gltf_blender import GltfBlender
from brdffit.models.gltf_clearcoat import (
    GltfBlenderClearcoat,
    GltfClearcoat,
    GltfThreejsClearcoat,
)
from brdffit.models.gltf_iridescence import GltfIridescence, GltfThreejsIridescence
from brdffit.models.gltf_pbr import GltfPBR
from brdffit.models.gltf_sheen import GltfBlenderSheen, GltfSheen, GltfThreejsSheen
from brdffit.models.gltf_threejs import GltfThreejs
from brdffit.models.lambert import Lambert
from brdffit.models.mono_ks import MonoKs, specular_colour_specs
from brdffit.models.oren_nayar import OrenNayar
from brdffit.models.phong import Phong
from brdffit.models.principled import Principled
from brdffit.models.rough_conductor import RoughConductor
from brdffit.models.rough_plastic import RoughPlastic
from brdffit.models.standard_surface import StandardSurface
from brdffit.models.standard_surface_coat import StandardSurfaceCoat
from brdffit.models.standard_surface_sheen import StandardSurfaceSheen

#: The built-in models, cheapest to richest (``auto`` tries them in this order).
BUILTIN: tuple[AbstractBRDFModel, ...] = (
    Lambert(), OrenNayar(), BlinnPhong(), Phong(),
    Beckmann(), Beckmann(fresnel="dielectric"), GGX(), GGX(fresnel="dielectric"),
    # renderer targets: a fit of these is the renderer's material (brdffit.export)
    GltfPBR(), GltfPBR(ior=True), GltfPBR(dielectric=True), GltfThreejs(), GltfBlender(),
    # layered: a coat, a sheen or a thin film over the glTF base (KHR_materials_clearcoat,
    # _sheen, _iridescence)
    GltfClearcoat(), GltfSheen(), GltfIridescence(),
    # a coat, a sheen or a film file as three.js shades it (fidelity.viewers["threejs"])
    GltfThreejsClearcoat(), GltfThreejsSheen(), GltfThreejsIridescence(),
    # a coat or a sheen file as Blender shades it (fidelity.viewers["blender"])
    GltfBlenderClearcoat(), GltfBlenderSheen(),
    RoughConductor(),
    RoughPlastic(), Principled(), StandardSurface(), StandardSurface(dielectric=True),
    Principled(clearcoat=True),
    # MaterialX's standard_surface with its coat, with its sheen
    StandardSurfaceCoat(), StandardSurfaceSheen(),
    # MaterialX's generalized Schlick lobe over a diffuse: a highlight whose colour turns
    GeneralizedSchlick(),
    GGX2(),
    # a third and a fourth lobe (each contains the one before): metals and metallic
    # paints under the log loss
    GGX3(), GGX4(),
)

REGISTRY: dict[str, AbstractBRDFModel] = {m.name: m for m in BUILTIN}

# Lobe models of the same parameters: one compiled program per family serves each
# (brdffit.models.base.share_programs).
share_programs(BlinnPhong, Phong)
share_programs(Beckmann, GGX)


def register(model: AbstractBRDFModel) -> AbstractBRDFModel:
    """Add ``model`` under ``model.name``, after the built-ins; the CLI, the service
    and ``auto`` of this process then know it. A built-in name cannot be replaced."""
    if not isinstance(model, AbstractBRDFModel):
        raise TypeError(f"{model!r} is not an AbstractBRDFModel")
    if model.name in {m.name for m in BUILTIN} and REGISTRY[model.name] is not model:
        raise ValueError(f"{model.name!r} is a built-in model")
    REGISTRY[model.name] = model
    if model.name not in {m.name for m in BUILTIN}:
        catalogue.add(model)  # brdffit models, the service's model list, the checks
    return model


for _plugin in catalogue.load_plugins():  # other packages' models (entry points)
    register(_plugin)


def get(name: str | AbstractBRDFModel) -> AbstractBRDFModel:
    """The model called ``name`` (a model instance is returned as is)."""
    if isinstance(name, AbstractBRDFModel):
        return name
    if name in REGISTRY:
        return REGISTRY[name]
    if isinstance(name, str) and name.endswith(MONO_SUFFIX):
        base = REGISTRY.get(name.removesuffix(MONO_SUFFIX))
        if base is not None and specular_colour_specs(base):
            return MonoKs(base)
    check_name(str(name))  # raises with the choices
    raise UnknownModelError(f"unknown model {name!r}")  # catalogue and registry disagree
