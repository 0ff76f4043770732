"""glTF 2.0 export: a material of the core metallic-roughness model, in a glTF document.

Target model ``gltf_pbr`` (docs/models.md), the BRDF of the glTF 2.0 spec's
Appendix B, so the mapping is a copy:

    pbrMetallicRoughness.baseColorFactor = [base_color R, G, B, 1]
    pbrMetallicRoughness.metallicFactor  = metallic
    pbrMetallicRoughness.roughnessFactor = roughness          (the spec's alpha = roughness^2)

The model's dielectric reflectance is the spec's default (ior 1.5, f0 = 0.04,
specular colour white), so ``KHR_materials_ior`` and ``KHR_materials_specular``
would only restate their defaults and are not written. The document holds the
material alone (``asset`` + ``materials``): a valid glTF file that a tool can merge
into a scene, or that the Khronos validator checks as it is.
"""

from __future__ import annotations

TARGET_MODEL = "gltf_pbr"
MEDIA_TYPE = "model/gltf+json"


def material(params: dict, name: str) -> dict:
    """The glTF material object of ``gltf_pbr`` parameters."""
    return {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [*(float(x) for x in params["base_color"]), 1.0],
            "metallicFactor": float(params["metallic"]),
            "roughnessFactor": float(params["roughness"]),
        },
    }


def document(params: dict, name: str) -> dict:
    """A glTF 2.0 JSON document holding the one material."""
    return {
        "asset": {"version": "2.0", "generator": "brdffit"},
        "materials": [material(params, name)],
    }
