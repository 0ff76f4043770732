"""glTF 2.0 export: a material of the core metallic-roughness model, in a glTF document.

Target model ``gltf_pbr`` (docs/models.md), the BRDF of the glTF 2.0 spec's
Appendix B, so the mapping is a copy:

    pbrMetallicRoughness.baseColorFactor = [base_color R, G, B, 1]
    pbrMetallicRoughness.metallicFactor  = metallic
    pbrMetallicRoughness.roughnessFactor = roughness          (the spec's alpha = roughness^2)

A ``gltf_pbr_ior`` fit also writes the extension ``KHR_materials_ior``
(``{"ior": ior}``, listed in ``extensionsUsed``), which carries the dielectric's
reflectance ``((ior - 1)/(ior + 1))^2``; a ``gltf_pbr`` fit is the spec's default
(ior 1.5, f0 = 0.04, white specular), which ``KHR_materials_ior`` and
``KHR_materials_specular`` would only restate, so neither is written. Other fits are
converted to the core ``gltf_pbr`` (every viewer shades it), their loss reported.

The document holds the material alone (``asset`` + ``materials``): a valid glTF file
that a tool can merge into a scene, or that the Khronos validator checks as it is.
"""

from __future__ import annotations

#: The models this target shades exactly; other fits are refitted as the first.
TARGET_MODELS = ("gltf_pbr", "gltf_pbr_ior")
#: target model -> the model that evaluates the file as the spec defines it (the same:
#: gltf_pbr is the spec's definition, tests/test_target_models.py)
SHADED_AS = {m: m for m in TARGET_MODELS}
MEDIA_TYPE = "model/gltf+json"
IOR_EXTENSION = "KHR_materials_ior"
IOR_NOTE = ("uses KHR_materials_ior: a viewer without the extension shades the dielectric "
            "with ior 1.5 (f0 0.04) instead")


def material(params: dict, name: str) -> dict:
    """The glTF material object of ``gltf_pbr`` (or ``gltf_pbr_ior``) parameters."""
    out = {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [*(float(x) for x in params["base_color"]), 1.0],
            "metallicFactor": float(params["metallic"]),
            "roughnessFactor": float(params["roughness"]),
        },
    }
    if "ior" in params:
        out["extensions"] = {IOR_EXTENSION: {"ior": float(params["ior"])}}
    return out


def document(params: dict, name: str) -> dict:
    """A glTF 2.0 JSON document holding the one material."""
    doc = {"asset": {"version": "2.0", "generator": "brdffit"}}
    if "ior" in params:
        doc["extensionsUsed"] = [IOR_EXTENSION]
    doc["materials"] = [material(params, name)]
    return doc


def write(params: dict, name: str, target_model: str) -> tuple[dict, dict[str, str], list[str]]:
    """The material (the glTF document), its files and the notes on them."""
    from brdffit import jsonout

    doc = document(params, name)
    notes = [IOR_NOTE] if "ior" in params else []
    return doc, {f"{name}.gltf": jsonout.dumps(doc, indent=1)}, notes
