"""MaterialX export: a ``gltf_pbr`` surface shader and its material (MaterialX 1.39).

Target model ``gltf_pbr`` (docs/models.md). MaterialX's standard library has the glTF
shading model as a node (``ND_gltf_pbr_surfaceshader``), whose inputs are glTF's
parameters under the same names, so the mapping is a copy:

    base_color = base_color,  metallic = metallic,  roughness = roughness

and ``ior = ior`` for a ``gltf_pbr_ior`` fit; the node's other inputs at their
defaults (ior 1.5, specular 1, no clearcoat, transmission, sheen or emission): the
gltf_pbr model's own assumptions.

What is not exact: MaterialX implements the node as a graph of its BSDF nodes, which
layers the dielectric lobe over the diffuse one by the lobe's directional albedo
rather than by glTF Appendix B's ``(1 - F)``; the parameters are glTF's exactly, the
shading agrees with the spec's formula only as closely as that graph does. The
export says so in its warnings.
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

TARGET_MODELS = ("gltf_pbr", "gltf_pbr_ior")
#: target model -> the model that evaluates the file as MaterialX shades it (None: not
#: modelled)
SHADED_AS = {m: None for m in TARGET_MODELS}
UNMODELLED_NOTE = ("fidelity: MaterialX's own shading of its gltf_pbr node is not modelled, "
                   "so log_rmse_to_table is not measured")
MEDIA_TYPE = "application/mtlx+xml"
SHADING_NOTE = ("MaterialX's gltf_pbr node layers its specular lobe over the diffuse by "
                "directional albedo, not glTF Appendix B's (1 - F): the parameters are exact, "
                "the shading there is MaterialX's approximation of the spec")


def _identifier(name: str) -> str:
    """A MaterialX element name: letters, digits and underscores, not starting with a digit."""
    out = "".join(c if c.isalnum() or c == "_" else "_" for c in name) or "brdffit"
    return out if not out[0].isdigit() else f"m_{out}"


def document(params: dict, name: str) -> str:
    """The MaterialX document (XML text) of ``gltf_pbr`` parameters."""
    ident = _identifier(name)
    shader = quoteattr("SR_" + ident)
    colour = ", ".join(repr(float(x)) for x in params["base_color"])
    return "\n".join([
        '<?xml version="1.0"?>',
        '<materialx version="1.39">',
        f'  <gltf_pbr name={shader} type="surfaceshader">',
        f'    <input name="base_color" type="color3" value="{colour}"/>',
        f'    <input name="metallic" type="float" value="{float(params["metallic"])!r}"/>',
        f'    <input name="roughness" type="float" value="{float(params["roughness"])!r}"/>',
        *([f'    <input name="ior" type="float" value="{float(params["ior"])!r}"/>']
          if "ior" in params else []),
        "  </gltf_pbr>",
        f'  <surfacematerial name={quoteattr("M_" + ident)} type="material">',
        f'    <input name="surfaceshader" type="surfaceshader" nodename={shader}/>',
        "  </surfacematerial>",
        "</materialx>",
        "",
    ])


def write(params: dict, name: str, target_model: str) -> tuple[str, dict[str, str], list[str]]:
    """The material (the XML text), its files and the notes on them."""
    text = document(params, name)
    return text, {f"{name}.mtlx": text}, [SHADING_NOTE]
